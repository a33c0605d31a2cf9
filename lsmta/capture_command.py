"""``lsmta capture``: a recording's videos and camera file in, files other tools read out.

Stages: read the camera file (format from its content, unit from the format where it has
one) -> open the videos (:func:`lsmta.io.read_videos`) -> cameras: refined from the
recording (:func:`lsmta.systems.refine_rig`; the refined ones are used only where they fit
held-out places at least as well as the file's), the file's as given (``--no-refine``),
calibrated from a bar recording (``--bar``, the file's cameras as the nominal rig), or from
a ChArUco board recording (``--board``: :func:`lsmta.calibration.charuco.detect_charuco`,
then :func:`lsmta.calibration.board.calibrate_board`) ->
:func:`lsmta.systems.capture_recording` -> :meth:`~lsmta.systems.BodyCapture.save`, and,
when the cameras were refined, :meth:`~lsmta.systems.RigRefinement.save` into
``<out>/refinement/`` (the refined cameras, used or not, and each camera's tie-point
residuals before and after).

Bad input ends with exit status 2 and one line naming what is wrong.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from .calibration.board import calibrate_board
from .calibration.charuco import detect_charuco, read_charuco_toml
from .camera_files import read_camera_file
from .io import cameras_for_videos, read_videos
from .systems import (
    ArmFitParams,
    CaptureParams,
    MarkerParams,
    RigRefinement,
    RigRefinementParams,
    SurfaceParams,
    Tracker2D,
    calibrate_rig,
    capture_recording,
    nyquist_checked,
    refine_rig,
)
from .systems.more_views import MoreViewsParams
from .systems.subject import SubjectMaskParams

EXAMPLE = """example (the Pose2Sim demo that ships with lsmta, 100 frames, full size):
  lsmta capture --videos data/pose2sim_demo/cam0{1,2,3,4}.mp4 \\
                --cameras data/pose2sim_demo/Calib.qca.txt --mismatch crop \\
                --frames 0:100 --out capture_demo
