"""Stage 3 of the LSMTA system: surfaces measured in chosen frames, seeds found automatically.

For each frame: seed correspondences along the epipolar curves of the calibrated cameras
(:func:`~lsmta.matching.find_seeds`, searched over the depths where the cameras' optical
axes meet, from 0.6 to 1.6 times that distance), then region-growing LSM and the
neighbourhood filter (:func:`~lsmta.matching.measure_surface`) with the LSM thresholds of
notebook 03.

The a-posteriori ``sigma0`` limit follows the residual level the frame's images actually
give, measured two ways, and takes the larger:

* from the image noise ``sigma`` measured in the video (:func:`~lsmta.noise.temporal_noise`):
  ``sigma0_factor * sigma`` (notebook 03's rule, twice the noise);
* from the seeds: LSM (no thresholds) at every seed, and the median ``sigma0`` of those
  that converge, ``s``; the limit is ``sigma0_factor * s / sqrt(2)``.

Both give the same limit for uncompressed video with independent noise in every view (an
LSM residual holds both images' noise: ``s = sqrt(2) sigma``). A compressed video keeps a
still background's pixels the same from frame to frame, so its temporal noise says little
about the differences between two views (coding artefacts, differing sensors); the seeds,
the frame's best correspondences, measure them.

Which grid nodes are tried: by default (``texture_rule="spread"``) those whose main patch has
a grey-value spread of at least 2 grey levels, whatever the noise. With
``texture_rule="precision"`` (:class:`~lsmta.matching.GrowParams` ``noise``) it follows from
the measured noise and the accepted precision instead: a node is tried where its template
patch's gradients could give LSM a position standard deviation within ``max_sigma_xy`` with
residuals as small as the noise, ``sqrt(2) sigma / sqrt(lambda_min) <= max_sigma_xy``
(``lambda_min``: the smaller eigenvalue of the patch's gradient tensor, over the largest
patch tried). A node that fails it cannot pass the precision test; one that passes is tried
whatever its grey-value spread (a quiet camera's faint texture, which the spread rule skips:
``tests/test_growth_census.py``). It is not the default: with it, the generated walk's surfaces
changed and the walk fit of ``tests/test_walk_full_fit.py`` got worse (the left hip's worst
frame 10.6 degrees, the test asks under 7); on the Pose2Sim demo it tries more nodes and
measures as many points (``experiments/surface_demo.py``). Either way a node counts as measured only
where LSM converges and passes every threshold. :func:`surface_census` says where a frame's
nodes were lost.

``SurfaceParams(method="rectified")`` measures a two-camera group on its rectified images
instead (:mod:`lsmta.systems.rectified`); the default is unchanged. With
``rectified_start="sgbm"`` LSM starts at OpenCV SGBM's disparities instead of growing from
seeds (``experiments/surface_rectified_demo.py``). It costs more than the growth: every
measured frame runs SGBM and LSM (on the demo's full-size pairs about 10-20 s CPU per pair
per frame); SGBM's memory is bounded (:func:`~lsmta.matching.refine.sgbm_start`,
``max_bytes``). ``method="auto"`` decides per pair on the first measured frame
(:func:`grow_failed`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import cv2
import numpy as np
from tqdm.auto import tqdm

from .._validate import as_array, as_scalar
from ..matching import (
    DisparityParams,
    GrowParams,
    LSMParams,
    LSMThresholds,
    MeasureSurfaceParams,
    Status,
    SurfaceResult,
    find_seeds,
    lsm,
    measure_surface,
)
from ..matching.seeds import WARPS, camera_depth
from ..triangulation import triangulate
from .checks import check_cameras, check_videos
from .rectified import NoSeedsError, measure_rectified_pair, surface_result
from .subject import SubjectMaskParams, background, on_subject, subject_masks


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
        The LSM's ``max_sigma0`` is this many times the larger of the image noise and the
        seeds' own residual level over sqrt(2) (see the module docstring).
    max_sigma_xy : float
        Largest accepted standard deviation of a match, px.
    texture_rule : {"spread", "precision"}
        Which nodes are tried (module docstring): where the patch's grey-value spread is at
        least 2 grey levels, or where the noise allows the accepted precision.
    method : {"grow", "rectified", "auto"}
        ``"grow"`` (default): seeds and LSM growth between the original images, as above.
        ``"auto"``: for a two-camera group the growth on the first measured frame decides
        (:func:`grow_failed`: it matched fewer than ``auto_min_share`` of the template's
        textured nodes); where it failed every frame is measured with ``"rectified"``,
        ``rectified_start="sgbm"`` and ``rectified_geometry="shift"`` (with a warning;
        if that raises, the growth's result is kept, with a warning), else the growth
        measures the rest. Groups of three or more cameras: the growth.
        ``"rectified"``: two cameras only; the pair is rectified and its disparities grown
        (:func:`~lsmta.systems.rectified.measure_rectified_pair`, with
        :class:`~lsmta.matching.DisparityParams`' defaults and ``max_sigma_xy``; the other
        fields above are not used), matches mapped back to the original pixels.
    rectified_depths : (float, float)
        ``"rectified"`` only: the depths searched, as multiples of the working point's
        depth: they set the disparity range, so they bound both the seeds and the matches
        kept (narrower than :func:`~lsmta.systems.rectified.rectify_pair`'s default
        0.6-1.6: a wide pair's disparities over that range span more than the image, and
        the seeds' uniqueness test fails there).
    rectified_start : {"grow", "sgbm"}
        ``"rectified"`` only: ``"grow"`` (default) grows the disparities from seeds;
        ``"sgbm"`` starts LSM at every node where OpenCV's SGBM has a disparity (no growth;
        a node counts only where LSM converges and passes the thresholds).
    rectified_geometry : {"row-affine", "shift"}
        ``"rectified"`` only: the LSM's geometric model (``"shift"``: the disparity alone,
        fewer unknowns for blurred, weakly textured patches).
    auto_min_share : float
        ``"auto"`` only: the growth failed where it matches fewer than this share of the
        template's textured nodes (the growth's census, :func:`grow_failed`).
    seed_warp : {"auto", "identity", "predicted"}
        The growth's seeds: the search patch :func:`~lsmta.matching.find_seeds` correlates
        and LSM starts from. ``"auto"`` (default): the map the cameras predict for a search
        camera that sees the template's patch turned by more than
        :data:`~lsmta.matching.seeds.AUTO_TURN_DEG` (a camera mounted on its side) or scaled
        by more than :data:`~lsmta.matching.seeds.AUTO_SCALE` (beyond them the square patch
        no longer correlates, nor LSM pulls in from it), the square patch for the others (a
        rig whose cameras all stand the same way and see the subject at similar scales: as
        before).
    seed_spacing_mm : float or None
        Least distance between two seed candidates (Shi-Tomasi corners,
        :func:`~lsmta.matching.find_seeds`' ``min_distance``), as a length on the subject at
        the working distance: ``seed_spacing_mm * f / d`` px (the template camera's focal
        length ``f``, px, and the working distance ``d``, mm; at least 3 px). The growth
        reaches only what a matched seed's region connects to, so a part the corners
        skip (a hand or a foot smaller than their spacing) stays empty. None (default):
        25 px, whatever the scale (as before).
    subject_mask : SubjectMaskParams or None
        With it, every measured frame's n-tuples whose template pixel lies off the moving
        subject (:func:`~lsmta.systems.subject.subject_masks` of the videos given) are
        dropped and counted (``SurfaceResult.off_subject``), with a warning per frame where
        the template's mask is empty or drops every point. Default None: nothing dropped.
    """

    template: int = 1
    n_seeds: int = 40
    step: int = 4
    patch: int = 7
    retry_patch: tuple = (9, 5)
    sigma0_factor: float = 2.0
    max_sigma_xy: float = 0.2
    texture_rule: str = "spread"
    method: str = "grow"
    rectified_depths: tuple = (0.8, 1.25)
    rectified_start: str = "grow"
    rectified_geometry: str = "row-affine"
    subject_mask: SubjectMaskParams | None = None
    auto_min_share: float = 0.01
    seed_warp: str = "auto"
    seed_spacing_mm: float | None = None

    def __post_init__(self):
        if self.seed_spacing_mm is not None:
            if isinstance(self.seed_spacing_mm, bool):
                raise TypeError("seed_spacing_mm: expected a length in mm or None, got a bool")
            object.__setattr__(self, "seed_spacing_mm",
                               as_scalar(self.seed_spacing_mm, "seed_spacing_mm",
                                         positive=True))
        if self.seed_warp not in WARPS:
            raise ValueError(f"seed_warp: expected one of {list(WARPS)}, got "
                             f"{self.seed_warp!r}")
        if not 0.0 < self.auto_min_share < 1.0:
            raise ValueError(f"auto_min_share: expected a share in (0, 1), got "
                             f"{self.auto_min_share!r}")
        if self.subject_mask is not None and not isinstance(self.subject_mask,
                                                            SubjectMaskParams):
            raise TypeError(f"subject_mask: expected a SubjectMaskParams or None, got "
                            f"{type(self.subject_mask).__name__}")
        if self.method not in ("grow", "rectified", "auto"):
            raise ValueError(f"method: expected 'grow', 'rectified' or 'auto', got "
                             f"{self.method!r}")
        try:
            lo, hi = (float(d) for d in self.rectified_depths)
        except (TypeError, ValueError):
            raise ValueError(f"rectified_depths: expected two numbers (near, far), got "
                             f"{self.rectified_depths!r}") from None
        if not 0 < lo < hi:
            raise ValueError(f"rectified_depths: expected 0 < near < far, got "
                             f"{self.rectified_depths!r}")
        if self.rectified_start not in ("grow", "sgbm"):
            raise ValueError(f"rectified_start: expected 'grow' or 'sgbm', got "
                             f"{self.rectified_start!r}")
        if self.rectified_geometry not in ("row-affine", "shift"):
            raise ValueError(f"rectified_geometry: expected 'row-affine' or 'shift', got "
                             f"{self.rectified_geometry!r}")
        if self.texture_rule not in ("precision", "spread"):
            raise ValueError(f"texture_rule: expected 'precision' or 'spread', got "
                             f"{self.texture_rule!r}")


