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
* per surface file (measured frame): the board's plane, from lsmta's own ChArUco corners
  (:func:`lsmta.calibration.charuco.detect_charuco`) in cameras 0, 2 and 3 (which see the
  board's face; 3 only in the second half, when 2 loses most of it), each corner intersected
  with the capture's cameras from every one that finds it, at least 6 corners in 2 cameras
  (their flatness: notebook 19 finds the corners flat to 0.23 mm RMS, the floor of what
  this check can show); every surface point's
  distance to that plane, for all points and for the board points (those whose image in
  their view group's template camera lies inside the hull of the corners found there):
  median |distance|, RMS and the share within 2 mm. The sheet is transparent: what is seen
  through it falls inside the hull but off the plane, so the share within 2 mm, not a
  best-fit plane of the points inside the hull, says how many points lie on the board;
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
from plyfile import PlyData

from lsmta.calibration.charuco import detect_charuco, read_charuco_toml
from lsmta.camera_files import read_camera_toml
from lsmta.cli import main as lsmta
from lsmta.data import CALISCOPE_DIR
from lsmta.io import read_videos
from lsmta.triangulation import triangulate

VIDEOS = [CALISCOPE_DIR / "videos" / f"cam_{k}.mp4" for k in range(4)]
CAMERAS = CALISCOPE_DIR / "camera_array.toml"
BOARD = CALISCOPE_DIR / "charuco.toml"


def run_command(args, out: Path) -> dict:
    """``lsmta capture`` (unless ``--reuse`` finds its summary): exit status and times."""
    if args.reuse and (out / "summary.json").exists():
        earlier = args.out.with_suffix(".json")
        if earlier.exists():                       # the times of the run that wrote them
            c = json.loads(earlier.read_text())["command"]
            return {**c, "reused": True}
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


NEAR_MM = 2.0                   # "on the board": within this distance of its plane
BOARD_CAMERAS = (0, 2, 3)       # the cameras that see the board's face (3: second half)


def _plane(points: np.ndarray):
    """Least-squares plane of (N, 3) points: centroid, unit normal, RMS distance (mm)."""
    centre = points.mean(axis=0)
    _, sv, vt = np.linalg.svd(points - centre, full_matrices=False)
    return centre, vt[-1], float(sv[-1] / np.sqrt(len(points)))


def _distances(d: np.ndarray) -> dict:
    """Median |d|, RMS and share within NEAR_MM of distances d (mm) to the board's plane."""
    if not len(d):
        return {"n": 0, "median_abs_mm": None, "rms_mm": None, "share_near": None}
    return {"n": int(len(d)), "median_abs_mm": float(np.median(np.abs(d))),
            "rms_mm": float(np.sqrt(np.mean(d ** 2))),
            "share_near": float(np.mean(np.abs(d) <= NEAR_MM))}


def board_corners(args, frames: list[int], cameras: list[int]) -> dict:
    """lsmta's ChArUco corners (K, F, N, 2) in ``cameras`` at the measured ``frames`` (at the
    command's scale), by camera index."""
    videos = read_videos([VIDEOS[k] for k in cameras], scale=args.scale)
    stacks = videos.load(progress=False)
    corners = detect_charuco([s[frames] for s in stacks], read_charuco_toml(BOARD))
    return {k: corners.xy[i] for i, k in enumerate(cameras)}


def _hull(xy: np.ndarray):
    """Convex hull (int32 polygon) of the finite corners, or None below 4."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    return cv2.convexHull(xy.astype(np.float32)) if len(xy) >= 4 else None


def _inside(hull, xy: np.ndarray) -> np.ndarray:
    return np.array([hull is not None and np.isfinite(p).all() and cv2.pointPolygonTest(
        hull, (float(p[0]), float(p[1])), False) >= 0 for p in xy], bool)


def surfaces(args, out: Path, summary: dict) -> dict:
    """Per PLY file: the board's plane from the corners, all points' and the board points'
    distances to it."""
    plys = sorted((out / "surfaces").glob("frame_*.ply"))
    frames = [int(p.stem.split("_")[1]) for p in plys]
    if not plys:
        return {"files": 0, "frames": {}}
    groups = [[int(c) for c in g["cameras"]] for g in summary["view_groups"]]
    templates = [int(g["template"]) for g in summary["view_groups"]]
    corners = board_corners(args, frames, sorted(set(BOARD_CAMERAS) | set(templates)))
    cams = read_camera_toml(out / "cameras.toml", unit="mm")
    rows = {}
    for i, (path, f) in enumerate(zip(plys, frames)):
        vertex = PlyData.read(str(path))["vertex"]
        pts = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(float)
        group = np.asarray(vertex["group"], int) - 1 if len(pts) else np.zeros(0, int)
        row = {"points": len(pts), "board": None}
        xy = np.stack([corners[k][i] for k in BOARD_CAMERAS])           # (3, N, 2)
        seen = np.isfinite(xy).all(axis=2)
        both = seen.sum(axis=0) >= 2
        if both.sum() >= 6:
            tri = triangulate([cams[k] for k in BOARD_CAMERAS], xy[:, both])
            centre, normal, flat = _plane(tri.points)
            d = (pts - centre) @ normal
            on = np.zeros(len(pts), bool)
            for g, t in enumerate(templates):
                sel = group == g
                on[sel] = _inside(_hull(corners[t][i]), cams[t].project(pts[sel], behind="nan"))
            row["board"] = {"corners": int(both.sum()), "corner_plane_rms_mm": flat,
                            "corner_views": int(seen[:, both].sum()),
                            "corner_reprojection_px": float(np.nanmedian(
                                tri.reprojection_error))}
            row["all"] = _distances(d)
            row["inside_hull"] = _distances(d[on])
        rows[f] = row
    return {"files": len(plys), "groups": groups, "templates": templates,
            "board_cameras": list(BOARD_CAMERAS), "near_mm": NEAR_MM, "frames": rows}


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
    print("view groups: " + ", ".join(f"{'+'.join(g['cameras'])} (template {g['template']})"
                                      for g in r["view_groups"]))
    print(f"surfaces: {s['files']} files; distance to the board's plane (lsmta's corners in "
          f"cameras {s.get('board_cameras')}; notebook 19: corners flat to 0.23 mm): "
          f"median |d| / RMS mm / share within {s.get('near_mm')} mm")
    for f, row in s["frames"].items():
        b = row["board"]
        if b is None:
            print(f"  frame {f:3d}: {row['points']:5d} points; < 6 corners in two cameras")
            continue
        print(f"  frame {f:3d}: corners {b['corners']:3d} flat to "
              f"{b['corner_plane_rms_mm']:.2f} mm | all {_d(row['all'])} | inside the hull "
              f"{_d(row['inside_hull'])}")
    t = r["trajectories"]
    print(f"trajectories: {t['total']} ({t['kept_by_filters']} kept by the filters), C3D "
          f"{t['c3d_points']} points x {t['c3d_frames']} frames at {t['c3d_rate_hz']:g} Hz, "
          f"median {t['frames_per_point_median']:.0f} frames each; tracked points' median "
          f"reprojection error {t['track_residual_px']} px")



def _d(x: dict) -> str:
    if not x["n"]:
        return "    0 points"
    return (f"{x['n']:4d} points {x['median_abs_mm']:6.2f} / {x['rms_mm']:6.2f} / "
            f"{100 * x['share_near']:3.0f} %")


if __name__ == "__main__":
    main()
