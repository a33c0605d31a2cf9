"""Where the LSMTA system's walk points lose the body, stage by stage (issue 36), and the
trajectory filters for a walking person (:meth:`lsmta.systems.FilterParams.walking`)
against notebook 05's, on cached studio captures.

    .venv/bin/python experiments/walk_cover.py --captures PKL [PKL ...] [--note TEXT] [--out PATH]

Each ``PKL`` is a ``(session, capture, seconds)`` pickle as ``experiments/walk_full_fit.py
--cache DIR`` writes it (the studio walk, 8 frames at 768 x 576, surfaces every 2 frames,
40 seeds 25 px apart, notebook 05's filters). Three runs per capture: *before* (the cached
capture as run), *before, walking filters only* (its unfiltered trajectories through
:meth:`~lsmta.systems.FilterParams.walking`) and *after* (the stages after the calibration
run again, with the cached cameras, with :meth:`~lsmta.systems.BodySystemParams.walking`:
the walking filters and seeds 50 mm apart, up to 200). After the fact (truth: the system's
world carried onto the true one by the held-out bar's check points,
``lsmta.evaluation.walk_system.check_alignment``) every stage's points are scored against
the generator's skin: per body part, the share of the seen outer skin samples (seen by two
cameras of one view group; 400 samples per part and frame) with no point within 15 mm
(uncovered), for the surfaces of the measured frames, the tracked (unfiltered) points and
the points after each filter; then the points' distance to the skin, the both-ways medians
of :func:`lsmta.evaluation.walk_system.score_walk`, and the times of the stages after the
calibration with both settings, run here one after the other (wall and CPU; the cached
run's wall times as recorded then beside them). Writes ``--out`` (default
``build/benchmarks/walk_cover.json``).
"""

from __future__ import annotations

import argparse
import pickle
import platform
import sys
import time
from dataclasses import asdict, replace
from datetime import date

import numpy as np

COVER_MM = 15.0
SEEN_IN = ("aligned on the true check points (held-out bar); the seen side: true skin "
           "samples seen by two cameras of one view group (true cameras, true visibility); "
           "scored after the fact")


def _world_points(xyz, al):
    x = xyz[np.isfinite(xyz).all(axis=-1)]
    return x @ al.R.T + al.t


def _uncovered(stage_points, frames, seen, names, part):
    """Per part and overall: the share of seen skin samples with no point within COVER_MM,
    pooled over ``frames``."""
    from scipy.spatial import cKDTree

    far = {n: [] for n in names}
    pooled = []
    for i in frames:
        world, s = seen[i]
        p = stage_points[i]
        d = cKDTree(p).query(world[s])[0] if len(p) else np.full(int(s.sum()), np.inf)
        pooled.append(d > COVER_MM)
        for k, n in enumerate(names):
            far[n].append(d[part[s] == k] > COVER_MM)
    out = {n: round(float(np.mean(np.concatenate(v))), 3) for n, v in far.items()
           if len(np.concatenate(v))}
    out["all"] = round(float(np.mean(np.concatenate(pooled))), 3)
    return out


def _seen(session, cap, al, rng):
    """Per processed frame: true skin samples (outer) and whether a view group sees them."""
    from lsmta.synth.body import inside_parts
    from lsmta.synth.render import project_surface_points

    body, frames = session.scene.body, np.asarray(cap.frames)
    part, local = body.sample_surface(n_per_part=400, rng=rng)
    proj = project_surface_points(session.scene, session.cameras, part, local, frames=frames)
    poses = body.part_poses(session.scene.motion, frames=frames)
    out = []
    for i in range(len(frames)):
        outer = ~inside_parts(body, poses[i], proj.world[i], exclude=part)
        s = np.zeros(len(part), bool)
        for v in cap.views:
            s |= proj.visible[i][np.asarray(v.group.cameras)].sum(axis=0) >= 2
        out.append((proj.world[i], s & outer))
    return out, part, poses


