"""`lsmta capture` on caliscope's four-camera ChArUco recording, as a user would run it.

    .venv/bin/python experiments/capture_caliscope.py [--scale 1.0] [--no-refine]
        [--out build/benchmarks/capture_caliscope] [--reuse]

The recording (``data/caliscope_4cam``, shipped with lsmta; the README of ``data``): four
1280 x 720 webcams, two mounted on their side, 48 frames at 6 fps, a person moving a
ChArUco board printed on a transparent sheet (cameras 0 and 2 see its face, camera 1 its
back, camera 3 its edge for the first half). The command is run with caliscope's own
calibration (``camera_array.toml``, metres), refined from the recording unless
``--no-refine``. Its files are read back (ezc3d, pyvista, ``lsmta.camera_files``) and the
numbers a user can check without truth are printed and written to ``<out>.json``
(``build/benchmarks/capture_caliscope.json`` by default):

* the tie-point residuals on held-out places per camera, before and after the refinement,
  and whether the refined cameras were used;
* per surface file (measured frame): the points, the board's points among them (those whose
  image in the view group's template camera lies inside the hull of the ChArUco corners
  lsmta finds in that frame, :func:`lsmta.calibration.charuco.detect_charuco`), and the
  board points' flatness: the RMS distance to their best-fit plane, mm (the board is flat);
* the trajectories in the C3D file, the frames each holds, the share kept by the filters
  and the tracked points' median reprojection error (``summary.json``);
* the command's wall and CPU time (this process, all threads).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import ezc3d
import numpy as np
import pyvista as pv

from lsmta.calibration.charuco import detect_charuco, read_charuco_toml
from lsmta.camera_files import read_camera_toml
from lsmta.cli import main as lsmta
from lsmta.data import CALISCOPE_DIR
from lsmta.io import read_videos

VIDEOS = [CALISCOPE_DIR / "videos" / f"cam_{k}.mp4" for k in range(4)]
CAMERAS = CALISCOPE_DIR / "camera_array.toml"
BOARD = CALISCOPE_DIR / "charuco.toml"


def run_command(args, out: Path) -> dict:
    """``lsmta capture`` (unless ``--reuse`` finds its summary): exit status and times."""
    if args.reuse and (out / "summary.json").exists():
        return {"status": 0, "wall_s": None, "cpu_s": None, "reused": True}
    argv = ["capture", "--videos", *map(str, VIDEOS), "--cameras", str(CAMERAS),
            "--scale", str(args.scale), "--out", str(out), "--quiet"]
    if args.no_refine:
        argv.append("--no-refine")
    print("lsmta " + " ".join(argv), flush=True)
    wall, cpu = time.perf_counter(), time.process_time()
    status = lsmta(argv)
    return {"status": status, "wall_s": time.perf_counter() - wall,
            "cpu_s": time.process_time() - cpu, "reused": False}


def refinement(out: Path) -> dict:
    """Per camera: held-out tie-point residuals before / after (px), refined cameras used."""
    path = out / "refinement" / "refinement.json"
    if not path.exists():
        return {"refined": False}
    r = json.loads(path.read_text())
    return {"refined": True, "used_refined": r["used_refined"], "kind": r["held_out_kind"],
            "held_out_points": r["held_out_points"],
            "cameras": {k: {"tie_points": c["tie_points"],
                            "held_out_before_px": c["held_out_before_px"],
                            "held_out_after_px": c["held_out_after_px"]}
                        for k, c in r["cameras"].items()}}


def _plane_rms(points: np.ndarray) -> float:
    """RMS distance (mm) of the points to their least-squares plane."""
    centred = points - points.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(points)))


def board_hulls(args, out: Path, summary: dict, frames: list[int]) -> dict:
    """Per frame: the hull (int32 polygon) of the board's corners lsmta detects in the first
    view group's template camera (at the command's scale), or None."""
    group = summary["view_groups"][0]
    k = group["cameras"].index(group["template"])
    cam_index = [int(c) for c in group["cameras"]][k]
    videos = read_videos([VIDEOS[cam_index]], scale=args.scale)
    stack = videos.load(progress=False)[0]
    corners = detect_charuco([stack[frames]], read_charuco_toml(BOARD))
    hulls = {}
    for i, f in enumerate(frames):
        xy = corners.xy[0, i]
        xy = xy[np.isfinite(xy).all(axis=1)]
        hulls[f] = (cv2.convexHull(xy.astype(np.float32)) if len(xy) >= 4 else None)
    return {"template_camera": cam_index, "hulls": hulls}


def surfaces(args, out: Path, summary: dict) -> dict:
    """Per PLY file: points, board points and the board points' plane RMS (mm)."""
    plys = sorted((out / "surfaces").glob("frame_*.ply"))
    frames = [int(p.stem.split("_")[1]) for p in plys]
    if not plys:
        return {"files": 0, "frames": {}}
    board = board_hulls(args, out, summary, frames)
    cams = read_camera_toml(out / "cameras.toml", unit="mm")
    tmpl = cams[board["template_camera"]]
    rows = {}
    for path, f in zip(plys, frames):
        cloud = pv.read(path)
        pts = np.asarray(cloud.points, float)
        row = {"points": len(pts), "board_points": 0, "board_plane_rms_mm": None,
               "board_found": board["hulls"][f] is not None}
        if len(pts) and row["board_found"]:
            xy = tmpl.project(pts, behind="nan")
            inside = np.array([np.isfinite(p).all() and cv2.pointPolygonTest(
                board["hulls"][f], (float(p[0]), float(p[1])), False) >= 0 for p in xy])
            row["board_points"] = int(inside.sum())
            if inside.sum() >= 10:
                row["board_plane_rms_mm"] = _plane_rms(pts[inside])
        row["all_plane_rms_mm"] = _plane_rms(pts) if len(pts) >= 3 else None
        rows[f] = row
    return {"files": len(plys), "template_camera": board["template_camera"], "frames": rows}


