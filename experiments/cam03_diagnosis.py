"""Why one camera's held-out still places miss: their residuals looked at, not tuned.

    .venv/bin/python experiments/cam03_diagnosis.py [--camera cam03] [--n-frames 7]
        [--still-between 2] [--tie max_tilt=4] [--worst 10] [--cache FILE] [--out DIR]

Runs the refinement of ``experiments/refinement_held_out.py`` (``--lsm on``, the settings
given; its ``run``) once, keeps the :class:`lsmta.systems.RigRefinement` in ``--cache``
(pickle, default ``build/cam03_diagnosis/<settings>/refinement.pkl``, with the settings and
the commit it was made at; a cache of other settings is refused) so that the figures can be
made again without it, and writes into ``--out`` (default
``build/cam03_diagnosis/<settings>/<camera>/``, not committed):

(a) ``quiver.png``: the camera's held-out still places over its frame with their residual
    vectors (refined cameras; projection minus measurement, drawn 50 times longer), the
    adjusted places' residuals beside them, and the change of the camera's intrinsics
    (refined against the file's) over the frame; ``field`` in the JSON: how much of the
    held-out residual a translation, a scale and a rotation about the principal point
    (principal point / focal length / roll) explain, fitted robustly (soft L1, 1 px scale:
    the large misses do not steer it); ``near_pairs``: held-out places within 30 px of each
    other in the camera and their residuals (a field moves neighbours alike).
(b) ``crops_NN.png``: the worst held-out still places (of the camera), each in every view that
    holds it and in up to three of its frames, a 41 x 41 px crop and a 161 x 161 px context
    crop, the measured position (green) and, in the camera, where the refined cameras put it
    (red). Per place in the JSON also: image-side numbers that might tell an ill-defined point
    (the structure tensor's eigenvalue ratio, the LSM's sigma, the spread over its frames),
    the distance to the nearest adjusted place and whether it lies inside their hull
    (``coverage``: the median inside and outside).
(c) ``by_pair``: the camera's residual with each place intersected from the camera and ONE
    other view only, and its prediction residual (the point intersected WITHOUT the camera,
    from the other views, where two or more see it, projected into it).
(d) ``lens``: the intrinsics freed per camera and their posterior/prior ratios, and the
    adjustment run again on the same adjusted places with the intrinsics held (``f`` only),
    with the default choice, with cx, cy, k1, k2 freed in every camera, and with k1 alone:
    the judged held-out still residual per camera of each (``lens.png``) and per place;
    ``refined_vs_given``: how far each camera moved from the file's.
Plus ``summary.json`` with every number. Findings (README, "Why cam03's held-out still places
miss"): not a field (neighbours 8 px apart miss by 0.09 and 6.5 px); the large misses are
features that recur at the same pixels but are not one 3-D point (silhouettes, creased brackets,
edges), seen by two views only; the rest grow where the camera has no adjusted places; the lens
is not determined by the places.
"""

from __future__ import annotations

import argparse
import json
import pickle
import subprocess
import warnings
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from refinement_held_out import run, tie_settings  # noqa: E402  this folder's experiment
from scipy.optimize import least_squares  # noqa: E402
from scipy.spatial import Delaunay  # noqa: E402

from lsmta.calibration.refine import RefineParams, refine_cameras  # noqa: E402
from lsmta.camera_files import read_camera_file  # noqa: E402
from lsmta.data import POSE2SIM_CAMERAS, POSE2SIM_VIDEOS  # noqa: E402
from lsmta.io import read_videos  # noqa: E402
from lsmta.report import write_json  # noqa: E402
from lsmta.triangulation import triangulate  # noqa: E402

GAIN = 50.0                     # quiver: residual drawn this many times longer


def settings(args) -> dict:
    """The refinement's settings (what the cache must match)."""
    return {"n_frames": args.n_frames, "still_between": args.still_between, "tie": args.tie,
            "scale": 1.0, "frames": "0:100", "lsm": True}