def stage_table(session, cap, al, seen, part, poses, seed, filters) -> dict:
    """One capture's stages scored: uncovered shares per stage (the surfaces of the
    measured frames, the tracked points, after each filter with ``filters`` run again on its
    unfiltered trajectories), the surfaces' seeds, accuracy, the filters' CPU time."""
    from lsmta.evaluation import walk_system as ws
    from lsmta.synth.surface import distance_to_body
    from lsmta.tracking import apply_filters

    body, T = session.scene.body, len(cap.frames)
    dens = sorted(cap.views[0].surfaces)
    surf = [[] for _ in range(T)]
    seeds = []
    for g, v in enumerate(cap.views):
        for f, r in v.surfaces.items():
            ok = r.neighbourhood_ok & r.intersection.valid
            surf[f].append(_world_points(r.intersection.points[ok], al))
            seeds.append({"group": g, "frame": int(f),
                          "seeds": [int(len(x.seeds_matched)) for x in r.grown],
                          "seeds_matched": [int(x.seeds_matched.sum()) for x in r.grown],
                          "kept": int(ok.sum())})
    surf = [np.concatenate(s) if s else np.zeros((0, 3)) for s in surf]
    raw = [_world_points(cap.trajectories.xyz[i], al) for i in range(T)]
    table = {"surfaces (measured frames)": _uncovered(surf, dens, seen, body.names, part),
             "tracked, unfiltered": _uncovered(raw, range(T), seen, body.names, part)}
    t0 = time.process_time()
    reps = apply_filters(cap.trajectories, **asdict(filters))
    cpu = time.process_time() - t0
    for k, name in enumerate(("threshold", "uniformity", "drift")):
        pts = [_world_points(reps[k].trajectories.xyz[i], al) for i in range(T)]
        table[f"after the {name} filter"] = _uncovered(pts, range(T), seen, body.names, part)
    c = replace(cap, filters=reps)
    d = np.concatenate([np.abs(distance_to_body(body, poses[i], _world_points(
        c.filtered.xyz[i], al))) for i in range(T)])
    s = ws.score_walk(c, session, al, rng=seed).summary()
    alive = [[int(n) for n in np.isfinite(v.tracks.xy[:, 0, :, 0]).sum(axis=1)]
             for v in cap.views]
    return {"filters": asdict(filters), "filters_cpu_s": round(cpu, 3),
            "surfaces": seeds, "tracks_alive_per_group_and_frame": alive,
            "removed_by_reason": [r.summary() for r in reps],
            "uncovered_share": table,
            "points_per_frame_median": s["points_per_frame_median"],
            "points_to_true_skin_median_mm": round(float(np.median(d)), 3),
            "points_to_true_skin_q90_mm": round(float(np.percentile(d, 90)), 3),
            "points_over_10mm_share": round(float(np.mean(d > 10)), 4),
            "score_walk_to_truth_median_mm": s["to_truth_median_mm"],
            "score_walk_seen_skin_to_point_median_mm": s["from_truth_median_mm"],
            "segments_covered_median": s["segments_covered_median"]}


def one_capture(path: str, seed: int) -> dict:
    """Before (the cached capture as run), its trajectories with the walking filters, and
    after (the stages after the calibration run again with
    :meth:`~lsmta.systems.BodySystemParams.walking`, the cached cameras, surfaces every 2
    frames as before)."""
    import numba

    from lsmta.evaluation import walk_system as ws
    from lsmta.systems import BodySystemParams, FilterParams
    from lsmta.systems.capture import capture_recording

    numba.set_num_threads(1)
    with open(path, "rb") as f:
        session, cap, _ = pickle.load(f)
    al, _ = ws.check_alignment(cap.cameras, session)
    seen, part, poses = _seen(session, cap, al, np.random.default_rng(seed))
    params = replace(BodySystemParams.walking(), density_every=cap.params.density_every)
    times = {}
    for label, p in (("before", cap.params), ("after", params.capture())):
        t0, c0 = time.perf_counter(), time.process_time()
        again = capture_recording(session.videos, cap.cameras, fps=session.fps,
                                  calibration=cap.calibration, params=p, progress=False,
                                  seed=seed)
        times[label] = {"wall_s": round(time.perf_counter() - t0, 2),
                        "cpu_s": round(time.process_time() - c0, 2),
                        "stages_wall_s": {k: round(float(v), 2)
                                          for k, v in again.seconds.items()}}
    after = again
    args = (session, al, seen, part, poses, seed)
    runs = {"before (as cached: notebook 05's filters, seeds 25 px apart, 40)":
            stage_table(session, cap, *args[1:], FilterParams()),
            "before, walking filters only": stage_table(session, cap, *args[1:],
                                                        FilterParams.walking()),
            "after (BodySystemParams.walking())": stage_table(session, after, *args[1:],
                                                              FilterParams.walking())}
    return {"capture": path, "frames": [int(f) for f in cap.frames],
            "measured_frames": sorted(cap.views[0].surfaces),
            "stage_seconds_wall_as_cached": {k: round(float(v), 2)
                                             for k, v in cap.seconds.items()},
            "stages_after_calibration_run_here": times, "runs": runs}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--captures", nargs="+", required=True)
    parser.add_argument("--seeds", nargs="+", type=int, default=None,
                        help="the skin samples' rng per capture (default 36, 37, ...)")
    parser.add_argument("--note", default="", help="e.g. the machine's load")
    parser.add_argument("--out", default="build/benchmarks/walk_cover.json")
    args = parser.parse_args(argv)
    from lsmta.report import write_json

    seeds = args.seeds or [36 + i for i in range(len(args.captures))]
    out = {"command": "python experiments/walk_cover.py " + " ".join(
               sys.argv[1:] if argv is None else argv),
           "date": date.today().isoformat(), "machine": platform.machine(), "note": args.note,
           "truth": SEEN_IN, "cover_mm": COVER_MM, "captures": []}
    for path, seed in zip(args.captures, seeds):
        r = one_capture(path, seed)
        out["captures"].append(r)
        print(path, r["stages_after_calibration_run_here"])
        for label, run in r["runs"].items():
            print(label)
            for stage, v in run["uncovered_share"].items():
                print(f"  {stage:30s} " + " ".join(f"{k}={v[k]:.2f}" for k in
                                                  ("shank_r", "foot_r", "forearm_l",
                                                   "hand_l", "head", "all") if k in v))
            print("  ", {k: v for k, v in run.items() if isinstance(v, float | int)})
    write_json(args.out, out)


if __name__ == "__main__":
    main()