def working_distance(cameras, template: int) -> float:
    """Distance (mm) from the template camera to where the cameras' optical axes meet
    (their principal points intersected)."""
    xy = np.stack([[[c.cx, c.cy]] for c in cameras])                  # (K, 1, 2)
    X = triangulate(cameras, xy, min_angle_deg=0.0).points[0]
    if not np.isfinite(X).all():
        raise ValueError("cameras: their optical axes do not meet; cannot find the working "
                         "volume")
    return float(camera_depth(cameras[template], X))


def seed_spacing_px(camera, distance: float, spacing_mm: float | None) -> int:
    """Least distance between seed candidates, px: ``spacing_mm`` on the subject at
    ``distance`` mm from ``camera`` (``spacing_mm * f / distance``, at least 3 px); 25 px
    for None (:class:`SurfaceParams` ``seed_spacing_mm``)."""
    if spacing_mm is None:
        return 25
    spacing_mm = as_scalar(spacing_mm, "spacing_mm", positive=True)
    distance = as_scalar(distance, "distance", positive=True)
    return max(3, int(round(spacing_mm * camera.f / distance)))


def seed_residual(images, seeds_xy, *, template: int, patch: int, seeds_A=None) -> float:
    """Median a-posteriori sigma0 of LSM at the seeds (grey levels; NaN if none converged).

    Parameters
    ----------
    images : sequence of K (H, W) arrays
    seeds_xy : (K, S, 2) array
        The seeds in every image (the template row included).
    template : int
    patch : int
        LSM patch size, px.
    seeds_A : (K, S, 2, 2) array, optional
        LSM's starting affine maps (:attr:`~lsmta.matching.Seeds.A`); default identity.
    """
    seeds_xy = as_array(seeds_xy, "seeds_xy", shape=(len(images), None, 2), allow_nan=True)
    if seeds_A is not None:
        seeds_A = as_array(seeds_A, "seeds_A", shape=(len(images), seeds_xy.shape[1], 2, 2))
    f = np.asarray(images[template], float)
    sigma0 = []
    for k, g in enumerate(images):
        if k == template:
            continue
        r = lsm(f, np.asarray(g, float), seeds_xy[template], seeds_xy[k],
                initial_A=None if seeds_A is None else seeds_A[k],
                params=LSMParams(patch=patch))
        sigma0.append(r.sigma0[np.asarray(r.status) == Status.CONVERGED])
    s = np.concatenate(sigma0)
    return float(np.median(s)) if len(s) else float("nan")


