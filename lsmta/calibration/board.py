"""Calibration from a board recording: K cameras watch a plane board with known corners.

Each frame shows the board in some of the cameras (a ChArUco board's corners are
identified, so partial views count). Without ground truth:

1. *interior orientation to start from*: per camera, Zhang's plane-board calibration
   (OpenCV ``calibrateCamera``: homographies, then its own adjustment; k1, k2 only), or the
   cameras the caller gives (e.g. from a separate intrinsic recording);
2. *exterior orientation*: the board's pose in every view (``solvePnP``); two cameras that
   see the board in the same frame know their relative pose through it; the median over
   shared frames (rotations by the chordal L2 mean) links every camera to the one that
   shares most frames with the others, chained through a spanning tree where two cameras
   share no frame; the corners are intersected;
3. *bundle adjustment* (:func:`~lsmta.calibration.bundle_adjust`) of all cameras and all
   corners, with the board's geometry entering as *corner pairs as bars*: every pair of
   corners one square apart in a frame is a distance observation of the square size; the
   other distances on the board are left free (they check the result). Free per camera
   by default: exterior orientation, f, principal point, k1, k2 (:data:`BOARD_INTRINSICS`).

The world frame is the reference camera's; the scale is the board's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..triangulation import triangulate
from .bundle import Bar, bundle_adjust
from .result import CalibrationResult

# what a small board in a few dozen frames determines: with k3, p1, p2 and b1 free as well,
# the standard deviation of k1 triples and k2, k3 run off (k2 = 25 on caliscope's camera 2)
BOARD_INTRINSICS = ("f", "cx", "cy", "k1", "k2")
MIN_CORNERS = 6


@dataclass(frozen=True, eq=False)
class BoardCalibration(CalibrationResult):
    """Result of :func:`calibrate_board`.

    Attributes
    ----------
    cameras : list of K Camera
        Calibrated cameras, world frame = camera ``reference``'s, mm.
    bundle : BundleResult
        The adjustment; its points are the corners, frame by frame (``F * C``).
    start : list of K Camera
        The approximations (step 2).
    reference : int
        The camera that defines the world frame.
    bar : Bar
        The corner pairs one square apart (indices into ``F * C``) and the square size.
    """

    start: list
    reference: int
    bar: Bar


def _zhang(xy_k, board, size):
    """Per-camera plane-board calibration: K, dist and the board pose per usable view."""
    views = [f for f in range(xy_k.shape[0])
             if np.isfinite(xy_k[f, :, 0]).sum() >= MIN_CORNERS]
    obj = [board[np.isfinite(xy_k[f, :, 0])].astype(np.float32) for f in views]
    img = [xy_k[f][np.isfinite(xy_k[f, :, 0])].astype(np.float32) for f in views]
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    _, K, dist, _, _ = cv2.calibrateCamera(obj, img, tuple(int(v) for v in size), None, None,
                                           flags=flags)
    return K, dist.ravel()


def _board_poses(cam: Camera, xy_k, board):
    """``{frame: (R, t)}`` board-to-camera poses of the views with enough corners."""
    K, dist, _, _ = cam.to_opencv()
    out = {}
    for f in range(xy_k.shape[0]):
        m = np.isfinite(xy_k[f, :, 0])
        if m.sum() < MIN_CORNERS:
            continue
        ok, rvec, tvec = cv2.solvePnP(board[m], xy_k[f, m], K, dist,
                                      flags=cv2.SOLVEPNP_IPPE)
        if ok:
            out[f] = (cv2.Rodrigues(rvec)[0], tvec.ravel())
    return out


def _relative(poses_a, poses_b):
    """Pose of camera b in camera a's frame (``x_b = R x_a + t``) from shared frames."""
    shared = sorted(set(poses_a) & set(poses_b))
    Rs, ts = [], []
    for f in shared:
        Ra, ta = poses_a[f]
        Rb, tb = poses_b[f]
        R = Rb @ Ra.T
        Rs.append(R)
        ts.append(tb - R @ ta)
    R = Rotation.from_matrix(np.stack(Rs)).mean().as_matrix()
    return R, np.median(np.stack(ts), axis=0)


