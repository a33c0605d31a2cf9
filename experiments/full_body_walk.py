"""The full body fitted to frames of the generated walk, points alone against points and
silhouettes, scored against the truth after the fact.

    .venv/bin/python experiments/full_body_walk.py [--frames 1 6 11] [--walk-frames 12]
        [--around] [--free-rounds 2]

Renders the walk in one camera of the triplet rig (``--scale`` of 768 x 576) and the empty
studio, cuts out the silhouettes and tracks their contour with snakes (trajectory
prediction), draws noisy surface points with outliers facing that camera (a truth input:
the LSMTA system measures only the arm; with ``--around`` from all round the body), fits
the full-body template twice (points alone;
points and the contours' lines of sight) with the shape shared across ``--frames``
(``--free-rounds`` rounds with the free shape after the tied ones), and
prints and writes build/benchmarks/full_body.json: worst and per-joint angle errors, length
errors, the skin's median distances to the true body both ways, outliers, times.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lsmta.body.full_fit import FullBodyFitParams, fit_full_body
from lsmta.evaluation import full_body as ef
from lsmta.evaluation import silhouettes as es
from lsmta.report import write_json


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[1, 6, 11])
    parser.add_argument("--walk-frames", type=int, default=12)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=25)
    parser.add_argument("--around", action="store_true", help="points from all round the body")
    parser.add_argument("--free-rounds", type=int, default=0)
    parser.add_argument("--out", default="build/benchmarks/full_body.json")
    args = parser.parse_args(argv)
    data = es.silhouette_walk(seed=args.seed, n_frames=args.walk_frames, scale=args.scale)
    trial = es.run_contour_trial(data, n_points=400)
    obs = ef.walk_observations(data, trial.predicted.contours, args.frames, around=args.around,
                               rng=args.seed)
    body, motion = data.scene.body, data.scene.motion
    out = {"frames": args.frames, "scale": args.scale, "around": args.around,
           "free_rounds": args.free_rounds}
    for name, rays in (("points", None), ("points+silhouettes", obs.rays)):
        t0 = time.perf_counter()
        fit = fit_full_body(obs.points, rays=rays, camera_centre=obs.camera_centre,
                            params=FullBodyFitParams(free_rounds=args.free_rounds))
        seconds = time.perf_counter() - t0
        errors = ef.joint_angle_errors(fit, body, motion, obs.frames)
        skins = [ef.skin_score(fit, body, motion, t, int(f), rng=args.seed)
                 for t, f in enumerate(obs.frames)]
        out[name] = {
            "seconds": seconds, "stature_mm": fit.stature,
            "worst_major_joint_deg": float(max(v.max() for v in errors.values())),
            "joints_deg": {k: v.round(2).tolist() for k, v in errors.items()},
            "length_error_pct": {k: 100 * (a / b - 1)
                                 for k, (a, b) in ef.length_errors(fit, body).items()},
            "skin_to_truth_median_mm": float(np.median(np.concatenate(
                [s.to_truth for s in skins]))),
            "truth_to_skin_median_mm": float(np.median(np.concatenate(
                [s.from_truth for s in skins]))),
            "open_edges": [s.open_edges for s in skins],
            "point_outliers": fit.n_point_outliers, "n_points": sum(map(len, obs.points)),
            "planted_outliers": int(sum(o.sum() for o in obs.is_outlier)),
            "silhouette_outliers": fit.n_silhouette_outliers,
        }
    for k, v in out.items():
        print(f"{k}: {v}")
    write_json(args.out, out)


if __name__ == "__main__":
    main()
