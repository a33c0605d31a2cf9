"""True silhouettes of the body, and the empty scene (for background models).

The true silhouette of a camera is the set of sample rays that hit the body, on an
``s x s`` grid inside every pixel (:meth:`lsmta.camera.Camera.pixel_grid`): a mask ``s``
times finer than the image whose outline is the true contour to about ``1 / (2 s)``
pixels. Nothing in front of the body hides it in the generated world (the wall is behind
it, the floor below), so every body hit belongs to the silhouette.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_int
from ..camera import Camera
from .body import Body, Motion
from .render import Scene, cast_body


def true_silhouettes(scene: Scene, cameras, frames, *, supersample: int = 4) -> np.ndarray:
    """Masks ``(T, K, H s, W s)`` bool of the rays through ``s x s`` points per pixel that
    hit the body in each of ``frames`` (int or sequence of T ints); sample ``(i, j)`` lies
    at pixel ``x = (j + 0.5) / s - 0.5``, ``y = (i + 0.5) / s - 0.5``."""
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    as_int(supersample, "supersample")
    poses = scene.body.part_poses(scene.motion, frames=frames)         # (T, P, 4, 4)
    masks = []
    for cam in cameras:
        grid = cam.pixel_grid(supersample=int(supersample))
        _, dirs = cam.rays(grid.reshape(-1, 2))                          # once per camera
        masks.append([np.isfinite(cast_body(scene.body, p, cam.C, dirs).t)
                      .reshape(grid.shape[:2]) for p in poses])
    return np.stack([np.stack(m) for m in masks], axis=1)


def empty_scene(scene: Scene) -> Scene:
    """The same scene (background, light, motion's length and rate) without the person:
    for filming the empty studio."""
    T = scene.motion.n_frames
    body = Body(parts=(), texture=scene.body.texture)
    motion = Motion(name="empty", fps=scene.motion.fps, root_position=np.zeros((T, 3)),
                    joint_angles=np.zeros((T, 0, 3)), part_names=())
    return Scene(body=body, motion=motion, background=scene.background, light=scene.light,
                 ambient=scene.ambient, backdrop=scene.backdrop)
