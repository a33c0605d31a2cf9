"""Cameras refined from tie points, with the given cameras as weighted priors.

A self-calibrating bundle adjustment for a rig that already has a calibration (a camera
file from another tool) which is a few pixels off. Unknowns: every camera's exterior
orientation (rotation vector, centre), its principal distance ``f`` and, where the data
determines them, its principal point and radial distortion; and the tie points. The
observations are the tie points' image coordinates (standard deviation ``sigma_px``) and
the given cameras' parameters as observations of themselves (a prior with the standard
deviations of :class:`RefineParams`). The priors on the camera centres give the datum and
the scale: nothing is held fixed, so the network is not bent by a datum.

Which intrinsics are freed (per camera)
----------------------------------------
The exterior orientation and ``f`` are always free. Every group of :attr:`RefineParams.groups`
(default: the principal point ``cx, cy``, and ``k1, k2``) is tried: the adjustment is run
with all groups free, and the posterior standard deviation of each parameter is read from
its covariance (points eliminated by the Schur complement). A group is freed for a camera
when every parameter of it has a posterior standard deviation below
``information_ratio`` times its prior's, that is when the tie points, not the prior,
carry most of what is known about it (at the default 0.5, more than three quarters of
its information). The others are held at the file's values, and the adjustment is
run again with those choices. A distortion that then stops growing with the radius inside
the image (it could not be inverted there) is held too: tie points that determine the
lens do not bend it that way.

Time offsets (optional, ``velocities``)
---------------------------------------
Views that are not exactly synchronised (free-running or software-synchronised video) see a
moving point where it was a fraction of a frame earlier or later. Given each tie point's
image velocity ``v`` in each view (px per frame, from the neighbouring frames), camera k's
observation is compared with the projection plus ``v d_k``, ``d_k`` its time offset in
frames, the first camera the time datum (``d_0 = 0``). Each offset is freed by a z-test:
the adjustment is run with every offset free (a weak prior, ``sigma_offset``, keeps one
without moving points defined), and an offset is kept free where its estimate is more than
``offset_z`` standard errors from 0; then the intrinsics are chosen again with those
offsets free. Where none passes, nothing changes: the result is the one without
``velocities``, number for number. On the Pose2Sim demo the tie points hold too few moving
points for it (``experiments/timing_offsets.py``: none freed), so
:func:`lsmta.systems.refine_rig` does not pass velocities.

Solver: Levenberg-Marquardt with the points eliminated from each step (Schur complement:
a small dense camera system, then 3 x 3 blocks per point), the Jacobian by SciPy's grouped
finite differences over its sparsity pattern,
then iteratively reweighted with one of SciPy's robust losses on the image residuals;
observations whose residual exceeds ``reject_k`` robust standard deviations are
dropped and the adjustment run once more.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.sparse import coo_matrix

from .._validate import as_array, as_int, as_scalar, freeze
from ..camera import Camera
from ..triangulation import triangulate
from .bundle import (
    _LOSS_DERIVATIVE,
    LOSSES,
    PARAMETER_NAMES,
    _levenberg_marquardt,
    camera_to_params,
    params_to_camera,
    project_params,
)

# the intrinsics that may be freed beyond f (each has a prior, see RefineParams)
_TRIED = ("cx", "cy", "k1", "k2", "k3", "p1", "p2")


@dataclass(frozen=True)
class RefineParams:
    """Settings of :func:`refine_cameras`.

    Attributes
    ----------
    sigma_px : float
        Standard deviation of a tie point's image coordinate, px.
    sigma_position : float
        Prior standard deviation of each camera-centre coordinate, mm.
    sigma_angle : float
        Prior standard deviation of each rotation-vector component, degrees.
    sigma_f : float
        Prior standard deviation of the principal distance, relative (0.02 = 2 %).
    sigma_principal : float
        Prior standard deviation of the principal point, px.
    sigma_k : float
        Prior standard deviation of k1, k2 and k3.
    sigma_p : float
        Prior standard deviation of the decentring coefficients p1, p2.
    groups : tuple of tuple of str
        Intrinsic groups tried beyond ``f``, each freed per camera where the data
        determines it (see the module docstring).
    information_ratio : float
        A group is freed where every posterior standard deviation is below this share of
        its prior's (0 < ratio <= 1).
    loss, f_scale : str, float
        Robust loss of :func:`scipy.optimize.least_squares` on the standardised image
        residuals, and where it bends (in units of ``sigma_px``). Cauchy by default: tie
        points matched in an epipolar band hold gross errors of up to the band's width,
        and a redescending loss gives them no pull, where soft-l1 still lets each pull
        with the square root of its size.
    reject_k : float
        Observations whose residual is longer than ``reject_k`` times the robust standard
        deviation of a coordinate (the median residual length over sqrt(2 ln 2), the
        median of a 2-D Gaussian's length; at least ``sigma_px``) are dropped before the
        last run.
    max_iter : int
        Most Levenberg-Marquardt iterations per run.
    sigma_offset : float
        Prior standard deviation of a camera's time offset, frames (with ``velocities``; a
        weak prior that only keeps an offset without moving points defined).
    offset_z : float
        With ``velocities``: a camera's time offset is freed where its estimate, with every
        other camera's free, is more than ``offset_z`` standard errors from 0 (a z-test; the
        standard error from the covariance, scaled by the a-posteriori standard deviation of
        unit weight where that exceeds 1). 3 by default: about one camera in 370 freed by
        chance where there is no offset.
    """

    sigma_px: float = 0.5
    sigma_position: float = 50.0
    sigma_angle: float = 1.0
    sigma_f: float = 0.02
    sigma_principal: float = 20.0
    sigma_k: float = 0.1
    sigma_p: float = 0.01
    groups: tuple = (("cx", "cy"), ("k1", "k2"))
    information_ratio: float = 0.5
    loss: str = "cauchy"
    f_scale: float = 3.0
    reject_k: float = 4.0
    max_iter: int = 100
    sigma_offset: float = 1.0
    offset_z: float = 3.0

    def __post_init__(self):
        for name in ("sigma_px", "sigma_position", "sigma_angle", "sigma_f",
                     "sigma_principal", "sigma_k", "sigma_p", "f_scale", "reject_k",
                     "sigma_offset", "offset_z"):
            as_scalar(getattr(self, name), name, positive=True)
        ratio = as_scalar(self.information_ratio, "information_ratio", positive=True)
        if ratio > 1:
            raise ValueError(f"information_ratio: expected a number in (0, 1], got {ratio}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss: expected one of {LOSSES}, got {self.loss!r}")
        as_int(self.max_iter, "max_iter")
        bad = [g for g in self.groups if not g or any(n not in _TRIED for n in g)]
        if bad:
            raise ValueError(f"groups: expected groups of names from {_TRIED}, got {bad}")

    def prior_sigmas(self, camera: Camera) -> np.ndarray:
        """The 16 prior standard deviations (:data:`PARAMETER_NAMES` order) of a camera."""
        s = np.full(16, np.inf)
        s[:3] = np.deg2rad(self.sigma_angle)
        s[3:6] = self.sigma_position
        index = {n: i for i, n in enumerate(PARAMETER_NAMES)}
        s[index["f"]] = self.sigma_f * camera.f
        s[index["cx"]] = s[index["cy"]] = self.sigma_principal
        s[[index["k1"], index["k2"], index["k3"]]] = self.sigma_k
        s[[index["p1"], index["p2"]]] = self.sigma_p
        return s


@dataclass(frozen=True)
class CameraRefinement:
    """Result of :func:`refine_cameras`.

    Attributes
    ----------
    cameras : tuple of K Camera
        The refined cameras (sizes and names of the given ones).
    points : (N, 3) array
        The adjusted tie points, mm (NaN for a point that lost its observations).
    residuals_before, residuals : (K, N, 2) arrays
        Image residuals (measured - projected, px) of the tie points triangulated with the
        given cameras, and after the adjustment; NaN where not observed.
    used : (K, N) bool array
        Observations kept in the last run.
    freed : tuple of K tuple of str
        The intrinsics adjusted per camera (always ``f``; the groups the data determined).
    ratios : (K, P) array
        Posterior over prior standard deviation of each tried group's parameters
        (columns in the order of :attr:`ratio_names`), from the run with all groups free.
    ratio_names : tuple of str
    sigma0 : float
        Standard deviation of unit weight of the last run (1 when ``sigma_px`` was right).
    time_offsets : (K,) array or None
        Each camera's time offset, frames (a view sampling the scene late by ``d`` sees a
        point moving at image velocity ``v`` at ``x + v d``): the adjusted offset where it
        was freed, 0 elsewhere (the first camera is the time datum). None without
        ``velocities``.
    offset_z : (K,) array or None
        Each offset's estimate over its standard error in the run with every offset free
        (NaN for the first camera); an offset is freed where this exceeds
        :attr:`RefineParams.offset_z` in size. None without ``velocities``.
    """

    cameras: tuple
    points: np.ndarray
    residuals_before: np.ndarray
    residuals: np.ndarray
    used: np.ndarray
    freed: tuple
    ratios: np.ndarray
    ratio_names: tuple
    sigma0: float
    time_offsets: np.ndarray | None = None
    offset_z: np.ndarray | None = None

    def __post_init__(self):
        freeze(self, ("points", "residuals_before", "residuals", "used", "ratios"))
        if self.time_offsets is not None:
            freeze(self, ("time_offsets", "offset_z"))

    @property
    def offsets_freed(self) -> np.ndarray:
        """(K,) bool: the cameras whose time offset was adjusted (all False without
        ``velocities``)."""
        if self.time_offsets is None:
            return np.zeros(len(self.cameras), bool)
        return np.asarray(self.time_offsets) != 0

    def median_residual(self, *, before: bool = False) -> np.ndarray:
        """Median residual length per camera ``(K,)``, px (observations kept, or all the
        observed ones before the adjustment)."""
        r = np.linalg.norm(self.residuals_before if before else self.residuals, axis=2)
        if not before:
            r = np.where(self.used, r, np.nan)
        with np.errstate(all="ignore"):
            return np.array([np.nanmedian(row) if np.isfinite(row).any() else np.nan
                             for row in r])


@dataclass
class _Problem:
    params0: np.ndarray        # (K, 16) given cameras
    sigmas: np.ndarray         # (K, 16) prior standard deviations
    cam: np.ndarray            # (M,) camera of each observation
    pt: np.ndarray             # (M,) point of each observation
    obs: np.ndarray            # (M, 2) image coordinates
    n_points: int
    sigma_px: float
    vel: np.ndarray | None = None        # (M, 2) image velocity of each observation, px/frame
    toff: np.ndarray | None = None       # (K,) bool: cameras whose time offset is free
    sigma_offset: float = 1.0

    @property
    def n_off(self) -> int:
        return 0 if self.toff is None else int(self.toff.sum())


def _residuals(x, pr: _Problem, free: np.ndarray):
    params = pr.params0.copy()
    nf, nt = int(free.sum()), pr.n_off
    params[free] = x[:nf]
    X = x[nf + nt:].reshape(pr.n_points, 3)
    proj = project_params(params, X[pr.pt], rows=pr.cam)
    prior = (params[free] - pr.params0[free]) / pr.sigmas[free]
    if nt:
        d = np.zeros(len(pr.toff))
        d[pr.toff] = x[nf:nf + nt]
        proj = proj + pr.vel * d[pr.cam][:, None]
        prior = np.concatenate([prior, x[nf:nf + nt] / pr.sigma_offset])
    image = ((pr.obs - proj) / pr.sigma_px).ravel()
    return np.concatenate([image, prior])


def _sparsity(pr: _Problem, free: np.ndarray):
    M, nf, nt = len(pr.obs), int(free.sum()), pr.n_off
    col = -np.ones(free.shape, int)
    col[free] = np.arange(nf)
    rows, cols = [], []
    cam_cols = col[pr.cam]                                    # (M, 16)
    for j in range(16):
        ok = cam_cols[:, j] >= 0
        for axis in (0, 1):
            rows.append(2 * np.nonzero(ok)[0] + axis)
            cols.append(cam_cols[ok, j])
    if nt:                                       # a camera's offset: its observations
        off_col = -np.ones(len(pr.toff), int)
        off_col[pr.toff] = nf + np.arange(nt)
        ok = off_col[pr.cam] >= 0
        for axis in (0, 1):
            rows.append(2 * np.nonzero(ok)[0] + axis)
            cols.append(off_col[pr.cam[ok]])
    for d in range(3):
        for axis in (0, 1):
            rows.append(2 * np.arange(M) + axis)
            cols.append(nf + nt + 3 * pr.pt + d)
    rows.append(2 * M + np.arange(nf + nt))
    cols.append(np.arange(nf + nt))
    r, c = np.concatenate(rows), np.concatenate(cols)
    return coo_matrix((np.ones(len(r)), (r, c)),
                      shape=(2 * M + nf + nt, nf + nt + 3 * pr.n_points))


def _normal_blocks(J, n_cam: int):
    """The normal matrix of a Jacobian whose first ``n_cam`` columns are the cameras' and
    the rest three per point: the dense camera block ``(n_cam, n_cam)``, the camera-point
    block as ``(n_cam, n_pts, 3)`` and the point blocks ``(n_pts, 3, 3)``."""
    J = J.tocsc()
    Jc, Jp = J[:, :n_cam], J[:, n_cam:]
    n_pts = Jp.shape[1] // 3
    Hpp = (Jp.T @ Jp).tocoo()
    same = Hpp.row // 3 == Hpp.col // 3
    B = np.zeros((n_pts, 3, 3))
    np.add.at(B, (Hpp.row[same] // 3, Hpp.row[same] % 3, Hpp.col[same] % 3), Hpp.data[same])
    W = (Jc.T @ Jp).toarray().reshape(n_cam, n_pts, 3)
    return (Jc.T @ Jc).toarray(), W, B, Jc, Jp


def _schur_step(J, r, lam: float, *, n_cam: int):
    """Levenberg-Marquardt step with the points eliminated: the reduced camera system is
    small and dense, then each point's 3 x 3 block."""
    Hcc, W, B, Jc, Jp = _normal_blocks(J, n_cam)
    gc, gp = Jc.T @ r, (Jp.T @ r).reshape(-1, 3)
    Hcc[np.diag_indices(n_cam)] *= 1 + lam
    B[:, [0, 1, 2], [0, 1, 2]] = B[:, [0, 1, 2], [0, 1, 2]] * (1 + lam) + 1e-12
    Binv = np.linalg.inv(B)
    WB = np.einsum("anj,njk->ank", W, Binv, optimize=True)
    S = Hcc - WB.reshape(n_cam, -1) @ W.reshape(n_cam, -1).T
    dc = -np.linalg.solve(S, gc - np.einsum("ank,nk->a", WB, gp))
    dp = -np.einsum("njk,nk->nj", Binv, gp + np.einsum("anj,a->nj", W, dc))
    return np.concatenate([dc, dp.ravel()])


