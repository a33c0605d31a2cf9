"""Constant-velocity Kalman filter per target, updated by single-camera 2-D observations.

State ``x = (X, Y, Z, VX, VY, VZ)`` in mm and mm/s. The motion model is the continuous
white-noise-acceleration model: per axis, over ``dt`` seconds,
``F = [[1, dt], [0, 1]]`` and ``Q = q [[dt³/3, dt²/2], [dt²/2, dt]]`` with the acceleration
spectral density ``q`` in mm²/s³ (small ``q``: a "stiff" model that believes in constant
velocity; large ``q``: a "weak" one that follows the observations).

An observation is one centroid ``z`` (pixels) from one camera. The update is the extended
Kalman update through that camera's projection (:meth:`lsmta.camera.Camera.project`,
distortion included), linearised with a central-difference Jacobian. Why hand-written and
not Stone Soup's ``ExtendedKalmanUpdater``: the estimator of Davis (2002, §3.5) keeps one
clock for all targets and must still use observations that are a few milliseconds *older*
than that clock (clock offsets between camera machines). We fold that lag into the
measurement function, ``h(x) = project(X - lag V)``, i.e. the position the target had
``lag`` seconds ago on its current straight-line motion, which Stone Soup's updaters do not
offer (they predict forwards to the detection's timestamp). The predictions are vectorised
over targets, which Stone Soup's per-track objects are not. Stone Soup runs the same
observations as a baseline in :mod:`lsmta.widearea.peers`.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array, as_points, as_scalar
from ..camera import Camera

STEP_MM = 0.5  # central-difference step of the projection Jacobian


def process_noise(dt, q: float) -> np.ndarray:
    """Per-axis process noise of the constant-velocity (white-acceleration) model,
    ``q [[dt³/3, dt²/2], [dt²/2, dt]]``, ``(M, 2, 2)`` for time steps ``dt`` (M,) in s and the
    acceleration spectral density ``q`` in mm²/s³ (no argument checks)."""
    dt = np.asarray(dt, dtype=float)
    Q = np.empty(dt.shape + (2, 2))
    Q[..., 0, 0] = q * dt**3 / 3
    Q[..., 0, 1] = Q[..., 1, 0] = q * dt**2 / 2
    Q[..., 1, 1] = q * dt
    return Q


def transition(dt, q: float) -> tuple[np.ndarray, np.ndarray]:
    """State transition and process noise of the constant-velocity model.

    Parameters
    ----------
    dt : (M,) array or float
        Time steps in seconds (>= 0).
    q : float
        Acceleration spectral density in mm²/s³ (per axis).

    Returns
    -------
    F, Q : (M, 6, 6) arrays
    """
    dt = np.atleast_1d(as_array(dt, "dt"))
    if dt.ndim != 1 or np.any(dt < 0):
        raise ValueError("dt: expected time steps >= 0 in seconds")
    q = as_scalar(q, "q", nonnegative=True)
    eye = np.eye(3)
    M = len(dt)
    F = np.tile(np.eye(6), (M, 1, 1))
    F[:, :3, 3:] = dt[:, None, None] * eye
    Q = np.kron(process_noise(dt, q), eye)               # (M, 6, 6): blocks times I
    return F, Q


def predict(x, P, dt, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Predict ``M`` targets ``dt`` seconds ahead.

    Parameters
    ----------
    x : (M, 6) array
        States (mm, mm/s).
    P : (M, 6, 6) array
        Covariances.
    dt : float or (M,) array
        Time steps in seconds (>= 0).
    q : float
        Acceleration spectral density in mm²/s³.

    Returns
    -------
    x, P : new arrays (the inputs are not changed)
    """
    x = as_array(x, "x", shape=(None, 6))
    P = as_array(P, "P", shape=(len(x), 6, 6))
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (len(x),))
    if np.any(dt < 0) or not np.isfinite(dt).all():
        raise ValueError("dt: expected finite time steps >= 0 in seconds")
    return _predict(x, P, dt, as_scalar(q, "q", nonnegative=True))


