"""Dense stereo on a real pair scored against its published truth: the Middlebury measures
(the "Cones" pair itself is loaded by :func:`lsmta.data.load_cones`).

Scores follow the Middlebury evaluation (Scharstein & Szeliski 2002, 2003): over the
non-occluded pixels with known disparity, the share of estimates more than 1 px (bad 1.0)
and 2 px (bad 2.0) off, the mean and median absolute error, and the density (the share of
those pixels that have an estimate at all). Every method is scored on the same pixels: the
nodes of a grid of spacing ``step``; dense maps are read at the nodes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..matching import DisparityParams, measure_disparity, peers

#: the truth is quantised to this step (px); a perfect estimate is up to half of it off
TRUTH_STEP = 0.25


def scores(estimate, truth, scored) -> dict:
    """Middlebury measures of a ``(rows, cols)`` disparity estimate (NaN: none).

    Returns ``density`` (share of the ``scored`` nodes with an estimate), and over those
    estimates ``bad1``, ``bad2`` (shares more than 1 and 2 px off), ``mean``, ``median``
    (absolute error, px) and ``n``; plus ``bad1_all``: estimates more than 1 px off *or
    missing*, over all scored nodes (Middlebury's bad-pixel rate for a dense method).
    """
    estimate = np.asarray(estimate, dtype=float)
    has = scored & np.isfinite(estimate)
    e = np.abs(estimate - truth)[has]
    n = int(has.sum())
    if n == 0:
        return {"density": 0.0, "n": 0, "bad1": np.nan, "bad2": np.nan, "mean": np.nan,
                "median": np.nan, "bad1_all": 1.0}
    return {"density": n / int(scored.sum()), "n": n, "bad1": float(np.mean(e > 1)),
            "bad2": float(np.mean(e > 2)), "mean": float(e.mean()),
            "median": float(np.median(e)),
            "bad1_all": float((np.sum(e > 1) + scored.sum() - n) / scored.sum())}


def quantisation_median(*, step: float = TRUTH_STEP) -> float:
    """Median absolute error of an exact estimate against truth rounded to ``step``: the
    rounding error is uniform on ``[-step/2, step/2]``, so its magnitude's median is
    ``step / 4`` (0.0625 px for Middlebury's 0.25 px)."""
    return step / 4.0


# ---------------------------------------------------------------------- one pair, all methods
#: the methods of :func:`compare_on_pair`, in table order: ours with automatic seeds, ours
#: started from SGBM (``measure_disparity(seeds="sgbm")``), and the peers
METHODS = ("ours", "ours, SGBM start", "SGBM, filters on", "SGBM, filters off", "BM")
#: our methods (scored against the targets)
OURS = METHODS[:2]


@dataclass(frozen=True)
class PairComparison:
    """Ours (automatic seeds, SGBM start), SGBM (filters on, off) and BM on one pair's grid
    nodes.

    Attributes
    ----------
    name : str
    step : int
        Grid spacing, px.
    n_scored : int
        Scored nodes (non-occluded, known truth).
    maps : dict
        Method (:data:`METHODS`) -> (rows, cols) disparity at the grid nodes, NaN: none.
    scores : dict
        Method -> :func:`scores` of its map.
    seconds : dict
        Method -> shortest wall time of ``repeats`` runs, s (ours: everything from the images
        to the grid, with SGBM's own run for the SGBM start).
    cpu_seconds : dict
        Method -> shortest CPU time (all threads of the process) of ``repeats`` runs, s.
    """

    name: str
    step: int
    n_scored: int
    maps: dict
    scores: dict
    seconds: dict
    cpu_seconds: dict

    @property
    def time_ratio(self) -> float:
        """Our (automatic seeds) CPU time over SGBM's with filters (the SGBM a user runs)."""
        return self.ratio("ours")

    def ratio(self, method: str, *, cpu: bool = True) -> float:
        """``method``'s time over SGBM's with filters: CPU (default) or wall time."""
        t = self.cpu_seconds if cpu else self.seconds
        return t[method] / t["SGBM, filters on"]

    def targets(self, *, method: str = "ours", time_limit: float = 5.0) -> dict:
        """Issue #33's targets for ``method`` (one of :data:`OURS`), each True (met) or
        False: ``median`` below the better SGBM's (filters on or off), ``bad1`` at most half
        of the better SGBM's, ``density`` at least SGBM's with filters (without them SGBM
        keeps every node by construction), ``time`` (CPU) at most ``time_limit`` x SGBM's
        with filters."""
        if method not in OURS:
            raise ValueError(f"method: expected one of {OURS}, got {method!r}")
        ours = self.scores[method]
        on, off = self.scores["SGBM, filters on"], self.scores["SGBM, filters off"]
        return {"median": bool(ours["median"] < min(on["median"], off["median"])),
                "bad1": bool(ours["bad1"] <= 0.5 * min(on["bad1"], off["bad1"])),
                "density": bool(ours["density"] >= on["density"]),
                "time": bool(self.ratio(method) <= time_limit)}


def compare_on_pair(pair, *, repeats: int = 3, params=None, disparity_range=None,
                    warm_up: bool = True) -> PairComparison:
    """Run ours (:func:`~lsmta.matching.disparity.measure_disparity`, ``params`` or its
    defaults :class:`~lsmta.matching.DisparityParams`: automatic seeds, and started from
    SGBM, ``seeds="sgbm"``) and OpenCV's SGBM (filters on, off) and BM on a
    :class:`~lsmta.data.StereoPair`, score all on the same grid nodes (our grid, spacing
    ``params.grow.step``: 4 by default).

    ``disparity_range`` defaults to the pair's own (from its file format), the same for
    every method; each is timed as the shortest of ``repeats`` runs, wall and CPU (with
    ``warm_up`` ours once more beforehand, untimed, so that numba's compilation is not
    counted: not needed once it has run in this process). The truth is read only for the
    scores.
    """
    if int(repeats) < 1:
        raise ValueError(f"repeats: expected a positive integer, got {repeats}")
    params = DisparityParams() if params is None else params
    step = params.grow.step
    lo, hi = pair.disparity_range if disparity_range is None else disparity_range
    truth, scored = pair.grid(step)

    def ours(seeds=None):
        return measure_disparity(pair.left, pair.right, disparity_range=(lo, hi), seeds=seeds,
                                 params=params).disparity

    runs = {
        "ours": ours,
        "ours, SGBM start": lambda: ours("sgbm"),
        "SGBM, filters on": lambda: peers.stereo_sgbm(
            pair.left, pair.right, min_disparity=int(lo), num_disparities=int(hi - lo)),
        "SGBM, filters off": lambda: peers.stereo_sgbm(
            pair.left, pair.right, min_disparity=int(lo), num_disparities=int(hi - lo),
            filters=False),
        "BM": lambda: peers.stereo_bm(pair.left, pair.right, num_disparities=int(hi - lo)),
    }
    if warm_up:
        ours()                                              # numba compiles once
        ours("sgbm")
    maps, seconds, cpu = {}, {}, {}
    for name, fn in runs.items():
        best, best_cpu = np.inf, np.inf
        for _ in range(int(repeats)):
            t0, c0 = time.perf_counter(), time.process_time()
            out = fn()
            best_cpu = min(best_cpu, time.process_time() - c0)
            best = min(best, time.perf_counter() - t0)
        if name in OURS:
            maps[name] = out
        else:   # OpenCV's own time (its call alone), the map read at the nodes
            best = min(best, out.seconds)
            maps[name] = out.disparity[::step, ::step]
        seconds[name], cpu[name] = best, best_cpu
    return PairComparison(name=pair.name, step=int(step), n_scored=int(scored.sum()),
                          maps=maps, scores={k: scores(m, truth, scored) for k, m in maps.items()},
                          seconds=seconds, cpu_seconds=cpu)
