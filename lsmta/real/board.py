"""Board recordings: our calibration next to another tool's, scored on the same corners
(notebook 19, experiments/calibration_benchmark.py; the recording is
:data:`lsmta.data.CALISCOPE_DIR`).

Scores of a set of cameras on a board recording, the same for every calibration:

* *reprojection RMS per camera*: the corners are placed where they reproject best for
  these cameras (a bundle adjustment with every camera held: points only, no board
  geometry), and each camera's 2-D residuals are summed as OpenCV and caliscope do
  (``sqrt(mean |e|^2)`` over its observations);
* *board-corner distance errors*: the corners of every frame intersected (forward
  intersection from at least two cameras), and every distance between two corners of one
  frame compared with the board's: the board is the only ground truth a real recording has;
* *camera position differences*: the centres after the best rigid motion of one
  calibration's centres onto the other's (both are metric, so no scale is fitted), and the
  angle between the cameras' attitudes after that motion.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..calibration import BundleParams, bundle_adjust, scaled
from ..calibration.board import BoardCalibration, calibrate_board
from ..camera import Camera
from ..camera_files import read_camera_toml, tomllib
from ..data import CALISCOPE_DIR
from ..io import BoardPoints, read_caliscope_points
from ..rigid import apply_rigid, fit_rigid
from ..triangulation import triangulate


@dataclass(frozen=True, eq=False)
class BoardScores:
    """Scores of one set of cameras on a board recording (see the module docstring).

    Attributes
    ----------
    rms_px : (K,) array
        Reprojection RMS per camera (2-D, OpenCV's convention), px.
    distance_error : (M,) array
        Intersected minus true distance for every pair of corners in a frame, mm.
    distance_true : (M,) array
        The true distances, mm.
    """

    rms_px: np.ndarray
    distance_error: np.ndarray
    distance_true: np.ndarray

    @property
    def distance_rms(self) -> float:
        return float(np.sqrt(np.mean(self.distance_error**2)))

    @property
    def distance_rms_percent(self) -> float:
        """RMS of the relative distance errors, per cent."""
        return float(100 * np.sqrt(np.mean((self.distance_error / self.distance_true)**2)))


def board_scores(cameras, points: BoardPoints, *, frames=None) -> BoardScores:
    """Score ``cameras`` on the corners of ``points`` (all frames, or the ``frames``
    indices)."""
    xy = points.xy if frames is None else points.xy[:, frames]
    K, F, C = xy.shape[:3]
    flat = xy.reshape(K, F * C, 2)
    X = triangulate(cameras, flat, min_angle_deg=0.0).points
    opt = bundle_adjust(cameras, flat, X, intrinsics=(), fixed_exterior=range(K),
                        scale_camera=0, params=BundleParams(covariance=False))
    sq = np.sum(opt.residuals**2, axis=2)
    rms = np.sqrt(np.nanmean(sq, axis=1))
    Xf = X.reshape(F, C, 3)
    i, j = np.triu_indices(C, 1)
    true = np.linalg.norm(points.board[i] - points.board[j], axis=1)
    meas = np.linalg.norm(Xf[:, i] - Xf[:, j], axis=2)            # (F, pairs)
    err = meas - true[None]
    ok = np.isfinite(err)
    return BoardScores(rms_px=rms, distance_error=err[ok],
                       distance_true=np.broadcast_to(true, err.shape)[ok])


def position_differences(cameras, reference):
    """Camera centre distances (mm) and attitude angles (degrees) between two
    calibrations after the best rigid motion of ``cameras`` onto ``reference``."""
    A = np.array([c.C for c in cameras])
    B = np.array([c.C for c in reference])
    R, t = fit_rigid(A, B)
    dist = np.linalg.norm(apply_rigid(R, t, A) - B, axis=1)
    # camera k's attitude after the motion: R_k R^T
    ang = [np.degrees(Rotation.from_matrix(np.asarray(c.R) @ R.T @ np.asarray(r.R).T)
                      .magnitude()) for c, r in zip(cameras, reference)]
    return dist, np.array(ang)


@dataclass(frozen=True, eq=False)
class CaliscopeComparison:
    """Our calibrations of caliscope's recording next to caliscope's own.

    Attributes
    ----------
    points : BoardPoints
    caliscope : list of Camera
        caliscope's calibration (``camera_array.toml``), mm.
    ours : BoardCalibration
        Everything from the recording alone (interior orientation included).
    ours_fixed : BoardCalibration
        Poses only, with caliscope's interior orientation held (what caliscope's own
        extrinsic stage adjusts).
    scores : dict of str -> BoardScores
        ``"caliscope"``, ``"ours"``, ``"ours_fixed"`` on all frames.
    heldout : dict of str -> BoardScores
        The same calibrations computed from the even frames only (caliscope's: as it is,
        from all), scored on the odd frames.
    file_error_px : (K,) array
        The ``error`` caliscope stores per camera (RMS of its intrinsic calibration on its
        own intrinsic recording), px.
    centre_difference, attitude_difference : (K,) arrays
        Ours (self-calibrated) against caliscope's, mm and degrees.
    """

    points: BoardPoints
    caliscope: list
    ours: BoardCalibration
    ours_fixed: BoardCalibration
    scores: dict
    heldout: dict
    file_error_px: np.ndarray
    centre_difference: np.ndarray
    attitude_difference: np.ndarray


def caliscope_comparison(*, folder=CALISCOPE_DIR) -> CaliscopeComparison:
    """Calibrate caliscope's four-camera recording and compare with its calibration."""
    folder = Path(folder)
    pts = read_caliscope_points(folder / "xy.csv")
    ref = read_camera_toml(folder / "camera_array.toml", unit="m")
    with open(folder / "camera_array.toml", "rb") as fh:
        file_error = np.array([c["error"] for c in tomllib.load(fh)["cameras"].values()])
    sizes = [c.image_size for c in ref]
    names = [c.name for c in ref]
    ours = calibrate_board(pts.xy, pts.board, sizes, names=names)
    fixed = calibrate_board(pts.xy, pts.board, sizes, cameras=ref, intrinsics=(),
                            names=names)
    even, odd = np.arange(0, pts.xy.shape[1], 2), np.arange(1, pts.xy.shape[1], 2)
    half = calibrate_board(pts.xy[:, even], pts.board, sizes, names=names)
    half_fixed = calibrate_board(pts.xy[:, even], pts.board, sizes, cameras=ref,
                                 intrinsics=(), names=names)
    scores = {"caliscope": board_scores(ref, pts), "ours": board_scores(ours.cameras, pts),
              "ours_fixed": board_scores(fixed.cameras, pts)}
    heldout = {"caliscope": board_scores(ref, pts, frames=odd),
               "ours": board_scores(half.cameras, pts, frames=odd),
               "ours_fixed": board_scores(half_fixed.cameras, pts, frames=odd)}
    dist, ang = position_differences(ours.cameras, ref)
    return CaliscopeComparison(points=pts, caliscope=ref, ours=ours, ours_fixed=fixed,
                               scores=scores, heldout=heldout, file_error_px=file_error,
                               centre_difference=dist, attitude_difference=ang)


