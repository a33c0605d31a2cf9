# Environment for off-screen rendering; sourced by the scripts (and by hand before `jupyter lab`).
export PYVISTA_OFF_SCREEN=true
export VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow
export PYDEVD_DISABLE_FILE_VALIDATION=1
