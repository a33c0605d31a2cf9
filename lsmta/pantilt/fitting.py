"""Calibration of pan-tilt cameras by nonlinear least squares (Davis 2002, eqs. 3 and 4).

As in the thesis, the intrinsics (principal distance, principal point, distortion) come
first, from one view of a 3-D target (:func:`calibrate_intrinsics`); then the home pose and,
for the general model, the two axes, from stacked (pan, tilt, world point, image point)
observations (:func:`calibrate`). Both minimise image residuals in pixels with
:func:`scipy.optimize.least_squares`, optionally under a robust loss, and report parameter
standard deviations from the Jacobian at the solution.

Parameters of :func:`calibrate` (names in :attr:`Fit.names`)
    ``omega_x, omega_y, omega_z``
        Small rotation (degrees) of the home orientation from the starting one,
        ``R0 = R_start @ rot(omega)^T`` (the camera turns by ``omega`` about its own axes).
    ``C_x, C_y, C_z``
        Projection centre at home, world mm.
    general model only: ``pan_dir_x, pan_dir_z``
        Pan axis direction in the home camera frame, ``(pan_dir_x, 1, pan_dir_z)``
        normalised: the tangents of its tilt from the camera's y axis.
    ``pan_off_x, pan_off_z``
        The pan axis passes through ``(pan_off_x, 0, pan_off_z)`` (mm, home camera frame,
        relative to the projection centre).
    ``tilt_dir_y, tilt_dir_z``, ``tilt_off_y, tilt_off_z``
        Likewise for the tilt axis, ``(1, tilt_dir_y, tilt_dir_z)`` through
        ``(0, tilt_off_y, tilt_off_z)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._validate import as_array, as_points, freeze
from ..camera import Camera
from .model import (
    EVI_D30_PAN_LIMITS,
    EVI_D30_TILT_LIMITS,
    PanTiltCamera,
    _image,
    check_angles,
    pose_arrays,
)

POSE_NAMES = ("omega_x", "omega_y", "omega_z", "C_x", "C_y", "C_z")
AXIS_NAMES = ("pan_dir_x", "pan_dir_z", "pan_off_x", "pan_off_z",
              "tilt_dir_y", "tilt_dir_z", "tilt_off_y", "tilt_off_z")
INTRINSIC_NAMES = ("f", "cx", "cy")
LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


@dataclass(frozen=True, eq=False)
class Fit:
    """Result of a calibration.

    Attributes
    ----------
    model : PanTiltCamera or Camera
        The calibrated model (:func:`calibrate`) or camera (:func:`calibrate_intrinsics`).
    names : tuple of str
        Parameter names (see the module docstring).
    params : (P,) array
        Estimated parameters (degrees for ``omega_*``, mm for positions and offsets, pixels
        for ``f, cx, cy``, dimensionless otherwise).
    std : (P,) array
        Standard deviations from the Jacobian, ``s² (JᵀJ)⁻¹`` with ``s²`` the residual
        variance per degree of freedom (approximate under a robust loss).
    covariance : (P, P) array
        The covariance matrix behind ``std``.
    residuals : (N, 2) array
        Modelled minus observed image points at the solution, pixels.
    sigma_px : float
        Residual standard deviation per image coordinate, ``sqrt(s²)``, pixels.
    loss : str
        The loss used.
    nfev : int
        Number of model evaluations.
    """

    model: object
    names: tuple
    params: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    sigma_px: float
    loss: str
    nfev: int

    def __post_init__(self):
        freeze(self, ("params", "std", "covariance", "residuals"))

    @property
    def errors(self) -> np.ndarray:
        """Length of each residual ``(N,)``, pixels."""
        return np.hypot(self.residuals[:, 0], self.residuals[:, 1])

    def table(self) -> dict:
        """``{name: (value, std)}``."""
        return {n: (float(v), float(s)) for n, v, s in zip(self.names, self.params, self.std)}


# ---------------------------------------------------------------------- helpers
def _rot(omega_deg) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.radians(np.asarray(omega_deg, dtype=float)))
    return R


def _check_loss(loss: str, f_scale: float):
    if loss not in LOSSES:
        raise ValueError(f"loss: expected one of {LOSSES}, got {loss!r}")
    if not f_scale > 0:
        raise ValueError(f"f_scale: expected a positive number of pixels, got {f_scale}")


def _covariance(res, names):
    J = res.jac
    m, n = J.shape
    dof = m - n
    s2 = 2 * res.cost / dof if dof > 0 else np.nan
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    _, sv, vt = np.linalg.svd(Js, full_matrices=False)
    if sv[-1] < 1e-5 * sv[0]:  # finite-difference Jacobians leave ~1e-7 in a null direction
        worst = names[int(np.argmax(np.abs(vt[-1])))]
        raise ValueError(
            f"pan, tilt: the observations do not determine the parameters (parameter {worst!r} "
            "is not constrained); spread the settings over both axes and the points over the "
            "image")
    cov = np.linalg.inv(Js.T @ Js) / np.outer(scale, scale) * s2
    return cov, np.sqrt(np.clip(np.diag(cov), 0, None)), float(np.sqrt(s2))


def model_from_params(start: Camera, params, kind: str, *,
                      pan_limits=EVI_D30_PAN_LIMITS,
                      tilt_limits=EVI_D30_TILT_LIMITS) -> PanTiltCamera:
    """The :class:`PanTiltCamera` described by ``params`` (see the module docstring) with
    intrinsics and starting orientation from ``start``, and the head's range
    ``pan_limits``, ``tilt_limits`` (degrees)."""
    p = np.asarray(params, dtype=float)
    R0 = np.asarray(start.R) @ _rot(p[:3]).T
    cam = start.replace(R=R0, C=p[3:6])
    if kind == "simple":
        return PanTiltCamera.simple(cam, pan_limits=pan_limits, tilt_limits=tilt_limits)
    a, b, ox, oz, c, d, oy, oz2 = p[6:14]
    return PanTiltCamera.from_offsets(cam, pan_axis_cam=(a, 1.0, b), pan_point_cam=(ox, 0.0, oz),
                                      tilt_axis_cam=(1.0, c, d), tilt_point_cam=(0.0, oy, oz2),
                                      pan_limits=pan_limits, tilt_limits=tilt_limits)


def project_pantilt_params(start: Camera, params, kind: str, X, pan, tilt) -> np.ndarray:
    """``model_from_params(start, params, kind)._project(X, pan, tilt)`` without building
    the model (the inner loop of :func:`calibrate` and the posterior); no argument checks."""
    p = np.asarray(params, dtype=float)
    R0 = np.asarray(start.R) @ _rot(p[:3]).T
    C0 = p[3:6]
    if kind == "simple":
        dp, qp, dt, qt = R0[1], C0, R0[0], C0
    else:
        a, b, ox, oz, c, d, oy, oz2 = p[6:14]
        dp = np.array([a, 1.0, b]) @ R0
        dt = np.array([1.0, c, d]) @ R0
        dp, dt = dp / np.linalg.norm(dp), dt / np.linalg.norm(dt)
        qp = C0 + np.array([ox, 0.0, oz]) @ R0
        qt = C0 + np.array([0.0, oy, oz2]) @ R0
    R, C = pose_arrays(R0, C0, dp, qp, dt, qt, pan, tilt)
    return _image(start, np.einsum("nij,nj->ni", R, X - C), "nan")


def params_from_model(model: PanTiltCamera, *, start: Camera | None = None) -> np.ndarray:
    """Inverse of :func:`model_from_params` for a general model (14 numbers).

    Relies on the sign convention that :class:`PanTiltCamera` enforces (pan axis along the
    camera's +y, tilt axis along +x), so the divisions by those components are safe and keep
    each axis's sense."""
    start = model.camera if start is None else start
    R = np.asarray(model.camera.R)
    rvec, _ = cv2.Rodrigues(R.T @ np.asarray(start.R))
    out = [*np.degrees(rvec.ravel()), *model.camera.C]
    dp, dt = R @ model.pan_axis, R @ model.tilt_axis
    pp = R @ (model.pan_point - model.camera.C)
    pt = R @ (model.tilt_point - model.camera.C)
    # move each point along its axis to the plane y = 0 (pan) or x = 0 (tilt)
    pp = pp - dp * pp[1] / dp[1]
    pt = pt - dt * pt[0] / dt[0]
    out += [dp[0] / dp[1], dp[2] / dp[1], pp[0], pp[2], dt[1] / dt[0], dt[2] / dt[0], pt[1], pt[2]]
    return np.array(out)


def _observations(pan, tilt, X, xy, model_limits):
    X = as_points(X, "X")
    xy = as_points(xy, "xy", 2)
    if len(xy) != len(X):
        raise ValueError(f"xy: expected {len(X)} image points like X, got {len(xy)}")
    pan = check_angles(pan, "pan", model_limits[0])
    tilt = check_angles(tilt, "tilt", model_limits[1])
    try:
        pan, tilt = (np.broadcast_to(a, (len(X),)).copy() for a in (pan, tilt))
    except ValueError:
        raise ValueError(f"pan, tilt: expected scalars or arrays of shape ({len(X)},) like X, "
                         f"got shapes {np.shape(pan)} and {np.shape(tilt)}") from None
    both = np.concatenate([pan, tilt])
    if np.any(both != 0) and np.all(np.abs(both) <= np.pi / 2):
        raise ValueError(
            "pan, tilt: every setting lies within ±π/2 but not all are zero; angles are in "
            "degrees and these look like radians (multiply by 180/π)")
    return pan, tilt, X, xy


# ---------------------------------------------------------------------- public
def calibrate(camera: Camera, pan, tilt, X, xy, *, kind: str = "general",
              loss: str = "linear", f_scale: float = 5.0, start: PanTiltCamera | None = None,
              pan_limits=None, tilt_limits=None) -> Fit:
    """Home pose and (general model) both axes from stacked observations (eq. 4).

    Parameters
    ----------
    camera : Camera
        Calibrated intrinsics (:func:`calibrate_intrinsics`) and a rough home pose to start
        from; the intrinsics stay fixed.
    pan, tilt : (N,) arrays or scalars
        Setting of each observation, degrees.
    X : (N, 3) array
        World points, mm.
    xy : (N, 2) array
        Their observed image points, pixels.
    kind : {"general", "simple"}
        Model to fit. The general model is started from the simple model's solution.
    loss : {"linear", "soft_l1", "huber", "cauchy", "arctan"}
        ``scipy.optimize.least_squares`` loss; ``f_scale`` (pixels) is where a robust loss
        starts to discount residuals.
    start : PanTiltCamera, optional
        Starting model for the general fit (instead of the simple model's solution).
    pan_limits, tilt_limits : (float, float), optional
        The head's range in degrees (default: that of ``start``, else the EVI-D30's).

    Returns
    -------
    Fit
        ``model`` is a :class:`PanTiltCamera` of the requested kind.

    Raises
    ------
    ValueError
        For too few observations or settings to determine the model (the general model needs
        at least two pan and two tilt settings), or settings that leave a parameter
        undetermined.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera: expected an lsmta.Camera, got {type(camera).__name__}")
    if kind not in ("simple", "general"):
        raise ValueError(f"kind: expected 'simple' or 'general', got {kind!r}")
    _check_loss(loss, f_scale)
    ref = start if start is not None else PanTiltCamera.simple(camera)
    pan_limits = ref.pan_limits if pan_limits is None else tuple(pan_limits)
    tilt_limits = ref.tilt_limits if tilt_limits is None else tuple(tilt_limits)
    pan, tilt, X, xy = _observations(pan, tilt, X, xy, (pan_limits, tilt_limits))
    names = POSE_NAMES + (AXIS_NAMES if kind == "general" else ())
    if 2 * len(X) <= len(names):
        raise ValueError(f"X: {len(X)} observations are too few for the {kind} model's "
                         f"{len(names)} parameters; expected at least {len(names) // 2 + 1}")
    if kind == "general":
        n_pan = len(np.unique(np.round(pan, 6)))
        n_tilt = len(np.unique(np.round(tilt, 6)))
        if n_pan < 2 or n_tilt < 2:
            raise ValueError(
                f"pan, tilt: the general model needs observations at two or more pan settings "
                f"and two or more tilt settings to determine both axes; got {n_pan} pan and "
                f"{n_tilt} tilt setting(s)")
    res = _solve(camera, pan, tilt, X, xy, kind=kind, start=start, loss=loss, f_scale=f_scale)
    cov, std, sigma = _covariance(res, names)
    model = model_from_params(camera, res.x, kind, pan_limits=pan_limits,
                              tilt_limits=tilt_limits)
    r = (model._project(X, pan, tilt) - xy)
    return Fit(model=model, names=names, params=res.x, std=std, covariance=cov, residuals=r,
               sigma_px=sigma, loss=loss, nfev=int(res.nfev))


def _solve(camera: Camera, pan, tilt, X, xy, *, kind: str, start, loss: str, f_scale: float):
    """The least-squares stage of :func:`calibrate` on checked observations: the simple
    model from the rough home pose, then (``kind="general"``) the general model from it, or
    from ``start`` when given. Returns SciPy's result."""

    def residuals(p, kind_):
        return (project_pantilt_params(camera, p, kind_, X, pan, tilt) - xy).ravel()

    def solve(p0, kind_):
        def fun(p):
            r = residuals(p, kind_)
            return np.where(np.isfinite(r), r, 1e4)
        return least_squares(fun, p0, loss=loss, f_scale=f_scale, x_scale="jac", method="trf")

    if kind == "general" and start is not None:
        p0 = params_from_model(start, start=camera)
    else:
        simple = solve(np.r_[np.zeros(3), camera.C], "simple")
        p0 = np.r_[simple.x, np.zeros(8)] if kind == "general" else None
        res = simple
    if kind == "general":
        res = solve(p0, "general")
    return res


def dlt_camera(X, xy, image_size, *, name: str = "") -> Camera:
    """A distortion-free camera from the direct linear transform of >= 6 non-coplanar points.

    The starting point of :func:`calibrate_intrinsics`; principal distance from the mean of
    the two focal lengths, no skew.
    """
    X = as_points(X, "X")
    xy = as_points(xy, "xy", 2)
    if len(X) < 6 or len(xy) != len(X):
        raise ValueError(f"X, xy: expected at least 6 matching points, got {len(X)} and {len(xy)}")
    A = np.zeros((2 * len(X), 12))
    Xh = np.c_[X, np.ones(len(X))]
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -xy[:, :1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -xy[:, 1:] * Xh
    _, sv, vt = np.linalg.svd(A)
    if sv[-2] < 1e-9 * sv[0]:
        raise ValueError("X: the points are (nearly) coplanar or collinear; the direct linear "
                         "transform needs a 3-D target")
    P = vt[-1].reshape(3, 4)
    K, R, Ch = cv2.decomposeProjectionMatrix(P)[:3]
    K = K / K[2, 2]
    C = Ch[:3, 0] / Ch[3, 0]
    # make the focal lengths positive and R proper
    S = np.diag(np.sign(np.diag(K)))
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:
        R = -R
    if np.mean((X - C) @ R[2]) < 0:  # points must be in front
        R = np.diag([-1.0, -1.0, 1.0]) @ R
        K = K @ np.diag([-1.0, -1.0, 1.0])
    f = 0.5 * (abs(K[0, 0]) + abs(K[1, 1]))
    return Camera(f=f, cx=K[0, 2], cy=K[1, 2], width=image_size[0], height=image_size[1], R=R,
                  C=C, name=name)


def calibrate_intrinsics(X, xy, image_size, *, distortion=("k1", "k2", "p1", "p2"),
                         loss: str = "linear", f_scale: float = 5.0, name: str = "") -> Fit:
    """Intrinsics and pose from one view of a 3-D target (the thesis's pre-process).

    Parameters
    ----------
    X : (N, 3) array
        Target points, mm; must not be coplanar (N >= 6; many more for distortion).
    xy : (N, 2) array
        Their observed image points, pixels.
    image_size : (int, int)
        ``(width, height)`` in pixels.
    distortion : tuple of str
        Which of ``k1, k2, k3, p1, p2`` to estimate (the others stay zero).
    loss, f_scale : see :func:`calibrate`.

    Returns
    -------
    Fit
        ``model`` is a :class:`~lsmta.camera.Camera`; ``names`` are ``f, cx, cy``, the
        distortion names and the pose names of :func:`calibrate`.
    """
    _check_loss(loss, f_scale)
    allowed = ("k1", "k2", "k3", "p1", "p2")
    distortion = tuple(distortion)
    if any(d not in allowed for d in distortion) or len(set(distortion)) != len(distortion):
        raise ValueError(f"distortion: expected distinct names from {allowed}, got {distortion}")
    X = as_points(X, "X")
    xy = as_array(xy, "xy", shape=(len(X), 2))
    names = INTRINSIC_NAMES + distortion + POSE_NAMES
    if 2 * len(X) <= len(names):
        raise ValueError(f"X: expected more than {len(names) // 2} points for {len(names)} "
                         f"parameters, got {len(X)}")
    start = dlt_camera(X, xy, image_size, name=name)

    def build(p):
        return start.replace(f=p[0], cx=p[1], cy=p[2], **dict(zip(distortion, p[3:-6])),
                             R=np.asarray(start.R) @ _rot(p[-6:-3]).T, C=p[-3:])

    def fun(p):
        r = (build(p).project(X, behind="nan") - xy).ravel()
        return np.where(np.isfinite(r), r, 1e4)

    p0 = np.r_[start.f, start.cx, start.cy, np.zeros(len(distortion)), np.zeros(3), start.C]
    res = least_squares(fun, p0, loss=loss, f_scale=f_scale, x_scale="jac")
    cov, std, sigma = _covariance(res, names)
    cam = build(res.x)
    return Fit(model=cam, names=names, params=res.x, std=std, covariance=cov,
               residuals=cam.project(X) - xy, sigma_px=sigma, loss=loss, nfev=int(res.nfev))


def projection_errors(model: PanTiltCamera, pan, tilt, X, xy) -> np.ndarray:
    """Image residuals ``(N, 2)`` (pixels): ``model.project(X, pan, tilt) - xy``; NaN for
    points behind the camera."""
    xy = as_points(xy, "xy", 2)
    return model._project(X, pan, tilt) - xy
