"""The mixed-scale system on a longer walk: time per stage and the error budget, with and
without prediction.

    .venv/bin/python experiments/mixed_scale_system.py [--travel 4000] [--speed 900]
        [--ceiling 8] [--seed 18] [--lead 0.3] [--no-baseline]

Builds the walk of notebook 15 (`lsmta.synth.mixed_scale.mixed_scale_scene`), by default
slower and so longer, with more ceiling cameras (they stand at X = +-2 m: a walk along X
beyond 4 m takes the head LED out of the rig's view, its track dies and the system aims at a
shoulder); calibrates the ceiling rig and the
heads by the library's procedures (`lsmta.evaluation.mixed_scale.calibrate_scene`), runs
`lsmta.systems.capture_mixed_scale` with prediction and, unless ``--no-baseline``, without
it, and scores both after the fact. Prints and writes
``build/benchmarks/mixed_scale_system.json``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lsmta.evaluation import mixed_scale as ms
from lsmta.report import write_json
from lsmta.synth.mixed_scale import mixed_scale_scene
from lsmta.systems import MixedScaleParams, capture_mixed_scale


def _scores(cap, sc) -> dict:
    return {"face_median_mm": sc.face_median_mm,
            "face_fitted": float(cap.face.fitted.mean()),
            "measured_share": float(sc.measured.mean()),
            "rigid_pairs_median_mm": sc.rigid_median_mm,
            "both_in_frame": sc.both_in_frame,
            "aim_error_median_mm": float(np.nanmedian(sc.aim_error)),
            "led_rms_mm": sc.led_rms_mm, "led_identity_changes": int(sc.led.identity_changes),
            "led_tracks": len(cap.tracking.tracks),
            "marker_px_median": sc.marker_px.tolist(), "stage_s": cap.seconds}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--travel", type=float, default=4000.0, help="mm")
    parser.add_argument("--speed", type=float, default=900.0, help="mm/s")
    parser.add_argument("--ceiling", type=int, default=8, help="ceiling cameras")
    parser.add_argument("--seed", type=int, default=18)
    parser.add_argument("--lead", type=float, default=0.3, help="prediction time, s")
    parser.add_argument("--no-baseline", action="store_true", help="skip the run without "
                        "prediction")
    parser.add_argument("--out", default="build/benchmarks/mixed_scale_system.json")
    args = parser.parse_args(argv)

    t0 = time.perf_counter()
    scene = mixed_scale_scene(rng=args.seed, travel=args.travel, speed=args.speed,
                              n_ceiling=args.ceiling)
    cal = ms.calibrate_scene(scene, rng=args.seed + 1)
    inputs = ms.walk_inputs(scene, cal, rng=args.seed + 2)
    prep_s = time.perf_counter() - t0
    print(f"walk {args.travel / 1000:g} m, {scene.times[-1]:.1f} s, {args.ceiling} ceiling "
          f"cameras; scene, calibration and rendering of the ceiling in {prep_s:.0f} s")
    out = {"travel_mm": args.travel, "speed_mm_s": args.speed, "ceiling": args.ceiling,
           "seed": args.seed, "prepare_s": prep_s,
           "ceiling_rms_px": cal.ceiling_rms_px.tolist(), "head_rms_px": cal.head_rms_px.tolist()}
    runs = [("prediction", args.lead, inputs.devices, inputs.identify)]
    if not args.no_baseline:
        devices, identify = ms.head_devices(scene, rng=args.seed + 3)
        runs.append(("no prediction", 0.0, devices, identify))
    for name, lead, devices, identify in runs:
        cap = capture_mixed_scale(inputs.ceiling, cal.heads, devices, identify,
                                  inputs.face_model, params=MixedScaleParams(lead=lead),
                                  progress=False)
        sc = ms.score_capture(cap, scene, devices)
        out[name] = _scores(cap, sc)
        print(f"{name}: system {sum(cap.seconds.values()):.0f} s")
        for r in cap.summary():
            print(f"  {r['stage']:<16} {r['seconds']:6.1f} s  {r['result']}")
        s = out[name]
        print(f"  face {s['face_median_mm']:.3f} mm median (fitted {s['face_fitted']:.0%}, "
              f"measured {s['measured_share']:.0%}); rigid pairs "
              f"{s['rigid_pairs_median_mm']:.3f} mm; face in both frames "
              f"{s['both_in_frame']:.1%}; LEDs {s['led_rms_mm']:.1f} mm RMS, "
              f"{s['led_identity_changes']} identity changes")
    write_json(args.out, out)


if __name__ == "__main__":
    main()