"""


def add_parser(sub) -> None:
    """The ``capture`` subcommand's arguments."""
    cap = sub.add_parser(
        "capture", help="run the LSMTA system on your own videos and camera file",
        description="Run the LSMTA system on a recording: videos and a camera file in, "
                    "refined cameras, trajectories (C3D, TRC), surfaces (PLY) and, with "
                    "--arm, one closed mesh of the fitted arm per fitted frame (PLY) out.",
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    cap.add_argument("--videos", nargs="+", required=True, metavar="VIDEO",
                     help="one synchronised video per camera, in the camera file's order")
    cap.add_argument("--cameras", default=None, metavar="FILE",
                     help="camera file: Qualisys .qca, OpenCV YAML, aniposelib / Pose2Sim / "
                          "caliscope TOML (needed unless --board calibrates the cameras)")
    cap.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    cap.add_argument("--frames", default=None, metavar="START:STOP",
                     help="frames to process (0-based, STOP excluded; default: all)")
    cap.add_argument("--scale", type=float, default=1.0,
                     help="resize factor of the frames, e.g. 0.5 (default 1)")
    cap.add_argument("--units", choices=("mm", "cm", "m"), default=None,
                     help="unit of the camera file's positions where its format has none")
    cap.add_argument("--mismatch", choices=("error", "crop"), default="error",
                     help="a video smaller than its camera: an error, or the camera's frame "
                          "with its right / bottom edge cut off")
    cap.add_argument("--no-refine", action="store_true",
                     help="use the camera file as it is (no refinement from the recording)")
    cap.add_argument("--bar", nargs="+", metavar="VIDEO", default=None,
                     help="videos of a reference bar: calibrate from them instead")
    cap.add_argument("--bar-length", type=float, default=None, metavar="MM",
                     help="distance between the bar's targets, mm (with --bar)")
    cap.add_argument("--board", nargs="+", metavar="VIDEO", default=None,
                     help="videos of a ChArUco board, one per camera: calibrate from them")
    cap.add_argument("--board-config", default=None, metavar="FILE",
                     help="the board (caliscope's charuco.toml layout; with --board)")
    cap.add_argument("--markers", choices=("skin", "blobs"), default=None,
                     help="also find markers in every view, track and join them: skin "
                          "markers (small grey blobs on skin) or any small bright blob")
    cap.add_argument("--tracker", choices=("lsmta", "klt"), default="lsmta",
                     help="the markers' 2-D tracker (default lsmta; klt: OpenCV's, the peer)")
    cap.add_argument("--marker-filter-hz", type=float, default=None, metavar="HZ",
                     help="cut-off of the zero-lag Butterworth low-pass (order 4) of the "
                          "markers' 3-D positions written to markers.c3d / .trc, Hz (default "
                          "6, Pose2Sim's, turned off with a warning at 12 fps or less; a "
                          "given one must be below half the frame rate); 0: not filtered")
    cap.add_argument("--surface-method", choices=("growth", "rectified-sgbm", "auto"),
                     default="growth",
                     help="how surfaces are measured: growth (default: seeds and LSM region "
                          "growing), rectified-sgbm (a two-camera view group on its rectified "
                          "images, LSM started at OpenCV SGBM's disparities; for wide, blurred "
                          "pairs; a group of 3 or more cameras falls back to the growth, "
                          "with a warning) or auto (the growth decides on the first measured "
                          "frame: rectified-sgbm for a pair where it matched fewer than 1%% "
                          "of its textured nodes). Cost: with rectified-sgbm every measured "
                          "frame (every 4th) runs SGBM + LSM, about 10-20 s CPU per pair per "
                          "frame at full size, so 100 full-size frames take far longer than "
                          "the growth; SGBM's memory is bounded (2 GiB: OpenCV's 5-path mode "
                          "above it)")
    cap.add_argument("--subject-mask", action="store_true",
                     help="drop surface points off the moving subject (each frame against "
                          "the median of every fifth frame, threshold 10 x the robust noise; "
                          "its 15-px radii scale with --scale); a recording where nothing "
                          "moves has no mask (a warning says so)")
    cap.add_argument("--more-views", action="store_true",
                     help="match every surface point in the cameras outside its view group "
                          "that see it and intersect it from all its views (the summary gives "
                          "the points in >= 3 views and their residual; its 13- and 21-px "
                          "patches scale with --scale)")
    cap.add_argument("--arm", action="store_true",
                     help="fit the arm model at the end (a person facing the cameras)")
    cap.add_argument("--quiet", action="store_true", help="no progress bars")


def _frames(text: str | None):
    if text is None:
        return None
    try:
        start, stop = (int(x) if x else None for x in text.split(":"))
    except ValueError:
        raise ValueError(f"--frames: expected START:STOP (e.g. 0:100), got {text!r}") from None
    return range(start or 0, stop) if stop is not None else slice(start or 0, None)


def _board(args, videos, progress: bool):
    """Cameras calibrated from ChArUco board videos, fitted to the recording's frames."""
    if args.board_config is None:
        raise ValueError("--board-config: the board's description (charuco.toml) is needed "
                         "with --board")
    board = read_charuco_toml(args.board_config)
    bv = read_videos(args.board)
    if bv.n_views != videos.n_views:
        raise ValueError(f"--board: {bv.n_views} board videos for {videos.n_views} cameras")
    corners = detect_charuco(bv.load(progress=progress), board, progress=progress)
    cal = calibrate_board(corners.xy, corners.board, bv.file_sizes,
                          names=[Path(p).stem for p in args.board])
    cams = cameras_for_videos(cal.cameras, videos, mismatch=args.mismatch)
    return cams, cal, f"calibrated from the board, image RMS {cal.bundle.rms:.3f} px"


def _cameras(args, videos, given, progress: bool):
    """(cameras fitting the videos' frames, calibration object or None, one-line note)."""
    if args.board and args.bar:
        raise ValueError("--board, --bar: give one calibration recording, not both")
    if args.board and args.bar:
        raise ValueError("--board, --bar: give one calibration recording, not both")
    if args.board:
        return _board(args, videos, progress)
    if given is None:
        raise ValueError("--cameras: a camera file is needed (or --board to calibrate)")
    if args.bar:
        if args.bar_length is None:
            raise ValueError("--bar-length: the bar's length (mm) is needed with --bar")
        bar = read_videos(args.bar, scale=args.scale)
        nominal = cameras_for_videos(given, bar, mismatch=args.mismatch)
        stacks = bar.load(progress=progress)
        if len({s.shape for s in stacks}) != 1:
            raise ValueError("--bar: the bar videos must all have one frame size")
        cal = calibrate_rig(np.stack(stacks), args.bar_length, nominal, progress=progress)
        if [(c.width, c.height) for c in cal.cameras] != [tuple(s) for s in videos.sizes]:
            raise ValueError(f"--bar: the bar videos' frames are {list(bar.sizes)} px but the "
                             f"recording's are {list(videos.sizes)}; record both at one size")
        return cal.cameras, cal, f"calibrated from the bar, image RMS {cal.bundle.rms:.3f} px"
    if args.no_refine:
        return cameras_for_videos(given, videos, mismatch=args.mismatch), None, "as given"
    if progress:
        print("lsmta capture: refining the cameras from the recording (tie points in "
              "evenly spaced frames; no progress bar; --no-refine skips it) ...",
              file=sys.stderr, flush=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # the choice below says it in one line
        ref = refine_rig(videos, given, params=RigRefinementParams(mismatch=args.mismatch))
    b, a = np.nanmedian(ref.held_out_before), np.nanmedian(ref.held_out_after)
    note = (f"refined from the recording (held-out {ref.held_out_kind} {b:.2f} -> {a:.2f} px "
            "median); "
            + ("refined cameras used" if ref.improved else
               "NOT better in every camera on held-out places: the file's cameras used"))
    return list(ref.chosen), ref, note


def _params(args) -> CaptureParams:
    markers = None
    if args.markers:
        markers = MarkerParams(detector=args.markers, sigma=2.5 * args.scale,
                               max_px=4.0 * args.scale, tracker=Tracker2D[args.tracker.upper()],
                               **_filter_hz(args.marker_filter_hz))
    surface = SurfaceParams(
        method={"growth": "grow", "rectified-sgbm": "rectified", "auto": "auto"}[
            args.surface_method],
        rectified_start="sgbm" if args.surface_method == "rectified-sgbm" else "grow",
        rectified_geometry="shift" if args.surface_method == "rectified-sgbm" else "row-affine",
        subject_mask=_scaled_mask(args.scale) if args.subject_mask else None)
    return CaptureParams(arm=ArmFitParams() if args.arm else None, markers=markers,
                         surface=surface,
                         more_views=_scaled_views(args.scale) if args.more_views else None)


def _filter_hz(hz: float | None) -> dict:
    """MarkerParams' ``filter_hz`` from ``--marker-filter-hz`` (None: the default; 0: off)."""
    return {} if hz is None else {"filter_hz": hz or None}


def _scaled_mask(scale: float) -> SubjectMaskParams:
    """The subject mask's closing and growing radii (px of full-size frames) at ``scale``."""
    p = SubjectMaskParams()
    return replace(p, close_px=max(1, round(p.close_px * scale)),
                   grow_px=max(1, round(p.grow_px * scale)))


def _scaled_views(scale: float) -> MoreViewsParams:
    """The more-views patches (px of full-size frames) at ``scale``, odd and at least 5."""
    p = MoreViewsParams()

    def odd(n: int) -> int:
        return max(5, 2 * round((n - 1) / 2 * scale) + 1)

    return replace(p, patch=odd(p.patch), retry_patch=tuple(odd(n) for n in p.retry_patch))


def run(args) -> int:
    """``lsmta capture``; returns the exit status."""
    progress = not args.quiet
    t0 = time.perf_counter()
    try:
        given = None if args.cameras is None else read_camera_file(args.cameras, unit=args.units)
        videos = read_videos(args.videos, frames=_frames(args.frames), scale=args.scale)
        params = _params(args)
        if params.markers is not None and args.marker_filter_hz:        # before any stage
            nyquist_checked(params.markers, videos.fps, explicit=True)
        t_cal = time.perf_counter()
        cameras, calibration, note = _cameras(args, videos, given, progress)
        t_cal = time.perf_counter() - t_cal
        print(f"lsmta capture: cameras {note}", file=sys.stderr)
        capture = capture_recording(videos, cameras, calibration=calibration,
                                    params=params,
                                    progress=progress)
    except (ValueError, FileNotFoundError) as err:
        message = (str(err).replace("pass mismatch='crop'", "pass --mismatch crop")
                   .replace("params.markers.filter_hz:", "--marker-filter-hz:")
                   .replace("filter_hz:", "--marker-filter-hz:"))
        print(f"lsmta capture: {message.splitlines()[0]}", file=sys.stderr)
        return 2
    files = capture.save(args.out)
    record = json.loads(Path(files["summary"]).read_text(encoding="utf-8"))
    record["cameras_note"] = note
    record["calibration_seconds"] = t_cal
    if isinstance(calibration, RigRefinement):      # per camera, before and after
        written = calibration.save(Path(args.out) / "refinement")
        record["refinement"] = {k: str(Path(v).relative_to(args.out)) for k, v in written.items()}
    record["seconds_total"] = time.perf_counter() - t0
    Path(files["summary"]).write_text(json.dumps(record, indent=2), encoding="utf-8")
    for row in capture.summary():
        took = f"{row['seconds']:7.1f} s" if np.isfinite(row["seconds"]) else "      -  "
        print(f"  {row['stage']:<13} {took}  {row['result']}", file=sys.stderr)
    print(f"lsmta capture: wrote {args.out} ({len(files['surfaces'])} surface files, "
          f"{len(files['mesh'])} mesh files) in "
          f"{record['seconds_total']:.0f} s", file=sys.stderr)
    return 0
