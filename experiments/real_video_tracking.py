"""LSMTA (2-D mode) against OpenCV's KLT on the project's real videos: survival, accuracy, time.

    .venv/bin/python experiments/real_video_tracking.py [--frames 40] [--points 384]
        [--pose2sim-scale 0.5] [--videos caliscope pose2sim]

No truth exists on real video, so each tracker is judged by its own forward-backward
error: the points are tracked ``--frames`` frames forward, then from where they ended back
to the first frame, and the distance between where a point started and where it came back
is its error (Kalal, Mikolajczyk & Matas 2010). A point *survives* when both runs kept it
and it came back within ``--fb-px`` (0.5 px). A tracker's own "kept" flag is reported too,
but it is not survival: a point can be kept on the wrong feature, and then it does not come
back.

Start points: OpenCV's ``goodFeaturesToTrack`` (Shi-Tomasi corners, 8 px apart) in the
first frame, the same for both trackers. Videos: the four caliscope webcams (1280 x 720, a
person moving a ChArUco board, about 6 fps: large steps between frames) and the four
Pose2Sim demo views (60 fps, at ``--pose2sim-scale``). Writes
``build/benchmarks/real_video_tracking.json``.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numba
import numpy as np

from lsmta import data
from lsmta.io import read_videos
from lsmta.report import write_json
from lsmta.tracking import TrackerParams, track_klt, track_points


def caliscope_clips(frames: int):
    folder = data.CALISCOPE_DIR / "videos"
    for path in sorted(folder.glob("cam_*.mp4")):
        yield f"caliscope {path.stem}", _grey_frames(path, frames, 1.0)


def pose2sim_clips(frames: int, scale: float):
    for view in data.POSE2SIM_VIEWS:
        yield f"pose2sim {view}", _grey_frames(data.POSE2SIM_DIR / f"{view}.mp4", frames, scale)


def _grey_frames(path, frames: int, scale: float) -> np.ndarray:
    videos = read_videos([path])
    out = []
    for t in range(min(frames, videos.n_frames)):
        im = videos.read(t)[0]
        if scale != 1.0:
            im = cv2.resize(im, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        out.append(im)
    return np.stack(out)


def forward_backward(track, seq: np.ndarray, start: np.ndarray):
    """Track ``start`` through ``seq`` and back; (kept, error px, seconds)."""
    t0 = time.perf_counter()
    end = track(seq, start)
    back = track(seq[::-1], end)
    seconds = time.perf_counter() - t0
    kept = np.isfinite(end).all(axis=1) & np.isfinite(back).all(axis=1)
    error = np.linalg.norm(back - start, axis=1)
    return kept, error, seconds


def lsmta_end(params):
    def track(seq, xy):
        ok = np.isfinite(xy).all(axis=1)
        out = np.full_like(xy, np.nan)
        if ok.any():
            out[ok] = track_points([seq], xy[ok][None], params=params).xy[-1, 0]
        return out
    return track


def klt_end(seq, xy):
    ok = np.isfinite(xy).all(axis=1)
    out = np.full_like(xy, np.nan)
    if ok.any():
        out[ok] = track_klt([seq], xy[ok][None]).xy[-1, 0]
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--points", type=int, default=384)
    parser.add_argument("--fb-px", type=float, default=0.5)
    parser.add_argument("--pose2sim-scale", type=float, default=0.5)
    parser.add_argument("--videos", nargs="+", default=["caliscope", "pose2sim"],
                        choices=["caliscope", "pose2sim"])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="build/benchmarks/real_video_tracking.json")
    args = parser.parse_args(argv)
    numba.set_num_threads(args.threads)

    clips = []
    if "caliscope" in args.videos:
        clips += list(caliscope_clips(args.frames))
    if "pose2sim" in args.videos:
        clips += list(pose2sim_clips(args.frames, args.pose2sim_scale))
    lsmta = lsmta_end(TrackerParams())
    warm = clips[0][1][:3]              # load the compiled kernels outside the timings
    lsmta(warm, np.array([[warm.shape[2] / 2, warm.shape[1] / 2]]))
    rows = []
    for name, seq in clips:
        corners = cv2.goodFeaturesToTrack(seq[0], args.points, 0.01, 8, blockSize=7)
        start = corners[:, 0].astype(float)
        row = {"video": name, "frames": int(len(seq)), "size": list(seq.shape[1:][::-1]),
               "points": int(len(start))}
        for label, track in (("lsmta", lsmta), ("klt", klt_end)):
            kept, error, seconds = forward_backward(track, seq, start)
            survived = kept & (error <= args.fb_px)
            row[label] = {"kept": int(kept.sum()), "survived": int(survived.sum()),
                          "fb_median_px": float(np.median(error[survived])) if survived.any()
                          else None,
                          "fb_median_kept_px": float(np.median(error[kept])) if kept.any()
                          else None,
                          "seconds": round(seconds, 2)}
        row["survival_ratio"] = row["lsmta"]["survived"] / max(row["klt"]["survived"], 1)
        row["time_ratio"] = row["lsmta"]["seconds"] / row["klt"]["seconds"]
        rows.append(row)
        ls, kl = row["lsmta"], row["klt"]
        print(f"{name:18s} {row['points']:4d} pts | survived LSMTA {ls['survived']:4d} "
              f"KLT {kl['survived']:4d} (x{row['survival_ratio']:.2f}) | kept LSMTA "
              f"{ls['kept']:4d} KLT {kl['kept']:4d} | fb median of survivors "
              f"{ls['fb_median_px'] or float('nan'):.3f} / {kl['fb_median_px'] or float('nan'):.3f}"
              f" px | time x{row['time_ratio']:.1f}", flush=True)
    total = {k: sum(r[k]["survived"] for r in rows) for k in ("lsmta", "klt")}
    summary = {"survived_total": total,
               "survival_ratio_total": total["lsmta"] / max(total["klt"], 1),
               "videos_where_lsmta_survives_at_least_klt":
                   int(sum(r["survival_ratio"] >= 1 for r in rows)),
               "time_ratio_median": float(np.median([r["time_ratio"] for r in rows]))}
    print(f"survived in total: LSMTA {total['lsmta']}, KLT {total['klt']} "
          f"(x{summary['survival_ratio_total']:.2f}); LSMTA >= KLT in "
          f"{summary['videos_where_lsmta_survives_at_least_klt']} of {len(rows)} videos; "
          f"time x{summary['time_ratio_median']:.1f} (median)")
    write_json(args.out, {"args": vars(args), "summary": summary, "videos": rows})


if __name__ == "__main__":
    main()
