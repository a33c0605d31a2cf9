"""Functional joints from the generated range-of-motion clip against the walk: the centre of
every joint, the segment lengths between found centres, and what each movement identifies.

    .venv/bin/python experiments/range_of_motion.py [--frames 200] [--walk-frames 50]
        [--points 100] [--noise 1.0] [--seed 1] [--views all_round front]

A CONTROLLED STUDY ON THE GENERATOR'S POINTS (truth inputs, on purpose): each part's
measured points are ``--points`` points of the generator's surface followed through the
motion by their identity, with ``--noise`` mm of Gaussian noise per coordinate, missing
where inside another part and, for the ``front`` view, where fewer than two of the papers'
three cameras see them (ray-cast occlusion). The system's own surface points are issue 36's
item 1, not this study. From those points alone the library fits each segment's rigid
motion and every joint (SCoRE for a centre, SARA's axis for a hinge;
:mod:`lsmta.body.functional_joints`); the truth (true joint positions, true segment
lengths) is compared after the fact. For each view: per joint the status, determinacy,
centre error (RMS over frames, mm) on the whole clip and on the walk; per segment length the
error (%); per movement the joints it identifies from its frames alone. Writes
``build/benchmarks/range_of_motion.json``.
"""

from __future__ import annotations

import argparse
import time

from lsmta.evaluation import range_of_motion as erom
from lsmta.report import write_json
from lsmta.synth.body import make_body, range_of_motion, walk
from lsmta.synth.rigs import triplet_rig

TRUTH = ("generator surface points followed by identity (controlled study: truth inputs), "
         "{noise:g} mm noise, {points} points per part, {view}; scored against the true joints "
         "and lengths")


def _study(body, motion, *, view: str, args) -> dict:
    t0 = time.perf_counter()
    data = erom.segment_points(body, motion, n_per_part=args.points, noise_mm=args.noise,
                               cameras=triplet_rig() if view == "front" else None,
                               rng=args.seed + 1)
    motions = erom.segment_motions(data)
    joints = erom.fit_joints(motions)
    out = {"frames": motion.n_frames, "seen_share": data.seen,
           "joints": erom.joint_scores(joints, body, motion),
           "lengths": erom.length_scores(joints, body),
           "centres": sorted(erom.identified(joints)),
           "axes": sorted(erom.identified(joints, status=erom.JointStatus.AXIS))}
    if motion.phases:
        out["movements"] = erom.movement_table(motions, motion)
    out["seconds"] = time.perf_counter() - t0
    return out


def _summary(res: dict) -> dict:
    major = [res["joints"][k]["centre_error_rms_mm"] for k in erom.MAJOR
             if k in res["joints"] and res["joints"][k]["status"] == "CENTRE"]
    lengths = [abs(v["error_pct"]) for v in res["lengths"].values() if v["error_pct"] is not None]
    return {"centres_found": len(res["centres"]),
            "major_centres_found": sum(k in res["centres"] for k in erom.MAJOR),
            "worst_major_centre_error_mm": max(major) if major else None,
            "worst_length_error_pct": max(lengths) if lengths else None,
            "lengths_missing": sum(v["found_mm"] is None for v in res["lengths"].values())}


def _print(view: str, name: str, res: dict) -> None:
    print(f"\n== {view}: {name} ({res['frames']} frames, {res['seen_share']:.0%} of the points "
          f"seen, {res['seconds']:.1f} s)")
    for k, v in res["joints"].items():
        if v["status"] == "NOT_SEEN":
            print(f"  {k:11s} NOT_SEEN (its segments share fewer than 3 posed frames)")
            continue
        err = v["centre_error_rms_mm"]
        print(f"  {k:11s} {v['status']:12s} determinacy {v['determinacy']:.3f}  centre sd "
              f"{v['centre_sd_mm']:7.1f} mm  error {'-' if err is None else f'{err:.1f}'} mm")
    for k, v in res["lengths"].items():
        e = v["error_pct"]
        found = "-" if e is None else f"{v['found_mm']:.1f} mm ({e:+.2f} %)"
        print(f"  {k:15s} true {v['true_mm']:5.0f} mm  found {found}")
    for phase, joints in res.get("movements", {}).items():
        got = [k for k, j in joints.items() if j["status"] == "CENTRE"]
        ax = [k for k, j in joints.items() if j["status"] == "AXIS"]
        print(f"  {phase:13s} centres: {', '.join(got) or '-'}; axes only: {', '.join(ax) or '-'}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--walk-frames", type=int, default=50)
    parser.add_argument("--points", type=int, default=100)
    parser.add_argument("--noise", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--views", nargs="+", default=["all_round", "front"],
                        choices=["all_round", "front"])
    parser.add_argument("--out", default="build/benchmarks/range_of_motion.json")
    args = parser.parse_args(argv)
    body = make_body(rng=args.seed)
    clip, gait = range_of_motion(n_frames=args.frames), walk(n_frames=args.walk_frames)
    out = {"settings": vars(args) | {"phases": [list(p) for p in clip.phases]}, "views": {}}
    for view in args.views:
        res = {"range_of_motion": _study(body, clip, view=view, args=args),
               "walk": _study(body, gait, view=view, args=args)}
        for name, r in res.items():
            _print(view, name, r)
            r["summary"] = _summary(r)
            print(f"  summary: {r['summary']}")
        res["truth"] = TRUTH.format(noise=args.noise, points=args.points,
                                    view="all round" if view == "all_round"
                                    else "seen by >= 2 of the triplet rig's cameras")
        out["views"][view] = res
    write_json(args.out, out)


if __name__ == "__main__":
    main()
