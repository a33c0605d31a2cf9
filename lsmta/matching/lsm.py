"""Adaptive least squares matching (Gruen 1985), batched over points.

Model
-----
A square template patch of ``patch x patch`` pixels around ``template_xy`` is related to
the search image by a geometric and a radiometric transformation::

    f(u) = r0 + r1 * g(c + A u) + e(u)

``f`` is the template, ``g`` the search image (cubic B-spline interpolant), ``u`` the
offset of a patch pixel from the patch centre (pixels, x then y), ``c`` the matched
position in the search image, ``A`` a 2 x 2 matrix, ``r0, r1`` offset and gain, ``e``
noise. ``geometry`` chooses what ``A`` may do: ``"shift"`` (A fixed at its start value,
2 parameters), ``"similarity"`` (rotation and scale, 4), ``"affine"`` (6); ``radiometry``
chooses ``"none"`` (r0 = 0, r1 = 1), ``"offset"`` (r0) or ``"linear"`` (r0 and r1).

The parameters are estimated by Gauss-Newton iterations on the linearised observation
equations, with the exact gradients of the spline interpolant of ``g`` at the warped
positions (the gradient of the resampled search patch, without finite differences). The
inner loop over patch pixels is compiled with numba (``_kernels.py``) and runs in parallel
over points.

Adaptive parameter control
--------------------------
Before each step the normal matrix of every point is scaled to unit diagonal; a
parameter whose variance inflation factor ``(C^-1)_ii`` exceeds ``max_vif`` (the patch
cannot tell it apart from the others, e.g. a shift along an edge, or scale in a patch of
parallel stripes) is fixed at its current value, worst first, until the rest is well
determined. The test runs on the first iteration's normal matrix; a fixed parameter stays at its
start value. ``LSMResult.fixed`` says which were fixed.

Precision
---------
From the normal equations of the last iteration, ``sigma0**2 = e^T e / (n - u)``
(``n`` pixels, ``u`` free parameters) and the covariance of the parameters is
``sigma0**2 (J^T J)^-1``; ``cov_xy`` and ``sigma_xy`` are its position block. This is the
classical a-posteriori estimate. It treats the search image as exact and charges all noise
to the template; with noise in both images ``sigma0`` counts both, so the estimate stays
close to the truth (the notebook checks how close).

Robust matching (beyond the paper)
----------------------------------
With ``robust=c`` the normal equations weight every patch pixel by the Tukey biweight of
its current residual, ``(1 - (e / c)^2)^2`` for ``|e| < c`` and 0 beyond (iteratively
reweighted least squares). Pixels that the model cannot fit — the part of a patch that
lies across an occlusion border, or a specular highlight — then drop out instead of
dragging the match. The cut-off starts at ``4 c`` and falls to ``c`` over the first
iterations, so that the start, still misaligned by a fraction of a pixel, is not cut
away; a point is not declared converged before the cut-off has reached ``c``.
``sigma0`` and the covariance are then the weighted ones,
``sigma0**2 = e^T W e / (trace W - u)``, and ``weight_share = trace W / n`` says how much
of the patch the match rests on. On clean patches with ``c`` about 4.7 times the residual
standard deviation, this ``sigma0`` comes out about 9 % below the plain one and
``weight_share`` about 0.92; a ``max_sigma0`` threshold is correspondingly a little
easier to pass.

Parameter vector (``LSMResult.params``), always 8 columns whatever the model:
``[x, y, a11, a12, a21, a22, r0, r1]`` — ``(x, y) = c`` and ``A = [[a11, a12], [a21, a22]]``.
"""

from __future__ import annotations

import enum
import numbers
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_point_pairs, check_patch
from . import _kernels
from .spline import SplineImage

PARAM_NAMES = ("x", "y", "a11", "a12", "a21", "a22", "r0", "r1")
GEOMETRIES = {"shift": 2, "similarity": 4, "affine": 6}
RADIOMETRIES = {"none": 0, "offset": 1, "linear": 2}


class Status(enum.IntEnum):
    """Outcome of matching one point."""

    CONVERGED = 0       #: the update fell below ``tol``
    MAX_ITERATIONS = 1  #: still moving after ``max_iter`` iterations
    DIVERGED = 2        #: moved further than ``max_displacement`` or ``A`` degenerated
    OUTSIDE = 3         #: the patch left the search image (or did not fit the template)
    SINGULAR = 4        #: too few determinable parameters (no texture)
    REJECTED = 5        #: converged, but rejected by quality thresholds


