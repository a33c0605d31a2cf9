"""The moving subject's pixels, found in the recording itself (no truth, no model).

Each view's frame is compared with the per-pixel temporal median of sampled frames of the
same view (the static room: a pixel the subject covers in few of the sampled frames keeps
its background value in the median). The rule for the threshold comes from the data:

* the robust temporal noise ``s = 1.4826 * median |frame - median|`` over the whole image
  (most pixels are static background, so the median absolute deviation measures their
  noise; floored at ``min_noise`` grey levels, since a compressed video's still pixels are
  often identical frame to frame);
* a pixel moves where ``|frame - median| > factor * s`` (default 10: the demo's robust
  noise is 1.5 grey levels, so about 15; compression noise has heavy tails, and isolated
  false alarms are removed below).

The moving pixels are cleaned morphologically: opened (``open_px``: specks go), closed
(``close_px``: the subject's uniform clothing, which differs little from the background
inside, is filled), components smaller than ``min_share`` of the largest dropped, then
dilated by ``grow_px`` (the subject's rim, where a patch still rests on it). Anything else
that moves (a treadmill belt, a shadow) is kept too: the mask says "moving", not "person".

Where it fails: a recording where nothing moves gives an empty mask, and a subject that
fills more than half the frame inflates the median-based noise (the threshold rises, the
mask shrinks); either can drop every surface point, so
:func:`~lsmta.systems.surfaces.measure_surfaces` warns per view group when a mask is empty
or drops every point. The radii are in pixels of the frames given: for frames resized by
``s`` scale ``close_px`` and ``grow_px`` by ``s`` (``lsmta capture --scale`` does).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_int, as_scalar
from ..matching import SurfaceResult
from ..triangulation import Intersection


@dataclass(frozen=True)
class SubjectMaskParams:
    """Settings of :func:`subject_masks` (module docstring).

    Attributes
    ----------
    every : int
        Sample every this many frames for the temporal median.
    max_samples : int
        At most this many sampled frames (evenly spread).
    factor : float
        Threshold in multiples of the robust temporal noise.
    min_noise : float
        Floor of the robust noise, grey levels.
    open_px, close_px, grow_px : int
        Radii of the opening, closing and final dilation, px.
    min_share : float
        Components smaller than this share of the largest are dropped.
    """

    every: int = 5
    max_samples: int = 21
    factor: float = 10.0
    min_noise: float = 1.0
    open_px: int = 1
    close_px: int = 15
    grow_px: int = 15
    min_share: float = 0.1

    def __post_init__(self):
        as_int(self.every, "every", minimum=1)
        as_int(self.max_samples, "max_samples", minimum=3)
        as_scalar(self.factor, "factor", positive=True)
        as_scalar(self.min_noise, "min_noise", positive=True)
        for name in ("open_px", "close_px", "grow_px"):
            as_int(getattr(self, name), name, minimum=0)
        if not 0.0 <= self.min_share <= 1.0:
            raise ValueError(f"min_share: expected a share in [0, 1], got {self.min_share!r}")


@dataclass(frozen=True)
class SubjectMasks:
    """The moving subject's pixels in one frame of K views.

    Attributes
    ----------
    masks : (K, H, W) bool array
    noise : (K,) array
        Robust temporal noise per view, grey levels.
    threshold : (K,) array
        The threshold used per view, grey levels.
    samples : (S,) int array
        The frames whose median is the background.
    """

    masks: np.ndarray
    noise: np.ndarray
    threshold: np.ndarray
    samples: np.ndarray


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _clean(moving: np.ndarray, p: SubjectMaskParams) -> np.ndarray:
    m = moving.astype(np.uint8)
    if p.open_px:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _disk(p.open_px))
    if p.close_px:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, _disk(p.close_px))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n > 1:
        area = stats[1:, cv2.CC_STAT_AREA]
        keep = np.r_[False, area >= p.min_share * area.max()]
        m = keep[labels].astype(np.uint8)
    if p.grow_px:
        m = cv2.dilate(m, _disk(p.grow_px))
    return m.astype(bool)


def _checked(videos, params):
    p = params or SubjectMaskParams()
    if not isinstance(p, SubjectMaskParams):
        raise TypeError(f"params: expected a SubjectMaskParams, got {type(p).__name__}")
    v = np.asarray(videos)
    if v.ndim != 4 or v.shape[1] < 3:
        raise ValueError(f"videos: expected (K, T, H, W) frames with T >= 3, got shape "
                         f"{v.shape}")
    return v, p


def _median_of(v, p: SubjectMaskParams) -> tuple:
    samples = np.arange(0, v.shape[1], p.every)
    if len(samples) < 3:
        samples = np.arange(v.shape[1])
    if len(samples) > p.max_samples:
        samples = samples[np.linspace(0, len(samples) - 1, p.max_samples).round().astype(int)]
    median = np.stack([np.median(v[k, samples], axis=0) for k in range(v.shape[0])])
    return median.astype(np.float32), samples


def background(videos, *, params: SubjectMaskParams | None = None) -> tuple:
    """The static background of every view: the per-pixel median of the sampled frames.

    Parameters
    ----------
    videos : (K, T, H, W) array
        Grey frames of K views (T >= 3).
    params : SubjectMaskParams, optional

    Returns
    -------
    median : (K, H, W) float32 array
    samples : (S,) int array
        The frames sampled (every ``params.every``-th, at most ``max_samples``; all when
        that leaves fewer than 3).
    """
    v, p = _checked(videos, params)
    return _median_of(v, p)


def subject_masks(videos, frame: int, *, params: SubjectMaskParams | None = None,
                  background=None) -> SubjectMasks:
    """The moving subject's pixels in ``frame`` of every view (module docstring).

    Parameters
    ----------
    videos : (K, T, H, W) array
        Grey frames of K views (T >= 3).
    frame : int
        The frame to mask.
    params : SubjectMaskParams, optional
    background : (median, samples), optional
        What :func:`background` returns for the same videos and params, to reuse over
        several frames.

    Returns
    -------
    SubjectMasks
    """
    v, p = _checked(videos, params)
    frame = as_int(frame, "frame", minimum=0)
    if not 0 <= frame < v.shape[1]:
        raise ValueError(f"frame: expected a frame index in [0, {v.shape[1] - 1}], got {frame}")
    bg, samples = _median_of(v, p) if background is None else background
    if np.shape(bg) != (v.shape[0],) + v.shape[2:]:
        raise ValueError(f"background: expected a median of shape {(v.shape[0],) + v.shape[2:]}, "
                         f"got {np.shape(bg)}")
    masks, noise, thresholds = [], [], []
    for k in range(v.shape[0]):
        d = np.abs(v[k, frame].astype(np.float32) - bg[k])
        s = max(1.4826 * float(np.median(d)), p.min_noise)
        masks.append(_clean(d > p.factor * s, p))
        noise.append(s)
        thresholds.append(p.factor * s)
    return SubjectMasks(masks=np.stack(masks), noise=np.array(noise),
                        threshold=np.array(thresholds), samples=samples)


def on_subject(result: SurfaceResult, mask, *, template: int) -> SurfaceResult:
    """``result`` without the n-tuples (and points) whose template pixel lies off ``mask``.

    Parameters
    ----------
    result : SurfaceResult
    mask : (H, W) bool array
        The template view's subject mask (:func:`subject_masks`).
    template : int
        The template's row in ``result.xy``.

    Returns
    -------
    SurfaceResult
        A new result; ``off_subject`` counts the n-tuples dropped (kept ones among them
        included), ``grown`` is left as measured.

    Raises
    ------
    ValueError
        For a result thinned to a voxel cloud (``result.cloud``): its voxels average
        n-tuples on and off the mask, so it is refused rather than left indexing n-tuples
        that are gone (measure without ``voxel``, then thin).
    """
    if result.cloud is not None:
        raise ValueError("result: a surface thinned to a voxel cloud (result.cloud is set) "
                         "cannot be filtered by a subject mask; measure it without voxel")
    m = np.asarray(mask, bool)
    if m.ndim != 2:
        raise ValueError(f"mask: expected an (H, W) bool array, got shape {m.shape}")

    def inside(xy):
        ij = np.rint(np.nan_to_num(xy, nan=-1.0)).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < m.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < m.shape[0])
        out = np.zeros(len(ij), bool)
        out[ok] = m[ij[ok, 1], ij[ok, 0]]
        return out

    keep = inside(result.template_xy)
    it = result.intersection
    inter = Intersection(
        points=it.points[keep], valid=it.valid[keep], n_rays=it.n_rays[keep],
        angle_deg=it.angle_deg[keep], ray_distance=it.ray_distance[:, keep],
        reprojection_error=None if it.reprojection_error is None
        else it.reprojection_error[:, keep])
    pts = inside(result.points_xy[template])
    return SurfaceResult(grown=result.grown, template_xy=result.template_xy[keep],
                         xy=result.xy[:, keep], sigma_xy=result.sigma_xy[:, keep],
                         neighbourhood_ok=result.neighbourhood_ok[keep],
                         rematched=result.rematched[keep], intersection=inter,
                         cloud=None,
                         points=result.points[pts], points_xy=result.points_xy[:, pts],
                         off_subject=result.off_subject + int((~keep).sum()))
