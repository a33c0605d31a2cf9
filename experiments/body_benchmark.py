"""Arm fitting: analytic vs finite-difference Jacobian, sparse vs dense, in one run.

    .venv/bin/python experiments/body_benchmark.py [--frames 9] [--points 400] [--repeats 2]
        [--no-fd] [--out build/benchmarks/body.json]

The simplified arm model of :mod:`lsmta.body` fitted to a sequence of controlled points
(noisy skin samples with 10 % outliers, as in notebook 07) with the same start, three ways:
analytic Jacobian handed to scipy as a sparse matrix (the default for sequences), the same
as a dense matrix, and scipy's 2-point finite differences (dense). Reported: best time of
each, ratios to the default, and the worst angle / length errors (so that a faster variant
that lands elsewhere shows). Writes build/benchmarks/body.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from lsmta.body import FitParams, arm_model, fit_sequence
from lsmta.evaluation import body as eb
from lsmta.report import best_time, write_json
from lsmta.synth import arm_wave, make_body


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=9)
    parser.add_argument("--points", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-fd", action="store_true", help="skip the finite differences")
    parser.add_argument("--out", default="build/benchmarks/body.json")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1998)
    body = make_body(rng=np.random.default_rng(1998))
    motion = arm_wave(n_frames=50)
    frames = np.linspace(4, 49, args.frames).astype(int)
    truth = eb.arm_truth(body, motion, frames)
    init, _ = eb.initial_state(truth, rng=rng)
    points = eb.controlled_points(body, motion, truth, rng=rng, n=args.points)
    model = arm_model()
    variants = {"analytic, sparse": dict(sparse_jacobian=True),
                "analytic, dense": dict(sparse_jacobian=False),
                "2-point, dense": dict(sparse_jacobian=False, jacobian="2-point")}
    if args.no_fd:
        del variants["2-point, dense"]
    out = {"frames": int(args.frames), "points_per_frame": int(args.points), "variants": {}}
    for name, kw in variants.items():
        def run(kw=kw):
            return fit_sequence(model, points, truth.torso_poses, init,
                                params=FitParams(sigma_mm=2.0, **kw))
        seconds, fit = best_time(run, repeats=args.repeats)
        s = eb.score_fit(fit, truth)
        out["variants"][name] = {"seconds": seconds, "status": fit.status.name, "nfev": fit.nfev,
                                 "max_angle_err_deg": s["max_angle_err_deg"],
                                 "max_length_err_pct": float(np.abs(s["length_err_pct"]).max())}
    base = out["variants"]["analytic, sparse"]["seconds"]
    for name, v in out["variants"].items():
        v["time_ratio_to_default"] = v["seconds"] / base
        print(f"{name:<18} {v['seconds']:7.2f} s  x{v['time_ratio_to_default']:5.1f}  "
              f"{v['status']:<13} worst angle {v['max_angle_err_deg']:.2f} deg, worst length "
              f"{v['max_length_err_pct']:.2f} %")
    write_json(args.out, out)


if __name__ == "__main__":
    main()
