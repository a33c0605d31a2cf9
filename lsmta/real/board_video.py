"""Caliscope's four-camera board recording from its pixels (notebook 19): the ChArUco corners
found in the videos (:mod:`lsmta.calibration.charuco`), checked against the corners
caliscope found in the same frames (``xy.csv``), the cameras calibrated from them, the
corners tracked through the videos by LSMTA (2-D mode) and KLT, and the board measured in
3-D. The only truth a real recording has is the board: 54 mm squares, flat.

* *corner differences*: ``|x_ours - x_caliscope|`` per corner, camera and frame (same
  charuco id, same ``sync_index``);
* *tracking error*: ``|x_tracked - x_detected|`` in the frames after the start, per
  tracker; *long runs* start from each camera's first frame with the board and follow it
  to the end; *steps* start in every frame from its detections (the image velocity from
  the frame before, where both frames have the corner) and go one frame ahead;
* *square error*: the distance of two neighbouring corners intersected in one frame
  (>= 2 cameras) minus the square; *planarity*: per frame with >= 4 corners spanning two
  rows and two columns, the corners' distances from their least-squares plane.

The cameras are not frame-locked (``timestamps.csv``): within one ``sync_index`` their frames
are up to tens of ms apart while the board moves. :func:`at_common_time` moves each
camera's corners to the frame's mean time by linear interpolation between that camera's
neighbouring frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .._validate import as_array, as_int, pack_windows
from ..calibration.board import BoardCalibration, calibrate_board
from ..calibration.charuco import (
    CALISCOPE,
    CharucoBoard,
    CharucoCorners,
    CharucoParams,
    detect_charuco,
    read_charuco_toml,
    refine_corners,
)
from ..camera_files import read_camera_toml
from ..data import CALISCOPE_DIR
from ..io import FrameTimes, read_caliscope_points, read_caliscope_times, read_videos
from ..tracking.klt import track_klt
from ..tracking.points import TrackerParams, track_points
from ..triangulation import triangulate
from .board import board_scores

MARGIN = 64          # px around the board's swept region given to the trackers


# ---------------------------------------------------------------------- detections
def caliscope_convention(corners: CharucoCorners) -> np.ndarray:
    """``(K, F, C, 2)`` the corners as caliscope writes them: a corner found in a frame's
    mirror image at ``x'`` is put at ``W - x'`` (one pixel right of ``W - 1 - x'``)."""
    xy = np.array(corners.xy)
    xy[corners.mirrored, :, 0] += 1.0
    return xy


def refined_again(images, xy, mirrored, *, params: CharucoParams = CALISCOPE) -> np.ndarray:
    """``(K, F, C, 2)`` corners written in caliscope's convention (``xy``, with
    ``mirrored (K, F)`` frames 1 px right) refined again by ``params``'s ``cornerSubPix``
    in these frames, in caliscope's convention: corners found in exactly these pixels by
    that refinement do not move (they are its fixed points)."""
    stacks = [np.asarray(s) for s in images]
    xy = as_array(xy, "xy", shape=(len(stacks), None, None, 2), allow_nan=True)
    out = np.array(xy)
    shift = np.asarray(mirrored, bool)[..., None] * 1.0
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, params.subpix_iterations,
            params.subpix_eps)
    w = (params.subpix_window, params.subpix_window)
    for k, f in zip(*np.nonzero(np.isfinite(xy[..., 0]).any(axis=-1))):
        m = np.isfinite(xy[k, f, :, 0])
        start = (xy[k, f, m] - [shift[k, f, 0], 0]).astype(np.float32).reshape(-1, 1, 2)
        moved = cv2.cornerSubPix(stacks[k][f], start, w, (-1, -1), crit).reshape(-1, 2)
        out[k, f, m] = moved + [shift[k, f, 0], 0]
    return out


def corner_differences(xy, reference) -> np.ndarray:
    """``(K, F, C)`` distances between two sets of the same corners, px; NaN where either
    lacks the corner."""
    a = as_array(xy, "xy", shape=(None, None, None, 2), allow_nan=True)
    b = as_array(reference, "reference", shape=a.shape, allow_nan=True)
    return np.linalg.norm(a - b, axis=-1)


