# Environment for off-screen rendering and quiet, deterministic runs; sourced by the scripts.
export PYVISTA_OFF_SCREEN=true
export VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow
export MPLBACKEND=Agg
export PYDEVD_DISABLE_FILE_VALIDATION=1