def head_commit() -> str:
    """``git rev-parse HEAD`` of the working tree ("unknown" outside git)."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def refinement(args):
    """The RigRefinement of these settings: from ``args.cache`` if there (its settings must
    be these; ValueError otherwise), else run and cache it with the settings and commit."""
    cache = Path(args.cache)
    if cache.exists():
        with cache.open("rb") as fh:
            stored = pickle.load(fh)
        if not isinstance(stored, dict) or "settings" not in stored:
            raise ValueError(f"--cache {cache}: no settings stored with the refinement; "
                             "delete it to run again")
        if stored["settings"] != settings(args):
            raise ValueError(f"--cache {cache}: made with {stored['settings']}, expected "
                             f"{settings(args)}; delete it or give another --cache")
        print(f"refinement from cache {cache} (made at commit {stored['commit']})")
        return stored["refinement"]
    videos = read_videos(POSE2SIM_VIDEOS, frames=range(0, 100), scale=1.0)
    ns = argparse.Namespace(scale=1.0, frames="0:100", n_frames=args.n_frames,
                            lsm_each=False, lsm_once=False, larger_patches="",
                            recording_geometry=False, still_between=args.still_between,
                            tie=args.tie)
    _, ref = run(videos, True, ns)
    cache.parent.mkdir(parents=True, exist_ok=True)
    with cache.open("wb") as fh:
        pickle.dump({"settings": settings(args), "commit": head_commit(), "refinement": ref}, fh)
    return ref


def residual_vectors(cameras, xy):
    """(K, N, 2) projection minus measurement of ``xy`` (K, N, 2) intersected with
    ``cameras`` from every view that sees it; NaN where unseen or not intersected."""
    X = triangulate(list(cameras), xy, min_angle_deg=0.0).points
    out = np.full(xy.shape, np.nan)
    ok = np.isfinite(X).all(axis=1)
    for k, cam in enumerate(cameras):
        out[k, ok] = cam.project(X[ok], behind="nan") - xy[k, ok]
    return np.where(np.isfinite(xy), out, np.nan)


def predicted(cameras, xy, c: int, views):
    """(N, 2) projection into camera ``c`` minus its measurement, the points intersected
    from ``views`` alone (NaN where fewer than two of them see a point or ``c`` does not)."""
    sub = np.where(np.isin(np.arange(len(xy)), views)[:, None, None], xy, np.nan)
    X = triangulate(list(cameras), sub, min_angle_deg=0.0).points
    ok = np.isfinite(X).all(axis=1) & np.isfinite(xy[c, :, 0])
    out = np.full((xy.shape[1], 2), np.nan)
    out[ok] = cameras[c].project(X[ok], behind="nan") - xy[c, ok]
    return out


def field_fit(cam, xy, d) -> dict:
    """How much of the residual vectors ``d`` (N, 2) at ``xy`` (N, 2) a translation, a scale
    and a rotation about the principal point explain, fitted robustly (soft L1 loss, scale
    1 px, so that a few large misses do not steer it): the fitted terms, the median length
    before and after."""
    ok = np.isfinite(d).all(axis=1)
    if ok.sum() < 4:
        return {"places": int(ok.sum())}
    u, v = xy[ok, 0] - cam.cx, xy[ok, 1] - cam.cy
    one, zero = np.ones_like(u), np.zeros_like(u)
    A = np.r_[np.c_[one, zero, u / 1000, -v / 1000], np.c_[zero, one, v / 1000, u / 1000]]
    b = np.r_[d[ok, 0], d[ok, 1]]
    p = least_squares(lambda q: A @ q - b, np.zeros(4), loss="soft_l1", f_scale=1.0).x
    rest = (b - A @ p).reshape(2, -1).T
    p = p * [1.0, 1.0, 1e-3, 1e-3]                      # back to per-pixel scale and rotation
    mean = d[ok].mean(axis=0)
    return {"places": int(ok.sum()), "shift_px": p[:2].round(3).tolist(),
            "scale_ppm": round(float(p[2]) * 1e6, 1), "rotation_mrad": round(float(p[3]) * 1e3, 3),
            "mean_vector_px": mean.round(3).tolist(),
            "median_px": round(float(np.median(np.linalg.norm(d[ok], axis=1))), 3),
            "median_after_field_px": round(float(np.median(np.linalg.norm(rest, axis=1))), 3),
            "fit": "soft_l1, f_scale 1 px"}


def near_pairs(records, c_name: str, within: float = 30.0) -> list:
    """Held-out places within ``within`` px of each other in camera ``c_name``: their ids,
    distance and residuals (px), nearest first."""
    out = []
    for i, a in enumerate(records):
        for b in records[i + 1:]:
            dist = float(np.linalg.norm(np.subtract(a["xy"][c_name], b["xy"][c_name])))
            if dist <= within:
                out.append({"places": [a["place"], b["place"]], "distance_px": round(dist, 1),
                            "residual_px": [a["residual_px"], b["residual_px"]]})
    return sorted(out, key=lambda r: r["distance_px"])


def intrinsic_change(given, refined, step: int = 96):
    """(M, 2) grid over the frame and (M, 2) where the refined camera's intrinsics put the
    ray that the file's intrinsics put at each grid pixel, minus the pixel (pose apart)."""
    u, v = np.meshgrid(np.arange(step / 2, given.width, step),
                       np.arange(step / 2, given.height, step))
    grid = np.c_[u.ravel(), v.ravel()].astype(float)
    rays = given.undistort(given.pixel_to_normalized(grid))
    return grid, refined.normalized_to_pixel(refined.distort(rays)) - grid