def _solve(pr: _Problem, free, X0, params: RefineParams):
    """Levenberg-Marquardt, each step by the Schur complement, then iteratively reweighted
    with the robust loss on the image residuals (the priors keep weight 1)."""
    nf, nt = int(free.sum()), pr.n_off
    x0 = np.concatenate([pr.params0[free], np.zeros(nt), X0.ravel()])
    sparsity = _sparsity(pr, free).tocsc()
    n_image = 2 * len(pr.obs)

    def fun(x):
        return _residuals(x, pr, free)

    step = partial(_schur_step, n_cam=nf + nt)
    sol = _levenberg_marquardt(fun, x0, sparsity, params.max_iter, 1e-9, 1e-12, None, step)
    if params.loss != "linear":
        for _ in range(5):
            z = (fun(sol.x)[:n_image] / params.f_scale) ** 2
            w = np.ones(n_image + nf + nt)
            w[:n_image] = np.sqrt(_LOSS_DERIVATIVE[params.loss](z))
            x_prev = sol.x
            sol = _levenberg_marquardt(lambda x, w=w: fun(x) * w, sol.x, sparsity, 10, 1e-6,
                                       1e-12, None, step)
            if np.linalg.norm(sol.x - x_prev) < 1e-8 * (1 + np.linalg.norm(x_prev)):
                break
    cams = pr.params0.copy()
    cams[free] = sol.x[:nf]
    return cams, sol.x[nf + nt:].reshape(-1, 3), sol, fun(sol.x)


