"""Camera model against OpenCV, side by side in one run: accuracy and speed.

    .venv/bin/python experiments/camera_benchmark.py [--points 200000] [--repeats 5]

Compares ``Camera.project`` with ``cv2.projectPoints`` and ``Camera.rays`` (Newton
undistortion) with ``cv2.undistortPoints`` run to a tight tolerance (its
``criteria`` argument) and with ``cv2.undistortPoints`` (its default, 5 fixed-point iterations).
Accuracy is the round-trip error in pixels (project the recovered ray again); speed is
points per second; ratios are ours / OpenCV's. Writes build/benchmarks/camera.json.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from lsmta.report import best_time, write_json
from lsmta.synth import triplet_rig


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="build/benchmarks/camera.json")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    cam = triplet_rig(rng=rng)[0]
    K, dist, rvec, tvec = cam.to_opencv()
    xy = rng.uniform([-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], (args.points, 2))
    o, d = cam.rays(xy)
    X = o + d * rng.uniform(2000, 8000, (args.points, 1))

    t_ours, p_ours = best_time(lambda: cam.project(X), repeats=args.repeats)
    t_cv, p_cv = best_time(lambda: cv2.projectPoints(X, rvec, tvec, K, dist)[0][:, 0],
                           repeats=args.repeats)

    def back(xn):  # normalised undistorted -> pixels through our forward model
        return cam.project(cam.C + np.c_[xn, np.ones(len(xn))] @ cam.R)

    t_rays, (_, dirs) = best_time(lambda: cam.rays(xy), repeats=args.repeats)
    err_rays = np.abs(cam.project(cam.C + 3000 * dirs) - xy).max()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    pts = xy.reshape(-1, 1, 2)
    t_iter, und_iter = best_time(
        lambda: cv2.undistortPoints(pts, K, dist, None, None, None, crit)[:, 0],
        repeats=args.repeats)
    t_def, und_def = best_time(lambda: cv2.undistortPoints(pts, K, dist)[:, 0],
                               repeats=args.repeats)
    rows = {
        "project": {"ours_pts_per_s": args.points / t_ours, "opencv_pts_per_s": args.points / t_cv,
                    "speed_ratio": t_cv / t_ours,
                    "max_difference_px": float(np.abs(p_ours - p_cv).max())},
        "undistort": {
            "ours_pts_per_s": args.points / t_rays,
            "opencv_iter_pts_per_s": args.points / t_iter,
            "opencv_default_pts_per_s": args.points / t_def,
            "speed_ratio_vs_iter": t_iter / t_rays,
            "speed_ratio_vs_default": t_def / t_rays,
            "ours_round_trip_px": float(err_rays),
            "opencv_iter_round_trip_px": float(np.abs(back(und_iter) - xy).max()),
            "opencv_default_round_trip_px": float(np.abs(back(und_def) - xy).max()),
        },
    }
    print(f"{args.points} points, best of {args.repeats} (speed ratio > 1: ours faster)")
    print(f"project   : ours {rows['project']['ours_pts_per_s']:.3g} pt/s, OpenCV "
          f"{rows['project']['opencv_pts_per_s']:.3g} pt/s, ratio "
          f"{rows['project']['speed_ratio']:.2f}, max difference "
          f"{rows['project']['max_difference_px']:.1e} px")
    u = rows["undistort"]
    print(f"undistort : ours {u['ours_pts_per_s']:.3g} pt/s (round trip "
          f"{u['ours_round_trip_px']:.1e} px); OpenCV iter {u['opencv_iter_pts_per_s']:.3g} pt/s "
          f"({u['opencv_iter_round_trip_px']:.1e} px), ratio {u['speed_ratio_vs_iter']:.2f}; "
          f"OpenCV default {u['opencv_default_pts_per_s']:.3g} pt/s "
          f"({u['opencv_default_round_trip_px']:.1e} px), ratio {u['speed_ratio_vs_default']:.2f}")
    write_json(args.out, {"points": args.points, "results": rows})


if __name__ == "__main__":
    main()
