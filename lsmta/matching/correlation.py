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

from .._validate import as_array, as_int, as_point_pairs, check_patch
from .spline import SplineImage, _grey, check_image


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

    return _search(patches, g, p_xy, radius, fits)


def search_patches(patches, search, predicted_xy, *, radius: int, valid=None
                   ) -> CorrelationResult:
    """The box search of :func:`correlation_search` for patches already sampled.

    Parameters
    ----------
    patches : (N, patch, patch) array
        Template patches (odd size), real dtype (read as float32, as OpenCV correlates
        them).
    search : (H, W) array
        Grey search image, real dtype (each box is read as float32).
    predicted_xy : (N, 2) array
        Predicted positions in ``search``, px (finite).
    radius : int
        Half-width of the search box, px (>= 1).
    valid : (N,) bool array, optional
        Patches that exist (the others are OUTSIDE); default all.

    Returns
    -------
    CorrelationResult
    """
    radius = as_int(radius, "radius", unit="pixels")
    tiles = np.asarray(patches)
    if tiles.dtype == bool or not (np.issubdtype(tiles.dtype, np.integer)
                                   or np.issubdtype(tiles.dtype, np.floating)):
        raise TypeError(f"patches: expected an array of a real dtype, got {tiles.dtype}")
    if tiles.ndim != 3 or tiles.shape[1] != tiles.shape[2] or tiles.shape[1] % 2 == 0:
        raise ValueError("patches: expected an array of shape (N, p, p) with p odd, "
                         f"got shape {tiles.shape}")
    tiles = tiles.astype(np.float32, copy=False)
    if not np.isfinite(tiles).all():
        raise ValueError("patches: contains non-finite values (NaN or inf); "
                         "expected finite grey levels")
    g = _grey(search, "search")
    n = len(tiles)
    p_xy = as_array(predicted_xy, "predicted_xy", shape=(n, 2))
    if valid is None:
        valid = np.ones(n, bool)
    else:
        valid = np.asarray(valid)
        if valid.dtype != bool or valid.shape != (n,):
            raise ValueError(f"valid: expected a bool array of shape ({n},), got "
                             f"{valid.dtype} of shape {valid.shape}")
    return _search(tiles, g, p_xy, radius, valid)


def _search(patches, search, predicted_xy, radius: int, valid) -> CorrelationResult:
    """:func:`search_patches` on checked arguments (``patches`` float32)."""
    n, patch = len(patches), patches.shape[1]
    h = patch // 2
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