@dataclass(frozen=True)
class LSMResult:
    """Least squares matching of N points (see the module docstring for the model).

    Attributes
    ----------
    xy : (N, 2) array
        Matched positions in the search image (pixels).
    params : (N, 8) array
        ``[x, y, a11, a12, a21, a22, r0, r1]``.
    fixed : (N, 8) bool array
        Parameters fixed by the adaptive control (the model's own constant parameters are
        not marked).
    sigma0 : (N,) array
        A-posteriori standard deviation of unit weight, in grey levels.
    sigma_xy : (N, 2) array
        Standard deviations of ``xy`` in pixels (NaN for a fixed coordinate).
    cov_xy : (N, 2, 2) array
        Covariance of ``xy`` in px² (the fixed coordinate's row and column are zero).
    iterations : (N,) int array
    displacement : (N,) array
        Distance of ``xy`` from the approximation, pixels.
    status : (N,) int array
        :class:`Status` codes.
    weight_share : (N,) array
        Sum of the pixel weights over the number of patch pixels: 1 without ``robust`` and
        ``template_mask``. With ``robust`` about 0.92 on a clean patch (Tukey weights of
        inliers are below 1) and lower where part of the patch drops out; with
        ``template_mask`` at most the patch's share of object pixels.
    """

    xy: np.ndarray
    params: np.ndarray
    fixed: np.ndarray
    sigma0: np.ndarray
    sigma_xy: np.ndarray
    cov_xy: np.ndarray
    iterations: np.ndarray
    displacement: np.ndarray
    status: np.ndarray
    weight_share: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """``status == CONVERGED``."""
        return self.status == Status.CONVERGED

    @property
    def A(self) -> np.ndarray:
        """``(N, 2, 2)`` affine matrices."""
        return self.params[:, 2:6].reshape(-1, 2, 2)

    def __len__(self) -> int:
        return len(self.xy)


