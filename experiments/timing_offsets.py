"""Are the demo's views offset in time? Residuals against image motion (issue #40).

    .venv/bin/python experiments/timing_offsets.py [--scale 1.0] [--frames 0:100]
        [--out build/benchmarks/timing_offsets.json] [--cache build/cache]
        [--min-speed 1.0]

Refines the Pose2Sim demo's cameras from the recording as ``lsmta capture`` does
(`lsmta.systems.refine_rig`, cached with the velocities per scale and frames under
``--cache``), measures each tie point's image velocity in every view (OpenCV's dense
Farneback flow between the frames before and after it, px per frame) and asks whether the
residuals are those of a timing error. A view k that samples the scene ``d_k`` frames late
sees a point moving at image velocity ``v`` displaced by ``v d_k``; with a rolling shutter
whose rows are read ``rho_k`` frames apart (relative to the frame's middle row ``y0``) the
delay of row y is ``d_k + rho_k (y - y0)``. Times are printed in ms at the recording's
frame rate, line delays in microseconds per row.

1. Tie points moving at ``--min-speed`` px per frame (full size) or more, per camera: the
   residual vectors (measured - reprojected, triangulated from all their views) regressed
   on ``v`` (apparent offset, through 0) and on ``v`` and ``v (y - y0)``; standard errors
   from the regression's scatter, and the share of the residuals' sum of squares explained.
   These are apparent offsets: the triangulation moves with the offsets.
2. Jointly (``joint_*``): ``d_k`` (first camera 0, the time datum) and optionally ``rho_k``
   fitted to those points with each re-triangulated from its observations moved back by
   ``v d_k`` (Cauchy loss at 0.5 px full size), and the same on the still tie points
   (below 0.1 px per frame), which must give none.
3. The held-out places ``refine_rig`` judges by, split into still places, one-frame places
   that do not move (< 0.1 px per frame) with the views that hold them, and moving ones
   (>= 0.5 px per frame): which of them make each camera's judged residual.
4. The adjustment of ``refine_rig`` run again with the places' velocities
   (``refine_cameras(..., velocities=...)``): the offsets its z-test frees.
5. The moving markers (``lsmta.systems.capture_markers`` with the refined cameras, every
   frame, raw intersections, no filter; velocities from their tracks): the same
   regression, and per camera pair the
   second camera's offset fitted with the points re-triangulated from the two views.
   Each marker is seen by two views only, so only offsets within a pair are determined;
   its standard error assumes independent frames (a track's errors are not: too small).
Everything is written to ``--out``; the README's numbers come from that file.
"""

from __future__ import annotations

import argparse
import pickle
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from tie_point_motion import velocities  # this folder's experiment: the same image velocities

from lsmta.calibration import refine_cameras
from lsmta.camera_files import read_camera_file
from lsmta.data import POSE2SIM_CAMERAS, POSE2SIM_VIDEOS
from lsmta.io import read_videos
from lsmta.report import write_json
from lsmta.systems import MarkerParams, RigRefinementParams, capture_markers, refine_rig
from lsmta.triangulation import triangulate


def residual_vectors(cameras, xy) -> np.ndarray:
    """(K, N, 2) measured - reprojected, points triangulated from all their views."""
    X = np.asarray(triangulate(list(cameras), xy, min_angle_deg=0.0).points)
    out = np.full(xy.shape, np.nan)
    ok = np.isfinite(X).all(axis=1)
    for k, c in enumerate(cameras):
        m = ok & np.isfinite(xy[k, :, 0])
        if m.any():
            out[k, m] = xy[k, m] - c.project(X[m], behind="nan")
    return out


def regress(r, v, y, y0):
    """Per camera: slope of r on v (and on v, v (y - y0)), standard errors, explained share."""
    out = []
    for k in range(len(r)):
        m = np.isfinite(r[k, :, 0]) & np.isfinite(v[k, :, 0])
        rr, vv, yy = r[k, m].ravel(), v[k, m].ravel(), np.repeat(y[k, m] - y0[k], 2)
        row = {"points": int(m.sum())}
        for name, A in (("offset", vv[:, None]), ("offset_line", np.c_[vv, vv * yy])):
            coef, *_ = np.linalg.lstsq(A, rr, rcond=None)
            e = rr - A @ coef
            s2 = e @ e / max(1, len(rr) - A.shape[1])
            se = np.sqrt(np.diag(s2 * np.linalg.pinv(A.T @ A)))
            row[name] = {"coef": coef.tolist(), "se": se.tolist(),
                         "explained": float(1 - e @ e / (rr @ rr)) if len(rr) else None}
        out.append(row)
    return out


