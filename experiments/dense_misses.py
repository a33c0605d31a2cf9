"""Where our dense matching leaves nodes that SGBM measures, on every real pair (#33 item 3).

    .venv/bin/python experiments/dense_misses.py [--out PATH]

For each Middlebury pair of :data:`lsmta.data.STEREO_PAIRS`, :func:`lsmta.real.stereo.
compare_on_pair` runs ours (defaults, automatic seeds) and SGBM (filters on) once. Every
scored node (non-occluded, known truth) that SGBM measures and we do not is a *miss*; each
miss gets the first of these labels that applies:

1. ``border``: within a whole ``patch`` of the image edge (generous: the matcher's patches
   may reach over the border by half a patch), or so near the left edge that its
   match would leave the right image (``x < largest disparity``);
2. ``occlusion``: within two grid steps of an occluded or unknown node (the truth's mask);
3. ``weak texture``: the grey values' standard deviation over the node's patch is below
   ``--weak-sigmas`` times the image noise (estimated from the left image by Immerkaer's
   Laplacian-difference method, "Fast noise variance estimation", CVIU 64(2), 1996);
4. ``slant``: the truth's disparity changes by more than ``--slant`` px per px between the
   node and its grid neighbours (a surface turned away from the cameras);
5. ``other``.

Beside each label: the share of those misses where SGBM is right (within 1 px of the
truth), so a miss that SGBM gets wrong is not counted as density we should have had. The
truth (occlusion mask, disparity) is read only to label and score the misses: this is a
diagnosis of where density is lost, not a result of the system. Writes
build/benchmarks/dense_misses.json.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import ndimage

from lsmta.data import STEREO_PAIRS, load_stereo_pair
from lsmta.matching import DisparityParams
from lsmta.real import stereo
from lsmta.report import write_json

LABELS = ("border", "occlusion", "weak texture", "slant", "other")


def image_noise(image) -> float:
    """Grey-value noise sigma of ``image`` (H, W) by Immerkaer (1996): the mean absolute
    response to the difference of two Laplacians, which cancels smooth image content."""
    g = np.asarray(image, float)
    m = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
    r = ndimage.convolve(g, m)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2.0) * np.abs(r).mean() / 6.0)


def label_misses(pair, ours, sgbm, *, step: int, patch: int, weak_sigmas: float,
                 slant: float) -> dict:
    """Counts of the misses (scored nodes SGBM measures and ``ours`` does not) per label,
    and the share of each where SGBM is within 1 px of the truth. ``ours``, ``sgbm``
    ``(rows, cols)`` disparity at the grid nodes, NaN: none."""
    truth, scored = pair.grid(step)
    miss = scored & np.isfinite(sgbm) & ~np.isfinite(ours)
    rows, cols = truth.shape
    x = np.arange(cols)[None, :] * step
    y = np.arange(rows)[:, None] * step
    H, W = pair.left.shape
    border = ((x < patch) | (y < patch) | (x >= W - patch) | (y >= H - patch)
              | (x < pair.disparity_range[1]))
    unknown = ~(pair.nonoccluded & np.isfinite(pair.disparity))[::step, ::step]
    near_occ = ndimage.binary_dilation(unknown, iterations=2)
    g = pair.left.astype(float)
    mean = ndimage.uniform_filter(g, patch)
    sd = np.sqrt(np.maximum(ndimage.uniform_filter(g * g, patch) - mean * mean, 0.0))
    weak = sd[::step, ::step] < weak_sigmas * image_noise(g)
    d = np.where(np.isfinite(truth), truth, np.nan)
    grads = [np.abs(np.diff(d, axis=a, prepend=np.nan)) / step for a in (0, 1)]
    grads += [np.abs(np.diff(d[::-1], axis=0, prepend=np.nan))[::-1] / step,
              np.abs(np.diff(d[:, ::-1], axis=1, prepend=np.nan))[:, ::-1] / step]
    steep = np.nan_to_num(np.stack(grads), nan=0.0).max(axis=0) > slant
    left = miss.copy()
    out = {"misses": int(miss.sum()), "scored": int(scored.sum())}
    right = np.abs(sgbm - truth) <= 1.0
    for name, mask in zip(LABELS, (border, near_occ, weak, steep, np.ones_like(miss))):
        sel = left & mask
        left &= ~mask
        out[name] = {"n": int(sel.sum()),
                     "share_of_scored": float(sel.sum() / max(scored.sum(), 1)),
                     "sgbm_right": float(right[sel].mean()) if sel.any() else None}
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weak-sigmas", type=float, default=3.0)
    parser.add_argument("--slant", type=float, default=0.25)
    parser.add_argument("--out", default="build/benchmarks/dense_misses.json")
    args = parser.parse_args(argv)
    params = DisparityParams()
    rows = []
    for name in STEREO_PAIRS:
        pair = load_stereo_pair(name)
        c = stereo.compare_on_pair(pair, repeats=1, warm_up=False)
        out = label_misses(pair, c.maps["ours"], c.maps["SGBM, filters on"], step=c.step,
                           patch=params.grow.patch, weak_sigmas=args.weak_sigmas,
                           slant=args.slant)
        rows.append({"pair": name, **out})
        print(f"\n{name}: {out['misses']} of {out['scored']} scored nodes measured by SGBM "
              f"and not by us (density ours {c.scores['ours']['density']:.3f}, SGBM "
              f"{c.scores['SGBM, filters on']['density']:.3f})")
        for label in LABELS:
            r = out[label]
            right = "-" if r["sgbm_right"] is None else f"{r['sgbm_right']:.0%}"
            print(f"  {label:<13} {r['n']:5d} ({r['share_of_scored']:6.2%} of scored); "
                  f"SGBM right on {right}")
    write_json(args.out, {"args": vars(args), "truth": "occlusion mask and disparity of the "
                          "pair's ground truth, to label and score misses", "rows": rows})


if __name__ == "__main__":
    main()