def trajectories(out: Path, summary: dict) -> dict:
    """The C3D file read back, with the summary's counts and residuals."""
    c3d = ezc3d.c3d(str(out / "trajectories.c3d"))
    xyz = c3d["data"]["points"][:3]                        # (3, N, T), mm
    present = np.isfinite(xyz).all(axis=0)
    per_point = present.sum(axis=1)
    return {"c3d_points": int(xyz.shape[1]), "c3d_frames": int(xyz.shape[2]),
            "c3d_rate_hz": float(c3d["parameters"]["POINT"]["RATE"]["value"][0]),
            "frames_per_point_median": float(np.median(per_point)) if len(per_point) else 0.0,
            "samples": int(present.sum()),
            "total": summary["trajectories"]["total"],
            "kept_by_filters": summary["trajectories"]["kept_by_filters"],
            "track_residual_px": [g.get("track_residual_px") for g in summary["view_groups"]],
            "tracks_per_group": [g["tracks"] for g in summary["view_groups"]],
            "tracking_from": [g["tracking_from"] for g in summary["view_groups"]]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--no-refine", action="store_true")
    ap.add_argument("--out", type=Path, default=Path("build/benchmarks/capture_caliscope"))
    ap.add_argument("--reuse", action="store_true",
                    help="read the files of an earlier run instead of running the command")
    args = ap.parse_args(argv)
    out = args.out / "capture"
    command = run_command(args, out)
    if command["status"] != 0:
        raise SystemExit(f"lsmta capture failed with status {command['status']}")
    summary = json.loads((out / "summary.json").read_text())
    cams = read_camera_toml(out / "cameras.toml", unit="mm")
    record = {"scale": args.scale, "refine": not args.no_refine, "command": command,
              "cameras_note": summary.get("cameras_note"),
              "cameras_read_back": [c.name for c in cams],
              "view_groups": [{"cameras": g["cameras"], "template": g["template"],
                               "surface_points": g["surface_points"]}
                              for g in summary["view_groups"]],
              "refinement": refinement(out), "surfaces": surfaces(args, out, summary),
              "trajectories": trajectories(out, summary),
              "report_html": (out / "report.html").exists()}
    _print(record)
    path = args.out.with_suffix(".json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2, default=str))
    print(f"wrote {path}")
    return record


def _print(r: dict) -> None:
    c = r["command"]
    if c["wall_s"] is not None:
        print(f"command: {c['wall_s']:.0f} s wall, {c['cpu_s']:.0f} s CPU (scale {r['scale']})")
    print(f"cameras: {r['cameras_note']}")
    ref = r["refinement"]
    if ref["refined"]:
        for k, cam in ref["cameras"].items():
            print(f"  camera {k}: held-out tie points {cam['held_out_before_px']:.2f} -> "
                  f"{cam['held_out_after_px']:.2f} px ({cam['tie_points']} tie points)")
    s = r["surfaces"]
    print(f"surfaces: {s['files']} files (template camera {s.get('template_camera')})")
    for f, row in s["frames"].items():
        rms = row["board_plane_rms_mm"]
        print(f"  frame {f:3d}: {row['points']:5d} points, {row['board_points']:5d} on the "
              f"board, board plane RMS " + ("-" if rms is None else f"{rms:.2f} mm"))
    t = r["trajectories"]
    print(f"trajectories: {t['total']} ({t['kept_by_filters']} kept by the filters), C3D "
          f"{t['c3d_points']} points x {t['c3d_frames']} frames at {t['c3d_rate_hz']:g} Hz, "
          f"median {t['frames_per_point_median']:.0f} frames each; tracked points' median "
          f"reprojection error {t['track_residual_px']} px")


if __name__ == "__main__":
    main()
