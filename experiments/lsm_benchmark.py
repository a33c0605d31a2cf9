"""LSM against OpenCV and scikit-image at full size, in one run: accuracy and speed.

    .venv/bin/python experiments/lsm_benchmark.py [--points 20000] [--peer-points 2000]

One 512 x 512 image pair under an affine + radiometric warp, noise sigma 2 grey levels,
8-bit. LSM matches ``--points`` patches in one batched call; the per-point peers run on
the first ``--peer-points`` of the same patches and starts (ILK and phase correlation on
a tenth of those: they are slow). For 13 x 13 and 21 x 21 patches the table gives the
median and RMS error of successful matches, the failure rate (no result or error above
0.5 px) and points per second; the speed ratio is LSM's points per second over OpenCV's
``findTransformECC`` (affine) called per point. Writes build/benchmarks/lsm.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from lsmta.evaluation.matching import METHODS, draw_points, run_trial
from lsmta.report import write_json
from lsmta.synth.patches import warped_pair


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--peer-points", type=int, default=2000)
    parser.add_argument("--noise", type=float, default=2.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="build/benchmarks/lsm.json")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    pair = warped_pair(rng=rng, shape=(512, 512), A=[[1.04, 0.06], [-0.05, 0.97]], c=(2.3, -1.4),
                       r0=10.0, r1=0.9, noise_sigma=args.noise)
    # warm-up: load the compiled kernels once, outside the timings
    run_trial(pair, rng=rng, n_points=10, bound=False)
    results = {}
    for patch in (13, 21):
        pts = draw_points(pair.template.shape, args.points, rng=rng, margin=40)
        trials = {}
        for name in METHODS:
            n = args.points if name == "lsm" else args.peer_points
            if name in ("ilk", "phase_correlation"):
                n = max(args.peer_points // 10, 10)
            trial_rng = np.random.default_rng(args.seed + 1)  # same starts for every method
            trials[name] = run_trial(pair, rng=trial_rng, methods=(name,), points=pts[:n],
                                     patch=patch, start_error=1.0, bound=False)
        rows = {}
        for name, trial in trials.items():
            s = trial.summary(name)
            s["points"] = len(trial.truth)
            s["points_per_second"] = 1e6 / s["us_per_point"]
            rows[name] = s
        ratio = rows["lsm"]["points_per_second"] / rows["ecc_affine"]["points_per_second"]
        results[f"{patch}x{patch}"] = {"methods": rows, "lsm_speed_over_ecc_affine": ratio}
        print(f"\n{patch}x{patch} patches, noise {args.noise:g}, starts within 1 px")
        print(f"{'method':>18} {'points':>7} {'median px':>10} {'rms px':>8} {'failures':>9} "
              f"{'points/s':>10}")
        for name, s in rows.items():
            print(f"{name:>18} {s['points']:7d} {s['median_px']:10.4f} {s['rms_px']:8.4f} "
                  f"{s['failure_rate']:9.2%} {s['points_per_second']:10.0f}")
        print(f"LSM throughput / per-point ECC (affine): {ratio:.1f}x")
    write_json(args.out, {"args": vars(args), "results": results})


if __name__ == "__main__":
    main()