def _lens_mask(camera):
    """``None`` when the camera's lens model can be inverted over its whole frame (checked
    every 8 px and along the border), else the ``(H, W)`` bool mask of the pixels where it
    can (a fitted distortion that folds over inside the frame has no ray past the fold)."""
    if not camera.has_distortion:
        return None
    W, H = camera.width, camera.height
    xs = np.unique(np.r_[np.arange(0, W, 8), W - 1]).astype(float)
    ys = np.unique(np.r_[np.arange(0, H, 8), H - 1]).astype(float)
    if camera.invertible(np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)).all():
        return None
    grid = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    return camera.invertible(grid.reshape(-1, 2)).reshape(H, W)


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
        Image noise, grey levels (e.g. :func:`~lsmta.noise.temporal_noise`); the sigma0
        limit is the larger of this rule and the seeds' (module docstring).
    params : SurfaceParams, optional
    progress : bool
        Show a progress bar over the frames.

    Returns
    -------
    dict of int -> SurfaceResult
        Frames without a seed are left out (with a warning). Template pixels where its lens
        model cannot be inverted are not grown into, and a match where a search camera's
        cannot is not triangulated (:func:`~lsmta.triangulation.triangulate`).
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
    if p.subject_mask is not None and v.shape[1] < 3:
        raise ValueError(f"videos: params.subject_mask needs at least 3 frames for the "
                         f"background median, got {v.shape[1]}")
    if p.method == "rectified":
        out = _rectified_surfaces(v, cams, frames, p, progress)
    elif p.method == "auto" and len(cams) == 2:
        out = _auto_surfaces(v, cams, frames, sigma, p, progress)
    else:
        out = _grown_surfaces(v, cams, frames, sigma, p, progress)
    return out if p.subject_mask is None else _masked(v, out, p)


