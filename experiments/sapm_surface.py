"""SAPM at full scale: the paper's Fig. 3 grid and its 2000-pose noise-free test, with Dask.

    .venv/bin/python experiments/sapm_surface.py [--quick] [--scheduler ADDRESS] [--workers 2]

Fig. 3 of Holstein & Li (2002): identification rate over 5 configuration levels (0..4
rad) x 100 distortion levels (0..10 % of l̄_s) x 10 random poses per cell, with the
13-segment, 44-marker model; plus about 2000 noise-free arbitrary poses, SAPM beside the
one-rigid-fit baseline. Every grid cell and every chunk of noise-free poses is one Dask
task with its own seed (``lsmta.evaluation.sapm.cell_seeds``), so the numbers do not depend
on the number of workers or their order. By default a local cluster of processes is
started; ``--scheduler`` uses an existing one (its workers need lsmta installed).

Writes to ``build/sapm/``: ``surface.csv`` (level, distortion, poses_correct,
points_correct, poses), ``surface.png``, ``noise_free.json`` (summaries and timing).
``--quick`` runs a 5 x 6 grid of 4 poses and 100 noise-free poses.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lsmta.evaluation import sapm as ev
from lsmta.report import write_json
from lsmta.sapm import SAPMParams
from lsmta.synth.markers import human_model


def noise_free_chunk(model, seed: int, n_poses: int, eps: float, beta: float):
    """One chunk of the noise-free test: SAPM and the baseline on the same poses."""
    trials = ev.pose_trials(model, n_poses, rng=np.random.default_rng(seed), level=np.pi,
                            methods=("sapm", "baseline"), params=SAPMParams(eps=eps, beta=beta))
    return {m: (t.correct, t.accuracy, t.seconds) for m, t in trials.items()}


def _client(args):
    from dask.distributed import Client, LocalCluster

    if args.scheduler:
        return Client(args.scheduler)
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster)


def _plot(levels, distortions, grid, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.ndimage import gaussian_filter1d

    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    D, L = np.meshgrid(100 * distortions, levels)
    smooth = gaussian_filter1d(grid, max(1.0, len(distortions) / 30), axis=1, mode="nearest")
    ax.plot_surface(D, L, 100 * smooth, cmap="viridis", vmin=0, vmax=100, edgecolor="none")
    ax.set_xlabel(r"distortion ψ [% of $\bar{l}_s$]")
    ax.set_ylabel("configuration level [rad]")
    ax.set_zlabel("poses fully correct [%]")
    ax.set_zlim(0, 100)
    ax.view_init(25, -55)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a small grid, for a smoke test")
    parser.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    parser.add_argument("--workers", type=int, default=2, help="local worker processes")
    parser.add_argument("--levels", type=float, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--distortions", type=int, default=100,
                        help="number of ψ levels in 0..10 %%")
    parser.add_argument("--poses", type=int, default=10, help="poses per grid cell")
    parser.add_argument("--noise-free", type=int, default=2000, help="noise-free poses")
    parser.add_argument("--eps", type=float, default=0.10)
    parser.add_argument("--beta", type=float, default=0.80)
    parser.add_argument("--eps-noise-free", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=2002)
    parser.add_argument("--out", default="build/sapm")
    args = parser.parse_args(argv)
    if args.quick:
        args.distortions, args.poses, args.noise_free = 6, 4, 100

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = human_model()
    levels = np.asarray(args.levels, float)
    distortions = np.linspace(0.0, 0.10, args.distortions)
    seeds = ev.cell_seeds(args.seed, (len(levels), len(distortions)))
    chunk = 50
    n_chunks = -(-args.noise_free // chunk)
    chunk_seeds = ev.cell_seeds(args.seed + 1, (n_chunks,))

    from dask.distributed import as_completed

    t0 = time.perf_counter()
    with _client(args) as client:
        print(f"Dask: {client}")
        model_f = client.scatter(model, broadcast=True)
        futures = {}
        for i in range(len(levels)):
            for j in range(len(distortions)):
                fut = client.submit(ev.surface_cell, model_f, int(seeds[i, j]), levels[i],
                                    distortions[j], args.poses,
                                    params=SAPMParams(eps=args.eps, beta=args.beta), pure=False)
                futures[fut] = ("cell", i, j)
        for c in range(n_chunks):
            n = min(chunk, args.noise_free - c * chunk)
            fut = client.submit(noise_free_chunk, model_f, int(chunk_seeds[c]), n,
                                args.eps_noise_free, args.beta, pure=False)
            futures[fut] = ("noise_free", c, n)
        poses = np.zeros(seeds.shape)
        points = np.zeros(seeds.shape)
        noise_free = {"sapm": [], "baseline": []}
        for fut in tqdm(as_completed(futures), total=len(futures), desc="SAPM tasks"):
            kind, a, b = futures[fut]
            if kind == "cell":
                poses[a, b], points[a, b] = fut.result()
            else:
                for m, cols in fut.result().items():
                    noise_free[m].append(cols)
    wall = time.perf_counter() - t0

    with open(out / "surface.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["level_rad", "distortion", "poses_correct", "points_correct", "poses"])
        for i, lev in enumerate(levels):
            for j, d in enumerate(distortions):
                w.writerow([lev, f"{d:.6f}", f"{poses[i, j]:.4f}", f"{points[i, j]:.4f}",
                            args.poses])
    print(f"wrote {out / 'surface.csv'}")
    _plot(levels, distortions, poses, out / "surface.png")

    summary = {"wall_s": wall, "grid_cells": int(poses.size), "poses_per_cell": args.poses,
               "eps": args.eps, "beta": args.beta, "eps_noise_free": args.eps_noise_free}
    for m, parts in noise_free.items():
        correct, accuracy, seconds = (np.concatenate(x) for x in zip(*parts))
        summary[m] = {"poses": int(len(correct)), "poses_correct": float(correct.mean()),
                      "points_correct": float(accuracy.mean()),
                      "median_s": float(np.median(seconds)),
                      "p95_s": float(np.percentile(seconds, 95))}
        print(f"noise-free, {m}: {100 * correct.mean():.2f} % of {len(correct)} poses fully "
              f"correct, {100 * accuracy.mean():.2f} % of points; median "
              f"{1000 * np.median(seconds):.1f} ms, 95th percentile "
              f"{1000 * np.percentile(seconds, 95):.1f} ms per pose")
    summary["grid_mean_poses_correct_by_level"] = dict(zip(map(str, levels),
                                                           poses.mean(axis=1).tolist()))
    summary["grid_mean_poses_correct_at_max_distortion"] = float(poses[:, -1].mean())
    print(f"grid: poses fully correct at ψ = 0: {100 * poses[:, 0].mean():.1f} %, at ψ = 10 %: "
          f"{100 * poses[:, -1].mean():.1f} %; wall time {wall:.0f} s")
    write_json(out / "noise_free.json", summary)


if __name__ == "__main__":
    main()