def joint_fit(cameras, xy, v, y, y0, line: bool, f_scale: float):
    """Offsets d_k (k >= 1; d_0 = 0) and optionally line delays rho_k fitted with every point
    re-triangulated from its observations moved back by v (d_k + rho_k (y - y0)); Cauchy
    loss bending at ``f_scale`` px (a marker track's jump or a wrong tie point gets no
    pull). Standard errors: the robust scale of the coordinates' residuals (1.4826 MAD)
    times the covariance of the loss-weighted Jacobian (independent observations assumed:
    along a marker's track they are not, so these are too small there)."""
    K = len(xy)
    n = (K - 1) + (K if line else 0)
    moved = np.isfinite(v[..., 0])
    v = np.where(moved[..., None], v, 0.0)

    def shifted(p):
        d = np.r_[0.0, p[:K - 1]]
        rho = p[K - 1:] if line else np.zeros(K)
        dt = d[:, None] + rho[:, None] * (y - y0[:, None])
        return xy - v * dt[..., None]

    def fun(p):
        r = residual_vectors(cameras, shifted(p))
        return np.nan_to_num(r).ravel()

    sol = least_squares(fun, np.zeros(n), diff_step=1e-3, loss="cauchy", f_scale=f_scale)
    J = sol.jac
    s = 1.4826 * np.median(np.abs(sol.fun[sol.fun != 0]))
    se = s * np.sqrt(np.diag(np.linalg.pinv(J.T @ J)))
    r0 = np.linalg.norm(residual_vectors(cameras, xy), axis=2)
    r1 = np.linalg.norm(residual_vectors(cameras, shifted(sol.x)), axis=2)

    def med(a):
        return [float(np.nanmedian(row)) for row in a]

    return {"params": sol.x.tolist(), "se": se.tolist(), "median_before_px": med(r0),
            "median_after_px": med(r1)}


def held_out_by_speed(ref, speed, slow: float, fast: float) -> dict:
    """Median residual per camera (refined cameras) of the held-out places: still (found in
    several frames), one-frame places that do not move (speed < ``slow``) and that move
    (speed >= ``fast``), px; a place's speed is the largest of its tie points'."""
    psp = np.zeros(len(ref.still))
    np.maximum.at(psp, ref.places, np.nan_to_num(speed))
    held, out = ref.held_out_places, {}
    for name, sel in (("still", held & ref.still),
                      ("one_frame_slow", held & ~ref.still & (psp < slow)),
                      ("one_frame_moving", held & ~ref.still & (psp >= fast))):
        xy = ref.place_xy[:, sel]
        e = triangulate(list(ref.cameras), xy, min_angle_deg=0.0).reprojection_error
        out[name] = {"places": int(sel.sum()),
                     "per_camera": np.isfinite(xy[..., 0]).sum(axis=1).tolist(),
                     "refined_px": [float(np.nanmedian(r)) if np.isfinite(r).any() else None
                                    for r in e]}
        if name == "one_frame_slow":             # which views hold them
            views = [tuple(np.flatnonzero(c).tolist()) for c in np.isfinite(xy[..., 0]).T]
            out[name]["by_views"] = {
                "-".join(ref.cameras[k].name for k in vs): {
                    "places": int(sum(w == vs for w in views)),
                    "refined_px": [float(np.nanmedian(e[k, [w == vs for w in views]]))
                                   for k in vs]}
                for vs in sorted(set(views))}
    return out


def marker_observations(args, videos, ref):
    """The moving markers' tracked positions (``lsmta.systems.capture_markers`` with the
    refined cameras, cached) and their velocities (central differences of the tracks, px per
    frame), frames 1..T-2 as points: two (K, N, 2) arrays, and the (N,) marker of each."""
    path = Path(args.cache) / f"timing_markers_{args.scale}_{args.frames.replace(':', '-')}.pkl"
    if path.exists():
        mc = pickle.loads(path.read_bytes())
    else:
        stacks = videos.load(progress=False)
        mc = capture_markers(stacks, ref.cameras, videos.read(0, colour=True),
                             params=MarkerParams(sigma=2.5 * args.scale, max_px=4.0 * args.scale))
        path.write_bytes(pickle.dumps(mc))
    xy = mc.xy[:, :, mc.moving]                                   # (T, K, M, 2)
    vel = np.full_like(xy, np.nan)
    vel[1:-1] = (xy[2:] - xy[:-2]) / 2.0
    K = xy.shape[1]
    obs = xy[1:-1].transpose(1, 0, 2, 3).reshape(K, -1, 2)
    v = vel[1:-1].transpose(1, 0, 2, 3).reshape(K, -1, 2)
    obs = np.where(np.isfinite(v), obs, np.nan)
    keep = np.isfinite(obs[..., 0]).sum(axis=0) >= 2
    marker = np.tile(np.arange(xy.shape[2]), xy.shape[0] - 2)
    return obs[:, keep], v[:, keep], marker[keep]