def _auto_surfaces(v, cams, frames, sigma: float, p: SurfaceParams, progress: bool) -> dict:
    """``method="auto"`` for a pair: the growth until a frame is measured; where it failed
    there (:func:`grow_failed`) every frame on the rectified pair from SGBM's starts, else
    the growth for the rest. A rectified run that raises keeps the growth's result."""
    out: dict[int, SurfaceResult] = {}
    i = 0
    while i < len(frames) and not out:
        out = _grown_surfaces(v, cams, frames[i:i + 1], sigma, p, False)
        i += 1
    if not grow_failed(out, min_share=p.auto_min_share):
        out.update(_grown_surfaces(v, cams, frames[i:], sigma, p, progress))
        return out
    warnings.warn("measure_surfaces: the growth matched fewer than "
                  f"{p.auto_min_share:.0%} of the template's textured nodes in its first "
                  "measured frame (SurfaceParams(method='auto')); the pair is measured on its "
                  "rectified images from SGBM's starts instead", stacklevel=3)
    try:
        return _rectified_surfaces(v, cams, frames, replace(
            p, rectified_start="sgbm", rectified_geometry="shift"), progress)
    except (ValueError, cv2.error, np.linalg.LinAlgError, MemoryError) as err:
        warnings.warn(f"measure_surfaces: the rectified pair failed ({type(err).__name__}: "
                      f"{str(err).splitlines()[0] if str(err) else ''}); "
                      "SurfaceParams(method='auto') keeps the growth's result", stacklevel=3)
        out.update(_grown_surfaces(v, cams, frames[i:], sigma, p, progress))
        return out


def _masked(v, out: dict, p: SurfaceParams) -> dict:
    """Every frame's result on the template's subject mask, with a warning where the mask
    is empty or drops every point (subject.py's docstring: where it fails)."""
    bg = background(v, params=p.subject_mask)            # once for every frame
    masked = {}
    for f, r in out.items():
        mask = subject_masks(v, f, params=p.subject_mask, background=bg).masks[p.template]
        masked[f] = m = on_subject(r, mask, template=p.template)
        if not mask.any():
            why = "is empty (nothing moves against the background)"
        elif r.kept.any() and not m.kept.any():
            why = f"drops every point ({int(r.kept.sum())})"
        else:
            continue
        warnings.warn(f"measure_surfaces: frame {f}: the template view's subject mask "
                      f"(SurfaceParams.subject_mask, lsmta capture --subject-mask) {why}; a "
                      "still recording, or a subject filling most of the frame, has no mask "
                      "to find: measure without it", stacklevel=3)
    return masked


def grow_failed(surfaces: dict, *, min_share: float = 0.01) -> bool:
    """Whether the growth failed: in its first measured frame it matched fewer than
    ``min_share`` of the template's textured nodes (the growth's own census of the first
    search image, :func:`surface_census`: ``matched`` against the nodes that were neither
    outside, masked nor without texture), or no frame has a seed.

    Parameters
    ----------
    surfaces : dict of int -> SurfaceResult
        :func:`measure_surfaces`' growth results.
    min_share : float
        The share of textured nodes below which the growth failed.

    Returns
    -------
    bool
        True where the growth failed (or nothing was measured).
    """
    if not surfaces:
        return True
    nodes = surfaces[min(surfaces)].grown[0].node_census
    textured = sum(v for k, v in nodes.items() if k not in ("outside", "masked", "no_texture"))
    return nodes["matched"] < min_share * max(textured, 1)


