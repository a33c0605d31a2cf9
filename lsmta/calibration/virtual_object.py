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

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_array
from ..triangulation import triangulate
from .bundle import (
    INTRINSIC_NAMES,
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
    """

    cameras: list
    error: np.ndarray
    fit_error: np.ndarray

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
        Most Gauss-Newton steps per point.
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
    params = np.stack([camera_to_params(c) for c in cams])[kk]
    obs = xy[kk, ii]
    N = len(X)

    def residuals(P):
        r = project_params(params, P[ii]) - obs
        return np.where(np.isfinite(r), r, 1e6)        # behind a camera: a large residual

    def cost(r):
        c = np.zeros(N)
        np.add.at(c, ii, (r**2).sum(axis=1))
        return c

    r = residuals(X)
    c = cost(r)
    lam = np.full(N, 1e-6)
    active = np.isfinite(X).all(axis=1) & (seen.sum(axis=0) >= 2)
    h = 1e-3                                            # mm, central differences
    eye = np.eye(3)
    for _ in range(int(n_iter)):
        if not active.any():
            break
        J = np.empty((len(kk), 2, 3))
        for a in range(3):
            J[:, :, a] = (project_params(params, X[ii] + h * eye[a])
                          - project_params(params, X[ii] - h * eye[a])) / (2 * h)
        J = np.nan_to_num(J)
        A = np.zeros((N, 3, 3))
        g = np.zeros((N, 3))
        np.add.at(A, ii, np.einsum("mji,mjk->mik", J, J))
        np.add.at(g, ii, np.einsum("mji,mj->mi", J, r))
        A[~active] = eye
        g[~active] = 0.0
        diag = np.maximum(np.einsum("nii->ni", A), 1e-12)
        pending = active.copy()
        step = np.zeros(N)
        for _ in range(10):                              # per-point damping
            dx = -np.linalg.solve(A + lam[:, None, None] * eye * diag[:, :, None],
                                  g[..., None])[..., 0]
            dx[~pending] = 0.0
            cn = cost(residuals(X + dx))
            better = pending & (cn <= c)
            X[better] += dx[better]
            c[better] = cn[better]
            step[better] = np.linalg.norm(dx[better], axis=1)
            lam[better] /= 10
            lam[pending & ~better] *= 10
            pending &= ~better
            if not pending.any():
                break
        r = residuals(X)
        # converged: a tiny step, or no step that lowers the cost
        active &= ~pending & (step >= tol * (1 + np.linalg.norm(X, axis=1)))
    return X


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
    X = triangulate_optimal(cams, xy)
    d = np.full(xy.shape[:2], np.nan)
    for k, cam in enumerate(cams):
        ok = np.isfinite(xy[k]).all(axis=1) & np.isfinite(X).all(axis=1)
        p = camera_to_params(cam)
        d[k, ok] = np.linalg.norm(project_params(p[None], X[ok]) - xy[k, ok], axis=1)
    return float(np.sqrt(np.nanmean(d**2)))


def _check_triangulation(triangulation):
    if triangulation not in ("optimal", "linear"):
        raise ValueError(f"triangulation: expected 'optimal' or 'linear', got {triangulation!r}")


def _history(cams_list, xy, xy_check, fit=None):
    err = np.array([projection_error(c, xy_check) if xy_check is not None else np.nan
                    for c in cams_list])
    if fit is None:
        fit = [projection_error(c, xy) for c in cams_list]
    return ConvergenceHistory(cameras=cams_list, error=err, fit_error=np.array(fit))


def resect(camera, X, xy, *, intrinsics=DAVIS_INTRINSICS):
    """Least-squares space resection: the exterior orientation and the free interior
    parameters of one camera from known points.

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
        Unchanged when fewer than ``min_points_per_camera`` points are usable, or when the
        solution leaves the valid camera model (f <= 0).
    """
    X = as_array(X, "X", shape=(None, 3), allow_nan=True)
    xy = as_array(xy, "xy", shape=(len(X), 2), allow_nan=True)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(xy).all(axis=1)
    free = np.zeros(16, bool)
    free[:6] = True
    for name in intrinsics:
        free[6 + INTRINSIC_NAMES.index(name)] = True
    if ok.sum() < min_points_per_camera(int(free.sum())):
        return camera
    p0 = camera_to_params(camera)
    Xo, obs = X[ok], xy[ok]

    def fun(x):
        p = p0.copy()
        p[free] = x
        return (project_params(p[None], Xo) - obs).ravel()

    sol = least_squares(fun, p0[free], method="lm", x_scale="jac")
    p = p0.copy()
    p[free] = sol.x
    try:
        return params_to_camera(p, camera)
    except ValueError:          # left the valid model (f <= 0, b1 <= -1): keep the old one
        return camera


def alternate(cameras, xy, *, n_iter: int = 30, intrinsics=DAVIS_INTRINSICS,
              xy_check=None, tol: float = 1e-6,
              triangulation: str = "optimal") -> ConvergenceHistory:
    """Davis's alternation: triangulate the path, resect every camera, repeat.

    Parameters
    ----------
    cameras : sequence of K Camera
        The initial guess.
    xy : (K, N, 2) array
        Observations of the calibration path, px (NaN: not seen).
    n_iter : int
        Alternations (stops early when the fit error - the objective - changes by less
        than ``tol`` relative).
    intrinsics : sequence of str
        Interior parameters re-solved with each camera's exterior orientation (the same
        as the joint adjustment's).
    xy_check : (K, M, 2) array, optional
        Independent path for the score.
    triangulation : {"optimal", "linear"}
        The point step. "optimal" (default): reprojection-optimal points, warm-started at
        the previous iteration's points, so that both blocks minimise the joint
        adjustment's objective (block-coordinate descent). "linear": Davis's linear
        intersection of the rays afresh at every iteration, which minimises 3-D ray
        distances, not image residuals, and so settles above the joint optimum.
    """
    _check_triangulation(triangulation)
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    hist = [cams]
    fit = [projection_error(cams, xy)]
    X = None
    for _ in range(int(n_iter)):
        if triangulation == "linear":
            X = _triangulate(cams, xy).points
        else:
            X = triangulate_optimal(cams, xy, points=X)
        cams = [resect(cam, X, xy[k], intrinsics=intrinsics) for k, cam in enumerate(cams)]
        hist.append(cams)
        fit.append(projection_error(cams, xy))
        if abs(fit[-2] - fit[-1]) < tol * fit[-1]:
            break
    return _history(hist, xy, xy_check, fit)


def joint_adjustment(cameras, xy, *, n_iter: int = 30, intrinsics=DAVIS_INTRINSICS,
                     xy_check=None) -> ConvergenceHistory:
    """Joint bundle adjustment of cameras and path from the same guess, scored after every
    Levenberg–Marquardt iteration of :func:`~lsmta.calibration.bundle_adjust` (its
    ``callback``)."""
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    X0 = _triangulate(cams, xy).points
    far = int(np.argmax([np.linalg.norm(c.C - cams[0].C) for c in cams]))
    r = bundle_adjust(cams, xy, X0, intrinsics=intrinsics, fixed_exterior=(0,),
                      scale_camera=far, max_nfev=int(n_iter) + 1, covariance=False)
    hist = [cams]
    for p in r.history:
        p = p.reshape(len(cams), 16)
        hist.append([params_to_camera(p[k], cams[k]) for k in range(len(cams))])
    return _history(hist, xy, xy_check)
