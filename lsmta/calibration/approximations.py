"""Approximate cameras and points for the bundle adjustment, without ground truth.

From the nominal interior orientation only (principal distance from the lens and pixel
size, principal point at the image centre, no distortion): the relative orientation of
two cameras from the essential matrix (OpenCV ``findEssentialMat`` with RANSAC and
``recoverPose``), the points they share by forward intersection, the scale from the
median bar length, and every further camera by space resection (OpenCV ``solvePnP``).
The first camera of the pair defines the world frame (its centre at the origin, its axes
the world axes).
"""

from __future__ import annotations

import cv2
import numpy as np

from .._validate import as_array
from ..camera import Camera
from ..triangulation import triangulate
from .bundle import Bar


def relative_orientation_start(cameras, xy, *, bar: Bar | None = None, pair=(0, 1),
                               threshold_px: float = 3.0):
    """Approximations of all cameras and points from image observations.

    Parameters
    ----------
    cameras : sequence of K Camera
        Cameras with the *nominal* interior orientation (``f``, ``cx``, ``cy``, image
        size, name); their exterior orientation and distortion are ignored.
    xy : (K, N, 2) array
        Image coordinates, px (NaN: not seen).
    bar : Bar, optional
        Scales the result to the bar's length (median over positions); otherwise the
        base of ``pair`` is one millimetre.
    pair : (int, int)
        The two cameras of the relative orientation.
    threshold_px : float
        RANSAC threshold of the essential matrix, px.

    Returns
    -------
    cameras : list of K Camera
        Nominal interior orientation, no distortion, approximate exterior orientation.
    points : (N, 3) array
        Approximate points, mm (NaN where fewer than two cameras see them).
    """
    cameras = list(cameras)
    K = len(cameras)
    xy = as_array(xy, "xy", shape=(K, None, 2), allow_nan=True)
    nominal = [c.replace(R=np.eye(3), C=np.zeros(3), k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
                         b1=0.0, b2=0.0) for c in cameras]
    i, j = _pair_indices(pair, K)
    if not (np.isfinite(threshold_px) and threshold_px > 0):
        raise ValueError(f"threshold_px: expected a positive number of pixels, got "
                         f"{threshold_px}")
    cams, X = _relative_pair(cameras, nominal, xy, i, j, threshold_px)
    scale = 1.0 if bar is None else _bar_scale(X, bar)
    cams[j] = cams[j].replace(C=cams[j].C * scale)
    X = X * scale
    for k in range(K):
        if k in (i, j):
            continue
        cams[k] = _resect_start(cameras[k].name or k, nominal[k], X, xy[k], threshold_px)
    X = triangulate(cams, xy, min_angle_deg=0.0).points
    return cams, X


def _pair_indices(pair, K: int) -> tuple[int, int]:
    """The two different camera indices of ``pair``, checked."""
    try:
        i, j = (int(v) for v in pair)
    except (TypeError, ValueError):
        raise ValueError(f"pair: expected two camera indices, got {pair!r}") from None
    if i == j or not (0 <= i < K and 0 <= j < K):
        raise ValueError(f"pair: expected two different camera indices in [0, {K - 1}], "
                         f"got {pair!r}")
    return i, j


def _relative_pair(cameras, nominal, xy, i: int, j: int, threshold_px: float):
    """Cameras ``i`` (the world frame) and ``j`` (base one unit long) from the essential
    matrix of the points both see, and those points intersected."""
    both = np.isfinite(xy[i]).all(axis=1) & np.isfinite(xy[j]).all(axis=1)
    if both.sum() < 8:
        raise ValueError(f"xy: cameras {cameras[i].name or i} and {cameras[j].name or j} "
                         f"share {both.sum()} point(s); the relative orientation needs >= 8")
    ni = nominal[i].pixel_to_normalized(xy[i, both])
    nj = nominal[j].pixel_to_normalized(xy[j, both])
    thr = threshold_px / nominal[i].f
    E, mask = cv2.findEssentialMat(ni, nj, np.eye(3), method=cv2.RANSAC, prob=0.9999,
                                   threshold=thr)
    if E is None or E.shape != (3, 3):
        E = E[:3] if E is not None and E.shape[0] > 3 else E
    if E is None:
        raise ValueError("xy: the essential matrix could not be estimated")
    _, R, t, _ = cv2.recoverPose(E, ni, nj, np.eye(3), mask=mask)
    cams = list(nominal)
    cams[j] = nominal[j].replace(R=R, C=-(R.T @ t.ravel()))
    X = triangulate([cams[i], cams[j]], xy[[i, j]], min_angle_deg=0.0).points
    return cams, X


