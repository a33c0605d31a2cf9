"""Surface measurement against OpenCV SGBM, over frames, grid steps and texture, in one run.

    .venv/bin/python experiments/surface_benchmark.py [--frames 0 10 20] [--steps 2 4]
        [--beyond] [--joint] [--seed 1998] [--seeds 5] [--scheduler ADDRESS] [--workers 2]
        [--no-real]

For each frame of the rendered walk (768 x 576 triplet, 2.5 m, noise 2 grey levels) and
texture contrast, the LSM pipeline of notebook 03 (patch 7, sigma0 up to twice the noise)
runs at each grid step, and SGBM on the rectified left-centre pair. With ``--beyond`` the
notebook's "beyond the paper" variant (robust LSM, shifted windows, median filter,
geometric check, template mask) runs too, and every row also gives the gross share among the target
nodes alone. With ``--joint`` the joint variant (geometrically constrained matching of the
triplet, :func:`lsmta.evaluation.surface.joint_beyond`) runs too. Prints density, median
and 95th-percentile 3-D error, gross-error share and time. Each of ``--seeds`` seeds (from
``--seed``: another rig, texture, noise and seed points; the seed points come from the
truth) is one Dask task, on a local cluster of ``--workers`` processes or on the scheduler
at ``--scheduler``; per method and contrast the median over the frames is one headline,
printed per seed and as median [min, max] over the seeds and written to
``build/benchmarks/surface_seeds.json`` / ``.csv``.

The real pair: Middlebury "Cones" (``data/middlebury_cones``), our
:func:`~lsmta.matching.measure_disparity` against OpenCV SGBM (filters on and off) and BM,
scored with the Middlebury measures on the nodes of a step-4 grid (the non-occluded ones
with known disparity); times are the shortest of three runs (no randomness: run once).
Writes build/benchmarks/surface.json (the first seed's rows, which notebook 03 quotes, and
the real pair).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from seed_spread import Headline, add_arguments, run

from lsmta.data import load_cones
from lsmta.evaluation import surface as evaluate
from lsmta.matching import (
    GrowParams,
    LSMThresholds,
    MeasureSurfaceParams,
    measure_disparity,
    measure_surface,
    peers,
)
from lsmta.real import stereo
from lsmta.report import best_time, write_json
from lsmta.synth import Renderer, Scene, make_body, triplet_rig, walk

SEEDS_IN = "seeds from truth (the LSM's seed points); true cameras"
SGBM_IN = "true cameras (the rectification)"
METRICS = (("density", "density", ""), ("median_mm", "median 3-D error", "mm"),
           ("gross", "gross-error share", ""))


def rendered_frames(seed: int, *, frames, contrast, noise: float):
    """The benchmark's generated frames, in its random stream: ``(contrast, frame number,
    frame, seeds, scene, cams)`` for each contrast and frame (the triplet rig, the walk, the
    body at each contrast, then per frame the rendering and the seed points from the truth
    drawn from one generator; experiments/surface_census.py reads the same frames)."""
    rng = np.random.default_rng(seed)
    cams = triplet_rig(rng=rng, distance=2500.0, baseline=700.0)
    for c in contrast:
        body = make_body(rng=np.random.default_rng(seed), contrast=c, wavelength=(12.0, 50.0))
        scene = Scene(body, walk(n_frames=30, start=(-300.0, 0.0)), None)
        renderer = Renderer(scene, cams, noise_sigma=noise)
        for f in frames:
            frame = renderer.render(f, rng=rng)
            seeds = evaluate.seeds_from_truth(scene, cams, f, rng=rng)
            yield c, f, frame, seeds, scene, cams


def run_seed(seed: int, *, frames, steps, contrast, noise: float, methods) -> dict:
    """The generated part for ``seed`` (rig, texture, noise, seeds): one row per contrast,
    frame and method, and per contrast and method the median over the frames of each metric
    (keys ``"<method> c<contrast> <metric>"``)."""
    import numba

    numba.set_num_threads(1)
    th = LSMThresholds(max_sigma0=2 * noise, max_displacement=4.0, max_sigma_xy=0.2,
                       scale_range=(0.5, 2.0), max_shear=0.5)
    rows = []
    for c, f, frame, seeds, scene, cams in rendered_frames(seed, frames=frames,
                                                             contrast=contrast, noise=noise):
        for step in steps:
            truth = evaluate.node_truth(frame, scene, cams, step=step, patch=13)
            for name in methods:
                paper = MeasureSurfaceParams(grow=GrowParams(step=step, patch=7,
                                                             thresholds=th))
                call = dict(params=paper)
                if name != "lsm":
                    options = (evaluate.beyond_the_paper if name == "beyond"
                               else evaluate.joint_beyond)
                    retry = replace(paper, grow=replace(paper.grow, retry_patch=(9, 5)))
                    call = options(noise, frame.images[1], retry)
                t0 = time.perf_counter()
                res = measure_surface(frame.images, cams, seeds, **call)
                seconds = time.perf_counter() - t0
                sc = evaluate.score_surface(res, truth)
                rows.append({"contrast": c, "frame": f, "method": f"{name} step {step}",
                             "density": sc["density"], **sc["filtered"],
                             "seconds": seconds})
        truth = evaluate.node_truth(frame, scene, cams, template=0, step=4, patch=13)
        sg = peers.sgbm(frame.images[0], frame.images[1], cams[0], cams[1])
        sc = evaluate.score_points(sg.points, sg.xy_first, truth, frame, template=0)
        rows.append({"contrast": c, "frame": f, "method": "sgbm", **sc,
                     "seconds": sg.seconds})
    out = {"seed": seed, "rows": rows}
    for r in rows:
        for key, _, _ in METRICS:
            out.setdefault(f"{r['method']} c{r['contrast']:g} {key}", []).append(r[key])
    return {k: (float(np.median(v)) if isinstance(v, list) and k != "rows" else v)
            for k, v in out.items()}


def _print_rows(rows):
    print(f"{'contrast':>8} {'frame':>5} {'method':>13} {'density':>8} {'median mm':>10} "
          f"{'p95 mm':>8} {'gross':>7} {'in target':>9} {'seconds':>8}")
    for r in rows:
        in_target = f"{r['gross_target']:9.1%}" if "gross_target" in r else " " * 9
        print(f"{r['contrast']:8.2f} {r['frame']:5d} {r['method']:>13} {r['density']:8.1%} "
              f"{r['median_mm']:10.2f} {r['p95_mm']:8.2f} {r['gross']:7.1%} "
              f"{in_target} {r['seconds']:8.2f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 10, 20])
    parser.add_argument("--steps", type=int, nargs="+", default=[2, 4])
    parser.add_argument("--contrast", type=float, nargs="+", default=[0.3, 0.1])
    parser.add_argument("--noise", type=float, default=2.0)
    parser.add_argument("--beyond", action="store_true",
                        help="also run the beyond-the-paper variant of notebook 03")
    parser.add_argument("--joint", action="store_true",
                        help="also run the joint (geometrically constrained) variant")
    parser.add_argument("--no-real", action="store_true", help="skip the Middlebury pair")
    parser.add_argument("--out", default="build/benchmarks/surface.json")
    add_arguments(parser, seed=1998)
    args = parser.parse_args(argv)
    methods = ["lsm"] + (["beyond"] if args.beyond else []) + (["joint"] if args.joint else [])
    settings = {"frames": args.frames, "steps": args.steps, "contrast": args.contrast,
                "noise": args.noise, "methods": methods}
    headlines = [Headline(f"{m} c{c:g} {key}", f"{m}, contrast {c:g}: {label} (median over "
                          f"frames {', '.join(map(str, args.frames))})", unit,
                          SGBM_IN if m == "sgbm" else SEEDS_IN, True)
                 for c in args.contrast
                 for m in [f"{n} step {st}" for st in args.steps for n in methods] + ["sgbm"]
                 for key, label, unit in METRICS]
    results, _ = run("surface", run_seed, headlines, args, parser=parser,
                     out_dir=Path(args.out).parent, settings=settings, **settings)
    for seed, r in results.items():
        print(f"\nseed {seed}:")
        _print_rows(r.get("rows", []))
    real = [] if args.no_real else real_pair()
    # the first seed's rows in the format notebook 03 quotes
    write_json(args.out, {"args": vars(args), "rows": results[args.seed].get("rows", []),
                          "real_pair": real})


def real_pair(*, step: int = 4, disparities=(0, 64)) -> list[dict]:
    """Middlebury Cones: ours against SGBM (filters on, off) and BM on the same grid nodes."""
    cones = load_cones()
    truth, scored = cones.grid(step)
    measure_disparity(cones.left, cones.right, disparity_range=disparities)   # compile once
    runs = {
        "ours": lambda: measure_disparity(cones.left, cones.right,
                                          disparity_range=disparities).disparity,
        "sgbm filters on": lambda: peers.stereo_sgbm(cones.left, cones.right).disparity[
            ::step, ::step],
        "sgbm filters off": lambda: peers.stereo_sgbm(cones.left, cones.right,
                                                      filters=False).disparity[::step, ::step],
        "bm": lambda: peers.stereo_bm(cones.left, cones.right).disparity[::step, ::step],
    }
    out = []
    print(f"\nMiddlebury Cones, step {step} grid ({scored.sum()} scored nodes)")
    print(f"{'method':>17} {'density':>8} {'bad 1.0':>8} {'bad 2.0':>8} {'mean':>6} "
          f"{'median':>7} {'seconds':>8}")
    for name, fn in runs.items():
        seconds, grid = best_time(fn)
        s = stereo.scores(grid, truth, scored)
        out.append({"method": name, **s, "seconds": seconds})
        print(f"{name:>17} {s['density']:8.3f} {s['bad1']:8.2%} {s['bad2']:8.2%} "
              f"{s['mean']:6.3f} {s['median']:7.3f} {seconds:8.3f}")
    return out


if __name__ == "__main__":
    main()
