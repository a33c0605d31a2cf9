"""Silhouettes and snakes over the whole generated walk; our background model against
OpenCV's MOG2 subtractor.

    .venv/bin/python experiments/silhouettes_walk.py [--frames 50] [--scale 0.5]

Renders the walk (one camera of the triplet rig, ``--scale`` of 768 x 576) and the empty
studio, cuts out silhouettes with our per-pixel background model and with MOG2 (the peer a
user would pick; trained on the same empty frames, the same clean-up), tracks the contour
with snakes with and without the trajectory prediction, and scores everything against the
true silhouettes. Prints and writes build/benchmarks/silhouettes.json: per-frame medians
(contour -> truth, truth -> contour), silhouette IoU of both subtractors, their time ratio.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lsmta.evaluation import silhouettes as es
from lsmta.report import write_json
from lsmta.silhouettes import learn_background, silhouettes


def _iou(masks, truth, s):
    T, Hs, Ws = truth.shape
    centre = truth.reshape(T, Hs // s, s, Ws // s, s).mean(axis=(2, 4)) >= 0.5
    return (masks & centre).sum(axis=(1, 2)) / np.maximum((masks | centre).sum(axis=(1, 2)), 1)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=25)
    parser.add_argument("--out", default="build/benchmarks/silhouettes.json")
    args = parser.parse_args(argv)
    data = es.silhouette_walk(seed=args.seed, n_frames=args.frames, scale=args.scale)
    t0 = time.perf_counter()
    ours = silhouettes(data.images, learn_background(data.empty))
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    peer = es.mog2_silhouettes(data.empty, data.images)
    t_peer = time.perf_counter() - t0
    trial = es.run_contour_trial(data)
    s = data.supersample
    out = {
        "frames": args.frames, "scale": args.scale,
        "median_to_truth_px": {"predicted": float(np.median(trial.median_predicted)),
                               "previous": float(np.median(trial.median_previous))},
        "median_from_truth_px": {"predicted": float(np.median(trial.median_from_truth_predicted)),
                                 "previous": float(np.median(trial.median_from_truth_previous))},
        "worst_frame_from_truth_px": {"predicted": float(trial.median_from_truth_predicted.max()),
                                      "previous": float(trial.median_from_truth_previous.max())},
        "iou": {"ours": float(np.median(_iou(ours, data.true_masks, s))),
                "mog2": float(np.median(_iou(peer, data.true_masks, s)))},
        "seconds": {"ours": t_ours, "mog2": t_peer, "ratio_mog2_over_ours": t_peer / t_ours},
    }
    for k, v in out.items():
        print(f"{k}: {v}")
    write_json(args.out, out)


if __name__ == "__main__":
    main()