def _posterior_sigmas(sol, free: np.ndarray, n_off: int = 0):
    """Standard deviations of the free camera parameters (unit weight), points eliminated
    by the Schur complement; with ``n_off`` free time offsets (after the camera parameters)
    also theirs: ``(K, 16)`` array, and the ``(n_off,)`` array when ``n_off``."""
    nf = int(free.sum())
    n = nf + n_off
    Hcc, W, B, _, _ = _normal_blocks(sol.jac, n)
    WB = np.einsum("anj,njk->ank", W, np.linalg.pinv(B), optimize=True)
    S = Hcc - WB.reshape(n, -1) @ W.reshape(n, -1).T
    sig = np.sqrt(np.clip(np.diag(np.linalg.pinv(S)), 0, None))
    out = np.full(free.shape, np.nan)
    out[free] = sig[:nf]
    return (out, sig[nf:]) if n_off else out


def _observations(xy):
    K, N, _ = xy.shape
    seen = np.isfinite(xy).all(axis=2)
    cam, pt = np.nonzero(seen)
    return cam, pt, xy[cam, pt]


def _image_residuals(params, X, xy, used, shift=None):
    """(K, N, 2) measured - projected (- ``shift``, the time offsets' displacement), px."""
    K, N, _ = xy.shape
    if shift is not None:
        xy = xy - shift
    out = np.full((K, N, 2), np.nan)
    for k in range(K):
        ok = used[k] & np.isfinite(X).all(axis=1)
        if ok.any():
            out[k, ok] = xy[k, ok] - project_params(params[k][None], X[ok])
    return out