def quiver_figure(path, image, c_name, held, train, change, ids):
    """(a): the held-out and adjusted residual vectors ((xy, d) pairs), the intrinsics'
    change; the held-out places labelled with their place ids."""
    (held_xy, held_d), (train_xy, train_d) = held, train
    fig, axes = plt.subplots(1, 3, figsize=(15, 9))
    titles = (f"{c_name}: held-out still places (x{GAIN:g})",
              f"{c_name}: adjusted places (x{GAIN:g})",
              f"{c_name}: refined - file intrinsics (x10)")
    data = ((held_xy, held_d, "r", GAIN), (train_xy, train_d, "b", GAIN),
            (change[0], change[1], "m", 10.0))
    for ax, title, (xy, d, col, g) in zip(axes, titles, data):
        ax.imshow(image, cmap="gray")
        ok = np.isfinite(d).all(axis=1)
        ax.quiver(xy[ok, 0], xy[ok, 1], g * d[ok, 0], g * d[ok, 1], color=col,
                  angles="xy", scale_units="xy", scale=1, width=0.004)
        ax.plot(xy[ok, 0], xy[ok, 1], "o", ms=3, mfc="none", mec="y")
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    for (x, y), i in zip(held_xy, ids):
        axes[0].annotate(str(i), (x, y), color="yellow", fontsize=6, xytext=(3, 3),
                         textcoords="offset points")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def crop(image, xy, half: int):
    """A (2 half + 1)^2 crop of ``image`` centred on the pixel nearest ``xy`` (zero padded)."""
    pad = np.pad(image, half + 1)
    x, y = int(round(xy[0])) + half + 1, int(round(xy[1])) + half + 1
    return pad[y - half:y + half + 1, x - half:x + half + 1]