def pair_offsets(cameras, obs, v, marker, ms: float, f_scale: float) -> dict:
    """Per camera pair that shares points: the second camera's offset relative to the first
    (fitted with the points re-triangulated from those two views), ms, its standard error,
    and the pair's median residuals before and after."""
    out = {}
    K = len(cameras)
    for a in range(K):
        for b in range(a + 1, K):
            sel = np.isfinite(obs[a, :, 0]) & np.isfinite(obs[b, :, 0])
            if sel.sum() < 10:
                continue
            xy = obs[[a, b]][:, sel]
            vv = v[[a, b]][:, sel]
            j = joint_fit([cameras[a], cameras[b]], xy, vv, xy[..., 1], np.zeros(2), False,
                          f_scale)
            out[f"{cameras[a].name}-{cameras[b].name}"] = {
                "points": int(sel.sum()), "markers": int(len(np.unique(marker[sel]))),
                "offset_ms": j["params"][0] * ms,
                "se_ms": j["se"][0] * ms, "median_before_px": j["median_before_px"],
                "median_after_px": j["median_after_px"]}
    return out


def offsets_in_the_adjustment(ref, vel) -> dict:
    """The refinement's own adjustment run again with the tie points' velocities
    (``refine_cameras(..., velocities=...)``, on the places ``refine_rig`` adjusted, each
    place's velocity the median of its tie points'): which time offsets its z-test frees,
    and whether the cameras are then those ``refine_rig`` found."""
    labels = np.unique(ref.places, return_inverse=True)[1]
    pv = np.full(ref.place_xy.shape, np.nan)
    for p in range(pv.shape[1]):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            pv[:, p] = np.nanmedian(vel[:, labels == p], axis=1)
    train = ~ref.held_out_places & ~ref.dropped_places
    t0 = time.process_time()
    r = refine_cameras(ref.given, ref.place_xy[:, train], velocities=pv[:, train])
    same = all(np.array_equal(a.R, b.R) and np.array_equal(a.C, b.C) and a.f == b.f
               for a, b in zip(r.cameras, ref.adjustment.cameras))
    return {"places": int(train.sum()), "time_offsets_frames": r.time_offsets.tolist(),
            "offset_z": [None if not np.isfinite(z) else float(z) for z in r.offset_z],
            "freed": r.offsets_freed.tolist(), "same_cameras_as_refine_rig": bool(same),
            "cpu_seconds": time.process_time() - t0}