@dataclass
class _State:
    cameras: tuple
    xy: np.ndarray          # (K, N, 2) tie points seen by >= 2 cameras
    params0: np.ndarray     # (K, 16) the given cameras
    sigmas: np.ndarray      # (K, 16) their prior standard deviations
    X: np.ndarray           # (N, 3) current points (NaN: not triangulated)
    used: np.ndarray        # (K, N) observations in use
    vel: np.ndarray | None = None   # (K, N, 2) image velocities, px/frame (NaN -> 0)


def _initial(cameras, xy, params: RefineParams, velocities=None) -> _State:
    if len(cameras) < 2 or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras: expected a sequence of at least two lsmta Camera")
    xy = as_array(xy, "xy", shape=(len(cameras), None, 2), allow_nan=True)
    if velocities is not None:
        velocities = as_array(velocities, "velocities", shape=xy.shape, allow_nan=True)
        if (np.isinf(velocities)).any():
            raise ValueError("velocities: expected finite image velocities or NaN (unknown)")
        velocities = np.nan_to_num(velocities, nan=0.0)
    seen = np.isfinite(xy).all(axis=2)
    keep = seen.sum(axis=0) >= 2
    xy = np.where(keep[None, :, None], xy, np.nan)
    seen &= keep[None]
    counts = seen.sum(axis=1)
    if (counts < 6).any():
        k = int(np.argmin(counts))
        raise ValueError(f"xy: camera {k} ({cameras[k].name or 'unnamed'}) sees {counts[k]} "
                         "tie points seen by another camera too; at least 6 are needed")
    X = np.asarray(triangulate(cameras, xy, min_angle_deg=0.0).points, float)
    if not np.isfinite(X).any():
        raise ValueError("xy: no tie point can be triangulated with the given cameras")
    return _State(cameras=cameras, xy=xy, X=X,
                  params0=np.stack([camera_to_params(c) for c in cameras]),
                  sigmas=np.stack([params.prior_sigmas(c) for c in cameras]),
                  used=seen & np.isfinite(X).all(axis=1)[None], vel=velocities)


