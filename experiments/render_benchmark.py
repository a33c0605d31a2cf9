"""Render time of the synthetic triplet against the number of rays per pixel.

    .venv/bin/python experiments/render_benchmark.py [--frames 4] [--supersample 1 3 5]

For each supersampling factor: the first triplet (which also builds the per-camera ray and
background cache) and the mean of the following ones, in seconds, on this machine.
Writes build/benchmarks/render.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lsmta.report import write_json
from lsmta.synth import Renderer, Scene, make_background, make_body, triplet_rig, walk


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--supersample", type=int, nargs="+", default=[1, 3, 5])
    parser.add_argument("--out", default="build/benchmarks/render.json")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    cams = triplet_rig(rng=rng)
    scene = Scene(make_body(rng=rng), walk(n_frames=50), make_background(rng=rng))
    rows = []
    for s in args.supersample:
        renderer = Renderer(scene, cams, supersample=s, noise_sigma=2.0)
        times = []
        for f in range(args.frames):
            start = time.perf_counter()
            renderer.render(f * 10 % 50, rng=rng)
            times.append(time.perf_counter() - start)
        rows.append({"supersample": s, "first_s": times[0],
                     "per_triplet_s": float(np.mean(times[1:])) if len(times) > 1 else None})
        print(f"supersample {s}: first triplet {times[0]:.2f} s, then "
              f"{rows[-1]['per_triplet_s']:.2f} s per 768x576 triplet")
    write_json(args.out, rows)


if __name__ == "__main__":
    main()