def _bar_scale(X, bar: Bar) -> float:
    """The factor that makes the median bar length of the points ``X`` the bar's."""
    d = np.linalg.norm(X[bar.pairs[:, 0]] - X[bar.pairs[:, 1]], axis=1)
    d = d[np.isfinite(d)]
    if not len(d):
        raise ValueError("bar: no bar position is seen by both cameras of the pair")
    return bar.length / np.median(d)


def _resect_start(name, nominal: Camera, X, xy_k, threshold_px: float) -> Camera:
    """One further camera by RANSAC resection from the points of the relative
    orientation (``name``: the camera's name or index in messages)."""
    m = np.isfinite(xy_k).all(axis=1) & np.isfinite(X).all(axis=1)
    if m.sum() < 6:
        raise ValueError(f"xy: camera {name} sees {m.sum()} of the "
                         "points of the relative orientation; resection needs >= 6")
    Km = np.array([[nominal.f, 0, nominal.cx], [0, nominal.f, nominal.cy],
                   [0, 0, 1.0]])
    ok, rvec, tvec, _ = cv2.solvePnPRansac(X[m], xy_k[m], Km, None,
                                           reprojectionError=threshold_px * 2)
    if not ok:
        raise ValueError(f"xy: resection of camera {name} failed")
    Rk, _ = cv2.Rodrigues(rvec)
    return nominal.replace(R=Rk, C=-(Rk.T @ tvec.ravel()))


def scaled(cameras, points, factor: float):
    """Cameras and points scaled by ``factor`` about the world origin (the scale-afterwards
    step of tools that adjust without the bar, e.g. easyWand, Argus)."""
    if not (np.isfinite(factor) and factor > 0):
        raise ValueError(f"factor: expected a positive finite scale, got {factor}")
    cams = [c.replace(C=c.C * factor) for c in cameras]
    return cams, np.asarray(points, dtype=float) * factor


def next_camera(cameras, placed, xy, *, min_angle_deg: float = 0.0):
    """The camera not yet placed that sees most of the points the placed ones intersect.

    Parameters
    ----------
    cameras : sequence of K Camera
        The placed ones as oriented so far.
    placed : sequence of int
        Indices of the placed cameras (at least two).
    xy : (K, N, 2) array
        Observations, px (NaN: not seen).
    min_angle_deg : float
        Smallest intersection angle of a point, degrees.

    Returns
    -------
    k : int
        The next camera.
    seen : (N,) bool array
        The points camera ``k`` sees that the placed cameras intersect.
    points : (N, 3) array
        The intersected points, mm (NaN where fewer than two placed cameras see one).
    """
    X = triangulate([cameras[k] for k in placed], xy[list(placed)],
                    min_angle_deg=min_angle_deg).points
    known = np.isfinite(X).all(axis=1)
    visible = np.isfinite(xy).all(axis=2)
    rest = [k for k in range(len(cameras)) if k not in placed]
    counts = [int((visible[k] & known).sum()) for k in rest]
    k = rest[int(np.argmax(counts))]
    return k, visible[k] & known, X


def resect_pnp(camera: Camera, points, xy, *, max_error_px: float, arg: str = "xy") -> Camera:
    """Exterior orientation of ``camera`` from 3-D points, its interior orientation kept
    and its distortion ignored: RANSAC PnP, then all points when RANSAC keeps fewer than 6
    (an approximation; :func:`~lsmta.calibration.resect` is the least-squares resection
    that adjusts the interior orientation and the distortion too).

    Parameters
    ----------
    camera : Camera
    points : (M, 3) array
        Points, mm.
    xy : (M, 2) array
        Their images, px.
    max_error_px : float
        RANSAC's inlier limit, px.
    arg : str
        The caller's argument named in the error when the resection fails.
    """
    Km = np.array([[camera.f, 0, camera.cx], [0, camera.f, camera.cy], [0, 0, 1.0]])
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points, xy, Km, None, reprojectionError=max_error_px, iterationsCount=500,
        flags=cv2.SOLVEPNP_SQPNP)
    if not ok or inliers is None or len(inliers) < 6:
        ok, rvec, tvec = cv2.solvePnP(points, xy, Km, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise ValueError(f"{arg}: the resection of camera {camera.name} failed")
    R, _ = cv2.Rodrigues(rvec)
    return camera.replace(R=R, C=-(R.T @ tvec.ravel()))
