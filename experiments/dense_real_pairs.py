"""Dense matching on every real rectified pair with ground truth: ours against SGBM and BM.

    .venv/bin/python experiments/dense_real_pairs.py [--repeats 3] [--out PATH]

For each Middlebury pair of :data:`lsmta.data.STEREO_PAIRS` (Cones, Teddy, Art, Tsukuba),
:func:`lsmta.real.stereo.compare_on_pair` runs our
:func:`~lsmta.matching.measure_disparity` (its defaults, automatic seeds) and OpenCV's SGBM
(filters on and off) and BM over the same disparity range (the pair's own, from its file
format), scores all four with the Middlebury measures on the nodes of the step-4 grid (the
non-occluded ones with known disparity) and times each as the shortest of ``--repeats``
runs. Prints the table with issue #33's targets per pair and writes
build/benchmarks/dense_real_pairs.json.

Protocol: the defaults were chosen on Cones (the tuning pair, notebook 16); Teddy, Art and
Tsukuba are held out: nothing was chosen by looking at their scores.
"""

from __future__ import annotations

import argparse
import os

import numba

from lsmta.data import STEREO_PAIRS, load_stereo_pair
from lsmta.real import stereo
from lsmta.report import verdict, write_json

TUNING = ("cones",)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="build/benchmarks/dense_real_pairs.json")
    args = parser.parse_args(argv)
    rows = []
    for i, name in enumerate(STEREO_PAIRS):
        c = stereo.compare_on_pair(load_stereo_pair(name), repeats=args.repeats, warm_up=i == 0)
        targets = c.targets()
        rows.append({"pair": name, "role": "tuning" if name in TUNING else "held out",
                     "n_scored": c.n_scored, "scores": c.scores, "seconds": c.seconds,
                     "time_ratio": c.time_ratio, "targets": targets})
        print(f"\n{name} ({rows[-1]['role']}; {c.n_scored} scored nodes)")
        print(f"{'method':<20} {'median':>7} {'bad 1.0':>8} {'density':>8} {'seconds':>8}")
        for method, s in c.scores.items():
            print(f"{method:<20} {s['median']:7.3f} {s['bad1']:8.2%} {s['density']:8.3f} "
                  f"{c.seconds[method]:8.3f}")
        print(f"time ratio {c.time_ratio:.1f} x SGBM; "
              + ", ".join(f"{k} {verdict(v)}" for k, v in targets.items()))
    write_json(args.out, {"args": vars(args), "tuning_pairs": list(TUNING),
                          "numba_threads": numba.config.NUMBA_NUM_THREADS,
                          "load_average": os.getloadavg()[0], "rows": rows})


if __name__ == "__main__":
    main()