def calibrate_board(xy, board, image_sizes, *, cameras=None, intrinsics=BOARD_INTRINSICS,
                    square_mm: float | None = None, bar_sigma: float = 0.1,
                    sigma_px: float = 0.5, names=None) -> BoardCalibration:
    """Calibrate K cameras from a plane board seen in F synchronised frames.

    Parameters
    ----------
    xy : (K, F, C, 2) array
        Image positions of the board's C corners, px; NaN where not detected.
    board : (C, 3) array
        The corners on the board, mm (z = 0).
    image_sizes : (K, 2) array
        ``(width, height)`` per camera, px.
    cameras : sequence of K Camera, optional
        Interior orientation to start from (their poses are ignored); by default from a
        plane-board calibration of each camera's own views.
    intrinsics : sequence of str
        Interior parameters adjusted (``()``: hold the start's, adjust only the poses).
    square_mm : float, optional
        Distance of neighbouring corners; by default the smallest distance on the board.
    bar_sigma : float
        Standard deviation of a corner distance, mm (the board's print and flatness).
    sigma_px : float
        A-priori standard deviation of a corner's image coordinate, px.
    names : sequence of str, optional
        Camera names.

    Returns
    -------
    BoardCalibration
    """
    board = as_array(board, "board", shape=(None, 3))
    C = len(board)
    xy = as_array(xy, "xy", shape=(None, None, C, 2), allow_nan=True)
    K, F = xy.shape[:2]
    sizes = np.asarray(image_sizes, dtype=int)
    if sizes.shape != (K, 2) or np.any(sizes < 2):
        raise ValueError(f"image_sizes: expected {K} (width, height) pairs, got "
                         f"{image_sizes!r}")
    if np.any(board[:, 2] != 0):
        raise ValueError("board: expected a plane board (z = 0 for every corner)")
    names = [f"cam{k}" for k in range(K)] if names is None else [str(n) for n in names]
    d = np.linalg.norm(board[:, None] - board[None], axis=2)
    square = float(d[d > 0].min()) if square_mm is None else as_scalar(square_mm, "square_mm",
                                                                        positive=True)
    start = _interior(xy, board, sizes, cameras, names)
    cams0, ref = _exterior(start, xy, board, names)
    flat = xy.reshape(K, F * C, 2)
    X0 = triangulate(cams0, flat, min_angle_deg=0.0).points
    # 3. bundle adjustment with the neighbouring corners as bars
    bar = _corner_bars(d, square, X0, F, C, bar_sigma)
    bundle = bundle_adjust(cams0, flat, X0, intrinsics=tuple(intrinsics),
                           fixed_exterior=(ref,), bar=bar, sigma_px=sigma_px)
    return BoardCalibration(cameras=bundle.cameras, start=cams0, bundle=bundle,
                            reference=ref, bar=bar)


def _interior(xy, board, sizes, cameras, names) -> list:
    """Step 1, interior orientation: Zhang's plane-board calibration of each camera's own
    views, or the given cameras (their poses reset)."""
    K = xy.shape[0]
    if cameras is None:
        start = []
        for k in range(K):
            Km, dist = _zhang(xy[k], board, sizes[k])
            start.append(Camera.from_opencv(Km, dist, np.zeros(3), np.zeros(3),
                                            tuple(sizes[k]), name=names[k]))
    else:
        start = [c.replace(R=np.eye(3), C=np.zeros(3), name=names[k])
                 for k, c in enumerate(cameras)]
        if len(start) != K:
            raise ValueError(f"cameras: expected {K} cameras, got {len(start)}")
    return start


def _exterior(start, xy, board, names):
    """Step 2, exterior orientation: a spanning tree from the best-connected camera (the
    reference); returns the oriented cameras and the reference."""
    K = len(start)
    poses = [_board_poses(start[k], xy[k], board) for k in range(K)]
    shared = np.array([[len(set(poses[a]) & set(poses[b])) if a != b else 0
                        for b in range(K)] for a in range(K)])
    ref = int(np.argmax(shared.sum(axis=1)))
    R_w = {ref: np.eye(3)}
    t_w = {ref: np.zeros(3)}
    while len(R_w) < K:
        a, b = max(((a, b) for a in R_w for b in range(K) if b not in R_w),
                   key=lambda ab: shared[ab])
        if shared[a, b] == 0:
            lost = [names[b] for b in range(K) if b not in R_w]
            raise ValueError(f"xy: cameras {lost} never see the board together with the "
                             "others (in a frame with >= 6 corners each)")
        R, t = _relative(poses[a], poses[b])
        R_w[b], t_w[b] = R @ R_w[a], R @ t_w[a] + t
    cams0 = [start[k].replace(R=R_w[k], C=-R_w[k].T @ t_w[k]) for k in range(K)]
    return cams0, ref


def _corner_bars(d, square, X0, F: int, C: int, bar_sigma: float) -> Bar:
    """Every pair of corners one square apart (``d``: the board's corner distances) in
    every frame whose two corners were intersected, as bars of the square's length."""
    ci, cj = np.nonzero(np.triu(np.isclose(d, square, rtol=1e-6)))
    frames = np.arange(F)[:, None] * C
    pairs = np.stack([(frames + ci).ravel(), (frames + cj).ravel()], axis=1)
    ok = np.isfinite(X0[pairs]).all(axis=(1, 2))
    return Bar(pairs=pairs[ok], length=square, sigma=bar_sigma)
