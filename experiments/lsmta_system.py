"""The LSMTA system from pixels on a longer, full-size arm wave: time per stage and error budget.

    .venv/bin/python experiments/lsmta_system.py [--frames 46] [--first 4]
        [--width 768 --height 576] [--every 4] [--seed 1998] [--no-truth-fed]

Renders the arm-wave session of notebook 14 (`lsmta.evaluation.body_system.arm_wave_session`)
with the whole 768 x 576 sensor by default, runs `lsmta.systems.capture_body` on it (nothing
of the truth goes in), then scores every stage after the fact and, unless ``--no-truth-fed``,
runs each stage fed with the truth as notebooks 01-07 do. Prints and writes
``build/benchmarks/lsmta_system.json``: per-stage wall times of the system, the
calibration's check points and residual ratio, the first frame's surface, the trajectories'
error at the last frame and the arm's joint angles and bone lengths, each next to its
truth-fed twin. The target for the whole sequence: the system under five minutes on two
cores.
"""

from __future__ import annotations

import argparse
import time

from lsmta.evaluation import body_system as bs
from lsmta.evaluation.surface import score_surface
from lsmta.report import write_json
from lsmta.systems import capture_body


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=46)
    parser.add_argument("--first", type=int, default=4)
    parser.add_argument("--width", type=int, default=768)
    parser.add_argument("--height", type=int, default=576)
    parser.add_argument("--every", type=int, default=4, help="density check, frames")
    parser.add_argument("--seed", type=int, default=1998)
    parser.add_argument("--no-truth-fed", action="store_true")
    parser.add_argument("--out", default="build/benchmarks/lsmta_system.json")
    args = parser.parse_args(argv)

    t0 = time.perf_counter()
    session = bs.arm_wave_session(seed=args.seed, n_frames=args.frames, first=args.first,
                                  every=args.every,
                                  params=bs.ArmWaveSessionParams(roi=(args.width, args.height)))
    render_s = time.perf_counter() - t0
    print(f"rendered {args.frames} frames of {args.width} x {args.height} px in {render_s:.0f} s")
    cap = capture_body(session.videos, session.bar_videos, session.bar_length, session.nominal,
                       fps=session.fps, seed=args.seed)
    total = sum(cap.seconds.values())
    for r in cap.summary():
        print(f"{r['stage']:<13} {r['seconds']:7.1f} s  {r['result']}")
    print(f"system total {total:.0f} s (target < 300 s)")

    al = bs.world_alignment(cap.cameras, session)
    cal = bs.calibration_scores(cap.cameras, session)
    truth0 = bs.surface_truth(session, 0)
    surf = bs.score_system_surface(cap.surfaces[0], truth0, al)
    score, part, _ = bs.score_system_tracks(session, cap.tracks, cap.filtered, alignment=al)
    last, n_last = bs.last_frame_error(score, cap.filtered.present)
    truth = bs.session_arm_truth(session)
    arm = {n: bs.score_arm(f, cap.arm.start.torso_poses, truth, frames=cap.arm.frames,
                           alignment=al)
           for n, f in (("simplified", cap.arm.simplified), ("full", cap.arm.full))}
    out = {
        "frames": args.frames, "first": args.first, "image_size": [args.width, args.height],
        "render_s": render_s, "system_s": total, "stage_s": cap.seconds,
        "calibration": {"rms_over_limit": cap.calibration.rms_over_limit,
                        "check_rms_mm": cal["check_rms"],
                        "swapped_labels": cap.calibration.labels.n_swapped},
        "noise_sigma": cap.noise.sigma,
        "surface": {"density": surf["density"], "median_mm": surf["filtered"]["median_mm"]},
        "trajectories": {"last_frame_median_mm": last, "n": n_last},
        "groups": bs.group_parts(session, cap.arm.start.groups, part),
        "arm_frames": len(cap.arm.frames),
        "arm": {n: {"max_angle_deg": s["max_angle_err_deg"],
                    "joint_max_deg": s["joint_max_deg"].tolist(),
                    "length_err_pct": s["length_err_pct"].tolist()} for n, s in arm.items()},
    }
    print(f"calibration: RMS / noise limit {cap.calibration.rms_over_limit:.3f}, check points "
          f"{cal['check_rms']:.3f} mm; noise {cap.noise.sigma:.2f}")
    print(f"surface frame 0: density {surf['density']:.3f}, median "
          f"{surf['filtered']['median_mm']:.3f} mm; trajectories at the last frame "
          f"{last:.2f} mm ({n_last})")
    print(f"arm fitted in {len(cap.arm.frames)} of {args.frames} frames (both segments tracked)")
    for n, s in arm.items():
        print(f"arm {n}: worst angle {s['max_angle_err_deg']:.2f} deg, lengths "
              f"{s['length_err_pct'].round(2)} %")
    if not args.no_truth_fed:
        t1 = time.perf_counter()
        fed_surface = score_surface(bs.truth_fed_surface(session, 0), truth0)
        fed = bs.truth_fed_tracking(session, every=args.every)
        fed_last, fed_n = bs.last_frame_error(fed.score, fed.filters[-1].trajectories.present)
        fed_arm = bs.truth_fed_arm(session, fed)
        fed_scores = {n: bs.score_arm(f, truth.torso_poses, truth, frames=fed_arm.frames)
                      for n, f in (("simplified", fed_arm.simplified), ("full", fed_arm.full))}
        out["truth_fed"] = {
            "seconds": time.perf_counter() - t1,
            "surface": {"density": fed_surface["density"],
                        "median_mm": fed_surface["filtered"]["median_mm"]},
            "trajectories": {"last_frame_median_mm": fed_last, "n": fed_n},
            "arm_frames": len(fed_arm.frames),
            "arm": {n: {"max_angle_deg": s["max_angle_err_deg"],
                        "length_err_pct": s["length_err_pct"].tolist()}
                    for n, s in fed_scores.items()},
        }
        print(f"truth-fed: surface density {fed_surface['density']:.3f}, median "
              f"{fed_surface['filtered']['median_mm']:.3f} mm; trajectories {fed_last:.2f} mm; "
              + "; ".join(f"arm {n} {s['max_angle_err_deg']:.2f} deg, "
                          f"{s['length_err_pct'].round(2)} %" for n, s in fed_scores.items()))
    write_json(args.out, out)


if __name__ == "__main__":
    main()
