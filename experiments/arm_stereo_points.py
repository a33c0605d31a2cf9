"""Stereo points of the rendered arm wave for notebook 07 (Plänkers et al. 1999, Fig. 8).

Renders three frames of :func:`lsmta.synth.arm_wave` in the triplet rig and measures the
surface with the project's own pipeline (:func:`lsmta.matching.measure_surface`: region
growing LSM in the three images, neighbourhood filter, forward intersection) with the
generator's exact cameras. The seeds come from the truth
(:func:`lsmta.evaluation.surface.seeds_from_truth`, kept where the renderer's part id is an
arm part), not from a user's clicks. This takes several minutes on a loaded
two-core machine, too long for the notebook's 60 s budget, so the points (and a crop of
each centre image) are written to ``data/arm_stereo/arm_wave_stereo.npz``, which the
notebook reads. Run from the repository root:

    PYTHONPATH=$PWD python experiments/arm_stereo_points.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from lsmta.evaluation import surface as evaluate
from lsmta.matching import GrowParams, LSMThresholds, MeasureSurfaceParams, measure_surface
from lsmta.synth import Renderer, Scene, arm_wave, make_body, triplet_rig

SEED = 1998
FRAMES = (10, 20, 30)
NOISE = 2.0                 # image noise, grey levels
STEP, PATCH, RETRY = 4, 7, (9, 5)
ARM = ("upper_arm_r", "forearm_r", "hand_r")
OUT = Path(__file__).resolve().parents[1] / "data" / "arm_stereo" / "arm_wave_stereo.npz"


def world():
    """The rig, body and motion of the notebook (same seeds)."""
    rng = np.random.default_rng(SEED)
    cameras = triplet_rig(rng=rng, distance=2500.0, baseline=700.0)
    body = make_body(rng=np.random.default_rng(SEED), contrast=0.3, wavelength=(12.0, 50.0))
    return cameras, body, arm_wave(n_frames=50), rng


def main(argv=None):
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-part", type=int, default=2, help="seeds per arm part")
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    out = Path(args.out)
    cameras, body, motion, rng = world()
    scene = Scene(body, motion, None)
    renderer = Renderer(scene, cameras, noise_sigma=NOISE)
    thresholds = LSMThresholds(max_sigma0=2.0 * NOISE, max_displacement=STEP, max_sigma_xy=0.2,
                               scale_range=(0.5, 2.0), max_shear=0.5)
    arm = [body.index(n) for n in ARM]
    points, frame_of, crops, boxes, seconds, errors = [], [], [], [], [], []
    for f in FRAMES:
        shot = renderer.render(f, rng=rng)
        seeds = evaluate.seeds_from_truth(scene, cameras, f, rng=rng, per_part=args.per_part)
        px = np.round(seeds[1]).astype(int)
        on_arm = np.isin(shot.part_id[1][px[:, 1], px[:, 0]], arm)
        t0 = time.perf_counter()
        grow = GrowParams(step=STEP, patch=PATCH, retry_patch=RETRY, thresholds=thresholds)
        res = measure_surface(shot.images, cameras, seeds[:, on_arm],
                              params=MeasureSurfaceParams(grow=grow, voxel=None))
        seconds.append(time.perf_counter() - t0)
        truth = evaluate.node_truth(shot, scene, cameras, step=STEP, patch=13)
        errors.append(evaluate.score_surface(res, truth)["filtered"]["median_mm"])
        points.append(res.points)
        frame_of.append(np.full(len(res.points), f))
        rows, cols = np.nonzero(np.isin(shot.part_id[1], arm))
        r0, r1 = max(rows.min() - 40, 0), rows.max() + 40
        c0, c1 = max(cols.min() - 40, 0), cols.max() + 40
        crops.append(shot.images[1][r0:r1, c0:c1])
        boxes.append((r0, r1, c0, c1))
        print(f"frame {f}: {len(res.points)} points in {seconds[-1]:.0f} s, "
              f"median error {errors[-1]:.2f} mm")
    h = max(c.shape[0] for c in crops)
    w = max(c.shape[1] for c in crops)
    stack = np.zeros((len(crops), h, w), np.uint8)
    for k, c in enumerate(crops):
        stack[k, :c.shape[0], :c.shape[1]] = c
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, frames=np.array(FRAMES), points=np.concatenate(points),
                        frame=np.concatenate(frame_of), crops=stack, boxes=np.array(boxes),
                        seconds=np.array(seconds), median_error_mm=np.array(errors))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
