"""Normalised cross-correlation search: the step before LSM in tracking.

For each point, the template patch is correlated with every position of a square search
box around a predicted position (OpenCV's ``matchTemplate`` with ``TM_CCOEFF_NORMED``
computes the scores), and the best position is refined to sub-pixel precision by fitting
a parabola through the peak and its neighbours, separately in x and y.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_int, as_point_pairs, check_patch
from .spline import SplineImage, check_image


class CorrelationStatus(enum.IntEnum):
    """Outcome of the search for one point."""

    OK = 0          #: peak inside the box, refined to sub-pixel
    AT_BORDER = 1   #: best score on the edge of the box: the true peak may lie outside
    OUTSIDE = 2     #: the template patch or the search box does not fit in its image
    FLAT = 3        #: no texture: the normalised correlation is undefined


@dataclass(frozen=True)
class CorrelationResult:
    """Best normalised cross-correlation positions of N patches.

    Attributes
    ----------
    xy : (N, 2) array
        Sub-pixel position of the best match in the search image (NaN when OUTSIDE/FLAT).
    score : (N,) array
        Correlation coefficient at the integer peak, in [-1, 1].
    status : (N,) int array
        :class:`CorrelationStatus` codes.
    """

    xy: np.ndarray
    score: np.ndarray
    status: np.ndarray


def correlation_search(template, search, template_xy, predicted_xy, *, patch: int = 13,
                       radius: int = 8) -> CorrelationResult:
    """Find each template patch in a box around its predicted position in the search image.

    Parameters
    ----------
    template, search : (H, W) arrays
        Grey images of any real dtype.
    template_xy : (N, 2) array
        Patch centres in the template (pixels; sub-pixel centres are resampled with the
        cubic spline).
    predicted_xy : (N, 2) array
        Predicted positions in the search image (pixels); the box spans
        ``round(predicted) +- radius`` pixels.
    patch : int
        Odd patch size, at least 5.
    radius : int
        Half-width of the search box in pixels (>= 1).

    Returns
    -------
    CorrelationResult
    """
    patch = check_patch(patch)
    radius = as_int(radius, "radius", unit="pixels")
    f = check_image(template, "template")
    g = check_image(search, "search")
    t_xy, p_xy = as_point_pairs(template_xy, predicted_xy, "template_xy", "predicted_xy")
    n = len(t_xy)
    h = patch // 2
    spline = SplineImage(f, "template")
    fits = spline.inside(t_xy, margin=h)
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    patches = np.zeros((n, patch, patch), dtype=np.float32)
    if fits.any():
        pts = t_xy[fits, None, None, :] + np.stack([gx, gy], axis=-1)[None].astype(float)
        patches[fits] = spline.sample(pts, gradient=False)

    return search_patches(patches, g, p_xy, radius, valid=fits)


def search_patches(patches, search, predicted_xy, radius: int, *, valid=None
                   ) -> CorrelationResult:
    """The box search of :func:`correlation_search` for patches already sampled.

    Parameters
    ----------
    patches : (N, patch, patch) float32 array
        Template patches (odd size).
    search : (H, W) array
        Search image, real dtype (each box is read as float32, as OpenCV correlates it).
    predicted_xy : (N, 2) array
        Predicted positions in ``search``, px.
    radius : int
        Half-width of the search box, px.
    valid : (N,) bool array, optional
        Patches that exist (the others are OUTSIDE); default all.

    Returns
    -------
    CorrelationResult
    """
    n, patch = len(patches), patches.shape[1]
    h = patch // 2
    valid = np.ones(n, bool) if valid is None else valid
    xy = np.full((n, 2), np.nan)
    score = np.full(n, np.nan)
    status = np.full(n, CorrelationStatus.OUTSIDE, dtype=np.int64)
    centre = np.rint(predicted_xy).astype(np.int64)
    H, W = search.shape
    reach = radius + h
    box_fits = ((centre[:, 0] - reach >= 0) & (centre[:, 0] + reach <= W - 1)
                & (centre[:, 1] - reach >= 0) & (centre[:, 1] + reach <= H - 1))
    todo = np.flatnonzero(valid & box_fits)
    flat_patch = _flat_rows(patches[todo].reshape(len(todo), patch * patch))
    for i, patch_flat in zip(todo.tolist(), flat_patch.tolist()):
        cx, cy = centre[i]
        window = np.asarray(search[cy - reach:cy + reach + 1, cx - reach:cx + reach + 1],
                            np.float32)
        if patch_flat or _flat(window):
            status[i] = CorrelationStatus.FLAT
            continue
        r = cv2.matchTemplate(window, patches[i], cv2.TM_CCOEFF_NORMED)   # (2R+1, 2R+1)
        iy, ix = divmod(int(np.argmax(r)), r.shape[1])
        score[i] = r[iy, ix]
        dx = dy = 0.0
        border = ix in (0, r.shape[1] - 1) or iy in (0, r.shape[0] - 1)
        if not border:
            dx = _parabola(r[iy, ix - 1], r[iy, ix], r[iy, ix + 1])
            dy = _parabola(r[iy - 1, ix], r[iy, ix], r[iy + 1, ix])
        xy[i] = (cx - radius + ix + dx, cy - radius + iy + dy)
        status[i] = CorrelationStatus.AT_BORDER if border else CorrelationStatus.OK
    return CorrelationResult(xy=xy, score=score, status=status)


def _flat(a) -> bool:
    """Grey levels of ``a`` (float32) with a standard deviation below 1e-6; the standard
    deviation is computed only when the range is below 1e-2 (a wider range has one far
    above 1e-6), to save its cost in the search loop."""
    lo, hi, _, _ = cv2.minMaxLoc(a)
    return bool(hi - lo < 1e-2) and bool(a.std() < 1e-6)


def _flat_rows(a) -> np.ndarray:
    """:func:`_flat` of every row of ``a`` (n, P) float32, ``(n,)`` bool."""
    out = np.zeros(len(a), bool)
    if len(a):
        narrow = np.flatnonzero(a.max(axis=1) - a.min(axis=1) < 1e-2)
        out[narrow] = [bool(a[i].std() < 1e-6) for i in narrow]
    return out


def _parabola(a: float, b: float, c: float) -> float:
    """Offset of the vertex of the parabola through (-1, a), (0, b), (1, c), within +-0.5."""
    d = a - 2 * b + c
    if d >= 0:
        return 0.0
    return float(min(max(0.5 * (a - c) / d, -0.5), 0.5))