def _adjust(st: _State, intrinsics, params: RefineParams, offsets=None):
    """One adjustment of the observations in use, ``intrinsics[k]`` free in camera k and
    the time offsets of the cameras where ``offsets`` (K,) is True (none: the problem
    without them). Returns the (K, 16) cameras, the (N, 3) points, the solution, the free
    mask and the problem."""
    sub = np.where(st.used.sum(axis=0) >= 2)[0]
    cam, pt, obs = _observations(np.where(st.used[:, sub, None], st.xy[:, sub], np.nan))
    toff = None if offsets is None or not np.any(offsets) else np.asarray(offsets, bool)
    pr = _Problem(params0=st.params0, sigmas=st.sigmas, cam=cam, pt=pt, obs=obs,
                  n_points=len(sub), sigma_px=params.sigma_px,
                  vel=None if toff is None else st.vel[cam, sub[pt]], toff=toff,
                  sigma_offset=params.sigma_offset)
    free = np.zeros(st.params0.shape, bool)
    free[:, :6] = True
    for k, names in enumerate(intrinsics):
        free[k, [PARAMETER_NAMES.index(n) for n in names]] = True
    cams, Xs, sol, fun = _solve(pr, free, st.X[sub], params)
    X = np.full_like(st.X, np.nan)
    X[sub] = Xs
    return cams, X, sol, fun, free, pr


