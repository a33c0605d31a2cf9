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
    """Outcome of the search for one point.

    Arrays are compared with ``.value`` (see :class:`~lsmta.matching.lsm.Status`).
    """

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


#: most box pixels cut out at once (4M): the gather holds them in the image's dtype and then
#: in float32, at most 48 MB for a float64 image (20 MB for 8 bits); one box larger than
#: that (a radius above about 1000 px) is still cut out whole
_BLOCK_PIXELS = 1 << 22


def _search(patches, search, predicted_xy, radius: int, valid) -> CorrelationResult:
    """:func:`search_patches` on checked arguments (``patches`` float32).

    The boxes are cut out and converted to float32 in one gather (in blocks of at most
    ``_BLOCK_PIXELS`` pixels), OpenCV correlates each box with its patch, and the peaks
    and their parabolas are found for all boxes at once (in float32, as the scores are):
    only ``matchTemplate`` runs per point."""
    n, h = len(patches), patches.shape[1] // 2
    xy = np.full((n, 2), np.nan)
    score = np.full(n, np.nan)
    status = np.full(n, CorrelationStatus.OUTSIDE.value, dtype=np.int64)
    centre = np.rint(predicted_xy).astype(np.int64)
    H, W = search.shape
    reach = radius + h
    box_fits = ((centre[:, 0] - reach >= 0) & (centre[:, 0] + reach <= W - 1)
                & (centre[:, 1] - reach >= 0) & (centre[:, 1] + reach <= H - 1))
    todo = np.flatnonzero(valid & box_fits)
    block = max(1, _BLOCK_PIXELS // (2 * reach + 1) ** 2)
    for b in range(0, len(todo), block):
        _search_boxes(patches, search, centre, radius, todo[b:b + block], xy, score, status)
    return CorrelationResult(xy=xy, score=score, status=status)


def _search_boxes(patches, search, centre, radius: int, todo, xy, score, status) -> None:
    """The boxes of the points ``todo`` (all inside ``search``): their results written
    into ``xy``, ``score`` and ``status``."""
    patch = patches.shape[1]
    reach = radius + patch // 2
    side = 2 * reach + 1
    span = np.arange(-reach, reach + 1)
    windows = np.asarray(search[(centre[todo, 1, None] + span)[:, :, None],
                                (centre[todo, 0, None] + span)[:, None, :]], np.float32)
    flat = _flat_rows(patches[todo].reshape(len(todo), patch * patch)) | \
        _flat_rows(windows.reshape(len(todo), side * side), wide=True)
    status[todo[flat]] = CorrelationStatus.FLAT.value
    box = np.flatnonzero(~flat)                 # the textured boxes (windows not copied)
    todo = todo[box]
    m, w = len(todo), 2 * radius + 1
    r = np.empty((m, w, w), np.float32)
    for j, (b, i) in enumerate(zip(box.tolist(), todo.tolist())):
        r[j] = cv2.matchTemplate(windows[b], patches[i], cv2.TM_CCOEFF_NORMED)
    iy, ix = np.divmod(np.argmax(r.reshape(m, w * w), axis=1), w)
    score[todo] = r[np.arange(m), iy, ix]
    border = (ix == 0) | (ix == w - 1) | (iy == 0) | (iy == w - 1)
    inner = np.flatnonzero(~border)
    dx, dy = np.zeros(m), np.zeros(m)
    jy, jx, peak = iy[inner], ix[inner], r[inner, iy[inner], ix[inner]]
    dx[inner] = _parabolas(r[inner, jy, jx - 1], peak, r[inner, jy, jx + 1])
    dy[inner] = _parabolas(r[inner, jy - 1, jx], peak, r[inner, jy + 1, jx])
    xy[todo, 0] = (centre[todo, 0] - radius + ix) + dx
    xy[todo, 1] = (centre[todo, 1] - radius + iy) + dy
    status[todo] = np.where(border, CorrelationStatus.AT_BORDER.value,
                            CorrelationStatus.OK.value)


def _flat_rows(a, *, wide: bool = False) -> np.ndarray:
    """Rows of ``a`` (n, P) float32 whose grey levels have a standard deviation below 1e-6,
    ``(n,)`` bool; the standard deviation is computed only where the range is below 1e-2
    (a wider range has one far above 1e-6). With ``wide`` the range is taken in float64
    (as ``cv2.minMaxLoc`` reports it), else in float32."""
    out = np.zeros(len(a), bool)
    if len(a):
        hi, lo = a.max(axis=1), a.min(axis=1)
        if wide:
            hi, lo = hi.astype(np.float64), lo.astype(np.float64)
        narrow = np.flatnonzero(hi - lo < 1e-2)
        out[narrow] = [bool(a[i].std() < 1e-6) for i in narrow]
    return out


def _parabolas(a, b, c) -> np.ndarray:
    """Offsets ``(n,)`` of the vertices of the parabolas through (-1, a), (0, b), (1, c)
    (float32 ``(n,)`` scores, computed in float32), within +-0.5; 0 where not a maximum."""
    d = a - 2 * b + c
    up = d >= 0
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.clip(0.5 * (a - c) / np.where(up, np.float32(-1), d), -0.5, 0.5)
    return np.where(up, np.float32(0), v).astype(np.float64)