# ---------------------------------------------------------------------- tracking
@dataclass(frozen=True, eq=False)
class CornerTracks:
    """A board's corners tracked per camera (2-D) by LSMTA and KLT from its detections.

    Attributes
    ----------
    detected : (K, T, C, 2) array
        The detections (the reference and the start points), px.
    start : (K,) int array
        First frame of each camera's long run (its first frame with >= 4 corners).
    window : (K, 4) int array
        ``x0, y0, x1, y1`` (half-open) of the image region given to the trackers: the
        region the detections sweep over the recording plus :data:`MARGIN`, so that no
        tracker interpolates the rest of the frame.
    long : dict of str -> (K, T, C, 2) array
        ``"lsmta"``, ``"klt"``: the long runs; NaN before the start and where lost.
    step : dict of str -> (K, T, C, 2) array
        ``"lsmta"``, ``"klt"``: frame ``t`` tracked from frame ``t - 1``'s detections, with
        the velocity from frame ``t - 2``'s (corners found in both), in the window of
        frame ``t - 1``'s corners plus :data:`MARGIN`.
    seconds : dict of str -> float
        Wall time per tracker and mode (``"lsmta long"``, ...).
    """

    detected: np.ndarray
    start: np.ndarray
    window: np.ndarray
    long: dict
    step: dict
    seconds: dict

    def errors(self, mode: str, tracker: str) -> np.ndarray:
        """``(K, T, C)`` distance of a tracker's positions to the detections, px (NaN where
        either is missing; the long runs' start frames excluded)."""
        if mode not in ("long", "step") or tracker not in ("lsmta", "klt"):
            raise ValueError(f"mode, tracker: expected 'long' or 'step' and 'lsmta' or 'klt', "
                             f"got {mode!r}, {tracker!r}")
        tracks = {"long": self.long, "step": self.step}[mode][tracker]
        e = np.linalg.norm(tracks - self.detected, axis=-1)
        if mode == "long":
            for k, s in enumerate(self.start):
                e[k, :s + 1] = np.nan
        return e


@dataclass(frozen=True)
class CornerJumps:
    """Where a tracker's far-off positions lie on the board (:func:`corner_jumps`).

    Attributes
    ----------
    far : int
        Positions more than ``far_px`` from their detected corner (frames with >= 4 corners).
    own : int
        Of those, within ``tol`` squares of their own corner (off by the board's scale only).
    diagonal : int
        On a diagonal neighbour (one square along both board axes): the corner that looks
        the same, since the four squares about it are coloured alike.
    other_corner : int
        On any other corner of the board's lattice (the adjacent ones included: their
        squares are coloured the other way round).
    elsewhere : int
        Farther than ``tol`` squares from every lattice point: lost, not jumped.
    """

    far: int
    own: int
    diagonal: int
    other_corner: int
    elsewhere: int


def corner_jumps(tracks: CornerTracks, board: CharucoBoard, *, mode: str = "long",
                 tracker: str = "lsmta", far_px: float = 2.0, tol: float = 0.2) -> CornerJumps:
    """Sort a tracker's positions more than ``far_px`` off their corner by where they lie.

    Each far position is mapped into board coordinates (squares) by the homography of the
    corners detected in its camera and frame; its offset from its own corner is then either
    near a whole number of squares (a jump to another corner of the lattice, or its own) or
    not (the track is lost on something else).

    Parameters
    ----------
    tracks : CornerTracks
    board : CharucoBoard
        The board the corners belong to (their charuco ids index ``board.corners``).
    mode, tracker : str
        As in :meth:`CornerTracks.errors`.
    far_px : float
        Distance to the detection beyond which a position counts as far, px.
    tol : float
        Largest distance from a lattice point, in squares, to count as on it.
    """
    if not (np.isfinite(far_px) and far_px > 0):
        raise ValueError(f"far_px: expected a positive distance in px, got {far_px!r}")
    if not (0 < tol < 0.5):
        raise ValueError(f"tol: expected a fraction of a square in (0, 0.5), got {tol!r}")
    e = tracks.errors(mode, tracker)
    xy = {"long": tracks.long, "step": tracks.step}[mode][tracker]
    grid = board.corners[:, :2] / board.square_mm
    counts = {"far": 0, "own": 0, "diagonal": 0, "other_corner": 0, "elsewhere": 0}
    for k, t, c in np.argwhere(e > far_px):
        seen = np.isfinite(tracks.detected[k, t, :, 0])
        if seen.sum() < 4:
            continue
        h, _ = cv2.findHomography(tracks.detected[k, t, seen], grid[seen])
        if h is None:
            continue
        off = cv2.perspectiveTransform(xy[k, t, c][None, None], h)[0, 0] - grid[c]
        steps = np.round(off)
        counts["far"] += 1
        if np.abs(off - steps).max() >= tol:
            counts["elsewhere"] += 1
        elif not steps.any():
            counts["own"] += 1
        elif np.all(np.abs(steps) == 1):
            counts["diagonal"] += 1
        else:
            counts["other_corner"] += 1
    return CornerJumps(**counts)


