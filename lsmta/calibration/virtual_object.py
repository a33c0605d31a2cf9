"""The virtual calibration object (Chen & Davis; Davis 2002, §3.2, Fig. 25).

One LED is carried through the room and seen by many cameras, not all of them seeing the
same part of its path. From a poor initial guess of the cameras, Davis *alternates*:
triangulate the path with the current cameras, then re-solve every camera from the path
(space resection; here a least-squares resection of the exterior orientation and the
free interior parameters, :func:`~lsmta.calibration.bundle.bundle_adjust` with the points
held), and repeat. The alternative is the *joint* bundle adjustment of cameras and path
from the same guess (:func:`~lsmta.calibration.bundle.bundle_adjust`, one camera's
exterior orientation and one coordinate of a second camera held as the datum).

Both are scored after every iteration by the projection error on an independent path:
the independent observations are triangulated with the current cameras and reprojected
(RMS distance, px). This score does not depend on the datum, so the two methods, whose
frames drift differently, are compared fairly.
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
        The same on the calibration path itself.
    """

    cameras: list
    error: np.ndarray
    fit_error: np.ndarray

    def iterations_to(self, tolerance: float = 0.01) -> int:
        """First iteration whose error is within ``tolerance`` (relative) of the final."""
        final = self.error[-1]
        return int(np.flatnonzero(self.error <= final * (1 + tolerance))[0])


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


def projection_error(cameras, xy) -> float:
    """RMS image distance (px) between observations ``xy`` ``(K, N, 2)`` and the
    reprojection of the points triangulated from them with ``cameras`` (a camera whose lens
    model folds over at its observations is left out of the intersection)."""
    xy = as_array(xy, "xy", shape=(len(cameras), None, 2), allow_nan=True)
    inter = _triangulate(cameras, xy)
    return float(np.sqrt(np.nanmean(inter.reprojection_error ** 2)))


def _history(cams_list, xy, xy_check):
    err = np.array([projection_error(c, xy_check) if xy_check is not None else np.nan
                    for c in cams_list])
    fit = np.array([projection_error(c, xy) for c in cams_list])
    return ConvergenceHistory(cams_list, err, fit)


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
        return (project_params(np.tile(p, (len(Xo), 1)), Xo) - obs).ravel()

    sol = least_squares(fun, p0[free], method="lm", x_scale="jac")
    p = p0.copy()
    p[free] = sol.x
    try:
        return params_to_camera(p, camera)
    except ValueError:          # left the valid model (f <= 0, b1 <= -1): keep the old one
        return camera


def alternate(cameras, xy, *, n_iter: int = 30, intrinsics=DAVIS_INTRINSICS,
              xy_check=None, tol: float = 1e-6) -> ConvergenceHistory:
    """Davis's alternation: triangulate the path, resect every camera, repeat.

    Parameters
    ----------
    cameras : sequence of K Camera
        The initial guess.
    xy : (K, N, 2) array
        Observations of the calibration path, px (NaN: not seen).
    n_iter : int
        Alternations (stops early when the fit error changes by less than ``tol``
        relative).
    intrinsics : sequence of str
        Interior parameters re-solved with each camera's exterior orientation.
    xy_check : (K, M, 2) array, optional
        Independent path for the score.
    """
    cams = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    hist = [cams]
    prev = projection_error(cams, xy)
    for _ in range(int(n_iter)):
        X = _triangulate(cams, xy).points
        cams = [resect(cam, X, xy[k], intrinsics=intrinsics) for k, cam in enumerate(cams)]
        hist.append(cams)
        cur = projection_error(cams, xy)
        if abs(prev - cur) < tol * cur:
            break
        prev = cur
    return _history(hist, xy, xy_check)


def joint_adjustment(cameras, xy, *, n_iter: int = 30, intrinsics=DAVIS_INTRINSICS,
                     xy_check=None) -> ConvergenceHistory:
    """Joint bundle adjustment of cameras and path from the same guess, scored after every
    solver iteration (``least_squares`` callback)."""
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
