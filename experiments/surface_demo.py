"""The surface stage alone on frame 0 of the Pose2Sim demo, with its rejection census.

    .venv/bin/python experiments/surface_demo.py [--cache /tmp/surface_demo_cache.pkl]
            [--scale 1.0] [--frames 0:100] [--out build/benchmarks/surface_demo]
        [--from-capture /tmp/cd_surface/capture]

The first run refines the cameras from the recording as ``lsmta capture`` does
(:func:`lsmta.systems.refine_rig` on ``--frames``, the chosen cameras) and measures each view
group's image noise as :func:`lsmta.systems.capture_recording` does (over the same frames), and
caches both in ``--cache``; later runs read frame 0 only and run
:func:`lsmta.systems.measure_surfaces` on it per view group, as the capture does. Prints and
writes ``<out>/surface_demo.json``, for the stage as it runs, with the precision rule for
which nodes are tried (``SurfaceParams.texture_rule``) and with larger patches: per group
the points on frame 0, the median multi-view
residual (the largest reprojection error of each kept point over its views, px, the median
over the points), the stage's CPU time, and the census: every LSM attempt of the growth by
outcome, every grid node by outcome, and the n-tuples through the filters
(:func:`lsmta.systems.surfaces.surface_census`). Target (issue #40): >= 2,000 points from
>= 3 views at a median residual <= 0.5 px (this rig's view groups are pairs, so the points
here have two views).
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from lsmta.camera import cropped_camera
from lsmta.camera_files import read_camera_file, read_camera_toml
from lsmta.data import POSE2SIM_CAMERAS, POSE2SIM_VIDEOS
from lsmta.io import read_videos
from lsmta.noise import temporal_noise
from lsmta.report import write_json
from lsmta.systems import (
    RigRefinementParams,
    SurfaceParams,
    measure_surfaces,
    refine_rig,
    view_groups,
)
from lsmta.systems.surfaces import surface_census


def _group_inputs(stacks, cameras, group):
    """The group's frames and cameras, cut to the group's common size (as the capture)."""
    w = min(stacks[k].shape[2] for k in group.cameras)
    h = min(stacks[k].shape[1] for k in group.cameras)
    v = np.stack([stacks[k][:, :h, :w] for k in group.cameras])
    cams = [cameras[k] if (cameras[k].width, cameras[k].height) == (w, h)
            else cropped_camera(cameras[k], 0, 0, w, h) for k in group.cameras]
    return v, cams


def _cache(path: Path, scale: float, frames: range, capture: str | None) -> dict:
    if path.exists():
        return pickle.loads(path.read_bytes())
    videos = read_videos([str(v) for v in POSE2SIM_VIDEOS], frames=frames, scale=scale)
    if capture is not None:           # the cameras a capture used (its cameras.toml)
        cameras = read_camera_toml(Path(capture) / "cameras.toml", unit="mm")
    else:
        given = read_camera_file(POSE2SIM_CAMERAS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = refine_rig(videos, given, params=RigRefinementParams(mismatch="crop"))
        cameras = list(ref.chosen)
    stacks = videos.load(progress=False)
    noise = [float(temporal_noise(_group_inputs(stacks, cameras, g)[0]).sigma)
             for g in view_groups(cameras)]
    data = {"cameras": cameras, "noise": noise, "scale": scale,
            "frames": [frames.start, frames.stop], "capture": capture}
    path.write_bytes(pickle.dumps(data))
    return data


def run_groups(stacks, cameras, noise, params: SurfaceParams) -> list:
    """Frame 0's surface per view group, with its census, residual and CPU time."""
    rows = []
    for g, sigma in zip(view_groups(cameras), noise):
        v, cams = _group_inputs(stacks, cameras, g)
        t0 = time.process_time()
        s = measure_surfaces(v, cams, [0], sigma=sigma,
                             params=replace(params, template=g.template_position))
        seconds = time.process_time() - t0
        names = "+".join(c.name or str(k) for c, k in zip(cams, g.cameras))
        if 0 not in s:
            rows.append({"group": names, "points": 0, "cpu_s": seconds})
            continue
        r = s[0]
        err = r.intersection.reprojection_error[:, r.kept]
        worst = np.nanmax(err, axis=0) if err.size else np.array([])
        rows.append({"group": names, "points": int(r.kept.sum()),
                     "median_residual_px": float(np.median(worst)) if worst.size else None,
                     "cpu_s": seconds, "census": surface_census(r)})
    return rows


#: the surface stage as it runs (the 2-grey-level spread rule, the default), with the precision
#: rule for which nodes are tried, and with larger patches or a looser precision limit
VARIANTS = {"default (spread rule)": SurfaceParams(),
            "precision rule": SurfaceParams(texture_rule="precision"),
            "patch 15, retry 21": SurfaceParams(patch=15, retry_patch=(21,)),
            "patch 21, retry 31": SurfaceParams(patch=21, retry_patch=(31,)),
            "max_sigma_xy 0.5 px": SurfaceParams(max_sigma_xy=0.5)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", default="/tmp/surface_demo_cache.pkl")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--frames", default="0:100")
    parser.add_argument("--out", default="build/benchmarks/surface_demo")
    parser.add_argument("--from-capture", default=None, metavar="DIR",
                        help="take the cameras from a capture's output (DIR/cameras.toml) "
                             "instead of refining them again")
    args = parser.parse_args(argv)
    start, stop = (int(x) for x in args.frames.split(":"))
    data = _cache(Path(args.cache), args.scale, range(start, stop), args.from_capture)
    made = {"scale": args.scale, "frames": [start, stop], "capture": args.from_capture}
    for key, value in made.items():   # a cache made with other settings is not reused silently
        if key in data and data[key] != value:
            raise SystemExit(f"--cache: made with {key} {data[key]}, not {value}; "
                             "remove it or give another --cache")
    videos = read_videos([str(v) for v in POSE2SIM_VIDEOS], frames=range(start, start + 1),
                         scale=args.scale)
    stacks = videos.load(progress=False)
    runs = {}
    for name, params in VARIANTS.items():
        rows = run_groups(stacks, data["cameras"], data["noise"], params)
        total = sum(r["points"] for r in rows)
        med = [r["median_residual_px"] for r in rows if r.get("median_residual_px") is not None]
        runs[name] = {"params": repr(params), "groups": rows, "points": total,
                      "target_points_met": total >= 2000,
                      "target_residual_met": bool(med) and max(med) <= 0.5}
        print(f"{name}: " + "; ".join(
            f"{r['group']} {r['points']} points, median residual "
            f"{r.get('median_residual_px') or float('nan'):.2f} px, {r['cpu_s']:.1f} s CPU"
            for r in rows), flush=True)
    record = {"scale": args.scale, "noise": data["noise"], "runs": runs}
    write_json(Path(args.out) / "surface_demo.json", record)
    for name, run in runs.items():
        print(f"\n{name}:")
        for r in run["groups"]:
            print(f"  {r['group']}: {json.dumps(r.get('census'))}")


if __name__ == "__main__":
    main()
