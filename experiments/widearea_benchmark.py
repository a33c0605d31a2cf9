"""Wide-area tracker against Stone Soup on the full walking-person scene: scores and speed.

    .venv/bin/python experiments/widearea_benchmark.py [--duration 3.6] [--seeds 2002]

Eighteen cameras, eight LEDs (on at 0.10-0.45 s, off at 2.80-3.15 s), clock offsets of
±4 ms, reflections and a monitor; the same frames go to our estimator (arrival order, 30 ms
late tolerance) and to the Stone Soup baseline (time-stamp order). Reports, per tracker and
seed: RMS error and coverage, identity changes, largest birth and death delays (among LEDs
that got a track / whose track died), LEDs never tracked, LEDs whose track outlived them to
the end of the run, OSPA, SIAP completeness
and spuriousness, and wall-clock time; the time ratio is ours / Stone Soup's.
Writes build/benchmarks/widearea.json. Takes a few minutes (Stone Soup ~20 ms a frame).
"""

from __future__ import annotations

import argparse

import numpy as np

from lsmta.evaluation.widearea import walking_trial
from lsmta.report import write_json


def _row(score, metrics, seconds):
    return {"rms_mm": score.rms_mm, "identity_changes": score.identity_changes,
            "max_birth_delay_ms": 1e3 * float(np.nanmax(score.birth_delay)),
            "max_death_delay_ms": 1e3 * float(np.nanmax(score.death_delay)),
            "coverage": score.coverage, "never_born": score.never_born,
            "never_deleted": score.never_deleted, **metrics, "seconds": seconds}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3.6)
    parser.add_argument("--seeds", type=int, nargs="+", default=[2002])
    parser.add_argument("--out", default="build/benchmarks/widearea.json")
    args = parser.parse_args(argv)
    runs = []
    for seed in args.seeds:
        w = walking_trial(rng=np.random.default_rng(seed), duration=args.duration,
                          with_stonesoup=True)
        ours = _row(w.score_ours, w.metrics_ours, w.seconds_ours)
        ss = _row(w.score_stonesoup, w.metrics_stonesoup, w.seconds_stonesoup)
        runs.append({"seed": seed, "frames": int(w.frames.n_frames), "ours": ours,
                     "stonesoup": ss, "time_ratio": ours["seconds"] / ss["seconds"]})
        for name, r in (("ours", ours), ("Stone Soup", ss)):
            print(f"seed {seed} {name:10s} " + ", ".join(
                f"{k} {v:.3g}" for k, v in r.items()))
    write_json(args.out, {"duration_s": args.duration, "runs": runs})


if __name__ == "__main__":
    main()
