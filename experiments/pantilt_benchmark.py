"""Pan-tilt aiming and calibration: speed and accuracy, side by side in one run.

    .venv/bin/python experiments/pantilt_benchmark.py [--targets 300] [--repeats 3]

Aiming: the local (compass) search of Davis (2002), Section 4.3 (``lsmta.pantilt.aim``),
against a direct solve with ``scipy.optimize.least_squares`` (``aim_least_squares``), for
targets that the true head centres at known settings, started from settings a few degrees
off (the previous command). Reported: time per target (the local search one target at a
time, as a controller calls it, and batched), the ratio direct / local, the error of the
found setting against the truth (degrees) and the final image error (pixels).
Calibration: time of the simple and general fits on the thesis's calibration sweeps and
the ratio general / simple. Writes build/benchmarks/pantilt.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from lsmta.pantilt import aim, aim_least_squares, calibrate, calibrate_intrinsics
from lsmta.report import best_time, write_json
from lsmta.synth.pantilt import calibration_sweeps, intrinsic_target, pantilt_head


def centred_targets(head, pan, tilt, distance=3000.0):
    """World points on the optical axis of the true head at the given settings."""
    cam = head.camera
    d = np.r_[cam.undistort(cam.pixel_to_normalized(np.array([[cam.cx, cam.cy]])))[0], 1.0]
    R, C = head.poses(pan, tilt)
    return C + np.einsum("nji,j->ni", R, d / np.linalg.norm(d)) * distance


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--start-offset", type=float, default=3.0,
                        help="standard deviation of the start setting from the truth, degrees")
    parser.add_argument("--out", default="build/benchmarks/pantilt.json")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    head = pantilt_head()
    n = args.targets
    pan = rng.uniform(-90, 90, n)
    tilt = rng.uniform(-22, 22, n)
    X = centred_targets(head, pan, tilt)
    start = np.c_[pan, tilt] + rng.normal(0, args.start_offset, (n, 2))
    start = np.clip(start, [-100, -25], [100, 25])

    def one_by_one():
        return [aim(head, X[i:i + 1], current=start[i]) for i in range(n)]

    t_local, local = best_time(one_by_one, repeats=args.repeats)
    t_batch, batch = best_time(lambda: aim(head, X, current=start), repeats=args.repeats)
    t_direct, direct = best_time(lambda: aim_least_squares(head, X, current=start),
                                 repeats=args.repeats)
    local_set = np.vstack([a.settings for a in local])
    truth = np.c_[pan, tilt]

    def summary(settings, err_px, reachable, seconds, iterations):
        return {"us_per_target": 1e6 * seconds / n,
                "max_setting_error_deg": float(np.abs(settings - truth).max()),
                "median_setting_error_deg": float(np.median(np.abs(settings - truth))),
                "max_image_error_px": float(np.max(err_px)),
                "reachable": float(np.mean(reachable)),
                "mean_iterations": float(np.mean(iterations))}

    rows = {
        "aim_local_one_by_one": summary(local_set, np.r_[[a.error_px[0] for a in local]],
                                        np.r_[[a.reachable[0] for a in local]], t_local,
                                        np.r_[[a.iterations[0] for a in local]]),
        "aim_local_batched": summary(batch.settings, batch.error_px, batch.reachable, t_batch,
                                     batch.iterations),
        "aim_least_squares": summary(direct.settings, direct.error_px, direct.reachable,
                                     t_direct, direct.iterations),
    }
    rows["aim_time_ratio_direct_over_local"] = t_direct / t_local
    rows["aim_time_ratio_direct_over_batched"] = t_direct / t_batch

    target = intrinsic_target(head, rng=rng)
    t_intr, intr = best_time(lambda: calibrate_intrinsics(target.X, target.xy,
                                                          head.camera.image_size),
                             repeats=args.repeats)
    cal = calibration_sweeps(head, rng=rng)
    cam = intr.model
    t_simple, _ = best_time(lambda: calibrate(cam, cal.pan, cal.tilt, cal.X, cal.xy,
                                              kind="simple"), repeats=args.repeats)
    t_general, fit = best_time(lambda: calibrate(cam, cal.pan, cal.tilt, cal.X, cal.xy),
                               repeats=args.repeats)
    rows["calibration"] = {"observations": len(cal), "intrinsics_s": t_intr,
                           "simple_s": t_simple, "general_s": t_general,
                           "time_ratio_general_over_simple": t_general / t_simple,
                           "general_nfev": fit.nfev}

    print(f"{n} targets, start {args.start_offset:g} deg (sd) from the truth, best of "
          f"{args.repeats}")
    for key in ("aim_local_one_by_one", "aim_local_batched", "aim_least_squares"):
        r = rows[key]
        print(f"{key:>21}: {r['us_per_target']:8.0f} us/target, setting error max "
              f"{r['max_setting_error_deg']:.4f} deg, image error max "
              f"{r['max_image_error_px']:.2f} px, reachable {r['reachable']:.0%}, "
              f"iterations {r['mean_iterations']:.1f}")
    print(f"time ratio direct / local: {rows['aim_time_ratio_direct_over_local']:.2f} "
          f"(one by one), {rows['aim_time_ratio_direct_over_batched']:.2f} (batched)")
    c = rows["calibration"]
    print(f"calibration of {c['observations']} observations: intrinsics {c['intrinsics_s']:.3f} s, "
          f"simple {c['simple_s']:.3f} s, general {c['general_s']:.3f} s "
          f"(ratio {c['time_ratio_general_over_simple']:.2f})")
    write_json(args.out, rows)


if __name__ == "__main__":
    main()