def _predict(x, P, dt, q):
    """:func:`predict` without the argument checks (dt: (M,) array)."""
    dt = dt[:, None]
    x_new = x.copy()
    x_new[:, :3] += dt * x[:, 3:]
    # F P F^T for F = [[I, dt I], [0, I]] blockwise
    Ppp, Ppv, Pvv = P[:, :3, :3], P[:, :3, 3:], P[:, 3:, 3:]
    d3 = dt[:, :, None]
    P_new = np.empty_like(P)
    P_new[:, :3, :3] = Ppp + d3 * (Ppv + np.transpose(Ppv, (0, 2, 1))) + d3**2 * Pvv
    P_new[:, :3, 3:] = Ppv + d3 * Pvv
    P_new[:, 3:, :3] = np.transpose(P_new[:, :3, 3:], (0, 2, 1))
    P_new[:, 3:, 3:] = Pvv
    P_new += np.kron(process_noise(dt[:, 0], q), np.eye(3))
    return x_new, P_new


def projection_jacobian(camera: Camera, X) -> np.ndarray:
    """Derivative of the pixel position with respect to the world point, ``(N, 2, 3)``
    in px/mm, by central differences of :meth:`Camera.project` (NaN behind the camera)."""
    if not isinstance(camera, Camera):
        raise TypeError("camera: expected an lsmta.camera.Camera")
    X = as_points(X, "X")
    N = len(X)
    steps = STEP_MM * np.concatenate([np.eye(3), -np.eye(3)])       # (6, 3)
    pts = (X[:, None, :] + steps[None]).reshape(-1, 3)
    xy = camera.project(pts, behind="nan").reshape(N, 6, 2)
    return np.transpose((xy[:, :3] - xy[:, 3:]) / (2 * STEP_MM), (0, 2, 1))


def ekf_update(x, P, camera: Camera, z, sigma_px: float, *, lag: float = 0.0):
    """Extended Kalman update of ``A`` targets, each by one centroid of the same frame.

    The targets are independent, so the ``A`` updates are done at once.

    Parameters
    ----------
    x : (A, 6) array
        States at the estimator's current time (mm, mm/s).
    P : (A, 6, 6) array
        Their covariances.
    camera : Camera
        The observing camera.
    z : (A, 2) array
        The centroid paired with each target, pixels.
    sigma_px : float
        Standard deviation of a centroid per image axis, pixels.
    lag : float
        How much earlier than the states' time the frame was taken, seconds (>= 0).

    Returns
    -------
    x, P : (A, 6), (A, 6, 6) arrays
        Updated states and covariances (Joseph form); targets whose projection fails
        (behind the camera) are returned unchanged.
    innovation : (A, 2) array
        ``z - h(x)`` in pixels (NaN where the projection failed).
    """
    x = as_array(x, "x", shape=(None, 6))
    A = len(x)
    P = as_array(P, "P", shape=(A, 6, 6))
    z = as_array(z, "z", shape=(A, 2))
    sigma_px = as_scalar(sigma_px, "sigma_px", positive=True)
    lag = as_scalar(lag, "lag", nonnegative=True)
    if not isinstance(camera, Camera):
        raise TypeError("camera: expected an lsmta.camera.Camera")
    return _ekf_update(x, P, camera, z, sigma_px, lag)


def measurement(camera: Camera, x, *, lag: float = 0.0):
    """Predicted centroids and measurement Jacobians of ``A`` targets in one camera.

    Parameters
    ----------
    camera : Camera
    x : (A, 6) array
        States (mm, mm/s).
    lag : float
        The frame was taken this many seconds before the states' time (>= 0).

    Returns
    -------
    h : (A, 2) array
        ``project(X - lag V)`` in pixels (NaN behind the camera).
    H : (A, 2, 6) array
        Its derivative with respect to the state, ``[J, -lag J]`` (zero where ``h`` is NaN).
    """
    if not isinstance(camera, Camera):
        raise TypeError("camera: expected an lsmta.camera.Camera")
    x = as_array(x, "x", shape=(None, 6))
    return _measurement(camera, x, as_scalar(lag, "lag", nonnegative=True))