def cached_refinement(args, videos):
    path = Path(args.cache) / f"timing_refine_{args.scale}_{args.frames.replace(':', '-')}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    t0 = time.process_time()
    ref = refine_rig(videos, read_camera_file(POSE2SIM_CAMERAS),
                     params=RigRefinementParams(mismatch="crop"))
    print(f"refine_rig: {time.process_time() - t0:.0f} s CPU")
    picks = [int(np.flatnonzero(np.asarray(videos.frames) == f)[0]) for f in ref.frames]
    vel = velocities(videos, picks, ref.tie_points.xy, ref.tie_points.frame)
    out = {"ref": ref, "vel": vel}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(out))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--frames", default="0:100")
    parser.add_argument("--out", default="build/benchmarks/timing_offsets.json")
    parser.add_argument("--cache", default="build/cache")
    parser.add_argument("--min-speed", type=float, default=1.0,
                        help="moving: image speed at least this, px per frame at full size")
    args = parser.parse_args(argv)
    start, stop = (int(x) for x in args.frames.split(":"))
    videos = read_videos(POSE2SIM_VIDEOS, frames=range(start, stop), scale=args.scale)
    c = cached_refinement(args, videos)
    ref, vel = c["ref"], c["vel"]
    xy = ref.tie_points.xy
    speed = np.nanmax(np.hypot(vel[..., 0], vel[..., 1]), axis=0)
    moving = speed >= args.min_speed * args.scale
    still = speed < 0.1 * args.scale
    y0 = np.array([c.height / 2.0 for c in ref.cameras])
    ms = 1000.0 / videos.fps
    f_scale = 0.5 * args.scale                     # the robust fits' bend: 0.5 px full size
    record = {"scale": args.scale, "frames": args.frames, "fps": videos.fps,
              "tie_points": int(xy.shape[1]), "moving": int(moving.sum()),
              "still": int(still.sum()), "cameras": {}}
    for name, cams in (("refined", ref.cameras), ("given", ref.given)):
        rec = {}
        r = residual_vectors(cams, xy[:, moving])
        rec["regression_moving"] = regress(r, vel[:, moving], xy[:, moving, 1], y0)
        for kind, sel in (("moving", moving), ("still", still)):
            for line in (False, True):
                rec[f"joint_{kind}{'_line' if line else ''}"] = joint_fit(
                    cams, xy[:, sel], vel[:, sel], xy[:, sel, 1], y0, line, f_scale)
        record["cameras"][name] = rec
        print(f"--- {name} cameras, {int(moving.sum())} moving tie points "
              f"(>= {args.min_speed} px/frame full size)")
        for k, row in enumerate(rec["regression_moving"]):
            o, ol = row["offset"], row["offset_line"]
            print(f"cam{k + 1}: n={row['points']:4d}  apparent offset {o['coef'][0] * ms:6.2f} "
                  f"+- {o['se'][0] * ms:.2f} ms, explains {o['explained']:.1%};  with line "
                  f"delay: {ol['coef'][0] * ms:6.2f} ms, rho {ol['coef'][1] * ms * 1e3:.2f} "
                  f"+- {ol['se'][1] * ms * 1e3:.2f} us/row, explains {ol['explained']:.1%}")
        for key in ("joint_moving", "joint_moving_line", "joint_still"):
            j = rec[key]
            print(f"{key}: d = {np.round(np.array(j['params'][:3]) * ms, 2).tolist()} ms "
                  f"+- {np.round(np.array(j['se'][:3]) * ms, 2).tolist()}; median px "
                  f"{np.round(j['median_before_px'], 2).tolist()} -> "
                  f"{np.round(j['median_after_px'], 2).tolist()}")
            if key.endswith("line"):
                print(f"   rho = {np.round(np.array(j['params'][3:]) * ms * 1e3, 2).tolist()} "
                      f"us/row +- {np.round(np.array(j['se'][3:]) * ms * 1e3, 2).tolist()}")
    record["held_out_by_speed"] = held_out_by_speed(ref, speed, 0.1 * args.scale,
                                                    0.5 * args.scale)
    print("held-out places by speed (refined cameras):")
    for name, row in record["held_out_by_speed"].items():
        print(f"  {name}: {row['places']} places {row['per_camera']} per camera, "
              f"{[None if x is None else round(x, 2) for x in row['refined_px']]} px")
        for vs, sub in row.get("by_views", {}).items():
            print(f"    seen by {vs}: {sub['places']}, "
                  f"{np.round(sub['refined_px'], 2).tolist()} px")
    record["adjustment_with_velocities"] = adj = offsets_in_the_adjustment(ref, vel)
    print(f"the adjustment with the tie points' velocities ({adj['places']} places): "
          f"z = {adj['offset_z']}, freed {adj['freed']}, same cameras as refine_rig: "
          f"{adj['same_cameras_as_refine_rig']} ({adj['cpu_seconds']:.1f} s CPU)")
    obs, v, marker = marker_observations(args, videos, ref)
    y0 = np.array([c.height / 2.0 for c in ref.cameras])
    markers = {"observations": int(obs.shape[1]),
               "per_camera": np.isfinite(obs[..., 0]).sum(axis=1).tolist(),
               "median_speed_px_per_frame": float(np.nanmedian(np.hypot(v[..., 0], v[..., 1])))}
    for name, cams in (("refined", ref.cameras), ("given", ref.given)):
        r = residual_vectors(cams, obs)
        markers[name] = {
            "median_px": np.nanmedian(np.linalg.norm(r, axis=2), axis=1).tolist(),
            "regression": regress(r, v, obs[..., 1], y0),
            "pairs": pair_offsets(cams, obs, v, marker, ms, f_scale)}
    record["markers"] = markers
    print(f"moving markers' tracks: {markers['observations']} points (frames x markers), "
          f"{markers['per_camera']} per camera, median speed "
          f"{markers['median_speed_px_per_frame']:.2f} px/frame")
    for name in ("refined", "given"):
        m = markers[name]
        print(f"  {name}: median residual {np.round(m['median_px'], 2).tolist()} px")
        for k, row in enumerate(m["regression"]):
            o = row["offset"]
            print(f"    cam{k + 1}: apparent offset {o['coef'][0] * ms:6.2f} +- "
                  f"{o['se'][0] * ms:.2f} ms, explains {o['explained']:.1%}; with line delay "
                  f"explains {row['offset_line']['explained']:.1%}")
        for pair, p in m["pairs"].items():
            print(f"    pair {pair}: {p['points']} points of {p['markers']} markers, offset "
                  f"{p['offset_ms']:.2f} +- {p['se_ms']:.2f} ms, median px "
                  f"{np.round(p['median_before_px'], 2).tolist()} -> "
                  f"{np.round(p['median_after_px'], 2).tolist()}")
    write_json(args.out, record)


if __name__ == "__main__":
    main()
