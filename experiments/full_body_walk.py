"""The full body fitted to frames of the generated walk, points alone against points and
silhouettes (and points from all round), over seeds: notebook 20's headline numbers as
median and range.

    .venv/bin/python experiments/full_body_walk.py [--frames 1 6 11] [--walk-frames 12]
        [--seed 25] [--seeds 5] [--scheduler ADDRESS] [--workers 2] [--no-around]

For each of ``--seeds`` seeds (from ``--seed``; one Dask task each, on a local cluster of
``--workers`` processes or on the scheduler at ``--scheduler``), as notebook 20 does:
renders the walk in one camera of the triplet rig (``--scale`` of 768 x 576) and the empty
studio, cuts out the silhouettes and tracks their contour with snakes with and without the
trajectory prediction (projected true trajectories plus 0.3 px: a truth input), draws noisy
surface points (1200 per frame, 1 mm) with 5 % outliers facing that camera (a truth input:
the LSMTA system measures only the arm), fits the full-body template twice (points alone;
points and the contours' lines of sight through the generator's exact camera) with the shape
shared across ``--frames``, and, unless ``--no-around``, once more to points from all round
the body with the free shape. Prints one row per seed and the median [min, max] of each
headline with the truth inputs its notebook record names; writes
``build/benchmarks/full_body_seeds.json`` / ``.csv`` and every seed's detail (per-joint
angle errors, lengths, skins, outliers, times) to ``build/benchmarks/full_body.json``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from seed_spread import Headline, add_arguments, run

from lsmta.report import write_json

TRACK_NOISE = 0.3      # px, image noise of the projected true trajectories (notebook 20)
N_EMPTY = 8            # frames of the empty studio
N_CONTOUR = 400        # snake vertices
FB_NOISE, FB_OUTLIERS = 1.0, 0.05
CONTOUR_IN = ("projected truth plus noise (the trajectories that predict the contour: true "
              f"surface points, {TRACK_NOISE:g} px)")
# the fits take the generator's points, so they live in the true world: every 3-D error
# (joint angles, skin distances) is taken there with no alignment
FB_IN = (f"true points plus noise (surface samples facing the camera, {FB_NOISE:g} mm, "
         f"{FB_OUTLIERS:.0%} outliers, so the fit is in the true world: no alignment)")
FB_SIL_IN = (f"{FB_IN}; {CONTOUR_IN}; true cameras (the lines of sight: the generator's exact "
             "camera)")
AROUND_IN = (f"true points plus noise (surface samples all round, {FB_NOISE:g} mm, "
             f"{FB_OUTLIERS:.0%} outliers, so the fit is in the true world: no alignment)")
HEADLINES = [
    Headline("contour_to_truth_px", "contour -> true outline, median (with prediction)", "px",
             CONTOUR_IN, True),
    Headline("contour_to_truth_previous_px", "contour -> true outline, median (previous "
             "contour)", "px", "none"),
    Headline("contour_from_truth_px", "true outline -> contour, median (with prediction)",
             "px", CONTOUR_IN, True),
    Headline("contour_from_truth_previous_px", "true outline -> contour, median (previous "
             "contour)", "px", "none"),
    Headline("iou", "silhouette IoU with the truth, median", "", "none"),
    Headline("worst_joint_points_deg", "worst major joint angle, points alone", "deg", FB_IN, True),
    Headline("worst_joint_deg", "worst major joint angle, points + silhouettes", "deg",
             FB_SIL_IN, True),
    Headline("worst_length_pct", "worst segment length error", "%", FB_SIL_IN, True),
    Headline("skin_to_truth_mm", "fitted skin -> true body, median", "mm", FB_SIL_IN, True),
    Headline("skin_from_truth_mm", "true body -> fitted skin, median", "mm", FB_SIL_IN, True),
    Headline("skin_worst_part_mm", "fitted skin -> true body, worst part's median", "mm",
             FB_SIL_IN, True),
    Headline("point_outliers", "point outliers at the solution, points + silhouettes", "",
             FB_SIL_IN, True),
    Headline("around_worst_joint_deg", "worst major joint angle, points all round (free "
             "shape)", "deg", AROUND_IN, True),
    Headline("around_worst_length_pct", "worst segment length error, points all round", "%",
             AROUND_IN, True),
    Headline("around_skin_to_truth_mm", "fitted skin -> true body, median, points all round "
             "(free shape)", "mm", AROUND_IN, True),
    Headline("around_skin_from_truth_mm", "true body -> fitted skin, median, points all round "
             "(free shape)", "mm", AROUND_IN, True),
    Headline("around_skin_worst_part_mm", "fitted skin -> true body, worst part's median, "
             "points all round (free shape)", "mm", AROUND_IN, True),
]


def run_seed(seed: int, *, frames, walk_frames: int, scale: float, n_points: int,
             ray_step: int, n_steps: int, free_rounds: int, around: bool,
             around_rounds: int) -> dict:
    """One walk for ``seed``: silhouettes, snakes, the full-body fits, scored after the fact."""
    from dataclasses import replace

    import numba
    import numpy as np

    from lsmta.body.full_fit import FullBodyFitParams, fit_full_body
    from lsmta.evaluation import full_body as ef
    from lsmta.evaluation import silhouettes as es

    numba.set_num_threads(1)
    t0 = time.perf_counter()
    data = es.silhouette_walk(seed=seed, n_frames=walk_frames, scale=scale, n_empty=N_EMPTY,
                              track_noise_px=TRACK_NOISE)
    trial = es.run_contour_trial(data, n_points=N_CONTOUR)
    out = {"seed": seed,
           "contour_to_truth_px": float(np.median(trial.median_predicted)),
           "contour_to_truth_previous_px": float(np.median(trial.median_previous)),
           "contour_from_truth_px": float(np.median(trial.median_from_truth_predicted)),
           "contour_from_truth_previous_px": float(np.median(trial.median_from_truth_previous)),
           "iou": float(np.median(trial.mask_iou))}
    detail = {"silhouettes_s": time.perf_counter() - t0,
              "worst_frame_from_truth_px": {
                  "predicted": float(trial.median_from_truth_predicted.max()),
                  "previous": float(trial.median_from_truth_previous.max())}}
    body, motion = data.scene.body, data.scene.motion
    contours = trial.predicted.contours[:, ::ray_step]
    params = FullBodyFitParams(n_steps=n_steps, free_rounds=free_rounds)

    def scores(fit, obs):
        errors = ef.joint_angle_errors(fit, body, motion, obs.frames)
        lengths = {k: 100 * (a / b - 1) for k, (a, b) in ef.length_errors(fit, body).items()}
        skins = [ef.skin_score(fit, body, motion, t, int(f), rng=seed)
                 for t, f in enumerate(obs.frames)]
        seg = np.concatenate([s.segment for s in skins])
        vert = np.concatenate([s.to_truth for s in skins])
        parts = {fit.model.names[k]: float(np.median(vert[seg == k])) for k in np.unique(seg)}
        worst_part = max(parts, key=parts.get)
        return {"worst_joint_deg": float(max(v.max() for v in errors.values())),
                "worst_length_pct": float(max(abs(e) for e in lengths.values())),
                "skin_to_truth_mm": float(np.median(vert)),
                "skin_from_truth_mm": float(np.median(np.concatenate(
                    [s.from_truth for s in skins]))),
                "skin_worst_part_mm": parts[worst_part], "worst_part": worst_part,
                "joints_deg": {k: np.round(v, 2).tolist() for k, v in errors.items()},
                "length_error_pct": lengths, "open_edges": [s.open_edges for s in skins],
                "point_outliers": int(fit.n_point_outliers)}

    obs = ef.walk_observations(data, contours, frames, n_points=n_points, noise_mm=FB_NOISE,
                               outlier_share=FB_OUTLIERS, rng=seed)
    fits = {}
    for name, rays in (("points", None), ("points+silhouettes", obs.rays)):
        t1 = time.perf_counter()
        fit = fit_full_body(obs.points, rays=rays, camera_centre=obs.camera_centre,
                            params=params)
        fits[name] = {"seconds": time.perf_counter() - t1, **scores(fit, obs),
                      "silhouette_outliers": fit.n_silhouette_outliers}
    s = fits["points+silhouettes"]
    out |= {"worst_joint_points_deg": fits["points"]["worst_joint_deg"],
            **{k: s[k] for k in ("worst_joint_deg", "worst_length_pct", "skin_to_truth_mm",
                                 "skin_from_truth_mm", "skin_worst_part_mm",
                                 "point_outliers")}}
    detail |= {"fits": fits, "n_points": sum(map(len, obs.points)),
               "planted_outliers": int(sum(o.sum() for o in obs.is_outlier))}
    if around:
        obs_a = ef.walk_observations(data, contours, frames, n_points=n_points,
                                     noise_mm=FB_NOISE, outlier_share=FB_OUTLIERS, around=True,
                                     rng=seed)
        t1 = time.perf_counter()
        fit = fit_full_body(obs_a.points, params=replace(params, free_rounds=around_rounds))
        a = {"seconds": time.perf_counter() - t1, **scores(fit, obs_a)}
        detail["fits"]["all round"] = a
        out |= {f"around_{k}": a[k] for k in ("worst_joint_deg", "worst_length_pct",
                                              "skin_to_truth_mm", "skin_from_truth_mm",
                                              "skin_worst_part_mm")}
    out["detail"] = detail
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[1, 6, 11],
                        help="frames of the walk fitted together (notebook 20: 1 6)")
    parser.add_argument("--walk-frames", type=int, default=12)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--points", type=int, default=1200, help="surface points per frame")
    parser.add_argument("--ray-step", type=int, default=2,
                        help="every n-th snake vertex becomes a line of sight")
    parser.add_argument("--steps", type=int, default=48, help="the fit's n_steps")
    parser.add_argument("--free-rounds", type=int, default=0,
                        help="free-shape rounds of the fits to points facing the camera")
    parser.add_argument("--no-around", action="store_true",
                        help="skip the fit to points from all round the body")
    parser.add_argument("--around-rounds", type=int, default=2,
                        help="free-shape rounds of the fit to points from all round")
    parser.add_argument("--out", default="build/benchmarks/full_body.json")
    add_arguments(parser, seed=25)
    args = parser.parse_args(argv)
    settings = {"frames": args.frames, "walk_frames": args.walk_frames, "scale": args.scale,
                "n_points": args.points, "ray_step": args.ray_step, "n_steps": args.steps,
                "free_rounds": args.free_rounds, "around": not args.no_around,
                "around_rounds": args.around_rounds}
    headlines = [h for h in HEADLINES if settings["around"] or not h.key.startswith("around")]
    results, table = run("full_body", run_seed, headlines, args, parser=parser,
                         out_dir=Path(args.out).parent, settings=settings, **settings)
    write_json(args.out, {**settings, "seeds": {str(s): r for s, r in results.items()},
                          "spread": table})


if __name__ == "__main__":
    main()