def swept_window(xy, size, *, margin: int = MARGIN) -> np.ndarray:
    """``(4,)`` ``x0, y0, x1, y1`` bounding the finite points of ``xy (..., 2)`` plus
    ``margin`` px, inside an image of ``size = (width, height)``."""
    pts = np.asarray(xy, dtype=float).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    w, h = int(size[0]), int(size[1])
    if not len(pts):
        return np.array([0, 0, w, h])
    lo = np.maximum(np.floor(pts.min(axis=0)) - margin, 0).astype(int)
    hi = np.minimum(np.ceil(pts.max(axis=0)) + margin + 1, [w, h]).astype(int)
    return np.array([lo[0], lo[1], hi[0], hi[1]])


def track_board_corners(images, detected, *, params: TrackerParams | None = None,
                        klt_window: int = 21, min_corners: int = 4) -> CornerTracks:
    """Track each camera's detected corners with LSMTA (2-D mode) and KLT: long runs from
    the first frame with ``min_corners``, and one-frame steps from every frame.

    Parameters
    ----------
    images : sequence of K (T, H, W) uint8 arrays
    detected : (K, T, C, 2) array
        The corners found in them, px; NaN where not found.
    params : TrackerParams, optional
        LSMTA's settings (default: the tracker's).
    klt_window : int
        KLT's window, px (odd).
    min_corners : int
        Corners the long run's first frame needs.

    Returns
    -------
    CornerTracks
    """
    params = params or TrackerParams()
    stacks = [np.asarray(s) for s in images]
    det = as_array(detected, "detected", shape=(len(stacks), None, None, 2), allow_nan=True)
    K, T, C = det.shape[:3]
    if any(s.shape[0] != T for s in stacks):
        raise ValueError(f"images: expected {T} frames per camera like detected, got "
                         f"{[s.shape[0] for s in stacks]}")
    min_corners = as_int(min_corners, "min_corners", unit="corners")
    found = np.isfinite(det[..., 0]).sum(axis=-1) >= min_corners
    start = np.array([int(np.argmax(f)) if f.any() else T for f in found])
    windows = np.stack([swept_window(det[k], s.shape[2:0:-1]) for k, s in enumerate(stacks)])
    long = {n: np.full_like(det, np.nan) for n in ("lsmta", "klt")}
    step = {n: np.full_like(det, np.nan) for n in ("lsmta", "klt")}
    seconds = dict.fromkeys(("lsmta long", "klt long", "lsmta step", "klt step"), 0.0)
    for k in range(K):
        x0, y0, x1, y1 = windows[k]
        seq = stacks[k][:, y0:y1, x0:x1]
        off = np.array([x0, y0], float)
        if start[k] < T - 1:
            _long_run(seq, det[k] - off, start[k], off, long, k, seconds, params, klt_window)
    _steps(stacks, det, params, klt_window, step, seconds)
    return CornerTracks(detected=det, start=start, window=windows, long=long, step=step,
                        seconds=seconds)


def _long_run(seq, det, s: int, off, out, k: int, seconds, p, klt_window) -> None:
    """Camera ``k``'s long runs from frame ``s`` (window coordinates in, image out)."""
    tracked = {}
    t0 = time.perf_counter()
    tracked["lsmta"] = track_points([seq[s:]], det[s][None], params=p).xy[:, 0]
    t1 = time.perf_counter()
    tracked["klt"] = track_klt([seq[s:]], det[s][None], window=klt_window).xy[:, 0]
    seconds["lsmta long"] += t1 - t0
    seconds["klt long"] += time.perf_counter() - t1
    for name, xy in tracked.items():
        out[name][k, s:] = xy + off


@dataclass(frozen=True)
class _Step:
    """One camera's step from frame ``t``: its corners ``rows`` with their start and
    velocity (window coordinates) and the window ``x0, y0, x1, y1`` in the frame."""

    k: int
    t: int
    rows: np.ndarray
    start: np.ndarray
    velocity: np.ndarray
    window: np.ndarray


