"""LSMTA tracking against OpenCV KLT on a full-size triplet walk: accuracy, survival, time,
over seeds.

    .venv/bin/python experiments/tracking_benchmark.py [--frames 30] [--points 3000]
        [--scale 1.0] [--step 2] [--patch 15] [--seed 2000] [--seeds 5]
        [--no-retry-rejected] [--return-to-first]
        [--scheduler ADDRESS] [--workers 2]

Renders a walk for the triplet rig at ``--scale`` of 768 x 576 pixels, starts both trackers
on the same ``--points`` visible surface points of frame 0 (grid every ``--step`` px of the
centre image) and tracks ``--frames`` frames: LSMTA with the density check (new points from
the true visible surface every second frame) and KLT with a forward-backward check. Prints
and writes (build/benchmarks/tracking.json) the wall time of each tracker, their ratio,
the median per-frame image error, the 3-D error by track age, survival and false
trajectories (> 10 mm); and the CPU time of each (process time, every thread: the judge on
a machine shared with other jobs, where wall time waits for them). The targets: a 30-frame
triplet sequence of a few thousand points in under two minutes (the issue that built it),
and issue 35's, LSMTA's CPU time <= 2x KLT's with accuracy and survival as good.

Where the time goes (#35 item 1; seed 2000, the defaults, 1 thread, CPU seconds of a warm
run, 2026-11-28, each stage's compiled call and its Python timed apart; load 2 to 7 on 2
cores, so +-15 %): LSMTA 8.2 s against KLT's 1.1-1.7 s. The inverse compositional matches of
the temporal step 2.2 s (159 000 rows, 14 us each; at 1000 points 6.7 iterations of 225
pixels a row, a quarter of them spent by the 8 % of the rows that reach ``max_iter``), their
forward LSM retries 0.9 s (12 400 rows, 72 us each), the spatial LSM across the cameras 1.2
s (78 000 inverse compositional rows and 4 900 forward retries), the correlation search 0.5
s (12 000 boxes), the coarse-to-fine step 0.5 s (84 000 translation rows), the search for
missing tracks 0.9 s (9 400 boxes, 8 300 inverse compositional and 4 600 forward matches),
the start and new points' templates and spatial LSM 0.4 s, the re-anchored templates 0.26 s,
the splines of the frames and their pyramids 0.13 s, and the Python between the calls about
0.3-0.9 s (10-30 ms a frame). The templates' normal matrices are computed once, when
anchored, and each stage is one compiled call per camera for all its points already. Exact
cuts (same tracks: to 3e-13 px, every status and anchor, here and on a caliscope and a
pose2sim video forward and back, to 6e-10 px): the inverse compositional sampler checks a
patch's positions before sampling it (its kernel -10 %); the spatial LSM, the start's
spatial LSM and the coarse-to-fine step skip the cameras after one where a track has already
failed (the translation rows 113 000 -> 84 000). Same sitting, one after the other (load
about 3): LSMTA/KLT CPU 8.3x before, 7.4x after; at 30 frames and 1000 points 3.55 -> 3.28
s. Those cuts are NOT in this code: they were reverted (branch s57-rv keeps them), because
on the tiny studio walk of tests/test_rom_fit.py (one thread) they change the fitted body
(the drop rule keeps all 12 clip frames, not 9-11), so they are not exact there; the
profile above was taken with them. The target (<= 2x) is NOT met: the temporal inverse
compositional matches alone cost more than KLT's whole run, so it asks for fewer matches or
iterations (not exact), not for less overhead.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from seed_spread import Headline, add_arguments, run

from lsmta.report import write_json

TRACK_IN = ("seeds from truth (start points and the density check's new points on the true "
            "visible surface); true cameras (the 3-D errors' intersection)")
HEADLINES = [
    Headline("lsmta_over_klt_time", "time LSMTA / KLT (timing)", "", "none"),
    Headline("lsmta_over_klt_cpu", "CPU time LSMTA / KLT (timing)", "", "none"),
    Headline("lsmta_s", "LSMTA tracking time (timing)", "s", "none"),
    Headline("lsmta_step_error_px", "LSMTA per-frame image error, median", "px", TRACK_IN, True),
    Headline("klt_step_error_px", "KLT per-frame image error, median", "px", TRACK_IN, True),
    Headline("lsmta_3d_error_at_oldest_mm", "LSMTA 3-D error at the oldest age", "mm", TRACK_IN,
             True),
    Headline("klt_3d_error_at_oldest_mm", "KLT 3-D error at the oldest age", "mm", TRACK_IN,
             True),
    Headline("lsmta_survival", "LSMTA start points alive at the end, share", "", TRACK_IN, True),
    Headline("klt_survival", "KLT points alive at the end, share", "", TRACK_IN, True),
    Headline("lsmta_false_share", "LSMTA false trajectories (> 10 mm), share", "", TRACK_IN,
             True),
    Headline("klt_false_share", "KLT false trajectories (> 10 mm), share", "", TRACK_IN, True),
]


def run_seed(seed: int, *, frames: int, points: int, scale: float, step: int, patch: int,
             threads: int, retry_rejected: bool = True, return_to_first: bool = False) -> dict:
    """One walk for ``seed``: both trackers from the same points, scored after the fact."""
    import numba
    import numpy as np

    from lsmta.evaluation import tracking as et
    from lsmta.tracking import TrackerParams

    numba.set_num_threads(threads)
    t0 = time.perf_counter()
    seq = et.walk_sequence(seed=seed, n_frames=frames, scale=scale, step=step)
    render_s = time.perf_counter() - t0
    s = scale / 0.5            # box sizes scale with the image
    params = TrackerParams(patch=patch, radius=int(round(4 * s)),
                           retry_radius=int(round(10 * s)), cell=16.0 * s,
                           min_distance=3.0 * s, retry_rejected=retry_rejected,
                           return_to_first=return_to_first)
    # warm-up: load the compiled kernels once, outside the timings
    et.run_tracking_trial(et.walk_sequence(seed=seed, n_frames=2, scale=0.25), 5,
                          rng=np.random.default_rng(0))
    trial = et.run_tracking_trial(seq, points, rng=np.random.default_rng(seed), params=params)
    sc, ks = trial.score, trial.klt_score
    age, e_ls, n_ls = et.by_age(sc.error_3d, trial.tracks.start)
    _, e_kl, n_kl = et.by_age(ks.error_3d, trial.klt.start)
    last = int(np.max(np.flatnonzero(np.isfinite(e_ls))))
    n0 = int((~trial.tracks.added).sum())
    out = {
        "seed": seed, "frames": frames, "image_size": list(seq.images.shape[2:][::-1]),
        "start_points": n0, "added_points": int(trial.tracks.added.sum()),
        "render_s": render_s,
        "lsmta_s": trial.seconds, "klt_s": trial.klt_seconds,
        "lsmta_over_klt_time": trial.seconds / trial.klt_seconds,
        "lsmta_cpu_s": trial.cpu_seconds, "klt_cpu_s": trial.klt_cpu_seconds,
        "lsmta_over_klt_cpu": trial.cpu_seconds / trial.klt_cpu_seconds,
        "lsmta_step_error_px": float(np.nanmedian(sc.step_error)),
        "klt_step_error_px": float(np.nanmedian(ks.step_error)),
        "oldest_age": last, "lsmta_3d_error_at_oldest_mm": float(e_ls[last]),
        "lsmta_tracks_at_oldest": int(n_ls[last]),
        "klt_3d_error_at_oldest_mm": float(e_kl[last]),
        "klt_tracks_at_oldest": int(n_kl[last]),
        "lsmta_start_points_alive_at_end": int(trial.tracks.alive[-1, ~trial.tracks.added].sum()),
        "klt_alive_at_end": int(trial.klt.alive[-1].sum()),
        "lsmta_false_share": float(sc.false.mean()), "klt_false_share": float(ks.false.mean()),
    }
    out["lsmta_survival"] = out["lsmta_start_points_alive_at_end"] / max(n0, 1)
    out["klt_survival"] = out["klt_alive_at_end"] / max(int(trial.klt.alive[0].sum()), 1)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--points", type=int, default=3000)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--step", type=int, default=2)
    parser.add_argument("--patch", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1,
                        help="numba threads (1 on a shared machine: parallel threads spin)")
    parser.add_argument("--no-retry-rejected", dest="retry_rejected", action="store_false",
                        help="TrackerParams(retry_rejected=False): fewer forward LSM retries")
    parser.add_argument("--return-to-first", action="store_true",
                        help="TrackerParams(return_to_first=True)")
    parser.add_argument("--out", default="build/benchmarks/tracking.json")
    add_arguments(parser, seed=2000)
    args = parser.parse_args(argv)
    settings = {k: getattr(args, k) for k in ("frames", "points", "scale", "step", "patch",
                                              "threads", "retry_rejected", "return_to_first")}
    results, _ = run("tracking", run_seed, HEADLINES, args, parser=parser,
                     out_dir=Path(args.out).parent, settings=settings, **settings)
    first = results[args.seed]
    print(f"\nseed {args.seed} in full:")
    for k, v in first.items():
        print(f"{k:>36}: {v:.4g}" if isinstance(v, float) else f"{k:>36}: {v}")
    write_json(args.out, first)


if __name__ == "__main__":
    main()