@dataclass(frozen=True)
class LSMThresholds:
    """Quality indicators of the LSMTA paper, as thresholds for accepting a match.

    Attributes
    ----------
    max_sigma0 : float
        Largest a-posteriori standard deviation of unit weight (grey levels).
    max_sigma_xy : float
        Largest standard deviation of either coordinate of the position (pixels).
    max_displacement : float
        Largest distance from the approximation (pixels).
    scale_range : (float, float)
        Accepted range of both singular values of ``A``.
    max_shear : float
        Largest ``|cos|`` of the angle between the columns of ``A``.
    min_weight_share : float
        Smallest :attr:`LSMResult.weight_share` accepted: a robust or masked match must
        rest on this share of its patch (always passed without ``robust`` and
        ``template_mask``).
    """

    max_sigma0: float = 20.0
    max_sigma_xy: float = 0.1
    max_displacement: float = 3.0
    scale_range: tuple = (0.7, 1.4)
    max_shear: float = 0.3
    min_weight_share: float = 0.5

    def accept(self, result: LSMResult) -> np.ndarray:
        """Boolean ``(N,)``: converged and passing every threshold."""
        sv = np.linalg.svd(result.A, compute_uv=False)
        cols = result.A.transpose(0, 2, 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.abs(np.einsum("ni,ni->n", cols[:, 0], cols[:, 1])) / (
                np.linalg.norm(cols[:, 0], axis=1) * np.linalg.norm(cols[:, 1], axis=1))
        sxy = np.where(np.isnan(result.sigma_xy), 0.0, result.sigma_xy)
        return (result.ok & (result.sigma0 <= self.max_sigma0)
                & (sxy.max(axis=1) <= self.max_sigma_xy)
                & (result.displacement <= self.max_displacement)
                & (sv.min(axis=1) >= self.scale_range[0]) & (sv.max(axis=1) <= self.scale_range[1])
                & (cos <= self.max_shear) & (result.weight_share >= self.min_weight_share))

    def apply(self, result: LSMResult) -> LSMResult:
        """A copy of ``result`` whose converged matches failing a threshold are REJECTED."""
        status = result.status.copy()
        status[result.ok & ~self.accept(result)] = Status.REJECTED
        return replace(result, status=status)


def _check_robust(robust) -> None:
    if robust is not None and (isinstance(robust, bool) or not isinstance(robust, numbers.Real)
                               or not np.isfinite(robust) or robust <= 0):
        raise ValueError(f"robust: expected a positive Tukey cut-off in grey levels or None, "
                         f"got {robust!r}")


def lsm(template, search, template_xy, search_xy, *, patch: int = 13, geometry: str = "affine",
        radiometry: str = "linear", initial_A=None, max_iter: int | None = None, tol: float = 1e-4,
        max_displacement: float | None = None, max_vif: float = 1e3,
        robust: float | None = None, template_mask=None,
        thresholds: LSMThresholds | None = None) -> LSMResult:
    """Least squares matching of N template patches in a search image, all at once.

    Parameters
    ----------
    template, search : (H, W) arrays
        Grey images of any real dtype (colour images are refused; convert them first).
        A :class:`~lsmta.matching.spline.SplineImage` may be passed instead to reuse its
        spline coefficients over several calls.
    template_xy : (N, 2) array
        Patch centres in the template (pixels; sub-pixel allowed).
    search_xy : (N, 2) array
        Approximate positions in the search image (pixels).
    patch : int
        Odd patch size in pixels, at least 5.
    geometry : {"shift", "similarity", "affine"}
    radiometry : {"none", "offset", "linear"}
    initial_A : (N, 2, 2) or (2, 2) array, optional
        Starting affine matrices (default identity), e.g. a neighbour's solution.
    max_iter : int, optional
        Iteration limit (default 40, or 100 with ``robust``: reweighting converges
        linearly, not quadratically).
    tol : float
        Convergence: largest change of the position and of ``A u`` over the patch, pixels.
    max_displacement : float, optional
        A point moving further than this from its approximation has diverged (default:
        the patch size).
    max_vif : float
        Variance inflation factor above which a parameter is fixed (adaptive control).
    robust : float, optional
        Tukey cut-off ``c`` in grey levels: residuals beyond it get zero weight (see the
        module docstring). About 4.7 times the residual standard deviation of a good match
        (for noise ``s`` in both images, roughly ``4.7 * sqrt(2) * s``) keeps 95 %
        efficiency on clean patches. None (default): ordinary least squares.
    template_mask : (H, W) bool array, optional
        Template pixels that belong to the object; the others (e.g. the backdrop around a
        silhouette) get zero weight in every patch (nearest pixel). Without it every patch
        pixel counts. A patch with less than ``thresholds.min_weight_share`` (default 0.5)
        of object pixels is rejected.
    thresholds : LSMThresholds, optional
        Applied to the result (:meth:`LSMThresholds.apply`).

    Returns
    -------
    LSMResult
        One row per point; a point that fails gets a status code, never an exception.
    """
    if geometry not in GEOMETRIES:
        raise ValueError(f"geometry: expected one of {list(GEOMETRIES)}, got {geometry!r}")
    if radiometry not in RADIOMETRIES:
        raise ValueError(f"radiometry: expected one of {list(RADIOMETRIES)}, got {radiometry!r}")
    patch = check_patch(patch)
    f_img = template if isinstance(template, SplineImage) else SplineImage(template, "template")
    g_img = search if isinstance(search, SplineImage) else SplineImage(search, "search")
    t_xy, s_xy = as_point_pairs(template_xy, search_xy, "template_xy", "search_xy")
    n = len(t_xy)
    if initial_A is None:
        A0 = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    else:
        A0 = as_array(initial_A, "initial_A")
        if A0.shape == (2, 2):
            A0 = np.broadcast_to(A0, (n, 2, 2)).copy()
        elif A0.shape != (n, 2, 2):
            raise ValueError(f"initial_A: expected shape (2, 2) or ({n}, 2, 2), got {A0.shape}")
        else:
            A0 = A0.copy()
    if max_iter is None:
        max_iter = 40 if robust is None else 100
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter: expected a positive integer, got {max_iter}")
    max_disp = float(patch) if max_displacement is None else float(max_displacement)
    _check_robust(robust)
    # Tukey cut-off per iteration: 4c, 3c, 2c, then c (0 switches the weights off)
    ramp = 3 if robust is not None else 0
    if max_iter <= ramp:
        raise ValueError(f"max_iter: expected more than {ramp} iterations with robust, "
                         f"got {max_iter}")

    h = patch // 2
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    U = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(float)     # (P, 2)
    P = len(U)

    status = np.full(n, Status.MAX_ITERATIONS, dtype=np.int64)
    fits = f_img.inside(t_xy, margin=h)
    status[~fits] = Status.OUTSIDE
    f = np.zeros((n, P))
    if fits.any():
        f[fits] = f_img.patches(t_xy[fits], U)
    fw = np.ones((n, P))
    if template_mask is not None:
        tm = np.asarray(template_mask)
        if tm.shape != f_img.shape or tm.dtype != bool:
            raise ValueError(f"template_mask: expected a boolean array of shape {f_img.shape}, "
                             f"got {tm.dtype} {tm.shape}")
        ij = np.rint(t_xy[:, None, :] + U).astype(np.int64)
        ij[..., 0] = np.clip(ij[..., 0], 0, tm.shape[1] - 1)
        ij[..., 1] = np.clip(ij[..., 1], 0, tm.shape[0] - 1)
        fw = tm[ij[..., 1], ij[..., 0]].astype(float)

    c = s_xy.copy()
    A = A0
    r0 = np.zeros(n)
    r1 = np.ones(n)
    k_geo = GEOMETRIES[geometry]
    k_rad = RADIOMETRIES[radiometry]
    k = k_geo + k_rad
    fixed = np.zeros((n, k), dtype=bool)
    iterations = np.zeros(n, dtype=np.int64)

    active = fits.copy()
    geo_code = list(GEOMETRIES).index(geometry)
    rad_code = list(RADIOMETRIES).index(radiometry)
    H, W = g_img.shape

    cols = [0, 1] + {"shift": [], "similarity": [2, 3], "affine": [2, 3, 4, 5]}[geometry] \
        + {"none": [], "offset": [6], "linear": [6, 7]}[radiometry]

    def normal_equations(idx, it):
        m = len(idx)
        N, b, ee, sw = np.empty((m, 8, 8)), np.empty((m, 8)), np.empty(m), np.empty(m)
        ok = np.empty(m, dtype=np.bool_)
        cut = 0.0 if robust is None else float(robust) * (1 + max(ramp - it, 0))
        _kernels.normal_equations(g_img.coefficients, g_img.pad, H, W, idx, f, fw, c, A, r0, r1, U,
                                  geo_code, rad_code, cut, N, b, ee, sw, ok)
        return N[:, cols][:, :, cols], b[:, cols], ee, sw, ok

    if k_rad and fits.any():
        # start the radiometry from the patches' means and spreads (Gruen: r0 = 0, r1 = 1)
        # (over the template mask's pixels)
        g0 = g_img.sample(s_xy[fits, None, :] + U @ A[fits].transpose(0, 2, 1), gradient=False)
        fa = f[fits]
        if template_mask is not None:
            m = fw[fits] > 0
            fa, g0 = np.ma.masked_array(fa, ~m), np.ma.masked_array(g0, ~m)
        fm, gm = fa.mean(axis=1), g0.mean(axis=1)
        if k_rad == 2:
            fs, gs = fa.std(axis=1), g0.std(axis=1)
            r1[fits] = np.ma.filled(np.ma.where(gs > 1e-9, fs / np.maximum(gs, 1e-9), 1.0), 1.0)
        r0[fits] = np.ma.filled(fm - r1[fits] * gm, 0.0)

    N_last = np.full((n, k, k), np.nan)
    ee_last = np.full(n, np.nan)
    sw_last = np.full(n, float(P))
    for it in range(int(max_iter)):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        N, b, ee, sw, ok = normal_equations(idx, it)
        if not ok.all():
            status[idx[~ok]] = Status.OUTSIDE
            active[idx[~ok]] = False
            idx, N, b, ee, sw = idx[ok], N[ok], b[ok], ee[ok], sw[ok]
            if idx.size == 0:
                break
        iterations[idx] = it + 1
        N_last[idx], ee_last[idx], sw_last[idx] = N, ee, sw
        if it == 0:  # which parameters can these patches determine?
            fixed[idx] = _adapt(N, fixed[idx], max_vif)
        dx = np.empty((len(idx), k))
        solved = np.empty(len(idx), dtype=np.bool_)
        _kernels.solve_free(N, b, ~fixed[idx], dx, solved)
        singular = (fixed[idx, 0] & fixed[idx, 1]) | ~solved

        if singular.any():
            status[idx[singular]] = Status.SINGULAR
            active[idx[singular]] = False
        go = ~singular
        ig = idx[go]
        dx = dx[go]
        dc, dA, dr0, dr1 = _split(geometry, radiometry, dx)
        c[ig] += dc
        A[ig] += dA
        r0[ig] += dr0
        r1[ig] += dr1

        moved = np.linalg.norm(c[ig] - s_xy[ig], axis=1)
        det = np.linalg.det(A[ig])
        bad = (moved > max_disp) | ~(det > 0.2) | ~(det < 5.0) | ~np.isfinite(c[ig]).all(axis=1)
        status[ig[bad]] = Status.DIVERGED
        active[ig[bad]] = False
        step = np.abs(dc).max(axis=1) + np.abs(dA).sum(axis=(1, 2)) * h
        done = ~bad & (step < tol) & (it >= ramp)
        status[ig[done]] = Status.CONVERGED
        active[ig[done]] = False

    # a-posteriori precision from the normal equations of each point's last iteration
    free = ~fixed
    seen = np.isfinite(ee_last)
    Nf = np.where(free[:, :, None] & free[:, None, :], N_last, 0.0) + np.eye(k) * fixed[:, :, None]
    Nf[~seen] = np.eye(k)
    try:
        Q = np.linalg.inv(Nf)
    except np.linalg.LinAlgError:
        Q = np.linalg.pinv(Nf, hermitian=True)
    Q = np.where(free[:, :, None] & free[:, None, :], Q, 0.0)
    dof = np.maximum(sw_last - free.sum(axis=1), 1.0)
    sigma0 = np.where(seen, np.sqrt(np.where(seen, ee_last, 0.0) / dof), np.nan)
    cov = sigma0[:, None, None] ** 2 * Q
    params = np.concatenate([c, A.reshape(n, 4), r0[:, None], r1[:, None]], axis=1)
    fixed8 = np.zeros((n, 8), dtype=bool)
    fixed8[:, :2] = fixed[:, :2]
    if geometry == "similarity":
        fixed8[:, 2:6] = (fixed[:, 2] | fixed[:, 3])[:, None]
    elif geometry == "affine":
        fixed8[:, 2:6] = fixed[:, 2:6]
    if radiometry == "offset":
        fixed8[:, 6] = fixed[:, k_geo]
    elif radiometry == "linear":
        fixed8[:, 6:8] = fixed[:, k_geo:k_geo + 2]
    cov_xy = cov[:, :2, :2].copy()
    with np.errstate(invalid="ignore"):
        sigma_xy = np.sqrt(np.diagonal(cov_xy, axis1=1, axis2=2)).copy()
    sigma_xy[fixed[:, :2]] = np.nan
    failed = status == Status.OUTSIDE
    result = LSMResult(xy=c, params=params, fixed=fixed8, sigma0=sigma0, sigma_xy=sigma_xy,
                       cov_xy=cov_xy, iterations=iterations,
                       displacement=np.where(failed, np.nan, np.linalg.norm(c - s_xy, axis=1)),
                       status=status, weight_share=sw_last / P)
    return thresholds.apply(result) if thresholds is not None else result


def _split(geometry, radiometry, dx):
    """Unknowns -> increments of c (m, 2), A (m, 2, 2), r0 (m,), r1 (m,)."""
    m = len(dx)
    dc = dx[:, :2]
    dA = np.zeros((m, 2, 2))
    j = 2
    if geometry == "similarity":
        a, b = dx[:, 2], dx[:, 3]
        dA[:, 0, 0], dA[:, 0, 1], dA[:, 1, 0], dA[:, 1, 1] = a, -b, b, a
        j = 4
    elif geometry == "affine":
        dA = dx[:, 2:6].reshape(m, 2, 2)
        j = 6
    dr0 = np.zeros(m)
    dr1 = np.zeros(m)
    if radiometry in ("offset", "linear"):
        dr0 = dx[:, j]
    if radiometry == "linear":
        dr1 = dx[:, j + 1]
    return dc, dA, dr0, dr1


def _adapt(N, fixed, max_vif):
    """Fix badly determined parameters (worst variance inflation first); returns the mask."""
    fixed = fixed.copy()
    k = N.shape[1]
    d = np.diagonal(N, axis1=1, axis2=2)
    scale = d.max(axis=1, keepdims=True)
    # a parameter without any signal is fixed at once
    fixed |= d <= 1e-12 * np.maximum(scale, 1e-300)
    for _ in range(k):
        free = ~fixed
        s = np.where(free, 1.0 / np.sqrt(np.where(free, d, 1.0)), 0.0)
        C = N * s[:, :, None] * s[:, None, :]
        C = np.where(free[:, :, None] & free[:, None, :], C, 0.0) + np.eye(k) * fixed[:, :, None]
        # C is positive semi-definite with unit diagonal: a tiny ridge keeps it invertible and
        # gives a degenerate parameter a huge inflation factor instead of an exception
        vif = np.diagonal(np.linalg.inv(C + 1e-10 * np.eye(k)), axis1=1, axis2=2)
        vif = np.where(fixed, 0.0, np.abs(vif))
        worst = vif.argmax(axis=1)
        over = vif[np.arange(len(vif)), worst] > max_vif
        if not over.any():
            break
        fixed[np.flatnonzero(over), worst[over]] = True
    return fixed