def _plan_steps(stacks, det) -> list:
    """Every step of every camera whose frame ``t`` has corners also found in ``t - 1``."""
    steps = []
    for k, stack in enumerate(stacks):
        size = stack.shape[2:0:-1]
        for t in range(1, det.shape[1] - 1):
            rows = np.flatnonzero(np.isfinite(det[k, t, :, 0] + det[k, t - 1, :, 0]))
            if rows.size:
                win = swept_window(det[k, t, rows], size)
                steps.append(_Step(k=k, t=t, rows=rows, start=det[k, t, rows] - win[:2],
                                   velocity=det[k, t, rows] - det[k, t - 1, rows], window=win))
    return steps


def _steps(stacks, det, p: TrackerParams, klt_window: int, out, seconds) -> None:
    """One-frame steps of every camera from every frame's detections: LSMTA in one call
    on a mosaic of the steps' windows (frame ``t``'s windows side by side, frame ``t + 1``'s
    in the same places: no search reaches across the :data:`MARGIN`), KLT window by
    window."""
    steps = _plan_steps(stacks, det)
    if not steps:
        return
    places, size = pack_windows([s.window[2:] - s.window[:2] for s in steps])
    mosaic = np.zeros((2, size[1], size[0]), np.uint8)
    for s, (ox, oy) in zip(steps, places):
        x0, y0, x1, y1 = s.window
        mosaic[:, oy:oy + y1 - y0, ox:ox + x1 - x0] = stacks[s.k][s.t:s.t + 2, y0:y1, x0:x1]
    starts = np.concatenate([s.start + o for s, o in zip(steps, places)])
    vel = np.concatenate([s.velocity for s in steps])
    t0 = time.perf_counter()
    moved = track_points([mosaic], starts[None], params=p, initial_velocity=vel[None]).xy[1, 0]
    seconds["lsmta step"] += time.perf_counter() - t0
    i = 0
    for s, o in zip(steps, places):
        n = len(s.rows)
        out["lsmta"][s.k, s.t + 1, s.rows] = moved[i:i + n] - o + s.window[:2]
        i += n
        x0, y0, x1, y1 = s.window
        t0 = time.perf_counter()
        klt = track_klt([stacks[s.k][s.t:s.t + 2, y0:y1, x0:x1]], s.start[None],
                        window=klt_window).xy[1, 0]
        seconds["klt step"] += time.perf_counter() - t0
        out["klt"][s.k, s.t + 1, s.rows] = klt + s.window[:2]


# ---------------------------------------------------------------------- 3-D
def at_common_time(xy, seconds) -> np.ndarray:
    """Each camera's corners moved to its synchronised frame's mean time.

    Parameters
    ----------
    xy : (K, F, C, 2) array
        Corners per camera and synchronised frame, px; NaN where not found.
    seconds : (K, F) array
        When each camera took its frame, s.

    Returns
    -------
    (K, F, C, 2) array
        ``x_k(t̄) = x_k(t_f) + (t̄ - t_f) (x_k(t_g) - x_k(t_f)) / (t_g - t_f)`` with
        ``t̄`` the mean of the cameras' times in frame ``f`` and ``g = f ± 1`` the
        camera's neighbouring frame on ``t̄``'s side (the other side, extrapolating, where
        that one lacks the corner or the recording ends); unchanged where both lack it.
    """
    xy = as_array(xy, "xy", shape=(None, None, None, 2), allow_nan=True)
    K, F = xy.shape[:2]
    ts = as_array(seconds, "seconds", shape=(K, F), allow_nan=True)
    mean = np.nanmean(ts, axis=0)
    out = xy.copy()
    for k in range(K):
        for f in range(F):
            dt = mean[f] - ts[k, f]
            if not np.isfinite(dt) or dt == 0:
                continue
            todo = np.isfinite(xy[k, f, :, 0])
            for g in ((f + 1, f - 1) if dt > 0 else (f - 1, f + 1)):
                if not (0 <= g < F and np.isfinite(ts[k, g])) or not todo.any():
                    continue
                moved = xy[k, f] + dt * (xy[k, g] - xy[k, f]) / (ts[k, g] - ts[k, f])
                ok = todo & np.isfinite(moved[:, 0])
                out[k, f, ok] = moved[ok]
                todo &= ~ok
    return out


