"""Why the demo's held-out tie points stay above 0.5 px: their residuals against their motion.

    .venv/bin/python experiments/tie_point_motion.py [--scale 1.0] [--frames 0:100]
        [--out build/benchmarks/tie_point_motion.json]

Refines the Pose2Sim demo's cameras from the recording as ``lsmta capture`` does
(`lsmta.systems.refine_rig`), then measures each tie point's image speed in every view
(OpenCV's dense Farneback flow between the frames before and after it) and groups the tie
points' reprojection residuals (largest over the views), with the file's and with the
refined cameras, by that speed. A still background point is seen again in every frame, so
the held-out frames' new tie points are mostly the moving person's. If the residuals grow
with speed, either the views are not exactly synchronised or moving features are located
less well. To tell them apart, every camera but the first is shifted in time by
``v * dt`` (its flow times an offset of -2 to 2 frames, one camera at a time, twice round)
and the moving points' median residual is taken again: a time offset would show as a clear
minimum away from 0. Prints and writes the table and the offsets.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from lsmta.camera_files import read_camera_file
from lsmta.data import POSE2SIM_CAMERAS, POSE2SIM_VIDEOS
from lsmta.io import read_videos
from lsmta.report import write_json
from lsmta.systems import RigRefinementParams, refine_rig
from lsmta.triangulation import triangulate

BINS = [(0.0, 0.3), (0.3, 1.0), (1.0, 3.0), (3.0, 10.0), (10.0, np.inf)]   # px per frame


def velocities(videos, picks, xy, frame_of) -> np.ndarray:
    """(K, N, 2) image velocity of every tie point, px per frame (central difference of
    the dense flow); NaN where a view does not hold the point. ``picks``: the tie points'
    frames as indices into ``videos``' selection."""
    vel = np.full(xy.shape, np.nan)
    last = videos.n_frames - 1
    if last < 1:
        raise SystemExit("--frames: expected at least two frames (the flow needs a neighbour)")
    for i, f in enumerate(picks):
        lo, hi = max(f - 1, 0), min(f + 1, last)
        a, b = videos.read(lo), videos.read(hi)
        sel = np.flatnonzero(frame_of == i)
        for k in range(len(xy)):
            flow = cv2.calcOpticalFlowFarneback(a[k], b[k], None, 0.5, 4, 21, 3, 7, 1.5, 0)
            ok = np.isfinite(xy[k, sel, 0])
            h, w = flow.shape[:2]
            ij = np.clip(np.round(xy[k, sel[ok]]).astype(int), 0, [w - 1, h - 1])
            vel[k, sel[ok]] = flow[ij[:, 1], ij[:, 0]] / (hi - lo)
    return vel


def worst_residual(cameras, xy) -> np.ndarray:
    return np.nanmax(triangulate(list(cameras), xy, min_angle_deg=0.0).reprojection_error,
                     axis=0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--frames", default="0:100")
    parser.add_argument("--out", default="build/benchmarks/tie_point_motion.json")
    args = parser.parse_args(argv)
    start, stop = (int(v) for v in args.frames.split(":"))
    videos = read_videos(POSE2SIM_VIDEOS,
                         frames=slice(start, stop), scale=args.scale)
    ref = refine_rig(videos, read_camera_file(POSE2SIM_CAMERAS),
                     params=RigRefinementParams(mismatch="crop"))
    tie = ref.tie_points
    picks = [int(np.flatnonzero(np.asarray(videos.frames) == f)[0]) for f in ref.frames]
    vel = velocities(videos, picks, tie.xy, tie.frame)
    speed = np.nanmax(np.hypot(vel[..., 0], vel[..., 1]), axis=0)
    out = {"scale": args.scale, "frames": args.frames, "tie_points": int(tie.xy.shape[1]),
           "held_out_before_px": ref.held_out_before.tolist(),
           "held_out_after_px": ref.held_out_after.tolist(), "by_speed": []}
    res = {name: worst_residual(cams, tie.xy) for name, cams in
           (("file", ref.given), ("refined", ref.cameras))}
    print("image speed (px/frame)   points   worst residual, file's / refined cameras (median)")
    for lo, hi in BINS:
        m = (speed >= lo) & (speed < hi)
        row = {"speed": [lo, hi], "points": int(m.sum()),
               **{f"{k}_px": float(np.nanmedian(v[m])) if m.any() else None
                  for k, v in res.items()}}
        out["by_speed"].append(row)
        print(f"{lo:5.1f} - {hi:<5.1f}            {row['points']:6d}   "
              f"{row['file_px'] or np.nan:5.2f} / {row['refined_px'] or np.nan:5.2f} px")
    moving = speed >= 1.0
    xy_m, v_m = tie.xy[:, moving], vel[:, moving]

    def median_at(dt):
        return float(np.nanmedian(worst_residual(ref.cameras,
                                                 xy_m + v_m * np.asarray(dt)[:, None, None])))

    offsets = np.zeros(len(tie.xy))
    grid = np.arange(-2.0, 2.01, 0.25)
    for _ in range(2):
        for k in range(1, len(tie.xy)):
            scores = []
            for dt in grid:
                trial = offsets.copy()
                trial[k] = dt
                scores.append(median_at(trial))
            offsets[k] = grid[int(np.argmin(scores))]
    out.update(moving_points=int(moving.sum()), moving_median_px=median_at(np.zeros(len(tie.xy))),
               best_offsets_frames=offsets.tolist(), moving_median_at_best_px=median_at(offsets))
    print(f"{out['moving_points']} moving points (>= 1 px/frame): median worst residual "
          f"{out['moving_median_px']:.2f} px; best time offsets {offsets.tolist()} frames "
          f"(first camera fixed) give {out['moving_median_at_best_px']:.2f} px")
    write_json(args.out, out)


if __name__ == "__main__":
    main()
