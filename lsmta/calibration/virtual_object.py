"""The virtual calibration object (Chen & Davis; Davis 2002, §3.2, Fig. 25).

One LED is carried through the room and seen by many cameras, not all of them seeing the
same part of its path. From a poor initial guess of the cameras, Davis *alternates*:
triangulate the path with the current cameras, then re-solve every camera from the path
(space resection: a least-squares resection of the exterior orientation and the free
interior parameters, :func:`resect`), and repeat. The alternative is the *joint* bundle
adjustment of cameras and path from the same guess
(:func:`~lsmta.calibration.bundle.bundle_adjust`, one camera's exterior orientation and
one coordinate of a second camera held as the datum).

Same objective in both blocks
    The joint adjustment minimises the sum of squared reprojection errors over the cameras'
    free parameters and the points. The alternation is block-coordinate descent on that
    same sum only if its point step minimises the reprojection error too: the default
    (``triangulation="optimal"``) starts each point at the linear intersection and
    refines it by Gauss-Newton on its reprojection error (:func:`triangulate_optimal`,
    vectorised over points). The linear intersection alone (``"linear"``, Davis's
    variant) minimises the squared *3-D* distances to the rays instead, which weighs a
    distant camera's pixel less than a near one's; alternating that with a resection
    (which minimises image residuals) is not a descent on any one objective and settles
    at a different point, above the joint optimum.

Both are scored after every iteration by the projection error on an independent path:
the independent observations are triangulated with the current cameras (reprojection-
optimal) and reprojected (RMS distance, px). This score does not depend on the datum, so
the two methods, whose frames drift differently, are compared fairly. ``fit_error`` is the
same on the calibration path: the RMS of the adjusted objective itself.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba as nb
import numpy as np

from .._validate import as_array, as_int, as_scalar
from ..triangulation import triangulate
from .bundle import (
    INTRINSIC_NAMES,
    BundleParams,
    Projector,
    _lens,
    bundle_adjust,
    camera_to_params,
    min_points_per_camera,
    params_to_camera,
    project_params,
)

DAVIS_INTRINSICS = ("f", "cx", "cy", "k1", "k2")


@dataclass(frozen=True, eq=False)
class ConvergenceHistory:
    """Cameras and scores after each iteration (index 0: the initial guess).

    Attributes
    ----------
    cameras : list of lists of Camera
    error : (n_iter + 1,) array
        Projection error on the independent path (RMS distance, px) after each iteration.
    fit_error : (n_iter + 1,) array
        The same on the calibration path itself: the RMS image distance (px) the joint
        adjustment minimises, with every point at its reprojection-optimal position.
    steps : tuple of str
        What each iteration was: ``"start"``, ``"exterior sweep"``, ``"sweep"`` (triangulate
        and resect all) or ``"joint"`` (one Levenberg-Marquardt step of the joint
        adjustment).
    seconds : float
        Wall time of the method (without the scores), s.
    """

    cameras: list
    error: np.ndarray
    fit_error: np.ndarray
    steps: tuple = ()
    seconds: float = float("nan")

    def iterations_to(self, *, tolerance: float = 0.01) -> int:
        """First iteration whose error is within ``tolerance`` (relative) of the final."""
        final = self.error[-1]
        return int(np.flatnonzero(self.error <= final * (1 + tolerance))[0])

    def iterations_to_value(self, value: float, *, tolerance: float = 0.01,
                            fit: bool = False) -> int | None:
        """First iteration whose error (``fit``: the fit error) is within ``tolerance``
        (relative) of ``value`` (for example another method's optimum); None if never."""
        e = self.fit_error if fit else self.error
        hit = np.flatnonzero(e <= value * (1 + tolerance))
        return int(hit[0]) if len(hit) else None


def _triangulate(cameras, xy):
    """Forward intersection that leaves out a camera whose current lens model cannot be
    inverted at its observations (a poor guess can fold the distortion polynomial)."""
    xy = xy.copy()
    for k, cam in enumerate(cameras):
        seen = np.isfinite(xy[k]).all(axis=1)
        try:
            cam.rays(xy[k, seen])
        except ValueError:
            xy[k] = np.nan
    return triangulate(cameras, xy, min_angle_deg=0.0)


def triangulate_optimal(cameras, xy, *, points=None, n_iter: int = 10,
                        tol: float = 1e-10) -> np.ndarray:
    """Reprojection-optimal forward intersection: every point minimises the sum of squared
    image distances to its observations (per-point Levenberg-Marquardt, vectorised over
    points), started at the linear intersection.

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : (K, N, 2) array
        Observations, px (NaN: not seen).
    points : (N, 3) array, optional
        Starting points, mm (default: the linear intersection).
    n_iter : int
        Most Levenberg-Marquardt steps per point (each damped per point).
    tol : float
        A point stops when its step is below ``tol`` times its distance from the origin
        (relative, mm).

    Returns
    -------
    (N, 3) array
        Points, mm; NaN for points seen by fewer than two cameras (or not intersected).
    """
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    X = (_triangulate(cams, xy).points if points is None
         else as_array(points, "points", shape=(xy.shape[1], 3), allow_nan=True).copy())
    seen = np.isfinite(xy).all(axis=2)
    kk, ii = np.nonzero(seen & np.isfinite(X).all(axis=1)[None, :])
    if len(kk) == 0:
        return X
    params = np.stack([camera_to_params(c) for c in cams])
    kk = np.ascontiguousarray(kk)
    project = Projector(params, kk)                        # rotations gathered once
    obs = xy[kk, ii]
    N, M = len(X), len(kk)

    # Every step works on the observations of the points still being solved only (the
    # others' numbers are not used): the same numbers as solving all points every time.
    def residuals(P, m, proj):
        r = proj(P[ii[m]]) - obs[m]
        return np.where(np.isfinite(r), r, 1e6)        # behind a camera: a large residual

    def cost(r, m):
        return np.bincount(ii[m], (r**2).sum(axis=1), N)

    everything = np.arange(M)
    r = residuals(X, everything, project)
    c = cost(r, everything)
    lam = np.full(N, 1e-6)
    active = np.isfinite(X).all(axis=1) & (seen.sum(axis=0) >= 2)
    h = 1e-3                                            # mm, central differences
    eye = np.eye(3)
    for _ in range(int(n_iter)):
        if not active.any():
            break
        ma = np.flatnonzero(active[ii])                  # observations of active points
        proj_a = project.subset(ma)
        J = _jacobian_points(project.subset(np.concatenate([ma] * 6)), X[ii[ma]], h)
        A, g = _normal_sums(np.ascontiguousarray(ii[ma]), J, r[ma], N)
        A[~active] = eye
        g[~active] = 0.0
        diag = np.maximum(np.einsum("nii->ni", A), 1e-12)
        pending, step = _damped_steps(X, c, lam, A, g, diag, active, ma, proj_a,
                                      lambda P, m, proj: cost(residuals(P, m, proj), m), ii)
        r[ma] = residuals(X, ma, proj_a)
        # converged: a tiny step, or no step that lowers the cost
        active &= ~pending & (step >= tol * (1 + np.linalg.norm(X, axis=1)))
    return X


def _damped_steps(X, c, lam, A, g, diag, active, ma, proj_a, cost_of, ii):
    """The per-point damping of one Levenberg-Marquardt step of :func:`triangulate_optimal`:
    up to ten tries per point, the damping ``lam`` (N,) times ten after a try that does not
    lower the cost ``c`` (N,), divided by ten after one that does (then taken: ``X``, ``c``
    and ``lam`` are updated in place). ``A`` (N, 3, 3), ``g`` (N, 3) and ``diag`` (N, 3) the
    normal equations, ``ma`` the observations of the ``active`` points and ``proj_a`` their
    projector; ``cost_of(P, m, proj)`` the (N,) cost of the points ``P`` over observations
    ``m``. Returns the (N,) points with no lower-cost step, and the (N,) step lengths, mm."""
    N = len(X)
    eye = np.eye(3)
    pending = active.copy()
    step = np.zeros(N)
    mp, proj_p = ma, proj_a
    for _ in range(10):
        p = np.flatnonzero(pending)
        dx = np.zeros((N, 3))
        dx[p] = -np.linalg.solve(A[p] + lam[p, None, None] * eye * diag[p, :, None],
                                 g[p, :, None])[..., 0]
        cn = cost_of(X + dx, mp, proj_p)
        better = pending & (cn <= c)
        X[better] += dx[better]
        c[better] = cn[better]
        step[better] = np.linalg.norm(dx[better], axis=1)
        lam[better] /= 10
        lam[pending & ~better] *= 10
        pending &= ~better
        if not pending.any():
            break
        keep = pending[ii[mp]]
        mp, proj_p = mp[keep], proj_p.subset(np.flatnonzero(keep))
    return pending, step


def _jacobian_points(project6: Projector, Xo, h: float) -> np.ndarray:
    """Central-difference Jacobian ``(M, 2, 3)`` of every observation's projection with
    respect to its point ``Xo`` (M, 3), step ``h`` mm: all six perturbed projections in one
    call of ``project6`` (the M observations' cameras six times over)."""
    eye = np.eye(3)
    M = len(Xo)
    Xp = np.concatenate([Xo + s * h * eye[a] for a in range(3) for s in (1, -1)])
    xy = project6(Xp).reshape(3, 2, M, 2)
    J = np.empty((M, 2, 3))
    for a in range(3):
        J[:, :, a] = (xy[a, 0] - xy[a, 1]) / (2 * h)
    return np.nan_to_num(J)


@nb.njit(cache=True, error_model="numpy")
def _normal_sums(index, J, r, n: int):
    """Normal equations of ``n`` small least-squares problems from their observations:
    ``A[q] = sum of J[m]^T J[m]`` ``(n, p, p)`` and ``g[q] = sum of J[m]^T r[m]`` ``(n, p)``
    over the observations m with ``index[m] == q``; ``J`` ``(M, 2, p)``, ``r`` ``(M, 2)``.
    The same numbers as ``np.einsum`` per observation summed by ``np.bincount`` (the
    same products, added in the same order)."""
    M, m2, p = J.shape
    A = np.zeros((n, p, p))
    g = np.zeros((n, p))
    for m in range(M):
        q = index[m]
        for i in range(p):
            for k in range(p):
                s = J[m, 0, i] * J[m, 0, k]
                for j in range(1, m2):
                    s = s + J[m, j, i] * J[m, j, k]
                A[q, i, k] += s
            s = J[m, 0, i] * r[m, 0]
            for j in range(1, m2):
                s = s + J[m, j, i] * r[m, j]
            g[q, i] += s
    return A, g


def projection_error(cameras, xy, *, triangulation: str = "optimal") -> float:
    """RMS image distance (px) between observations ``xy`` ``(K, N, 2)`` and the
    reprojection of the points triangulated from them with ``cameras``.

    ``triangulation="optimal"``: each point minimises its reprojection error
    (:func:`triangulate_optimal`); ``"linear"``: the linear intersection of the rays (a
    camera whose lens model folds over at its observations is left out of it).
    """
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    _check_triangulation(triangulation)
    if triangulation == "linear":
        inter = _triangulate(cams, xy)
        return float(np.sqrt(np.nanmean(inter.reprojection_error ** 2)))
    return _optimal_rms(cams, xy)[0]


def _optimal_rms(cams, xy, X=None):
    """:func:`projection_error` with reprojection-optimal points started at ``X`` (default:
    the linear intersection); also returns the points."""
    X = triangulate_optimal(cams, xy, points=X)
    ok = np.isfinite(xy).all(axis=2) & np.isfinite(X).all(axis=1)[None, :]
    kk, ii = np.nonzero(ok)
    P = np.stack([camera_to_params(c) for c in cams])
    d = np.linalg.norm(project_params(P, X[ii], rows=kk) - xy[kk, ii], axis=1)
    return float(np.sqrt(np.mean(d**2))), X


def _check_triangulation(triangulation):
    if triangulation not in ("optimal", "linear"):
        raise ValueError(f"triangulation: expected 'optimal' or 'linear', got {triangulation!r}")


def _history(cams_list, xy, xy_check, fit=None, *, steps, seconds):
    """Scores of every iteration's cameras, the points warm-started at the previous
    iteration's (the same optimum, found in fewer steps)."""
    def scores(obs):
        out, X = [], None
        for c in cams_list:
            e, X = _optimal_rms(c, obs, X)
            out.append(e)
        return np.array(out)

    err = scores(xy_check) if xy_check is not None else np.full(len(cams_list), np.nan)
    return ConvergenceHistory(cameras=cams_list, error=err,
                              fit_error=scores(xy) if fit is None else np.array(fit),
                              steps=tuple(steps), seconds=float(seconds))


def resect(camera, X, xy, *, intrinsics=DAVIS_INTRINSICS):
    """Least-squares space resection: the exterior orientation and the free interior
    parameters of one camera from known points (:func:`resect_all` for one camera).

    Parameters
    ----------
    camera : Camera
        Approximation.
    X : (N, 3) array
        Points, mm (NaN rows are left out).
    xy : (N, 2) array
        Their image coordinates, px (NaN rows are left out).
    intrinsics : sequence of str
        Free interior parameters (:data:`~lsmta.calibration.bundle.INTRINSIC_NAMES`).

    Returns
    -------
    Camera
        Unchanged when fewer than ``min_points_per_camera`` points are usable.
    """
    X = as_array(X, "X", shape=(None, 3), allow_nan=True)
    xy = as_array(xy, "xy", shape=(len(X), 2), allow_nan=True)
    return resect_all([camera], X, xy[None], intrinsics=intrinsics)[0]


def resect_all(cameras, X, xy, *, intrinsics=DAVIS_INTRINSICS, n_iter: int = 30,
               tol: float = 1e-8) -> list:
    """Space resection of K cameras at once from the same points: per camera,
    Levenberg-Marquardt on its squared image residuals over its exterior orientation and
    the free interior parameters, vectorised over cameras (central-difference Jacobians of
    all cameras in one projection per parameter; one damping factor per camera).

    Parameters
    ----------
    cameras : sequence of K Camera
        Approximations.
    X : (N, 3) array
        Points, mm (NaN rows are left out).
    xy : (K, N, 2) array
        Their image coordinates in each camera, px (NaN: not seen).
    intrinsics : sequence of str
        Free interior parameters, the same for every camera.
    n_iter : int
        Most iterations.
    tol : float
        A camera stops when its cost falls by less than ``tol`` (relative).

    Returns
    -------
    list of K Camera
        A camera seeing fewer than ``min_points_per_camera`` points is returned unchanged;
        a step that would leave the valid camera model (f <= 0, b1 <= -1) is refused.
    """
    cams = list(cameras)
    K = len(cams)
    X = as_array(X, "X", shape=(None, 3), allow_nan=True)
    xy = as_array(xy, "xy", shape=(K, len(X), 2), allow_nan=True)
    free = _free_mask(intrinsics)
    ok = np.isfinite(xy).all(axis=2) & np.isfinite(X).all(axis=1)[None, :]
    active = ok.sum(axis=1) >= min_points_per_camera(int(free.sum()))
    kk, ii = np.nonzero(ok & active[:, None])
    P = np.stack([camera_to_params(c) for c in cams])
    if len(kk):
        P = _lm_cameras(P, free, kk, X[ii], xy[kk, ii], active, int(n_iter), tol)
    return [params_to_camera(P[k], c) if active[k] else c for k, c in enumerate(cams)]


def _free_mask(intrinsics) -> np.ndarray:
    """(16,) bool: the exterior orientation and the named interior parameters."""
    free = np.zeros(16, bool)
    free[:6] = True
    for name in intrinsics:
        if name not in INTRINSIC_NAMES:
            raise ValueError(f"intrinsics: expected names from {INTRINSIC_NAMES}, got {name!r}")
        free[6 + INTRINSIC_NAMES.index(name)] = True
    return free


def _jacobian_cameras(P, cols, step, kk, Xo):
    """Central-difference Jacobian ``(M, 2, len(cols))`` of every observation's projection
    with respect to its camera's parameters ``cols``: all perturbations in one projection."""
    n, M, K = len(cols), len(kk), len(P)
    Q = np.repeat(P[None], 2 * n, axis=0)                         # (2n, K, 16)
    a = np.arange(n)
    Q[a, :, cols] += step[:, None]
    Q[n + a, :, cols] -= step[:, None]
    ext = np.concatenate([a[cols < 6], n + a[cols < 6]])          # perturbed pose
    lens = np.concatenate([a[cols >= 6], n + a[cols >= 6]])       # perturbed interior only
    xy = np.empty((2 * n, M, 2))
    rows = (np.arange(len(ext))[:, None] * K + kk[None, :]).ravel()
    xy[ext] = project_params(Q[ext].reshape(-1, 16), np.tile(Xo, (len(ext), 1)),
                             rows=rows).reshape(len(ext), M, 2)
    if len(lens):
        # the pose is unperturbed: the camera coordinates are the same, only the lens runs
        rows = (np.arange(len(lens))[:, None] * K + kk[None, :]).ravel()
        Xc = np.tile(Projector(P, kk).frame(Xo), (len(lens), 1))
        out = np.empty((len(Xc), 2))
        _lens(Xc, np.ascontiguousarray(Q[lens].reshape(-1, 16)[:, 6:]), rows, out)
        xy[lens] = out.reshape(len(lens), M, 2)
    J = (xy[:n] - xy[n:]) / (2 * step[:, None, None])             # (n, M, 2)
    return np.ascontiguousarray(np.nan_to_num(np.transpose(J, (1, 2, 0))))


def _lm_cameras(P, free, kk, Xo, obs, active, n_iter, tol):
    """Per-camera Levenberg-Marquardt (see :func:`resect_all`); ``kk`` (M,) the camera of
    each observation ``obs`` (M, 2) of point ``Xo`` (M, 3); returns the new (K, 16)."""
    K = len(P)
    kk = np.ascontiguousarray(kk)                  # one compiled signature of _normal_sums
    cols = np.flatnonzero(free)
    step = np.where(cols < 3, 1e-6, 1e-6 * np.maximum(1.0, np.abs(P[:, cols]).max(axis=0)))

    def residuals(Q):
        r = project_params(Q, Xo, rows=kk) - obs
        return np.where(np.isfinite(r), r, 1e6)

    def cost(r):
        return np.bincount(kk, (r**2).sum(axis=1), K)

    def valid(Q):
        return (Q[:, 6] > 0) & (Q[:, 14] > -1)

    P = P.copy()
    r = residuals(P)
    c = cost(r)
    lam = np.full(K, 1e-3)
    running = active.copy()
    eye = np.eye(len(cols))
    for _ in range(n_iter):
        if not running.any():
            break
        J = _jacobian_cameras(P, cols, step, kk, Xo)
        A, g = _normal_sums(kk, J, r, K)
        A[~running] = eye
        g[~running] = 0.0
        diag = np.maximum(np.einsum("kii->ki", A), 1e-12)
        pending = running.copy()
        for _ in range(10):                                  # per-camera damping
            dp = -np.linalg.solve(A + lam[:, None, None] * eye * diag[:, :, None],
                                  g[..., None])[..., 0]
            dp[~pending] = 0.0
            Q = P.copy()
            Q[:, cols] += dp
            cn = np.where(valid(Q), cost(residuals(Q)), np.inf)
            better = pending & (cn <= c)
            drop = np.where(better, (c - cn) / np.maximum(c, 1e-300), 0.0)
            P[better] = Q[better]
            c[better] = cn[better]
            lam[better] = np.maximum(lam[better] / 10, 1e-12)
            lam[pending & ~better] *= 10
            running &= ~(better & (drop < tol))
            pending &= ~better
            if not pending.any():
                break
        running &= ~pending                                  # no step lowers the cost
        r = residuals(P)
    return P


@dataclass(frozen=True)
class AlternationParams:
    """Settings of :func:`alternate`.

    Attributes
    ----------
    n_iter : int
        Most iterations: sweeps (triangulate every point, resect every camera) plus joint
        steps. Stops early when the fit error (the objective) changes by less than ``tol``
        (relative) in one iteration after the exterior-only sweeps.
    intrinsics : tuple of str
        Interior parameters re-solved with each camera's exterior orientation (the same as
        the joint adjustment's).
    tol : float
    triangulation : {"optimal", "linear"}
        The point step. "optimal": reprojection-optimal points, warm-started at the
        previous iteration's points, so that both blocks minimise the joint adjustment's
        objective (block-coordinate descent). "linear": Davis's linear intersection of the
        rays afresh at every sweep, which minimises 3-D ray distances, not image
        residuals, and so settles above the joint optimum.
    exterior_first : int
        The first sweeps resect the exterior orientation only (the interior parameters
        stay at the guess): a poor path then cannot be absorbed by bending every camera's
        lens, which sends the plain alternation down a long, nearly flat valley of the
        objective.
    joint_every : int or None
        After every ``joint_every`` sweeps, ``joint_steps`` Levenberg-Marquardt steps of
        the joint adjustment of cameras and points (from the alternation's cameras and
        points): they move both blocks together along the directions that couple them,
        where block-coordinate descent zig-zags. None: the paper's plain alternation.
    joint_steps : int
    """

    n_iter: int = 30
    intrinsics: tuple = DAVIS_INTRINSICS
    tol: float = 1e-6
    triangulation: str = "optimal"
    exterior_first: int = 0
    joint_every: int | None = None
    joint_steps: int = 2

    def __post_init__(self):
        _check_triangulation(self.triangulation)
        for key, low in (("n_iter", 0), ("exterior_first", 0), ("joint_steps", 1)):
            as_int(getattr(self, key), key, minimum=low)
        as_int(self.joint_every, "joint_every", allow_none=True)
        if self.joint_every is not None and self.triangulation != "optimal":
            raise ValueError("joint_every: joint steps need triangulation='optimal' (the "
                             "joint adjustment minimises image residuals)")
        _free_mask(self.intrinsics)
        as_scalar(self.tol, "tol", nonnegative=True)


# The documented change that brings the alternation to the joint optimum (notebook 01)
IMPROVED_ALTERNATION = AlternationParams(n_iter=50, tol=1e-4, exterior_first=3,
                                         joint_every=4, joint_steps=2)


def alternate(cameras, xy, *, params: AlternationParams | None = None,
              xy_check=None) -> ConvergenceHistory:
    """Davis's alternation: triangulate the path, resect every camera, repeat
    (with :data:`IMPROVED_ALTERNATION`: exterior-only sweeps first, and joint steps).

    Parameters
    ----------
    cameras : sequence of K Camera
        The initial guess.
    xy : (K, N, 2) array
        Observations of the calibration path, px (NaN: not seen).
    params : AlternationParams, optional
        Default: the paper's plain alternation (reprojection-optimal points).
    xy_check : (K, M, 2) array, optional
        Independent path for the score.
    """
    p = AlternationParams() if params is None else params
    if not isinstance(p, AlternationParams):
        raise TypeError("params: expected an AlternationParams")
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    t0 = time.perf_counter()
    state = _Alternation(cams=cams, hist=[cams], fit=[projection_error(cams, xy)],
                         steps=["start"])
    far = int(np.argmax([np.linalg.norm(c.C - cams[0].C) for c in cams]))
    sweeps = 0
    while len(state.hist) <= p.n_iter:
        sweeps += 1
        _sweep(state, xy, p, exterior_only=sweeps <= p.exterior_first)
        if p.joint_every and sweeps >= p.exterior_first \
                and (sweeps - p.exterior_first) % p.joint_every == 0:
            _joint_steps(state, xy, p, far)
        if sweeps > p.exterior_first and abs(state.fit[-2] - state.fit[-1]) < p.tol * \
                state.fit[-1]:
            break
    return _history(state.hist[:p.n_iter + 1], xy, xy_check, state.fit[:p.n_iter + 1],
                    steps=state.steps[:p.n_iter + 1], seconds=time.perf_counter() - t0)


@dataclass
class _Alternation:
    """The running state of :func:`alternate`."""

    cams: list
    hist: list
    fit: list
    steps: list
    X: np.ndarray | None = None


def _sweep(state: _Alternation, xy, p: AlternationParams, *, exterior_only: bool) -> None:
    """Triangulate every point with the current cameras, then resect every camera."""
    if p.triangulation == "linear":
        state.X = _triangulate(state.cams, xy).points
    else:
        state.X = triangulate_optimal(state.cams, xy, points=state.X)
    state.cams = resect_all(state.cams, state.X, xy,
                            intrinsics=() if exterior_only else p.intrinsics, n_iter=10)
    _record(state, xy, "exterior sweep" if exterior_only else "sweep")


def _joint_steps(state: _Alternation, xy, p: AlternationParams, far: int) -> None:
    """``p.joint_steps`` Levenberg-Marquardt steps of the joint adjustment from the current
    cameras and (reprojection-optimal) points; each step is one iteration."""
    X = triangulate_optimal(state.cams, xy, points=state.X)
    r = bundle_adjust(state.cams, xy, X, intrinsics=p.intrinsics, fixed_exterior=(0,),
                      scale_camera=far,
                      params=BundleParams(max_nfev=p.joint_steps, covariance=False))
    K = len(state.cams)
    for q in r.history:
        q = q.reshape(K, 16)
        state.cams = [params_to_camera(q[k], state.cams[k]) for k in range(K)]
        _record(state, xy, "joint")
    if r.history:
        state.X = np.where(np.isfinite(r.points), r.points, X)


def _record(state: _Alternation, xy, step: str) -> None:
    state.hist.append(state.cams)
    state.fit.append(_optimal_rms(state.cams, xy, state.X)[0])
    state.steps.append(step)


def joint_adjustment(cameras, xy, *, n_iter: int = 30, intrinsics=DAVIS_INTRINSICS,
                     xy_check=None) -> ConvergenceHistory:
    """Joint bundle adjustment of cameras and path from the same guess, scored after every
    Levenberg–Marquardt iteration of :func:`~lsmta.calibration.bundle_adjust` (its
    ``callback``)."""
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    X0 = _triangulate(cams, xy).points
    far = int(np.argmax([np.linalg.norm(c.C - cams[0].C) for c in cams]))
    t0 = time.perf_counter()
    r = bundle_adjust(cams, xy, X0, intrinsics=intrinsics, fixed_exterior=(0,),
                      scale_camera=far,
                      params=BundleParams(max_nfev=int(n_iter) + 1, covariance=False))
    seconds = time.perf_counter() - t0
    hist = [cams]
    for p in r.history:
        p = p.reshape(len(cams), 16)
        hist.append([params_to_camera(p[k], cams[k]) for k in range(len(cams))])
    return _history(hist, xy, xy_check, steps=["start"] + ["joint"] * (len(hist) - 1),
                    seconds=seconds)