@dataclass(frozen=True, eq=False)
class BoardGeometry:
    """A plane board's corners intersected frame by frame, against its known geometry.

    Attributes
    ----------
    points : (F, C, 3) array
        The corners, mm (NaN where seen by fewer than two cameras).
    square_error : (M,) array
        Every intersected pair of neighbouring corners: distance minus the square, mm.
    plane_rms : (F,) array
        RMS distance of the frame's corners from their least-squares plane, mm (NaN
        where the frame has fewer than 4 corners or they do not span two rows and two
        columns).
    plane_residual : (P,) array
        Those distances, all frames pooled, mm.
    """

    points: np.ndarray
    square_error: np.ndarray
    plane_rms: np.ndarray
    plane_residual: np.ndarray

    @property
    def square_rms(self) -> float:
        return float(np.sqrt(np.mean(self.square_error**2)))

    @property
    def planarity_rms(self) -> float:
        return float(np.sqrt(np.mean(self.plane_residual**2)))


def board_geometry(cameras, xy, board) -> BoardGeometry:
    """Intersect a plane board's corners in every frame and measure its squares and its
    flatness.

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : (K, F, C, 2) array
        The corners per camera and frame, px; NaN where not found.
    board : (C, 3) array
        The corners on the board, mm (z = 0); neighbours are the pairs at the smallest
        distance.

    Returns
    -------
    BoardGeometry
    """
    board = as_array(board, "board", shape=(None, 3))
    cameras = list(cameras)
    xy = as_array(xy, "xy", shape=(len(cameras), None, len(board), 2), allow_nan=True)
    K, F, C = xy.shape[:3]
    X = triangulate(cameras, xy.reshape(K, F * C, 2), min_angle_deg=0.0).points
    X = X.reshape(F, C, 3)
    d = np.linalg.norm(board[:, None] - board[None], axis=2)
    square = d[d > 0].min()
    i, j = np.nonzero(np.triu(np.isclose(d, square, rtol=1e-6)))
    err = np.linalg.norm(X[:, i] - X[:, j], axis=2) - square
    plane_rms = np.full(F, np.nan)
    residual = []
    for f in range(F):
        ok = np.isfinite(X[f, :, 0])
        on = board[ok]
        if ok.sum() < 4 or len(np.unique(on[:, 0])) < 2 or len(np.unique(on[:, 1])) < 2:
            continue
        P = X[f, ok] - X[f, ok].mean(axis=0)
        r = P @ np.linalg.svd(P, full_matrices=False)[2][2]
        plane_rms[f] = np.sqrt(np.mean(r**2))
        residual.append(r)
    return BoardGeometry(points=X, square_error=err[np.isfinite(err)], plane_rms=plane_rms,
                         plane_residual=np.concatenate(residual) if residual else np.zeros(0))


# ---------------------------------------------------------------------- the study
@dataclass(frozen=True, eq=False)
class CaliscopePixels:
    """Caliscope's recording from its videos (see the module docstring).

    Attributes
    ----------
    paths : tuple of K Path
        The videos.
    board : CharucoBoard
        From ``charuco.toml``.
    times : FrameTimes
        ``timestamps.csv``; video frame ``i`` is ``times.frames[i]``.
    corners : dict of str -> CharucoCorners
        One detection, three refinements: ``"opencv"`` (OpenCV's corners as they come),
        ``"symmetry"`` (ours), ``"caliscope style"`` (a second ``cornerSubPix`` in a
        23 x 23 window, as caliscope does).
    reference : (K, F, C, 2) array
        Caliscope's ``xy.csv`` on the videos' frames.
    differences : dict of str -> (K, F, C) array
        Distances to ``reference``, px: each of ``corners`` (for ``"caliscope style"`` with
        caliscope's mirror convention), ``"caliscope style, pixel centres"`` (ours for
        mirrored frames), and ``"xy.csv refined again"`` (:func:`refined_again`: how far
        caliscope's corners move under its own refinement in these frames).
    calibration : BoardCalibration
        :func:`calibrate_board` on the ``"symmetry"`` corners (everything from the 48
        frames).
    caliscope : list of K Camera
        Caliscope's calibration (``camera_array.toml``), mm.
    scores : dict of (str, str) -> BoardScores
        ``(cameras, corners)``: our cameras on the ``"symmetry"`` corners, caliscope's on
        each of ``corners``.
    tracks : CornerTracks
        From and against the ``"opencv"`` corners.
    geometry : dict of str -> BoardGeometry
        With our cameras: ``"symmetry"``, ``"opencv"`` (the corners as they are),
        ``"symmetry, common time"`` (moved to each frame's mean time), ``"LSMTA steps"``,
        ``"KLT steps"`` (the steps' positions in place of the ``"opencv"`` corners); with
        caliscope's cameras: ``"symmetry, caliscope's cameras"``.
    seconds : dict of str -> float
        Wall time per stage.
    """

    paths: tuple
    board: CharucoBoard
    times: FrameTimes
    corners: dict
    reference: np.ndarray
    differences: dict
    calibration: BoardCalibration
    caliscope: list
    scores: dict
    tracks: CornerTracks
    geometry: dict
    seconds: dict