def crops_figure(path, frames_of, xy_views, names, c, predicted_c, title):
    """(b): one place, a row per (frame, view): its 41-px crop (x4) and 161-px context."""
    rows = [(f, k) for f in frames_of for k in range(len(names))
            if np.isfinite(xy_views[f][1][k]).all()]
    fig, axes = plt.subplots(len(rows), 2, figsize=(6, 2.9 * len(rows)), squeeze=False)
    for (f, k), ax2 in zip(rows, axes):
        image, xy = xy_views[f][0][k], xy_views[f][1][k]
        for ax, half in zip(ax2, (20, 80)):
            ax.imshow(crop(image, xy, half), cmap="gray", extent=(-half - .5, half + .5,
                                                                   half + .5, -half - .5))
            ax.plot(xy[0] - round(xy[0]), xy[1] - round(xy[1]), "+", color="lime", ms=12)
            if k == c and np.isfinite(predicted_c).all():
                p = predicted_c + xy
                ax.plot(p[0] - round(xy[0]), p[1] - round(xy[1]), "x", color="red", ms=10)
            ax.set_title(f"{names[k]} frame {f} ({xy[0]:.0f}, {xy[1]:.0f})", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def place_frames(ref, p: int) -> dict:
    """Recording frame -> (K, 2) median position of place ``p``'s tie points of that frame."""
    idx = np.flatnonzero(ref.places == p)
    out = {}
    for fi in np.unique(ref.tie_points.frame[idx]):
        pts = ref.tie_points.xy[:, idx[ref.tie_points.frame[idx] == fi]]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[int(ref.frames[fi])] = np.nanmedian(pts, axis=1)
    return out


def by_pair(cameras, held, c: int, names) -> dict:
    """(c): the camera's residual with each place intersected from it and ONE other view,
    and the prediction residual (intersected without it)."""
    K = len(cameras)
    out = {}
    for j in range(K):
        if j == c:
            continue
        both = np.isfinite(held[c, :, 0]) & np.isfinite(held[j, :, 0])
        d = np.linalg.norm(predicted(cameras, held[:, both], c, [c, j]), axis=1)
        out[f"{names[c]}+{names[j]}"] = {
            "places": int(both.sum()),
            "median_px": round(float(np.nanmedian(d)), 3) if both.any() else None}
    others = [j for j in range(K) if j != c]
    d = np.linalg.norm(predicted(cameras, held, c, others), axis=1)
    ok = np.isfinite(d)
    out[f"without {names[c]}"] = {"places": int(ok.sum()), "median_px": round(
        float(np.median(d[ok])), 3) if ok.any() else None}
    return out


def lens_runs(ref, train, held) -> dict:
    """(d): the adjustment again on the same adjusted places with the intrinsics held, chosen
    as by default, and all freed; each run's held-out still residual per camera. Returns the
    record and each run's cameras."""
    from refinement_held_out import medians
    base = RefineParams()
    variants = {"held (f only)": replace(base, groups=()), "default choice": base,
                "cx,cy,k1,k2 all freed": replace(base, information_ratio=1.0),
                "k1 alone freed": replace(base, information_ratio=1.0, groups=(("k1",),))}
    out = {"refine_rig": {"freed": [list(f) for f in ref.adjustment.freed],
                          "ratio_names": list(ref.adjustment.ratio_names),
                          "ratios": np.round(ref.adjustment.ratios, 3).tolist(),
                          "held_out_still_px": medians(ref.cameras, held)}}
    cams = {}
    for name, params in variants.items():
        adj = refine_cameras(ref.given, train, params=params)
        cams[name] = adj.cameras
        out[name] = {"freed": [list(f) for f in adj.freed],
                     "adjusted_px": np.round(adj.median_residual(), 3).tolist(),
                     "held_out_still_px": medians(adj.cameras, held),
                     "cameras": [{"f": round(cam.f, 2), "cx": round(cam.cx, 2),
                                  "cy": round(cam.cy, 2), "k1": round(cam.k1, 4),
                                  "k2": round(cam.k2, 4), "p1": round(cam.p1, 5),
                                  "p2": round(cam.p2, 5), "k3": round(cam.k3, 4)}
                                 for cam in adj.cameras]}
    return out, cams


def per_place(ref, p, held_i, c, names, dh, dg, draw, pred, train_c) -> dict:
    """The record of held-out still place ``p`` (column ``held_i`` of the held-out set);
    ``inside_adjusted`` whether camera ``c`` sees it inside the convex hull of the adjusted
    places it sees (else the refined cameras extrapolate there)."""
    xy = ref.place_xy[:, p]
    seen = np.isfinite(xy[:, 0])
    near = (float(np.min(np.linalg.norm(train_c - xy[c], axis=1)))
            if len(train_c) else None)
    return {"place": int(p), "views": [names[k] for k in np.flatnonzero(seen)],
            "xy": {names[k]: np.round(xy[k], 1).tolist() for k in np.flatnonzero(seen)},
            "frames": sorted(place_frames(ref, p)),
            "residual_px": round(float(np.linalg.norm(dh[c, held_i])), 3),
            "residual_vector_px": np.round(dh[c, held_i], 3).tolist(),
            "residual_given_px": round(float(np.linalg.norm(dg[c, held_i])), 3),
            "residual_raw_positions_px": round(float(np.linalg.norm(draw[c, held_i])), 3),
            "prediction_without_px": None if not np.isfinite(pred[held_i]).all()
            else round(float(np.linalg.norm(pred[held_i])), 3),
            "nearest_adjusted_place_px": None if near is None else round(near, 1),
            **point_quality(ref, p),
            "inside_adjusted": bool(len(train_c) >= 3
                                    and Delaunay(train_c).find_simplex(xy[c][None])[0] >= 0)}


def point_quality(ref, p: int) -> dict:
    """Image-side numbers of place ``p`` that might tell an ill-defined point: the largest
    LSM standard deviation of its tie points' matches (px, of the frames searched) and how
    far its tie points of different frames spread in some view (px)."""
    idx = np.flatnonzero(ref.places == p)
    xy = ref.tie_points.xy[:, idx]
    seen = np.isfinite(xy[..., 0]).any(axis=1)
    spread = max(float(np.max(np.ptp(xy[k][np.isfinite(xy[k, :, 0])], axis=0)))
                 for k in np.flatnonzero(seen))
    sigma = None
    if ref.lsm is not None:
        s = ref.lsm.sigma[:, np.flatnonzero(ref.lsm.kept)[idx]]
        sigma = round(float(np.nanmax(s)), 3) if np.isfinite(s).any() else None
    return {"lsm_sigma_max_px": sigma, "spread_px": round(spread, 2)}


def structure_ratio(image, xy, half: int = 20) -> float:
    """Smaller over larger eigenvalue of the structure tensor in a (2 half + 1)^2 window
    at ``xy`` (0: an edge or flat, 1: a corner or blob)."""
    g = crop(image.astype(float), xy, half + 1)
    gy, gx = np.gradient(g)
    gx, gy = gx[1:-1, 1:-1], gy[1:-1, 1:-1]
    t = np.array([[np.sum(gx * gx), np.sum(gx * gy)], [np.sum(gx * gy), np.sum(gy * gy)]])
    ev = np.linalg.eigvalsh(t)
    return float(ev[0] / ev[1]) if ev[1] > 0 else 0.0


def coverage(records) -> dict:
    """Median residual of the held-out places inside and outside the adjusted places' hull,
    and nearer or farther than 50 px from the nearest adjusted place, in the camera (a
    camera with no adjusted place: every place outside and beyond)."""
    def near(r):
        return r["nearest_adjusted_place_px"] is not None and r["nearest_adjusted_place_px"] < 50

    out = {}
    for key, test in (("inside_hull", lambda r: r["inside_adjusted"]),
                      ("outside_hull", lambda r: not r["inside_adjusted"]),
                      ("adjusted_within_50_px", near),
                      ("adjusted_beyond_50_px", lambda r: not near(r))):
        px = [r["residual_px"] for r in records if test(r)]
        out[key] = {"places": len(px),
                    "median_px": round(float(np.median(px)), 3) if px else None}
    return out


def crops_of_worst(ref, videos, records, c, names, out, worst: int) -> list:
    """(b) for the ``worst`` largest residuals: a figure each (at most 3 frames)."""
    paths = []
    cache = {}
    for rank, rec in enumerate(sorted(records, key=lambda r: -r["residual_px"])[:worst]):
        per_frame = place_frames(ref, rec["place"])
        shown = sorted(per_frame)[:3]
        views = {}
        for f in shown:
            if f not in cache:
                cache[f] = videos.read(f)
            views[f] = (cache[f], per_frame[f])
        path = out / f"crops_{rank:02d}.png"
        crops_figure(path, shown, views, names, c, np.array(rec["residual_vector_px"]),
                     f"place {rec['place']}: {names[c]} residual {rec['residual_px']:.2f} px "
                     f"(views {', '.join(rec['views'])}; frames {rec['frames']})")
        paths.append(str(path))
    return paths


def lens_figure(path, lens, names) -> None:
    """(d) as bars: held-out still residual per camera for each lens choice."""
    runs = [k for k in lens if k != "refine_rig"]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    width = 0.8 / len(runs)
    for i, name in enumerate(runs):
        px = [np.nan if v is None else v for v in lens[name]["held_out_still_px"]]
        ax.bar(np.arange(len(names)) + i * width, px, width, label=name)
    ax.axhline(0.5, color="k", lw=0.8, ls="--")
    ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
    ax.set_ylabel("held-out still median, px")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def diagnose(ref, videos, c: int, out: Path, worst: int) -> dict:
    """Every figure and number of the module docstring for camera ``c``."""
    names = [cam.name or str(k) for k, cam in enumerate(ref.given)]
    sel = ref.held_out_places & ref.still
    train_sel = ~ref.held_out_places & ~ref.dropped_places & ~ref.unused_places \
        & ~ref.inconsistent_places
    held, train = ref.place_xy[:, sel], ref.place_xy[:, train_sel]
    if train.shape[1] > ref_max_points(ref):
        raise ValueError("more adjusted places than max_points: the re-runs would differ")
    dh, dt = residual_vectors(ref.cameras, held), residual_vectors(ref.cameras, train)
    dg = residual_vectors(ref.given, held)
    draw = residual_vectors(ref.cameras, ref.raw_place_xy[:, sel])
    pred = predicted(ref.cameras, held, c, [j for j in range(len(names)) if j != c])
    seen, tseen = np.isfinite(held[c, :, 0]), np.isfinite(train[c, :, 0])
    train_c = train[c, tseen]
    records = [per_place(ref, p, i, c, names, dh, dg, draw, pred, train_c)
               for i, p in enumerate(np.flatnonzero(sel)) if seen[i]]
    images = {}
    for rec in records:                     # the structure tensor, each view, first frame
        f = rec["frames"][0]
        images[f] = images[f] if f in images else videos.read(f)
        at = place_frames(ref, rec["place"])[f]
        rec["structure_ratio_min"] = round(min(
            structure_ratio(images[f][k], at[k]) for k in range(len(names))
            if np.isfinite(at[k]).all()), 3)
    out.mkdir(parents=True, exist_ok=True)
    frame0 = videos.read(int(ref.frames[0]))[c]
    quiver_figure(out / "quiver.png", frame0, names[c], (held[c, seen], dh[c, seen]),
                  (train_c, dt[c, tseen]), intrinsic_change(ref.given[c], ref.cameras[c]),
                  [r["place"] for r in records])
    lens, lens_cams = lens_runs(ref, train, held)
    for name, cams in lens_cams.items():                # (d) per place, this camera
        d = np.linalg.norm(residual_vectors(cams, held)[c, seen], axis=1)
        for rec, v in zip(records, d):
            rec.setdefault("residual_by_lens_px", {})[name] = round(float(v), 3)
    lens_figure(out / "lens.png", lens, names)
    return {
        "camera": names[c], "frames": list(ref.frames),
        "held_out_still_places": int(seen.sum()),
        "held_out_still_px": round(float(np.median(np.linalg.norm(dh[c, seen], axis=1))), 3),
        "adjusted_places": int(tseen.sum()),
        "adjusted_px": round(float(np.median(np.linalg.norm(dt[c, tseen], axis=1))), 3)
        if tseen.any() else None,
        "field": {"held_out": field_fit(ref.cameras[c], held[c, seen], dh[c, seen]),
                  "adjusted": field_fit(ref.cameras[c], train_c, dt[c, tseen])},
        "views_per_place": {str(v): int(n) for v, n in zip(*np.unique(
            np.isfinite(held[:, seen, 0]).sum(axis=0), return_counts=True))},
        "coverage": coverage(records),
        "near_pairs": near_pairs(records, names[c]),
        "by_pair": by_pair(ref.cameras, held, c, names),
        "by_pair_given": by_pair(ref.given, held, c, names),
        "refined_vs_given": moved(ref.given, ref.cameras),
        "lens": lens, "places": sorted(records, key=lambda r: -r["residual_px"]),
        "figures": {"quiver": str(out / "quiver.png"), "lens": str(out / "lens.png"),
                    "crops": crops_of_worst(ref, videos, records, c, names, out, worst)}}


def moved(given, refined) -> dict:
    """Per camera how far the refinement took it from the file's: principal distance (%),
    centre (mm) and rotation (degrees); a camera the tie points do not hold moves by about
    its prior's standard deviation (2 %, 50 mm, 1 degree), differently on each split."""
    out = {}
    for g, r in zip(given, refined):
        cos = (np.trace(np.asarray(r.R) @ np.asarray(g.R).T) - 1.0) / 2.0
        out[g.name] = {"f_percent": round(100.0 * (r.f / g.f - 1.0), 2),
                       "centre_mm": np.round(np.asarray(r.C) - np.asarray(g.C), 1).tolist(),
                       "turn_deg": round(float(np.degrees(np.arccos(np.clip(cos, -1, 1)))), 3)}
    return out


def ref_max_points(ref) -> int:
    """The refinement's ``max_points`` (the library's default: the experiment's settings)."""
    from lsmta.systems import RigRefinementParams
    return RigRefinementParams().max_points


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", default="cam03")
    parser.add_argument("--n-frames", type=positive_int, default=7)
    parser.add_argument("--still-between", type=positive_int, default=2)
    parser.add_argument("--tie", default="max_tilt=4")
    parser.add_argument("--worst", type=positive_int, default=10)
    parser.add_argument("--cache", default=None,
                        help="pickle of the RigRefinement (default: under build/cam03_diagnosis)")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    tie_settings(args.tie)                                      # a bad --tie fails here
    names = [cam.name or str(k) for k, cam in enumerate(read_camera_file(POSE2SIM_CAMERAS))]
    if args.camera not in names:
        parser.error(f"--camera: expected one of {names}, got {args.camera!r}")
    tag = f"n{args.n_frames}_sb{args.still_between}_{args.tie.replace('=', '-') or 'default'}"
    root = Path("build/cam03_diagnosis") / tag
    args.cache = args.cache or str(root / "refinement.pkl")
    out = Path(args.out) if args.out else root / args.camera
    try:
        ref = refinement(args)
    except ValueError as err:
        parser.error(str(err))
    names = [cam.name or str(k) for k, cam in enumerate(ref.given)]
    videos = read_videos(POSE2SIM_VIDEOS, frames=range(0, 100), scale=1.0)
    summary = diagnose(ref, videos, names.index(args.camera), out, args.worst)
    write_json(out / "summary.json", summary)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("places",)}, indent=1))


if __name__ == "__main__":
    main()
