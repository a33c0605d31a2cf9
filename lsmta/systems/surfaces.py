"""Stage 3 of the LSMTA system: surfaces measured in chosen frames, seeds found automatically.

For each frame: seed correspondences along the epipolar curves of the calibrated cameras
(:func:`~lsmta.matching.find_seeds`, searched over the depths where the cameras' optical
axes meet, from 0.6 to 1.6 times that distance), then region-growing LSM and the
neighbourhood filter (:func:`~lsmta.matching.measure_surface`) with the LSM thresholds of
notebook 03, whose a-posteriori ``sigma0`` limit is twice the image noise measured in the
video (:func:`~lsmta.noise.temporal_noise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from .._validate import as_scalar
from ..matching import (
    GrowParams,
    LSMThresholds,
    MeasureSurfaceParams,
    SurfaceResult,
    find_seeds,
    measure_surface,
)
from ..triangulation import triangulate
from .checks import check_cameras, check_videos


@dataclass(frozen=True)
class SurfaceParams:
    """Settings of the surface measurement (notebook 03's, with the automatic seeds).

    Attributes
    ----------
    template : int
        Template camera (the centre camera of the triplet).
    n_seeds : int
        Seeds per frame (:func:`~lsmta.matching.find_seeds`).
    step, patch : int
        Grid spacing and LSM patch, px.
    retry_patch : tuple of int
        Patches of the retries.
    sigma0_factor : float
        The LSM's ``max_sigma0`` is this many times the image noise.
    max_sigma_xy : float
        Largest accepted standard deviation of a match, px.
    """

    template: int = 1
    n_seeds: int = 40
    step: int = 4
    patch: int = 7
    retry_patch: tuple = (9, 5)
    sigma0_factor: float = 2.0
    max_sigma_xy: float = 0.2


def working_distance(cameras, template: int) -> float:
    """Distance (mm) from the template camera to where the cameras' optical axes meet
    (their principal points intersected)."""
    xy = np.stack([[[c.cx, c.cy]] for c in cameras])                  # (K, 1, 2)
    X = triangulate(cameras, xy, min_angle_deg=0.0).points[0]
    if not np.isfinite(X).all():
        raise ValueError("cameras: their optical axes do not meet; cannot find the working "
                         "volume")
    return float((X - cameras[template].C) @ cameras[template].R[2])


def measure_surfaces(videos, cameras, frames, *, sigma: float,
                     params: SurfaceParams | None = None,
                     progress: bool = False) -> dict:
    """Measure the surface in the given frames of K synchronised videos.

    Parameters
    ----------
    videos : (K, T, H, W) array
        Grey frames.
    cameras : sequence of K Camera
        Calibrated cameras.
    frames : iterable of int
        Frames to measure.
    sigma : float
        Image noise, grey levels (e.g. :func:`~lsmta.noise.temporal_noise`).
    params : SurfaceParams, optional
    progress : bool
        Show a progress bar over the frames.

    Returns
    -------
    dict of int -> SurfaceResult
    """
    cams = check_cameras(cameras, "cameras")
    v = check_videos(videos, "videos", cams, min_frames=1)
    p = params or SurfaceParams()
    sigma = as_scalar(sigma, "sigma", positive=True)
    if not 0 <= p.template < len(cams):
        raise ValueError(f"params.template: expected a camera index in [0, {len(cams) - 1}], "
                         f"got {p.template}")
    frames = [int(f) for f in frames]
    bad = [f for f in frames if not 0 <= f < v.shape[1]]
    if bad:
        raise ValueError(f"frames: expected frame indices in [0, {v.shape[1] - 1}], got {bad}")
    d = working_distance(cams, p.template)
    thresholds = LSMThresholds(max_sigma0=p.sigma0_factor * sigma, max_displacement=p.step,
                               max_sigma_xy=p.max_sigma_xy, scale_range=(0.5, 2.0),
                               max_shear=0.5)
    surface = MeasureSurfaceParams(grow=GrowParams(step=p.step, patch=p.patch,
                                                   retry_patch=p.retry_patch,
                                                   thresholds=thresholds))
    out: dict[int, SurfaceResult] = {}
    for f in tqdm(frames, desc="surfaces", disable=not progress):
        seeds = find_seeds(v[:, f], cams, template=p.template, n_seeds=p.n_seeds,
                           depth_range=(0.6 * d, 1.6 * d))
        if seeds.xy.shape[1] == 0:
            raise ValueError(f"videos: no seed found in frame {f} (no textured point matches "
                             "along the epipolar curves); check the calibration")
        out[f] = measure_surface(v[:, f], cams, seeds.xy, template=p.template, params=surface)
    return out