def _choose_intrinsics(st: _State, params: RefineParams, offsets=None):
    """Adjust with every tried group free (and the time offsets where ``offsets``) and
    keep, per camera, the groups whose posterior standard deviations are all below
    ``information_ratio`` times the prior's."""
    tried = [n for g in params.groups for n in g]
    _, _, sol, _, free, pr = _adjust(st, [("f", *tried)] * len(st.cameras), params, offsets)
    post = _posterior_sigmas(sol, free, pr.n_off)
    post = post[0] if pr.n_off else post
    cols = [PARAMETER_NAMES.index(n) for n in tried]
    ratios = post[:, cols] / st.sigmas[:, cols]
    chosen = []
    for k in range(len(st.cameras)):
        names = ["f"]
        for g in params.groups:
            if all(ratios[k, tried.index(n)] < params.information_ratio for n in g):
                names += list(g)
        chosen.append(tuple(names))
    return tuple(chosen), ratios, tuple(tried)


def _offsets_of(sol, free, pr: _Problem) -> np.ndarray:
    """(K,) time offsets of a solution, frames (0 where not free)."""
    d = np.zeros(len(free))
    if pr.n_off:
        nf = int(free.sum())
        d[pr.toff] = sol.x[nf:nf + pr.n_off]
    return d


def _choose_offsets(st: _State, intrinsics, params: RefineParams):
    """Adjust with every camera's time offset free but the first's (the time datum) and
    free those more than ``offset_z`` standard errors from 0. Returns the (K,) bool mask
    and the (K,) z values (NaN for the first camera)."""
    trial = np.ones(len(st.cameras), bool)
    trial[0] = False
    _, _, sol, fun, free, pr = _adjust(st, intrinsics, params, trial)
    dof = max(1, 2 * len(pr.obs) - 3 * pr.n_points)
    sigma0 = float(np.sqrt(np.sum(fun ** 2) / dof))
    _, se = _posterior_sigmas(sol, free, pr.n_off)
    z = np.full(len(trial), np.nan)
    z[trial] = _offsets_of(sol, free, pr)[trial] / (se * max(1.0, sigma0))
    return np.abs(np.nan_to_num(z)) > params.offset_z, z


def _folds(params16: np.ndarray, camera: Camera) -> bool:
    """Whether the radial distortion of ``params16`` folds over inside the image (with a
    10 % margin): the distorted radius ``r (1 + k1 r² + k2 r⁴ + k3 r⁶)`` stops growing
    before it reaches the image's corners, so those pixels could not be undistorted."""
    f, cx, cy, k1, k2, k3 = params16[6:12]
    corners = np.array([[0, 0], [camera.width, 0], [0, camera.height],
                        [camera.width, camera.height]], float) - [cx, cy]
    reach = 1.1 * np.max(np.hypot(*corners.T)) / f          # distorted radius to reach
    r = np.linspace(0.0, 4.0 * reach, 800)                     # undistorted radii
    growing = 1 + 3 * k1 * r ** 2 + 5 * k2 * r ** 4 + 7 * k3 * r ** 6 > 0
    stop = np.argmin(growing) if not growing.all() else len(r) - 1
    r_d = r[stop] * (1 + k1 * r[stop] ** 2 + k2 * r[stop] ** 4 + k3 * r[stop] ** 6)
    return bool(not growing.all() and r_d < reach)