def caliscope_pixels(*, folder=CALISCOPE_DIR,
                     params: TrackerParams | None = None) -> CaliscopePixels:
    """Run the study on caliscope's recording in ``folder`` (``videos/cam_*.mp4``,
    ``videos/timestamps.csv``, ``xy.csv``, ``charuco.toml``, ``camera_array.toml``);
    ``params``: LSMTA's settings."""
    folder = Path(folder)
    clock, t0 = {}, time.perf_counter()
    times = read_caliscope_times(folder / "videos" / "timestamps.csv")
    paths = tuple(folder / "videos" / f"cam_{c}.mp4" for c in times.camera_ids)
    images = read_videos(paths).load(progress=False)
    board = read_charuco_toml(folder / "charuco.toml")
    ref = read_caliscope_points(folder / "xy.csv")
    reference = _on_frames(ref.xy, ref.frames, times.frames)
    cal_cams = read_camera_toml(folder / "camera_array.toml", unit="m")
    clock["read"], t0 = time.perf_counter() - t0, time.perf_counter()
    opencv = detect_charuco(images, board, params=CharucoParams(refine="opencv"))
    clock["detect"], t0 = time.perf_counter() - t0, time.perf_counter()
    corners = {"opencv": opencv, "symmetry": refine_corners(images, opencv, board),
               "caliscope style": refine_corners(images, opencv, board, params=CALISCOPE)}
    clock["refine"], t0 = time.perf_counter() - t0, time.perf_counter()
    differences = {n: corner_differences(c.xy, reference) for n, c in corners.items()}
    differences["caliscope style, pixel centres"] = differences["caliscope style"]
    differences["caliscope style"] = corner_differences(
        caliscope_convention(corners["caliscope style"]), reference)
    differences["xy.csv refined again"] = corner_differences(
        refined_again(images, reference, opencv.mirrored), reference)
    ours = corners["symmetry"]
    calibration = calibrate_board(ours.xy, ours.board, [c.image_size for c in cal_cams],
                                  names=[c.name for c in cal_cams])
    clock["calibrate"], t0 = time.perf_counter() - t0, time.perf_counter()
    scores = {(who, name): board_scores(cams, corners[name].board_points(
        frames=times.frames, camera_ids=times.camera_ids))
        for who, cams, names in (("ours", calibration.cameras, ("symmetry",)),
                                 ("caliscope", cal_cams, tuple(corners)))
        for name in names}
    clock["score"], t0 = time.perf_counter() - t0, time.perf_counter()
    tracks = track_board_corners(images, opencv.xy, params=params)
    clock["track"], t0 = time.perf_counter() - t0, time.perf_counter()
    geometry = _geometries(calibration.cameras, cal_cams, corners, tracks, times)
    clock["geometry"] = time.perf_counter() - t0
    return CaliscopePixels(paths=paths, board=board, times=times, corners=corners,
                           reference=reference, differences=differences,
                           calibration=calibration, caliscope=cal_cams, scores=scores,
                           tracks=tracks, geometry=geometry, seconds=clock)


def _on_frames(xy, frames, wanted) -> np.ndarray:
    """``xy (K, F, C, 2)`` of ``frames`` laid out on the ``wanted`` frames (NaN where
    absent)."""
    out = np.full((xy.shape[0], len(wanted)) + xy.shape[2:], np.nan)
    pos = {int(f): i for i, f in enumerate(frames)}
    for i, f in enumerate(wanted):
        if int(f) in pos:
            out[:, i] = xy[:, pos[int(f)]]
    return out


def _geometries(ours, theirs, corners: dict, tracks: CornerTracks, times: FrameTimes) -> dict:
    sym, board = corners["symmetry"].xy, corners["symmetry"].board
    return {"symmetry": board_geometry(ours, sym, board),
            "opencv": board_geometry(ours, corners["opencv"].xy, board),
            "symmetry, common time": board_geometry(ours, at_common_time(sym, times.seconds),
                                                    board),
            "LSMTA steps": board_geometry(ours, tracks.step["lsmta"], board),
            "KLT steps": board_geometry(ours, tracks.step["klt"], board),
            "symmetry, caliscope's cameras": board_geometry(theirs, sym, board)}
