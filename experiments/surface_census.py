"""Where notebook 03's joint matching loses density and makes gross errors (#33, notebook 03).

    .venv/bin/python experiments/surface_census.py [--frames 0 10 20] [--seed 1998]
        [--variants NAME ...] [--out PATH]

Renders the frames exactly as ``experiments/surface_benchmark.py`` does for its first
contrast (0.3) and seed (the same random stream: rig, body, then per frame the render and the
seeds), runs the joint configuration (:func:`lsmta.evaluation.surface.joint_beyond`, step 4,
patch 7, retries 9 and 5) and sorts every missed target node (visible in all three cameras,
its 13 x 13 window on the body: the population of the density) twice:

* by **stage**, from the matcher's own statuses: the grower's per-node outcome
  (``GrowResult.node_outcome``: outside, masked, no_texture, given_up, failed_open,
  never_reached) with, for nodes tried and failed, why the main patch failed at the last try
  (``GrowResult.node_failure``: the first threshold test failed, or the non-convergence
  status); matched nodes that are missing were dropped by the neighbourhood filter;
* by **scene label**, the first that applies: ``silhouette`` (within ``border`` + 2 px of
  the backdrop mask's edge in image 1), ``occlusion`` (a depth jump > 20 mm within 9 x 9 px
  of the generator's depth: occlusion borders, and steep slopes too), ``grazing`` (the
  truth's surface seen at cos < 0.3 by some camera), ``weak texture`` (in image 1 the
  precision rule of :class:`~lsmta.matching.GrowParams` ``noise`` fails for the 7 x 7
  patch: sqrt(2) noise / sqrt(lambda_min) > 0.2 px), ``other``. The matcher's seeds are the
  benchmark's simulated clicks from the truth (``seeds_from_truth``).

The gross errors (> 5 x the median 3-D error, among the filtered points, as
``score_surface``) are labelled the same way and counted by the attempt that matched them
(``GrowResult.method``, or the neighbourhood filter's re-match). ``--variants`` also runs
changes of the joint configuration (:data:`VARIANTS`: growth from diagonal and farther
neighbours, shifted windows, more attempts, a 4-px mask erosion, a robust patch no larger
than the main one, no robust attempt, a stricter ``min_weight_share``). Protocol for
choosing among them: frames 5, 15, 25 are the tuning frames; the benchmark's 0, 10, 20 are
held out and run with a chosen variant only. Prints one block per frame and variant, with
the CPU time of the matching; writes build/benchmarks/surface_census.json.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from dataclasses import replace

import numpy as np
from scipy import ndimage
from surface_benchmark import rendered_frames

from lsmta.evaluation import surface as evaluate
from lsmta.matching import GrowParams, LSMThresholds, MeasureSurfaceParams, measure_surface
from lsmta.matching.grow import ATTEMPT_OUTCOMES, NODE_OUTCOMES, NodeOutcome
from lsmta.matching.masks import backdrop_mask
from lsmta.report import write_json

LABELS = ("silhouette", "occlusion", "grazing", "weak texture", "other")
NOISE = 2.0
STEP = 4
#: the joint configuration and its variants: keywords of :func:`joint_call`
VARIANTS = {"joint": {}, "reach": {"reach": True}, "border 4": {"border": 4},
            "reach, border 4": {"reach": True, "border": 4}, "shift": {"shift": 3},
            "attempts 5": {"max_attempts": 5}, "robust patch 7": {"robust_patch": 7},
            "no robust": {"robust": None}, "share 0.7": {"min_weight_share": 0.7}}


def frames_as_benchmark(seed: int, frames, *, contrast: float = 0.3):
    """``(frame, seeds, truth, scene, cams)`` per frame, the benchmark's own frames
    (:func:`surface_benchmark.rendered_frames`, same random stream)."""
    for _, _, frame, seeds, scene, cams in rendered_frames(seed, frames=frames,
                                                           contrast=(contrast,), noise=NOISE):
        truth = evaluate.node_truth(frame, scene, cams, step=STEP, patch=13)
        yield frame, seeds, truth, scene, cams


def joint_call(frame, *, border: int = 7, min_weight_share: float = 0.5, **grow) -> dict:
    """The benchmark's joint configuration (its ``joint`` method, step 4); ``grow``: changes
    of its :class:`~lsmta.matching.GrowParams` (e.g. ``reach=True``)."""
    th = LSMThresholds(max_sigma0=2 * NOISE, max_displacement=4.0, max_sigma_xy=0.2,
                       scale_range=(0.5, 2.0), max_shear=0.5, min_weight_share=min_weight_share)
    paper = MeasureSurfaceParams(grow=GrowParams(step=STEP, patch=7, thresholds=th,
                                                 retry_patch=(9, 5)))
    call = evaluate.joint_beyond(NOISE, frame.images[1], paper, border=border)
    p = call["params"]
    return dict(call, params=replace(p, grow=replace(p.grow, **grow)))


def scene_labels(frame, cams, truth, *, border: int) -> np.ndarray:
    """The first scene label (index into :data:`LABELS`) of every grid node."""
    step = truth["step"]
    img = frame.images[1].astype(float)
    mask = backdrop_mask(img, 12.0)
    near_edge = ~ndimage.binary_erosion(mask, iterations=border + 2)
    depth = np.nan_to_num(frame.depth[1], nan=1e9)
    jump = (ndimage.maximum_filter(depth, size=9) - ndimage.minimum_filter(depth, size=9)) > 20
    world = frame.world_xyz[1]
    du, dv = np.gradient(world, axis=1), np.gradient(world, axis=0)
    n = np.cross(du, dv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    worst = np.full(world.shape[:2], np.inf)
    for cam in cams:
        v = np.asarray(cam.C) - world
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        worst = np.minimum(worst, np.abs(np.sum(n * v, axis=-1)))
    grazing = np.nan_to_num(worst, nan=1.0) < 0.3
    gy, gx = np.gradient(img)
    box = [ndimage.uniform_filter(a, 7) * 49 for a in (gx * gx, gx * gy, gy * gy)]
    lam = (box[0] + box[2]) / 2 - np.sqrt(((box[0] - box[2]) / 2) ** 2 + box[1] ** 2)
    weak = np.sqrt(2.0) * NOISE / np.sqrt(np.maximum(lam, 1e-12)) > 0.2
    out = np.full(img.shape, LABELS.index("other"))
    for name, sel in reversed(list(zip(LABELS[:4], (near_edge, jump, grazing, weak)))):
        out[sel] = LABELS.index(name)
    return out[::step, ::step]


def census(res, truth, labels) -> dict:
    """Missed target nodes by stage and by label; gross errors by label."""
    step = truth["step"]
    target = truth["visible"] & truth["interior"]
    g = res.grown[0]
    r = (res.template_xy[:, 1] // step).astype(int)
    c = (res.template_xy[:, 0] // step).astype(int)
    kept = np.zeros_like(target)
    kept[r[res.neighbourhood_ok], c[res.neighbourhood_ok]] = True
    stage = np.array(NODE_OUTCOMES, dtype=object)[g.node_outcome]
    fail = g.node_failure
    tried = fail >= 0
    stage[tried] = [f"{s}: {ATTEMPT_OUTCOMES[k]}" for s, k in zip(stage[tried], fail[tried])]
    stage[(g.node_outcome == NodeOutcome.MATCHED) & ~kept] = "neighbourhood filter"
    miss = target & ~kept
    by_stage = Counter(stage[miss])
    by_label = Counter(LABELS[k] for k in labels[miss])
    cross = Counter(f"{LABELS[k]} | {s}" for k, s in zip(labels[miss], stage[miss]))
    world = truth["world"][r, c]
    body = truth["on_body"][r, c]
    sel = body & res.neighbourhood_ok & res.intersection.valid
    err = np.linalg.norm(res.intersection.points - world, axis=1)[sel]
    gross = err > 5 * np.median(err)
    gross_labels = Counter(LABELS[k] for k in labels[r[sel][gross], c[sel][gross]])
    in_target = target[r[sel], c[sel]]
    # the attempt that matched each point (or the neighbourhood filter's re-match)
    how = np.where(res.rematched, "re-matched", g.method)[sel]
    gross_how = Counter(how[gross])
    all_how = Counter(how)
    return {"target": int(target.sum()), "kept": int((kept & target).sum()),
            "density": float((kept & target).sum() / target.sum()),
            "missed": int(miss.sum()), "by_stage": dict(by_stage.most_common()),
            "by_label": dict(by_label.most_common()), "cross": dict(cross.most_common(12)),
            "n_points": int(sel.sum()), "gross": float(gross.mean()),
            "gross_n": int(gross.sum()), "gross_in_target_n": int((gross & in_target).sum()),
            "gross_by_label": dict(gross_labels.most_common()),
            "gross_by_attempt": {k: f"{gross_how.get(k, 0)} of {v}"
                                 for k, v in all_how.most_common()}}


def _print(f, name, s, cpu):
    print(f"\nframe {f}, {name}: density {s['density']:.1%} ({s['kept']} of {s['target']}), "
          f"gross {s['gross']:.2%} ({s['gross_n']} of {s['n_points']} points, "
          f"{s['gross_in_target_n']} at target nodes), CPU {cpu:.1f} s")
    print(f"  {s['missed']} missed, by stage: " + ", ".join(
        f"{k} {v}" for k, v in s["by_stage"].items()))
    print("  by scene label: " + ", ".join(f"{k} {v}" for k, v in s["by_label"].items()))
    print("  label | stage (top): " + "; ".join(f"{k} {v}" for k, v in s["cross"].items()))
    print("  gross errors by label: " + ", ".join(
        f"{k} {v}" for k, v in s["gross_by_label"].items()))
    print("  gross errors by attempt: " + ", ".join(
        f"{k} {v}" for k, v in s["gross_by_attempt"].items()))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 10, 20])
    parser.add_argument("--seed", type=int, default=1998)
    parser.add_argument("--variants", nargs="*", default=[],
                        choices=[k for k in VARIANTS if k != "joint"],
                        help="also run these variants of the joint configuration")
    parser.add_argument("--out", default="build/benchmarks/surface_census.json")
    args = parser.parse_args(argv)
    rows = []
    for frame, seeds, truth, _, cams in frames_as_benchmark(args.seed, args.frames):
        labels = scene_labels(frame, cams, truth, border=7)
        for name in ["joint"] + args.variants:
            t0 = time.process_time()
            res = measure_surface(frame.images, cams, seeds, **joint_call(frame, **VARIANTS[name]))
            cpu = time.process_time() - t0
            s = census(res, truth, labels)
            _print(frame.frame, name, s, cpu)
            rows.append({"frame": frame.frame, "variant": name, "cpu_s": cpu, **s})
    write_json(args.out, {"args": vars(args), "rows": rows})


if __name__ == "__main__":
    main()