def _hold_folding(st: _State, cams, freed, params: RefineParams) -> tuple:
    """Hold the distortion group of a camera whose adjusted distortion folds inside its
    image (a sign of tie points that do not determine it), at the given values."""
    out = []
    for k, names in enumerate(freed):
        if _folds(cams[k], st.cameras[k]):
            held = {n for g in params.groups if {"k1", "k2", "k3"} & set(g) for n in g}
            names = tuple(n for n in names if n not in held)
        out.append(names)
    return tuple(out)


def _shift(st: _State, d) -> np.ndarray | None:
    """(K, N, 2) displacement of each observation by its camera's time offset ``d``."""
    return None if st.vel is None or d is None else st.vel * np.asarray(d)[:, None, None]


def _drop_outliers(st: _State, cams, X, params: RefineParams, shift=None) -> None:
    r = np.linalg.norm(_image_residuals(cams, X, st.xy, st.used, shift), axis=2)
    scale = max(params.sigma_px, float(np.nanmedian(r[st.used])) / np.sqrt(2 * np.log(2)))
    used = st.used & ~(r > params.reject_k * scale)
    st.used = used & (used.sum(axis=0) >= 2)[None]
    st.X = X


def refine_cameras(cameras, xy, *, params: RefineParams | None = None,
                   velocities=None) -> CameraRefinement:
    """Refine a rig's cameras from tie points, the given cameras acting as priors.

    Parameters
    ----------
    cameras : sequence of K Camera
        The rig as given (e.g. read from another tool's camera file).
    xy : (K, N, 2) array
        Tie points' image coordinates, px; NaN where a camera does not see a point. Points
        seen by fewer than two cameras are ignored.
    params : RefineParams, optional
    velocities : (K, N, 2) array, optional
        Each tie point's image velocity in each view, px per frame (NaN or 0: still or
        unknown). Given, a time offset per camera (the first camera the datum) is tried and
        freed where the data determines it (:attr:`RefineParams.offset_z`): a view that
        samples the scene ``d`` frames late sees the point at its projection plus
        ``velocity * d``. Where none is freed the result is that without ``velocities``.

    Returns
    -------
    CameraRefinement

    Raises
    ------
    ValueError
        Fewer than two cameras, a camera with fewer than 6 tie points, tie points that
        cannot be triangulated with the given cameras, or ``velocities`` not of ``xy``'s
        shape or not finite (NaN allowed).
    """
    params = RefineParams() if params is None else params
    st = _initial(tuple(cameras), xy, params, velocities)
    before = _image_residuals(st.params0, st.X, st.xy, st.used)
    freed, ratios, tried = _choose_intrinsics(st, params)
    offsets, z = (None, None) if st.vel is None else _choose_offsets(st, freed, params)
    if offsets is not None and offsets.any():
        freed, ratios, tried = _choose_intrinsics(st, params, offsets)
    cams, X, sol, _, free, pr = _adjust(st, freed, params, offsets)
    held = _hold_folding(st, cams, freed, params)
    if held != freed:
        freed = held
        cams, X, sol, _, free, pr = _adjust(st, freed, params, offsets)
    _drop_outliers(st, cams, X, params, _shift(st, _offsets_of(sol, free, pr)))
    cams, X, sol, fun, free, pr = _adjust(st, freed, params, offsets)
    d = None if st.vel is None else _offsets_of(sol, free, pr)
    dof = max(1, 2 * len(pr.obs) - 3 * pr.n_points)    # the priors add as many as they fix
    return CameraRefinement(
        cameras=tuple(params_to_camera(p, c) for p, c in zip(cams, st.cameras)), points=X,
        residuals_before=before,
        residuals=_image_residuals(cams, X, st.xy, st.used, _shift(st, d)),
        used=st.used, freed=freed, ratios=ratios, ratio_names=tried,
        sigma0=float(np.sqrt(np.sum(fun ** 2) / dof)),
        time_offsets=d, offset_z=z)