def aniposelib_board_peer(points: BoardPoints, start, *, frames=None):
    """aniposelib's ``CameraGroup.bundle_adjust_iter`` on the board corners, from the same
    approximations as ours (``start``: :attr:`BoardCalibration.start`), scaled afterwards
    so that the median intersected distance of neighbouring corners is the square size
    (aniposelib adjusts without the board's geometry). Optional: needs aniposelib (see
    ENVIRONMENT.md).

    Returns
    -------
    cameras : list of Camera
    seconds : float
        Wall time of the adjustment.
    """
    from aniposelib.cameras import Camera as ACamera  # deferred: optional peer, not installed
    from aniposelib.cameras import CameraGroup  # deferred: optional peer, not installed

    xy = points.xy if frames is None else points.xy[:, frames]
    K, F, C = xy.shape[:3]
    acams = []
    for c in start:
        Km, dist, rvec, tvec = c.to_opencv()
        acams.append(ACamera(matrix=Km, dist=dist, size=c.image_size, rvec=rvec, tvec=tvec,
                             name=c.name))
    group = CameraGroup(acams)
    t0 = time.perf_counter()
    group.bundle_adjust_iter(np.ascontiguousarray(xy.reshape(K, F * C, 2)),
                             n_samp_full=10**6, n_samp_iter=10**6, verbose=False)
    seconds = time.perf_counter() - t0
    cams = [Camera.from_opencv(a.get_camera_matrix(), a.get_distortions(), a.get_rotation(),
                               a.get_translation(), c.image_size, name=c.name)
            for a, c in zip(group.cameras, start)]
    X = triangulate(cams, xy.reshape(K, F * C, 2), min_angle_deg=0.0).points.reshape(F, C, 3)
    d = np.linalg.norm(points.board[:, None] - points.board[None], axis=2)
    square = d[d > 0].min()
    i, j = np.nonzero(np.triu(np.isclose(d, square)))
    meas = np.linalg.norm(X[:, i] - X[:, j], axis=2)
    cams, _ = scaled(cams, np.zeros((0, 3)), square / np.nanmedian(meas))
    return cams, seconds
