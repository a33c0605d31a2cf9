"""Wand calibration with the lens chosen from the data (issue 34): ``calibrate_wand`` with
``distortion="auto"`` on a generated wide-angle rig (:data:`lsmta.synth.wand.WIDE_RIG`,
2560 x 1600 px, 100 degrees, strong barrel distortion), against a pinhole fit of the same
observations and the 11-parameter DLT camera (easyWand's output model) fitted to them.

    .venv/bin/python experiments/wand_lens_benchmark.py [--seeds 3] [--frames 40]

Per seed and image noise (0.3 px: centroids; 1.0 px: clicked in DLTdv): the lens model
chosen per camera, the image RMS per coordinate (easyWand's convention) of ours, of the
pinhole fit and of the DLT peer (:func:`lsmta.evaluation.wand.dlt_peer_rms`, a bundle
adjustment with the DLT camera: the lowest RMS any DLT fit reaches), the ratio ours / DLT,
the wand length scatter against the floor of the true cameras, and the error of the
recovered lens shape (px, up to the farthest observation). The real rig of the issue is not
measured here (no file of it): these are generated recordings. The focal length is given
(1070 px), as easyWand and Argus ask for it. Writes build/benchmarks/wand_lens.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from lsmta.calibration import calibrate_wand
from lsmta.evaluation.wand import (
    distortion_error_px,
    dlt_peer_rms,
    observed_radius_px,
    wand_trial,
)
from lsmta.report import build_dir, write_json
from lsmta.synth.wand import WIDE_RIG, WIDE_VOLUME


def run(seeds: int, frames: int) -> list:
    out = []
    for seed in range(seeds):
        for sigma in (0.3, 1.0):
            t = wand_trial(seed=seed, n_frames=frames, n_heldout=20, sigma_px=sigma,
                           rig={**WIDE_RIG, "half_size": WIDE_VOLUME}, swap_fraction=0.1,
                           focal_px=WIDE_RIG["focal_px"])
            r, rec = t.result, t.recording
            radius = [observed_radius_px(g, rec.xy[k]) for k, g in enumerate(rec.cameras)]
            pinhole = calibrate_wand(rec.xy, rec.length, rec.cameras[0].image_size,
                                     focal_px=WIDE_RIG["focal_px"], distortion="none")
            dlt = dlt_peer_rms(pinhole, rec.length)
            row = dict(
                seed=seed, sigma_px=sigma, status=r.status.name,
                intrinsics=[list(i) for i in r.intrinsics],
                rms_per_coordinate_px=r.rms_px_per_coordinate.tolist(),
                pinhole_rms_per_coordinate_px=pinhole.rms_px_per_coordinate.tolist(),
                dlt_rms_per_coordinate_px=dlt.tolist(),
                ratio_ours_over_dlt=(r.rms_px_per_coordinate / dlt).tolist(),
                wand_std_percent=r.wand_length_std_percent,
                pinhole_wand_std_percent=pinhole.wand_length_std_percent,
                floor_std_percent=t.floor_std_percent,
                lens_error_px=[distortion_error_px(c, g, rk) for c, g, rk in
                               zip(r.cameras, rec.cameras, radius)],
                lens_size_px=[distortion_error_px(g.replace(k1=0.0, k2=0.0), g, rk)
                              for g, rk in zip(rec.cameras, radius)],
                seconds=r.seconds)
            print({k: (np.round(v, 3).tolist() if isinstance(v, list) and k != "intrinsics"
                       else v) for k, v in row.items()})
            out.append(row)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--frames", type=int, default=40)
    args = parser.parse_args(argv)
    rows = run(args.seeds, args.frames)
    write_json(build_dir() / "benchmarks" / "wand_lens.json",
               dict(rows=rows, rig=WIDE_RIG, volume=WIDE_VOLUME))


if __name__ == "__main__":
    main()
