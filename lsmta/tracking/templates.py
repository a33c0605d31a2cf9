"""Anchored templates: a track's patch from its anchor frame, matched into any later frame.

Drift-free temporal matching (Matthews, Ishikawa & Baker 2004, "The template update
problem", IEEE PAMI 26(6)): instead of matching frame ``t``'s patch into frame ``t + 1``
(whose small errors add up frame after frame, a random walk of the position), every frame
is matched against the *anchor* patch ``f`` sampled once, at the track's anchor position
in its anchor frame; the previous frame's solution is only the start. The model is the
affine least squares matching model of :func:`~lsmta.matching.lsm` with linear radiometry,

    r0 + r1 g(c + A u) = f(u) + e(u),

``u`` the offset of a patch pixel (px), ``c`` the position in the search image, ``A`` the
affinity accumulated since the anchor frame.

Because ``f`` never changes, the inverse compositional iteration (Baker & Matthews 2004,
"Lucas-Kanade 20 years on") pays off: the steepest-descent images ``f_x, f_y, f_x u_x,
f_x u_y, f_y u_x, f_y u_y`` of the template and the inverse of their normal matrix are
computed once, when the track is anchored, and each iteration only resamples the search
image. The radiometry is *projected out* (Hager & Belhumeur 1998): each iteration fits
``g = a + b f`` over the patch, the residual ``e = (g - a) / b - f`` is then orthogonal to
``1`` and ``f``, and the steepest-descent images are orthogonalised against both; the
update ``dp = H^-1 sum SD(u)^T e(u)`` is composed inversely, ``W <- W o W(dp)^-1``.

The inverse compositional step linearises about the template. Where the search patch is
not close to an affine copy of it (weak texture, noise, shading or a fold), that step can
point the wrong way and the iterations diverge although the forward additive LSM, which
linearises about the search image, converges; so every match that fails its thresholds
is tried again with :func:`~lsmta.matching.lsm` from the same start (the stored patches,
stacked into one image, are its template).

Parameters whose variance inflation exceeds ``MAX_VIF`` in the normal matrix (a shift
along an edge, a scale in parallel stripes) get no update (the pseudo-inverse with a
relative eigenvalue cut); their variance still counts in the precision, so such a patch
fails the ``max_sigma_xy`` threshold instead of sliding.

Precision, as in :func:`~lsmta.matching.lsm`: ``sigma0^2 = e^T e / (n - 8)`` with ``e``
the residual of the best fit ``f = r0 + r1 g`` at the final geometry (grey levels of the
template; the projected residual above is that divided by the correlation coefficient),
and the position covariance ``sigma0^2 A Q A^T``, ``Q`` the position block of the inverse
normal matrix.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._validate import as_int, as_scalar
from ..matching.correlation import CorrelationStatus, search_patches
from ..matching.lsm import LSMParams, LSMResult, LSMThresholds, Status, lsm
from ..matching.spline import SplineImage

_ARRAYS = ("values", "gx", "gy", "update", "q_xy", "ok", "mask", "full")
MAX_VIF = 1e3  #: eigenvalues below 1 / MAX_VIF of the largest (unit-diagonal scaling) are cut
#: smallest share of a partial template's pixels that must lie inside its image
MIN_INSIDE = 0.5


@dataclass(frozen=True)
class Templates:
    """Anchor patches of N tracks in one camera, with what inverse compositional matching
    needs of them (see the module docstring).

    Attributes
    ----------
    values : (N, P) array
        Template grey levels, patch pixels in row order (P = patch²).
    gx, gy : (N, P) arrays
        Their gradients, grey levels per pixel.
    update : (N, 6, 6) array
        Pseudo-inverse of the normal matrix of the projected steepest-descent images
        (badly determined directions cut, see ``MAX_VIF``).
    q_xy : (N, 2, 2) array
        Position block of the (full) inverse normal matrix, for the precision.
    ok : (N,) bool array
        Textured enough to be matched (the template's grey levels vary).
    mask : (N, P) bool array
        The template pixels inside the image it was sampled from (all, except for a
        *partial* template, one whose patch reached over the image's border).
    full : (N,) bool array
        Every pixel inside (``mask`` all True). A partial template has no normal matrix
        (``update``, ``q_xy`` NaN): only the forward LSM with partial patches matches it.
    patch : int
    """

    values: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    update: np.ndarray
    q_xy: np.ndarray
    ok: np.ndarray
    mask: np.ndarray
    full: np.ndarray
    patch: int

    def __len__(self) -> int:
        return len(self.values)

    def put(self, rows, other: Templates) -> None:
        """Write ``other``'s templates into ``rows`` (in place: re-anchoring)."""
        for name in _ARRAYS:
            getattr(self, name)[rows] = getattr(other, name)

    def take(self, rows) -> Templates:
        """A new store of the templates ``rows``."""
        rows = np.asarray(rows, np.int64)
        return Templates(**{name: getattr(self, name)[rows] for name in _ARRAYS},
                         patch=self.patch)

    def extend(self, other: Templates) -> Templates:
        """A new store with ``other``'s templates appended (tracks added)."""
        return Templates(**{name: np.concatenate([getattr(self, name), getattr(other, name)])
                            for name in _ARRAYS}, patch=self.patch)


def search_templates(templates: Templates, rows, search, predicted_xy, radius: int):
    """Best normalised cross-correlation positions ``(n, 2)`` of the (unwarped) templates
    ``rows`` in a box of half-width ``radius`` around ``predicted_xy`` in ``search`` (an
    ``(H, W)`` image); NaN where the peak is on the box's border, the box leaves the image
    or the template is partial.

    The stored patches are the templates of the search of
    :func:`~lsmta.matching.correlation_search` (:func:`~lsmta.matching.correlation.search_patches`).
    """
    rows = np.asarray(rows, np.int64)
    xy = np.full((len(rows), 2), np.nan)
    if not len(rows):
        return xy
    patch = templates.patch
    tiles = templates.values[rows].reshape(len(rows), patch, patch)
    # search_patches checks every argument (``search``: a 2-D grey image of finite values)
    res = search_patches(tiles, search, predicted_xy, radius=radius)
    # a partial template's missing pixels are no texture: it is not searched
    good = (res.status == CorrelationStatus.OK.value) & templates.full[rows]
    xy[good] = res.xy[good]
    return xy


def offsets(patch: int) -> np.ndarray:
    """``(P, 2)`` pixel offsets ``u`` (x, y) of a square patch, in row order (one read-only
    array per patch size, made once)."""
    return _offsets(int(patch))


@functools.lru_cache(maxsize=8)
def _offsets(patch: int) -> np.ndarray:
    h = patch // 2
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    U = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(float)
    U.flags.writeable = False
    return U


def sample_templates(image: SplineImage, xy, patch: int, *, normals: bool = True,
                     partial: bool = False) -> Templates:
    """Anchor ``N`` templates at the positions ``xy`` ``(N, 2)`` of ``image``.

    A position whose patch leaves the image, or whose patch is flat, gets ``ok = False``.
    With ``partial`` a position inside the image whose patch reaches over its border gets
    a *partial* template instead (as KLT keeps a window that reaches over the border): its
    pixels outside the image are masked (``mask``; value and gradients 0), and it is
    ``ok`` when at least ``MIN_INSIDE`` of its pixels are inside and they are not flat.
    With ``normals=False`` only the grey levels and gradients are sampled (all that
    :func:`match_translation` uses); ``update`` and ``q_xy`` are then NaN, so such a store
    cannot pass :func:`match_templates`' thresholds by mistake.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    U = offsets(patch)
    n, P = len(xy), len(U)
    values, gx, gy = np.zeros((n, P)), np.zeros((n, P)), np.zeros((n, P))
    finite = np.isfinite(xy).all(axis=1)
    ok = image.inside(xy, margin=patch // 2) & finite
    if ok.any():
        values[ok], gx[ok], gy[ok] = image.sample(xy[ok, None, :] + U, gradient=True)
    f = values - values.mean(axis=1, keepdims=True)
    ff = (f * f).sum(axis=1)
    full = ok.copy()
    ok &= ff > 1e-9 * P
    mask = np.broadcast_to(full[:, None], (n, P)).copy()
    part = np.flatnonzero(partial & ~full & finite & image.inside(np.nan_to_num(xy)))
    if part.size:
        ok[part] = _sample_partial(image, xy[part], U, values, gx, gy, mask, part)
    if not normals:
        return Templates(values=values, gx=gx, gy=gy, update=np.full((n, 6, 6), np.nan),
                         q_xy=np.full((n, 2, 2), np.nan), ok=ok, mask=mask, full=full,
                         patch=patch)
    fh = f / np.sqrt(np.maximum(ff, 1e-300))[:, None]
    H = np.empty((n, 6, 6))
    _normals(gx, gy, fh, U, H)
    update, q_xy = _inverses(H, ok & full)
    update[~full], q_xy[~full] = np.nan, np.nan
    return Templates(values=values, gx=gx, gy=gy, update=update, q_xy=q_xy, ok=ok, mask=mask,
                     full=full, patch=patch)


def _sample_partial(image: SplineImage, xy, U, values, gx, gy, mask, rows) -> np.ndarray:
    """Sample the partial templates ``rows`` at ``xy`` ``(m, 2)`` into ``values``, ``gx``,
    ``gy`` and ``mask`` (pixels inside ``image`` only); returns which are usable ``(m,)``:
    at least ``MIN_INSIDE`` of the pixels inside, and those not flat."""
    pts = xy[:, None, :] + U                                      # (m, P, 2)
    inside = image.inside(pts)
    mask[rows] = inside
    v, x, y = image.sample(pts[inside], gradient=True)
    for a, s in ((values, v), (gx, x), (gy, y)):
        block = np.zeros(inside.shape)
        block[inside] = s
        a[rows] = block
    cnt = inside.sum(axis=1)
    mean = (values[rows] * inside).sum(axis=1) / np.maximum(cnt, 1)
    spread = (((values[rows] - mean[:, None]) * inside) ** 2).sum(axis=1)
    return (cnt >= MIN_INSIDE * len(U)) & (spread > 1e-9 * np.maximum(cnt, 1))


@nb.njit(cache=True)
def _normals(gx, gy, fh, U, H):
    """Normal matrices ``H`` (n, 6, 6) of the steepest-descent images ``gx, gy, gx u_x,
    gx u_y, gy u_x, gy u_y`` (n, P) with the radiometry projected out: each image minus
    its mean (orthogonal to the constant), then minus its projection on the unit-norm,
    zero-mean template ``fh`` (orthogonal to the template itself)."""
    n, P = gx.shape
    sd = np.empty((P, 6))
    for i in range(n):
        for p in range(P):
            sd[p, 0] = gx[i, p]
            sd[p, 1] = gy[i, p]
            sd[p, 2] = gx[i, p] * U[p, 0]
            sd[p, 3] = gx[i, p] * U[p, 1]
            sd[p, 4] = gy[i, p] * U[p, 0]
            sd[p, 5] = gy[i, p] * U[p, 1]
        for k in range(6):
            m = 0.0
            for p in range(P):
                m += sd[p, k]
            m /= P
            proj = 0.0
            for p in range(P):
                sd[p, k] -= m
                proj += fh[i, p] * sd[p, k]
            for p in range(P):
                sd[p, k] -= fh[i, p] * proj
        for k in range(6):
            for q in range(k, 6):
                a = 0.0
                for p in range(P):
                    a += sd[p, k] * sd[p, q]
                H[i, k, q] = a
                H[i, q, k] = a


def _inverses(H, ok):
    """Cut pseudo-inverse (for the update) and the position block of the ridge inverse
    (for the precision) of the normal matrices ``H`` (n, 6, 6)."""
    if not len(H):
        return np.zeros((0, 6, 6)), np.zeros((0, 2, 2))
    d = np.sqrt(np.maximum(np.diagonal(H, axis1=1, axis2=2), 1e-300))
    C = H / d[:, :, None] / d[:, None, :]
    C[~ok] = np.eye(6)
    w, V = np.linalg.eigh(C)
    keep = w > w[:, -1:] / MAX_VIF
    winv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    cut = np.einsum("nij,nj,nkj->nik", V, winv, V) / d[:, :, None] / d[:, None, :]
    full = np.einsum("nij,nj,nkj->nik", V, 1.0 / np.maximum(w, 1e-12 * w[:, -1:]), V)
    q = full[:, :2, :2] / d[:, :2, None] / d[:, None, :2]
    cut[~ok] = 0.0
    q[~ok] = np.nan
    return cut, q


def match_templates(templates: Templates, rows, search: SplineImage, start_xy, start_A, *,
                    thresholds: LSMThresholds | None = None, max_iter: int = 30,
                    tol: float = 0.01, max_displacement: float | None = None,
                    fallback: bool = True, inverse: bool = True,
                    partial: bool = False) -> LSMResult:
    """Match the templates ``rows`` into ``search``, started at ``start_xy`` with ``start_A``.

    Parameters
    ----------
    templates : Templates
    rows : (n,) int array
        Which templates.
    search : SplineImage
    start_xy : (n, 2) array
        Start positions in the search image, px.
    start_A : (n, 2, 2) array
        Start affinities (template offsets to search-image offsets).
    thresholds : LSMThresholds, optional
        Applied to the result.
    max_iter : int
    tol : float
        Convergence: largest change of the position and of ``A u`` over the patch, px.
    max_displacement : float, optional
        A point moving further than this from its start has diverged (default: the patch
        size).
    fallback : bool or (n,) bool array
        Where the inverse compositional match fails (or fails ``thresholds``), run the
        forward additive :func:`~lsmta.matching.lsm` from the same start (per row with an
        array: one call for rows that differ in it).
    inverse : bool
        False: the forward additive LSM for every match (no inverse compositional
        iterations, whatever ``fallback`` says). With a template that changes every frame,
        the inverse compositional step, whose Jacobian comes from the noisy template, is
        biased by that noise, and the bias adds up from frame to frame.
    partial : bool
        Patches may reach over the search image's border: a partial template (``full``
        False), and a template whose inverse compositional match left the image (status
        OUTSIDE), or whose forward retry did, are matched with the forward LSM with partial
        patches (:class:`~lsmta.matching.lsm.LSMParams` ``partial``: the pixels outside the
        template or the search image get zero weight; ``thresholds.min_weight_share`` rejects
        a patch mostly outside), whatever ``fallback`` says. False: a partial template is
        never matched (status SINGULAR) and a patch leaving the image is OUTSIDE.

    Returns
    -------
    LSMResult
        As :func:`~lsmta.matching.lsm` reports it; for the inverse compositional matches
        ``fixed`` is all False and ``weight_share`` 1. ``displacement`` is measured from
        ``start_xy``.
    """
    return _match(templates, rows, search, start_xy, start_A, thresholds=thresholds,
                  max_iter=max_iter, tol=tol, max_displacement=max_displacement,
                  fallback=fallback, inverse=inverse, partial=partial, retry_rejected=True)


def _match(templates: Templates, rows, search: SplineImage, start_xy, start_A, *, thresholds,
           max_iter, tol, max_displacement, fallback, inverse, partial,
           retry_rejected) -> LSMResult:
    """:func:`match_templates`; with ``retry_rejected`` False, no forward retry
    (``fallback``) where the inverse compositional match converged but failed
    ``thresholds`` (REJECTED) or found no positive correlation with the template
    (SINGULAR): only where it diverged or kept moving (the tracker's choice,
    ``TrackerParams.retry_rejected``)."""
    rows = np.asarray(rows, np.int64)
    n = len(rows)
    max_disp = float(templates.patch if max_displacement is None else max_displacement)
    result = _inverse_compositional(templates, rows, search, start_xy, start_A, max_iter, tol,
                                    max_disp, inverse)
    start = np.asarray(start_xy, float).reshape(n, 2)
    start_A = np.asarray(start_A, float).reshape(n, 2, 2)
    outside = result.status == Status.OUTSIDE.value
    if thresholds is not None:
        result = thresholds.apply(result)
    usable = templates.ok[rows]
    full = templates.full[rows]
    retry = np.broadcast_to(np.asarray(fallback, bool), (n,)) | (not inverse)
    if inverse and not retry_rejected:
        retry = retry & ((result.status == Status.MAX_ITERATIONS.value)
                         | (result.status == Status.DIVERGED.value))
    redo = np.flatnonzero(~result.ok & usable & ~outside & full & retry)
    kw = dict(max_iter=max_iter, tol=tol, max_disp=max_disp, thresholds=thresholds)
    if redo.size:
        result = _forward(result, templates, rows, redo, search, start, start_A, False, **kw)
    if partial:      # the forward retry may have left the image too
        outside |= result.status == Status.OUTSIDE.value
        border = np.flatnonzero(usable & (outside | ~full) & np.isfinite(start).all(axis=1)
                                & np.isfinite(start_A).all(axis=(1, 2)))
        if border.size:
            result = _forward(result, templates, rows, border, search, start, start_A, True,
                              **kw)
    return result


def _forward(result: LSMResult, templates: Templates, rows, sel, search: SplineImage, start,
             start_A, partial: bool, *, max_iter, tol, max_disp, thresholds) -> LSMResult:
    """``result`` with the rows ``sel`` replaced by the forward LSM of their templates
    (stacked into one image) from ``start``, ``start_A``; with ``partial``, patches over
    the border allowed and each template's masked pixels given zero weight."""
    tiles, centres = _mosaic(templates, rows[sel])
    mask = templates.mask[rows[sel]].reshape(tiles.shape) if partial else None
    fa = lsm(tiles, search, centres, start[sel], params=LSMParams(
        patch=templates.patch, max_iter=max_iter, tol=tol, max_displacement=max_disp,
        partial=partial, thresholds=thresholds), initial_A=start_A[sel], template_mask=mask)
    merged = {}
    for name in LSMResult.__dataclass_fields__:
        merged[name] = getattr(result, name).copy()
        merged[name][sel] = getattr(fa, name)
    return LSMResult(**merged)


def _inverse_compositional(templates: Templates, rows, search: SplineImage, start_xy, start_A,
                           max_iter, tol, max_disp: float, inverse: bool) -> LSMResult:
    """The inverse compositional matches of :func:`match_templates` (with ``inverse``
    False: none, every point left at its start with status MAX_ITERATIONS), before any
    thresholds."""
    n = len(rows)
    c = np.array(start_xy, float).reshape(n, 2)
    A = np.array(start_A, float).reshape(n, 2, 2)
    status = np.full(n, Status.MAX_ITERATIONS.value, np.int64)
    iterations = np.zeros(n, np.int64)
    ee, r0, r1 = np.full(n, np.nan), np.zeros(n), np.ones(n)
    H, W = search.shape
    if inverse:
        _solve(search.coefficients, search.pad, H, W, rows, templates.values, templates.gx,
               templates.gy, templates.update, templates.ok & templates.full,
               offsets(templates.patch), c, A,
               int(max_iter), float(tol), max_disp, float(templates.patch // 2), status,
               iterations, ee, r0, r1)
    P = templates.values.shape[1]
    sigma0 = np.sqrt(ee / (P - 8))
    cov = sigma0[:, None, None] ** 2 * (A @ templates.q_xy[rows] @ A.transpose(0, 2, 1))
    with np.errstate(invalid="ignore"):
        sigma_xy = np.sqrt(np.diagonal(cov, axis1=1, axis2=2)).copy()
    start = np.asarray(start_xy, float).reshape(n, 2)
    outside = status == Status.OUTSIDE.value
    return LSMResult(
        xy=c, params=np.concatenate([c, A.reshape(n, 4), r0[:, None], r1[:, None]], axis=1),
        fixed=np.zeros((n, 8), bool), sigma0=sigma0, sigma_xy=sigma_xy, cov_xy=cov,
        iterations=iterations,
        displacement=np.where(outside, np.nan, np.linalg.norm(c - start, axis=1)),
        status=status, weight_share=np.ones(n))


def _mosaic(templates: Templates, rows):
    """The patches ``rows`` stacked into one image ``(n * patch, patch)``, and their centres
    ``(n, 2)`` in it (whole pixels: read as they are, never interpolated)."""
    n, patch = len(rows), templates.patch
    tiles = templates.values[rows].reshape(n * patch, patch)
    centres = np.stack([np.full(n, patch // 2), np.arange(n) * patch + patch // 2], axis=1)
    return tiles, centres.astype(float)


@nb.njit(cache=True, inline="always")
def _weights(t):
    """The four cubic B-spline weights at fraction ``t`` in [0, 1)."""
    s = 1.0 - t
    return (s * s * s / 6.0, (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
            (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0, t * t * t / 6.0)


@nb.njit(cache=True, inline="always")
def _value(coef, pad, x, y):
    """Cubic B-spline value at (x, y) from the padded coefficients."""
    ix = int(np.floor(x))
    iy = int(np.floor(y))
    tx = x - ix
    ty = y - iy
    wx0, wx1, wx2, wx3 = _weights(tx)
    wy0, wy1, wy2, wy3 = _weights(ty)
    r = iy + pad - 1
    q = ix + pad - 1
    return (wy0 * (wx0 * coef[r, q] + wx1 * coef[r, q + 1] + wx2 * coef[r, q + 2]
                   + wx3 * coef[r, q + 3])
            + wy1 * (wx0 * coef[r + 1, q] + wx1 * coef[r + 1, q + 1]
                     + wx2 * coef[r + 1, q + 2] + wx3 * coef[r + 1, q + 3])
            + wy2 * (wx0 * coef[r + 2, q] + wx1 * coef[r + 2, q + 1]
                     + wx2 * coef[r + 2, q + 2] + wx3 * coef[r + 2, q + 3])
            + wy3 * (wx0 * coef[r + 3, q] + wx1 * coef[r + 3, q + 1]
                     + wx2 * coef[r + 3, q + 2] + wx3 * coef[r + 3, q + 3]))


@nb.njit(cache=True, inline="always")
def _sample_warped(coef, pad, height, width, U, cx, cy, a11, a12, a21, a22, g):
    """Grey values ``g`` (P,) of the template offsets ``U`` (P, 2) warped by the affinity
    ``a`` and moved to ``(cx, cy)``, px; returns (every sample inside the image, their sum)
    and stops at the first sample outside."""
    gm = 0.0
    for p in range(U.shape[0]):
        x = cx + a11 * U[p, 0] + a12 * U[p, 1]
        y = cy + a21 * U[p, 0] + a22 * U[p, 1]
        if not (x >= 0.0 and x <= width - 1.0 and y >= 0.0 and y <= height - 1.0):
            return False, gm
        g[p] = _value(coef, pad, x, y)
        gm += g[p]
    return True, gm


@nb.njit(cache=True, inline="always")
def _sample_shifted(coef, pad, height, width, side, cx, cy, g, rows_h):
    """:func:`_sample_warped` for the identity affinity (a square patch of ``side`` pixels,
    row order, centred at ``(cx, cy)``): every sample shares the same spline weights, so
    the 4 x 4 sums split into a pass along the rows (into ``rows_h``, ``(side + 3, side)``)
    and one along the columns, 8 products per sample instead of 16 and the weights once.
    Returns (every sample inside the image, their sum)."""
    h = side // 2
    if not (cx - h >= 0.0 and cx + h <= width - 1.0 and cy - h >= 0.0
            and cy + h <= height - 1.0):
        return False, 0.0
    ix = int(np.floor(cx))
    iy = int(np.floor(cy))
    tx = cx - ix
    ty = cy - iy
    wx0, wx1, wx2, wx3 = _weights(tx)
    wy0, wy1, wy2, wy3 = _weights(ty)
    r0 = iy - h + pad - 1
    q0 = ix - h + pad - 1
    for a in range(side + 3):
        r = r0 + a
        for u in range(side):
            q = q0 + u
            rows_h[a, u] = (wx0 * coef[r, q] + wx1 * coef[r, q + 1] + wx2 * coef[r, q + 2]
                            + wx3 * coef[r, q + 3])
    gm = 0.0
    for v in range(side):
        for u in range(side):
            val = (wy0 * rows_h[v, u] + wy1 * rows_h[v + 1, u] + wy2 * rows_h[v + 2, u]
                   + wy3 * rows_h[v + 3, u])
            g[v * side + u] = val
            gm += val
    return True, gm


@nb.njit(parallel=True, cache=True, fastmath=True)
def _solve(coef, pad, height, width, rows, f, fx, fy, update, ok, U, c, A, max_iter, tol,
           max_disp, h, status, iterations, ee_out, r0_out, r1_out):
    """Inverse compositional iterations for every point j (template ``rows[j]``); writes
    ``c``, ``A`` in place and the status, iterations, residual square sum and radiometry."""
    n = rows.shape[0]
    P = U.shape[0]
    for j in nb.prange(n):
        i = rows[j]
        if not ok[i]:
            status[j] = 4                                   # SINGULAR: flat template
            continue
        g = np.empty(P)
        b = np.zeros(6)
        d = np.zeros(6)
        fm = 0.0
        for p in range(P):
            fm += f[i, p]
        fm /= P
        ff = 0.0
        for p in range(P):
            ff += (f[i, p] - fm) * (f[i, p] - fm)
        sx, sy = c[j, 0], c[j, 1]
        cx, cy = sx, sy
        a11, a12, a21, a22 = A[j, 0, 0], A[j, 0, 1], A[j, 1, 0], A[j, 1, 1]
        st = 1
        for it in range(max_iter):
            iterations[j] = it + 1
            inside, gm = _sample_warped(coef, pad, height, width, U, cx, cy, a11, a12, a21,
                                        a22, g)
            if not inside:
                st = 3                                      # OUTSIDE
                break
            gm /= P
            fg = 0.0
            gg = 0.0
            for p in range(P):
                fg += (f[i, p] - fm) * (g[p] - gm)
                gg += (g[p] - gm) * (g[p] - gm)
            gain = fg / ff                                  # g = a + gain f
            if not gain > 1e-6:
                st = 4                                      # SINGULAR: no positive correlation
                break
            off = gm - gain * fm
            for k in range(6):
                b[k] = 0.0
            for p in range(P):
                e = (g[p] - off) / gain - f[i, p]
                ex = fx[i, p] * e
                ey = fy[i, p] * e
                b[0] += ex
                b[1] += ey
                b[2] += ex * U[p, 0]
                b[3] += ex * U[p, 1]
                b[4] += ey * U[p, 0]
                b[5] += ey * U[p, 1]
            # residual and radiometry of the best fit f = r0 + r1 g, as lsm reports them
            r1_out[j] = fg / gg
            r0_out[j] = fm - fg / gg * gm
            ee_out[j] = max(ff - fg * fg / gg, 0.0)
            for k in range(6):
                d[k] = 0.0
                for m in range(6):
                    d[k] += update[i, k, m] * b[m]
            # W <- W o W(d)^-1: A' = A (I + dA)^-1, c' = c - A' dc
            m11, m12, m21, m22 = 1.0 + d[2], d[3], d[4], 1.0 + d[5]
            det = m11 * m22 - m12 * m21
            if not abs(det) > 1e-9:
                st = 2
                break
            i11, i12, i21, i22 = m22 / det, -m12 / det, -m21 / det, m11 / det
            n11 = a11 * i11 + a12 * i21
            n12 = a11 * i12 + a12 * i22
            n21 = a21 * i11 + a22 * i21
            n22 = a21 * i12 + a22 * i22
            dcx = -(n11 * d[0] + n12 * d[1])
            dcy = -(n21 * d[0] + n22 * d[1])
            d0 = max(abs(dcx), abs(dcy)) + (abs(n11 - a11) + abs(n12 - a12) + abs(n21 - a21)
                                              + abs(n22 - a22)) * h
            cx += dcx
            cy += dcy
            a11, a12, a21, a22 = n11, n12, n21, n22
            detA = a11 * a22 - a12 * a21
            moved = np.sqrt((cx - sx) ** 2 + (cy - sy) ** 2)
            if not (moved <= max_disp and detA > 0.2 and detA < 5.0):
                st = 2                                      # DIVERGED
                break
            if d0 < tol:
                st = 0                                      # CONVERGED
                break
        status[j] = st
        c[j, 0], c[j, 1] = cx, cy
        A[j, 0, 0], A[j, 0, 1], A[j, 1, 0], A[j, 1, 1] = a11, a12, a21, a22


def match_translation(templates: Templates, rows, search: SplineImage, start_xy, *,
                      max_iter: int = 30, tol: float = 0.01,
                      max_displacement: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Translation-only inverse compositional matching (Lucas-Kanade, as pyramidal KLT does
    on its coarse levels) of the templates ``rows`` into ``search`` from ``start_xy``.

    The model is ``g(c + u) = f(u) + a + e(u)``: a shift and a grey-level offset, no gain,
    so a start where the patch correlates negatively with the template still moves (the
    affine model with linear radiometry of :func:`match_templates` refuses it).

    Parameters
    ----------
    templates : Templates
        The template store (:func:`sample_templates`; ``normals=False`` is enough: only
        ``values``, ``gx``, ``gy``, ``ok`` and ``full`` are used).
    rows : (n,) int array
        Which templates, indices into ``templates``; a template with ``ok`` False, or a
        partial one (``full`` False), is not matched (not converged, returned at its start).
    search : SplineImage
        The image the templates are matched into.
    start_xy : (n, 2) array
        Start positions in ``search``, px.
    max_iter : int
        Most iterations per row (>= 1).
    tol : float
        Convergence: an iteration that changes the position by less than this (largest
        coordinate, px, > 0) ends the row as converged.
    max_displacement : float, optional
        A row moving further than this (px, > 0) from its start has diverged and stops
        (default: the patch size).

    Returns
    -------
    xy : (n, 2) array
        Positions, px. A row that did not converge (too many iterations, diverged, its
        patch left the image, a flat template) returns its last iterate, not NaN: use
        ``converged``.
    converged : (n,) bool array
    """
    if not isinstance(templates, Templates):
        raise TypeError(f"templates: expected a Templates store, got {type(templates).__name__}")
    if not isinstance(search, SplineImage):
        raise TypeError(f"search: expected a SplineImage, got {type(search).__name__}")
    raw = np.asarray(rows)
    if raw.size and not np.issubdtype(raw.dtype, np.integer):
        raise ValueError(f"rows: expected integer template indices, got dtype {raw.dtype}")
    rows = raw.astype(np.int64).reshape(-1)
    n = len(rows)
    if n and (rows.min() < 0 or rows.max() >= len(templates)):
        raise ValueError(f"rows: expected template indices in [0, {len(templates) - 1}], got "
                         f"{rows.min()}..{rows.max()}")
    c = np.array(start_xy, float)
    if c.shape != (n, 2):
        raise ValueError(f"start_xy: expected shape ({n}, 2) (one position per row), got "
                         f"{c.shape}")
    max_iter = as_int(max_iter, "max_iter", minimum=1, unit="iterations")
    tol = as_scalar(tol, "tol", positive=True)
    max_disp = as_scalar(templates.patch if max_displacement is None else max_displacement,
                         "max_displacement", positive=True)
    converged = np.zeros(n, bool)
    H, W = search.shape
    if n:
        _solve_translation(search.coefficients, search.pad, H, W, rows, templates.values,
                           templates.gx, templates.gy, templates.ok & templates.full,
                           offsets(templates.patch),
                           c, max_iter, tol, max_disp, converged)
    return c, converged


@nb.njit(parallel=True, cache=True, fastmath=True)
def _solve_translation(coef, pad, height, width, rows, f, fx, fy, ok, U, c, max_iter, tol,
                       max_disp, converged):
    """Inverse compositional translation + grey offset for every point j; writes ``c`` and
    ``converged`` in place.

    ``U`` must be ``offsets(patch)`` (the square patch's offsets in row order): only its
    length is read, and the search image is sampled on that grid by :func:`_sample_shifted`,
    whatever ``U`` holds."""
    n = rows.shape[0]
    P = U.shape[0]
    side = int(np.sqrt(P) + 0.5)
    assert side * side == P and U[0, 0] == -(side // 2) and U[1, 0] == U[0, 0] + 1
    for j in nb.prange(n):
        i = rows[j]
        if not ok[i]:
            continue
        mx = 0.0
        my = 0.0
        fm = 0.0
        for p in range(P):
            mx += fx[i, p]
            my += fy[i, p]
            fm += f[i, p]
        mx /= P
        my /= P
        fm /= P
        hxx = 0.0
        hxy = 0.0
        hyy = 0.0
        for p in range(P):
            ax = fx[i, p] - mx
            ay = fy[i, p] - my
            hxx += ax * ax
            hxy += ax * ay
            hyy += ay * ay
        det = hxx * hyy - hxy * hxy
        if not det > 1e-12 * (hxx + hyy) * (hxx + hyy):
            continue
        sx, sy = c[j, 0], c[j, 1]
        cx, cy = sx, sy
        g = np.empty(P)
        rows_h = np.empty((side + 3, side))
        for _it in range(max_iter):
            inside, gm = _sample_shifted(coef, pad, height, width, side, cx, cy, g, rows_h)
            if not inside:
                break
            gm /= P
            bx = 0.0
            by = 0.0
            for p in range(P):
                e = (g[p] - gm) - (f[i, p] - fm)
                bx += (fx[i, p] - mx) * e
                by += (fy[i, p] - my) * e
            dx = (hyy * bx - hxy * by) / det
            dy = (hxx * by - hxy * bx) / det
            cx -= dx
            cy -= dy
            if not np.sqrt((cx - sx) ** 2 + (cy - sy) ** 2) <= max_disp:
                break
            if max(abs(dx), abs(dy)) < tol:
                converged[j] = True
                break
        c[j, 0], c[j, 1] = cx, cy