def _measurement(camera, x, lag):
    A = len(x)
    X = x[:, :3] - lag * x[:, 3:]
    steps = STEP_MM * np.concatenate([np.zeros((1, 3)), np.eye(3), -np.eye(3)])  # (7, 3)
    xy = camera.project((X[:, None, :] + steps[None]).reshape(-1, 3),
                        behind="nan").reshape(A, 7, 2)
    h = xy[:, 0]
    J = np.transpose((xy[:, 1:4] - xy[:, 4:]) / (2 * STEP_MM), (0, 2, 1))   # (A, 2, 3)
    ok = np.isfinite(h).all(axis=1) & np.isfinite(J).all(axis=(1, 2))
    H = np.concatenate([J, -lag * J], axis=2)                               # (A, 2, 6)
    H[~ok] = 0.0
    h = np.where(ok[:, None], h, np.nan)
    return h, H


def innovation_covariance(P, H, sigma_px: float) -> np.ndarray:
    """``S = H P Hᵀ + σ² I``, ``(A, 2, 2)`` in px², for ``P (A, 6, 6)`` and ``H (A, 2, 6)``."""
    return np.einsum("aij,ajk,alk->ail", H, P, H) + sigma_px**2 * np.eye(2)


def kalman_update(x, P, H, h, z, *, sigma_px: float):
    """Kalman update of ``A`` independent targets from their measurement prediction.

    Parameters
    ----------
    x, P : (A, 6), (A, 6, 6) arrays
        States and covariances.
    H : (A, 2, 6) array
        Measurement Jacobians (:func:`measurement`).
    h : (A, 2) array
        Predicted centroids, px (NaN: the target is left unchanged).
    z : (A, 2) array
        Observed centroids, px.
    sigma_px : float
        Standard deviation of a centroid per image axis, px.

    Returns
    -------
    x, P, innovation
        As :func:`ekf_update` (Joseph form; new arrays).
    """
    x = as_array(x, "x", shape=(None, 6))
    A = len(x)
    P = as_array(P, "P", shape=(A, 6, 6))
    H = as_array(H, "H", shape=(A, 2, 6))
    h = as_array(h, "h", shape=(A, 2), allow_nan=True)
    z = as_array(z, "z", shape=(A, 2))
    return _kalman_update(x, P, H, h, z, as_scalar(sigma_px, "sigma_px", positive=True))


def _kalman_update(x, P, H, h, z, sigma_px):
    ok = np.isfinite(h).all(axis=1)
    R = sigma_px**2 * np.eye(2)
    PHt = np.einsum("aij,akj->aik", P, H)                                   # (A, 6, 2)
    S = np.einsum("aij,ajk->aik", H, PHt) + R
    K = np.linalg.solve(S, np.transpose(PHt, (0, 2, 1))).transpose(0, 2, 1)  # (A, 6, 2)
    innovation = np.where(ok[:, None], z - np.nan_to_num(h), 0.0)
    I_KH = np.eye(6) - np.einsum("aij,ajk->aik", K, H)
    x_new = x + np.einsum("aij,aj->ai", K, innovation)
    P_new = (np.einsum("aij,ajk,alk->ail", I_KH, P, I_KH)
             + np.einsum("aij,jk,alk->ail", K, R, K))
    P_new = 0.5 * (P_new + np.transpose(P_new, (0, 2, 1)))   # keep rounding from piling up
    return x_new, P_new, np.where(ok[:, None], innovation, np.nan)


def _ekf_update(x, P, camera, z, sigma_px, lag):
    """:func:`ekf_update` without the argument checks."""
    h, H = _measurement(camera, x, lag)
    return _kalman_update(x, P, H, h, z, sigma_px)
