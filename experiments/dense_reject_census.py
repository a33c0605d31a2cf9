"""Which test of ours rejects the nodes SGBM measures and we do not (#33 items 1 and 3).

    .venv/bin/python experiments/dense_reject_census.py [--pairs cones art teddy]
        [--max-sigma-xy S] [--slow] [--precision-fill] [--out PATH]

For each pair (by default Cones, Art and Teddy, the tuning pairs of ``GrowParams.slow`` and
``DisparityParams.precision_fill``; Tsukuba is held out and never looked at node by node;
the automatic seeds' defaults were chosen on Cones alone and hold Art and Teddy out, but
this census looks at them node by node for those seeds too, so they are spent: any future
change of the automatic seeds' defaults has Art and Teddy as tuning pairs) and each of our
variants (automatic seeds; started from SGBM, ``seeds="sgbm"``) with the library's defaults
or ``--max-sigma-xy``: every scored node (non-occluded, known truth; the truth's mask is
read only to pick the nodes the density counts) that SGBM (filters on) measures and we do
not, by the reason our own records give (:attr:`~lsmta.matching.GrowResult.node_outcome` and
``node_failure`` of every stage: the growth, the growths from new seeds or the LSM at SGBM's
nodes and the growth after it; the last stage that tried the node speaks):

* a rejecting test of the main patch's last attempt (``sigma0``, ``sigma_xy``,
  ``displacement``, ``scale``, ``shear``) or no convergence (``max_iterations``,
  ``diverged``, ``outside``, ``singular``);
* ``range``: accepted by the adjustment but outside the disparity range (dropped);
* ``no_texture``: below the texture floor, never tried; ``never_reached``: usable, but no
  matched neighbour (or no SGBM start) ever led to it; ``outside``: the patch does not fit.

Beside each class, the share of its nodes where SGBM is within 1 px of the truth. Writes
build/benchmarks/dense_reject_census.json.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from lsmta.data import load_stereo_pair
from lsmta.matching import DisparityParams, measure_disparity, peers
from lsmta.matching.grow import AttemptOutcome, NodeOutcome
from lsmta.report import write_json

TUNING = ("cones", "art", "teddy")
VARIANTS = {"ours": None, "ours, SGBM start": "sgbm"}


def miss_reasons(result) -> np.ndarray:
    """Every grid node's reason (str array) from the stages' own records: the last stage that
    tried the node (its main patch's outcome; ``range`` if accepted but dropped), else the
    first stage's node outcome (``no_texture``, ``never_reached``, ``outside``, ...)."""
    stages = [result.grown] + [g for _, g in result.regrown]
    first = stages[0].node_outcome
    out = np.array([NodeOutcome(v).name.lower() for v in first.ravel()],
                   dtype=object).reshape(first.shape)
    for g in stages:
        tried = np.isin(g.node_outcome, (NodeOutcome.GIVEN_UP, NodeOutcome.FAILED_OPEN,
                                         NodeOutcome.MATCHED))
        names = np.array(["range" if v in (-1, AttemptOutcome.ACCEPTED)
                          else AttemptOutcome(v).name.lower() for v in g.node_failure.ravel()],
                         dtype=object).reshape(first.shape)
        out[tried] = names[tried]
    return out


def census(pair, seeds, params) -> dict:
    """The misses of one variant on one pair by reason, with SGBM's share right."""
    lo, hi = pair.disparity_range
    truth, scored = pair.grid(4)
    res = measure_disparity(pair.left, pair.right, disparity_range=(lo, hi), seeds=seeds,
                            params=params)
    sg = peers.stereo_sgbm(pair.left, pair.right, min_disparity=int(lo),
                           num_disparities=int(hi - lo)).disparity[::4, ::4]
    miss = scored & np.isfinite(sg) & ~np.isfinite(res.disparity)
    why = miss_reasons(res)
    right = np.abs(sg - truth) <= 1.0
    out = {}
    for name in sorted(set(why[miss])):
        sel = miss & (why == name)
        out[name] = {"n": int(sel.sum()), "sgbm_right": float(right[sel].mean())}
    e = np.abs(res.disparity - truth)[scored & np.isfinite(res.disparity)]
    return {"misses": int(miss.sum()), "scored": int(scored.sum()),
            "density": float(np.isfinite(res.disparity)[scored].mean()),
            "median": float(np.median(e)), "bad1": float(np.mean(e > 1)), "reasons": out}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", default=list(TUNING))
    parser.add_argument("--max-sigma-xy", type=float, default=None)
    parser.add_argument("--slow", action="store_true", help="the slow nodes' attempt "
                        "(GrowParams.slow) in both variants")
    parser.add_argument("--precision-fill", action="store_true", help="the automatic seeds' "
                        "texture test by a rule (DisparityParams.precision_fill)")
    parser.add_argument("--out", default="build/benchmarks/dense_reject_census.json")
    args = parser.parse_args(argv)
    if "tsukuba" in args.pairs:
        raise SystemExit("tsukuba is held out: its nodes are not diagnosed")
    params = DisparityParams()
    if args.max_sigma_xy is not None:
        th = replace(params.grow_params().thresholds, max_sigma_xy=args.max_sigma_xy)
        params = DisparityParams(grow=replace(params.grow, thresholds=th),
                                 sgbm_grow=replace(params.grow_params(sgbm=True), thresholds=th))
    params = replace(params, precision_fill=args.precision_fill)
    if args.slow:
        params = replace(params, grow=replace(params.grow, slow=True),
                         sgbm_grow=None if params.sgbm_grow is None
                         else replace(params.sgbm_grow, slow=True))
    rows = []
    for name in args.pairs:
        pair = load_stereo_pair(name)
        for variant, seeds in VARIANTS.items():
            c = census(pair, seeds, params)
            rows.append({"pair": name, "variant": variant, **c})
            print(f"{name:7s} {variant:17s} density {c['density']:.3f} med {c['median']:.3f} "
                  f"bad1 {c['bad1']:.2%} misses {c['misses']}: " + ", ".join(
                      f"{k} {v['n']} ({v['sgbm_right']:.0%})" for k, v in
                      sorted(c["reasons"].items(), key=lambda kv: -kv[1]["n"])))
    write_json(args.out, {"args": vars(args), "rows": rows})


if __name__ == "__main__":
    main()
