"""Pieces of the mixed-scale system's close-up stages (:func:`~lsmta.systems.
capture_mixed_scale`): the frame from which the face markers are tracked, and where lost
markers may start again (the filled face projected into each head, on a dot)."""

from __future__ import annotations

import numpy as np

from .._validate import as_array, as_scalar
from ..pantilt import PanTiltCamera


def first_settled(times, head_since, settle: float) -> int:
    """The first frame at which the heads have been aimed at the same target for
    ``settle`` s (``head_since``: when the frame's head target became the head, NaN for
    none), or 0 when there is none."""
    with np.errstate(invalid="ignore"):
        ok = np.flatnonzero(np.asarray(times) - np.asarray(head_since) >= settle)
    return int(ok[0]) if len(ok) else 0


_NINE = np.stack(np.meshgrid(np.arange(-4, 5), np.arange(-4, 5)), -1).reshape(-1, 2)  # (x, y)


def reacquisition_seeds(images, heads, settings, face, found, *, dot_contrast: float = 30.0,
                        crowd_px: float = 6.0) -> np.ndarray:
    """Where lost markers may start again: the filled face projected into each head.

    Parameters
    ----------
    images : (K, F, H, W) array
    heads : sequence of K PanTiltCamera
        As calibrated.
    settings : (K, F, 2) array
        Read-back angles, degrees.
    face : (F, M, 3) array
        The filled face, mm (NaN where not fitted).
    found : (K, F, M) bool array
        Markers the tracker has in each frame (they are not restarted).
    dot_contrast : float
        The image at the projection must exceed the median of its 9 x 9 neighbourhood by
        this many grey levels (a dot, not skin; a marker turned away draws none).
    crowd_px : float
        Projections closer than this to another one are not used (their dots merge).

    Returns
    -------
    (K, F, M, 2) array
        Seeds for :func:`~lsmta.tracking.markers.track_markers`, px (NaN elsewhere).
    """
    if np.ndim(images) != 4:
        raise ValueError(f"images: expected an array of shape (K, F, H, W), got shape "
                         f"{np.shape(images)}")
    K, F, H, W = np.shape(images)
    heads = list(heads)
    if len(heads) != K or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError(f"heads: expected {K} lsmta.pantilt.PanTiltCamera (one per image "
                        "sequence)")
    settings = as_array(settings, "settings", shape=(K, F, 2))
    face = as_array(face, "face", shape=(F, None, 3), allow_nan=True)
    M = face.shape[1]
    found = np.asarray(found)
    if found.dtype != bool or found.shape != (K, F, M):
        raise ValueError(f"found: expected a bool array of shape ({K}, {F}, {M}), got "
                         f"{found.dtype} {found.shape}")
    as_scalar(dot_contrast, "dot_contrast", nonnegative=True)
    as_scalar(crowd_px, "crowd_px", nonnegative=True)
    seeds = np.full((K, F, M, 2), np.nan)
    for k, head in enumerate(heads):
        for f in np.flatnonzero(np.isfinite(face).all(axis=(1, 2))):
            cam = head.camera_at(*settings[k, f])
            p = cam.project(face[f], behind="nan")
            finite = np.isfinite(p).all(axis=1)
            d = np.nan_to_num(np.linalg.norm(p[:, None] - p[None], axis=2), nan=np.inf)
            np.fill_diagonal(d, np.inf)
            c = np.rint(np.where(finite[:, None], p, -100.0)).astype(int)
            ok = finite & ~found[k, f] & (c[:, 0] >= 4) & (c[:, 0] < W - 4) & (c[:, 1] >= 4) \
                & (c[:, 1] < H - 4) & (d.min(axis=1) >= crowd_px)
            m = np.flatnonzero(ok)
            patch = images[k, f][c[m, 1, None] + _NINE[:, 1], c[m, 0, None] + _NINE[:, 0]]
            dot = patch[:, 40].astype(float) - np.median(patch, axis=1) >= dot_contrast
            seeds[k, f, m[dot]] = p[m[dot]]
    return seeds
