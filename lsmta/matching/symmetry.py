"""Chessboard corners refined by point symmetry, by least squares (ours, beyond the papers).

An X-junction of a chessboard looks the same turned by 180 degrees about the corner
``c``, and stays so in any affine view (a lens is locally affine), under a point-symmetric
blur and under pixel-area sampling: ``I(c + u) = I(c - u)``. The image is matched against
its own point reflection -- least squares matching whose template is the search patch
turned about the unknown centre:

.. math::

    \\min_c \\sum_u w(u)\\,[I(c + u) - I(c - u)]^2, \\qquad
    \\frac{\\partial r_u}{\\partial c} = \\nabla I(c + u) - \\nabla I(c - u),

over a square window ``|u|_inf <= h`` with Gaussian weights ``w`` (sigma ``h / 2``), ``I``
the cubic B-spline interpolant (:class:`~lsmta.matching.spline.SplineImage`, exact
gradients), solved by Gauss-Newton. ``cv2.cornerSubPix`` instead finds the point where the
window's gradients are orthogonal to the lines to it, which any other edge in the window
(a ChArUco marker's) pulls; here whatever is point-symmetric about the corner -- the
markers' black frames of a ChArUco board are -- does not pull, and the window need only
stay clear of what is not (the markers' codes).

Precision: ``sigma0^2 (J^T W J)^{-1}`` with ``sigma0^2`` the weighted residual variance
(``u`` and ``-u`` give one residual twice: ``(P - 1) / 2`` observations of a window of
``P`` pixels); :attr:`SymmetricCorners.sigma_xy` is the square root of its mean diagonal
(px).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_scalar, freeze
from .spline import SplineImage, check_image


@dataclass(frozen=True, eq=False)
class SymmetricCorners:
    """Result of :func:`symmetric_corners`.

    Attributes
    ----------
    xy : (N, 2) array
        The corners, px; NaN where not ``ok``.
    ok : (N,) bool array
        Converged within ``max_iter``, moved at most ``max_shift`` from the start, window
        inside the image, normal matrix regular.
    sigma_xy : (N,) array
        Standard deviation of the position from the fit, px (NaN where not ``ok``).
    iterations : (N,) int array
    """

    xy: np.ndarray
    ok: np.ndarray
    sigma_xy: np.ndarray
    iterations: np.ndarray

    def __post_init__(self):
        freeze(self, ("xy", "ok", "sigma_xy", "iterations"))


def symmetric_corners(image, xy, *, half=3, max_iter: int = 20, tol: float = 1e-3,
                      max_shift: float | None = None) -> SymmetricCorners:
    """Refine chessboard corners by the point symmetry of their neighbourhood.

    Parameters
    ----------
    image : (H, W) array
        Grey image.
    xy : (N, 2) array
        Start positions, px (within about ``half / 2`` of the corners).
    half : int or (N,) int array
        Half-size ``h`` of each corner's window, px (``2 h + 1`` square, ``h >= 2``).
    max_iter : int
        Gauss-Newton iterations.
    tol : float
        Convergence: largest step, px.
    max_shift : float, optional
        Largest accepted distance from the start, px (default: ``h``).

    Returns
    -------
    SymmetricCorners
    """
    img = check_image(image, "image")
    start = as_array(xy, "xy", shape=(None, 2))
    n = len(start)
    h = np.broadcast_to(np.asarray(half), (n,))
    if h.size and (h.dtype == bool or np.any(h != np.rint(h)) or np.any(h < 2)):
        raise ValueError(f"half: expected integers >= 2 (pixels), got {half!r}")
    h = h.astype(int)
    max_iter = as_int(max_iter, "max_iter", unit="iterations")
    tol = as_scalar(tol, "tol", positive=True)
    limit = h.astype(float) if max_shift is None else np.full(
        n, as_scalar(max_shift, "max_shift", positive=True))
    out = SymmetricCorners(xy=np.full((n, 2), np.nan), ok=np.zeros(n, bool),
                           sigma_xy=np.full(n, np.nan), iterations=np.zeros(n, int))
    if not n:
        return out
    reach = int(h.max() + np.ceil(limit.max())) + 3
    x0, y0 = np.maximum(np.floor(start.min(axis=0)).astype(int) - reach, 0)
    x1, y1 = np.minimum(np.ceil(start.max(axis=0)).astype(int) + reach + 1,
                        [img.shape[1], img.shape[0]])
    if x1 - x0 < 5 or y1 - y0 < 5:
        return out
    spline = SplineImage(img[y0:y1, x0:x1], "image")
    c, ok, sigma, it = _gauss_newton(spline, start - [x0, y0], h, max_iter, tol)
    ok &= np.linalg.norm(c - (start - [x0, y0]), axis=1) <= limit
    xy_out = np.where(ok[:, None], c + [x0, y0], np.nan)
    return SymmetricCorners(xy=xy_out, ok=ok, sigma_xy=np.where(ok, sigma, np.nan),
                            iterations=it)


def _gauss_newton(spline: SplineImage, c, h, max_iter: int, tol: float):
    """The fit of every corner at once (window ``max(h)``, weights zero outside each
    corner's own ``h``)."""
    H = int(h.max())
    g = np.arange(-H, H + 1, dtype=float)
    U = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)                 # (P, 2)
    inside = np.abs(U).max(axis=1)[None] <= h[:, None]                      # (N, P)
    w = np.where(inside, np.exp(-np.sum(U**2, axis=1)[None] / (2 * (h[:, None] / 2.0)**2)),
                 0.0)
    c = c.astype(float).copy()
    active = np.ones(len(c), bool)
    ok = np.zeros(len(c), bool)
    it = np.zeros(len(c), int)
    sigma = np.full(len(c), np.nan)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        fits = spline.inside(c[idx], margin=H + 1)
        active[idx[~fits]] = False
        idx = idx[fits]
        if not idx.size:
            break
        r, J, ww = _residuals(spline, c[idx], U, w[idx])
        N = np.einsum("npi,npj,np->nij", J, J, ww)
        b = np.einsum("npi,np,np->ni", J, r, ww)
        regular = np.linalg.cond(N) < 1e8
        active[idx[~regular]] = False
        idx, N, b = idx[regular], N[regular], b[regular]
        step = -np.linalg.solve(N, b[..., None])[..., 0]
        c[idx] += step
        it[idx] += 1
        done = np.abs(step).max(axis=1) < tol
        ok[idx[done]] = True
        active[idx[done]] = False
    good = np.flatnonzero(ok & np.all(np.isfinite(c), axis=1))
    good = good[spline.inside(c[good], margin=H + 1)]
    ok[:] = False
    ok[good] = True
    if good.size:
        r, J, ww = _residuals(spline, c[good], U, w[good])
        N = np.einsum("npi,npj,np->nij", J, J, ww)
        # u and -u give one residual twice (sign flipped): (P - 1) / 2 observations
        dof = np.maximum(((ww > 0).sum(axis=1) - 1) / 2 - 2, 1)
        s0sq = np.einsum("np,np->n", r**2, ww) / dof
        cov = s0sq[:, None, None] * np.linalg.inv(N)
        sigma[good] = np.sqrt(np.trace(cov, axis1=1, axis2=2) / 2)
    return c, ok, sigma, it


def _residuals(spline: SplineImage, c, U, w):
    """``r (n, P)``, ``J (n, P, 2)`` and the weights of corners ``c (n, 2)``."""
    v1, gx1, gy1 = spline.sample(c[:, None] + U[None])
    v2, gx2, gy2 = spline.sample(c[:, None] - U[None])
    J = np.stack([gx1 - gx2, gy1 - gy2], axis=-1)
    return v1 - v2, J, w
