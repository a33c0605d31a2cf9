"""Rendered multi-camera sequences for tracking, with the truth of every surface point.

A tracked point is a body-local surface point ``(part, local)``: its true image positions
and 3-D positions in every frame come from :func:`~lsmta.synth.render.project_surface_points`,
so a tracker's trajectory can be compared with the point it started on, frame by frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validate import as_rng
from .render import Renderer, Scene, SurfaceProjection, project_surface_points


@dataclass(frozen=True, eq=False)
class SurfacePoints:
    """Body surface points seen by every camera in one frame.

    Attributes
    ----------
    frame : int
    part : (M,) int array
    local : (M, 3) array
        Part-local coordinates (mm).
    xy : (K, M, 2) array
        True image positions in that frame (pixels).
    """

    frame: int
    part: np.ndarray
    local: np.ndarray
    xy: np.ndarray


@dataclass(frozen=True, eq=False)
class Sequence:
    """A rendered sequence of K cameras.

    Attributes
    ----------
    scene : Scene
    cameras : list of Camera
    images : (K, T, H, W) uint8 array
    surface : dict of int -> SurfacePoints
        Visible surface points on the template image's grid, for the frames asked for.
    """

    scene: Scene
    cameras: list
    images: np.ndarray
    surface: dict

    @property
    def fps(self) -> float:
        return float(self.scene.motion.fps)

    def truth(self, part, local) -> SurfaceProjection:
        """True image positions ``(T, K, N, 2)``, visibility and 3-D positions of points."""
        return project_surface_points(self.scene, self.cameras, part, local)


def render_sequence(scene: Scene, cameras, *, rng: np.random.Generator | int | None = None,
                    noise_sigma: float = 2.0, supersample: int = 1, surface_frames=(0,),
                    template: int = 1, step: int = 4, margin: int = 6) -> Sequence:
    """Render every frame of ``scene`` in ``cameras``, and sample visible surface points.

    Parameters
    ----------
    scene : Scene
    cameras : sequence of K Camera
    rng : numpy.random.Generator, int or None
        Draws the image noise.
    noise_sigma : float
        Image noise, grey levels.
    supersample : int
        Rays per pixel side (odd).
    surface_frames : iterable of int
        Frames whose surface points are sampled: grid nodes (every ``step`` pixels) of the
        template image whose ``2 margin + 1`` window lies on the body and whose surface
        point every camera sees.
    template : int
        The template camera (for K = 1, use 0).
    """
    rng = as_rng(rng)
    cameras = list(cameras)
    renderer = Renderer(scene, cameras, supersample=supersample, noise_sigma=noise_sigma)
    T = scene.motion.n_frames
    wanted = set(int(f) for f in surface_frames)
    images, surface = [], {}
    for t in range(T):
        fr = renderer.render(t, rng=rng)
        images.append(fr.images)
        if t in wanted:
            pid = fr.part_id[template]
            inner = ndimage.minimum_filter(pid, size=2 * margin + 1, mode="constant",
                                           cval=-2) >= 0
            grid = np.zeros_like(inner)
            grid[::step, ::step] = True
            rr, cc = np.nonzero(inner & grid)
            part = pid[rr, cc].astype(np.int64)
            local = fr.local_xyz[template][rr, cc]
            proj = project_surface_points(scene, cameras, part, local, frames=t)
            seen = proj.visible[0].all(axis=0)
            surface[t] = SurfacePoints(frame=t, part=part[seen], local=local[seen],
                                       xy=proj.xy[0][:, seen])
    return Sequence(scene=scene, cameras=cameras, images=np.stack(images, axis=1),
                    surface=surface)