def _grown_surfaces(v, cams, frames, sigma: float, p: SurfaceParams, progress: bool) -> dict:
    """:func:`measure_surfaces` with ``method="grow"`` (module docstring)."""
    d = working_distance(cams, p.template)
    spacing = seed_spacing_px(cams[p.template], d, p.seed_spacing_mm)
    mask = _lens_mask(cams[p.template])
    noise = sigma if p.texture_rule == "precision" else None
    out: dict[int, SurfaceResult] = {}
    missed = []
    for f in tqdm(frames, desc="surfaces", disable=not progress):
        seeds = find_seeds(v[:, f], cams, template=p.template, n_seeds=p.n_seeds,
                           depth_range=(0.6 * d, 1.6 * d), warp=p.seed_warp,
                           min_distance=spacing)
        if seeds.xy.shape[1] == 0:
            missed.append(f)
            continue
        level = seed_residual(v[:, f], seeds.xy, template=p.template, patch=p.patch,
                              seeds_A=seeds.A)
        limit = p.sigma0_factor * max(sigma, np.nan_to_num(level / np.sqrt(2)))
        thresholds = LSMThresholds(max_sigma0=limit, max_displacement=p.step,
                                   max_sigma_xy=p.max_sigma_xy, scale_range=(0.5, 2.0),
                                   max_shear=0.5)
        surface = MeasureSurfaceParams(grow=GrowParams(step=p.step, patch=p.patch,
                                                       retry_patch=p.retry_patch,
                                                       thresholds=thresholds, noise=noise))
        out[f] = measure_surface(v[:, f], cams, seeds.xy, template=p.template, mask=mask,
                                 seeds_A=seeds.A, params=surface)
    if missed:                                  # one warning for all of them
        where = (f"frame {missed[0]}" if len(missed) == 1 else
                 f"frames {', '.join(map(str, missed))} ({len(missed)} of {len(frames)})")
        warnings.warn(f"measure_surfaces: no seed found in {where}: no textured point "
                      "matches along the epipolar curves in every camera; "
                      + ("the frame is" if len(missed) == 1 else "they are") + " left out",
                      stacklevel=3)
    return out


def _rectified_surfaces(v, cams, frames, p: SurfaceParams, progress: bool) -> dict:
    """:func:`measure_surfaces` with ``method="rectified"`` (see :class:`SurfaceParams`)."""
    if len(cams) != 2:
        raise ValueError(f"cameras: SurfaceParams(method='rectified') (lsmta capture "
                         f"--surface-method rectified-sgbm) measures a pair; expected 2 "
                         f"cameras, got {len(cams)} (capture_recording measures such a view "
                         "group by the growth)")
    xy = np.stack([[[c.cx, c.cy]] for c in cams])
    point = triangulate(cams, xy, min_angle_deg=0.0).points[0]
    if not np.isfinite(point).all():
        raise ValueError("cameras: their optical axes do not meet; cannot find the working "
                         "volume")
    base = DisparityParams().grow_params()
    grow = replace(base, geometry=p.rectified_geometry,
                   thresholds=replace(base.thresholds, max_sigma_xy=p.max_sigma_xy))
    out: dict[int, SurfaceResult] = {}
    for f in tqdm(frames, desc="surfaces", disable=not progress):
        try:
            r = measure_rectified_pair(v[0, f], v[1, f], cams[0], cams[1], working_point=point,
                                       depth_range=p.rectified_depths,
                                       start=p.rectified_start,
                                       params=DisparityParams(grow=grow))
        except NoSeedsError:
            warnings.warn(f"measure_surfaces: no seed found in frame {f} on the rectified "
                          "pair; the frame is left out", stacklevel=3)
            continue
        out[f] = surface_result(r, template=p.template)
    return out


def surface_census(result: SurfaceResult) -> dict:
    """Where a frame's surface lost its nodes, stage by stage (numbers that add up).

    Parameters
    ----------
    result : SurfaceResult

    Returns
    -------
    dict
        ``growth``: per search image, ``seeds`` and ``seeds_matched``, ``attempts`` (every
        LSM attempt by outcome, :data:`~lsmta.matching.grow.ATTEMPT_OUTCOMES`, adding up to
        its ``n_lsm``) and ``nodes`` (every grid node by outcome,
        :data:`~lsmta.matching.grow.NODE_OUTCOMES`); then the n-tuples (nodes matched in
        every search image): ``tuples`` = ``neighbourhood_dropped`` + ``not_intersected``
        + ``kept``.
    """
    ok, valid = result.neighbourhood_ok, result.intersection.valid
    return {"growth": [{"seeds": int(len(g.seeds_matched)),
                        "seeds_matched": int(np.sum(g.seeds_matched)),
                        "attempts": dict(g.attempt_census), "nodes": dict(g.node_census)}
                       for g in result.grown],
            "tuples": int(len(ok)), "neighbourhood_dropped": int((~ok).sum()),
            "not_intersected": int((ok & ~valid).sum()), "kept": int((ok & valid).sum())}
