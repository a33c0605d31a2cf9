"""Dense stereo on a real pair scored against its published truth: the Middlebury measures
(the "Cones" pair itself is loaded by :func:`lsmta.data.load_cones`).

Scores follow the Middlebury evaluation (Scharstein & Szeliski 2002, 2003): over the
non-occluded pixels with known disparity, the share of estimates more than 1 px (bad 1.0)
and 2 px (bad 2.0) off, the mean and median absolute error, and the density (the share of
those pixels that have an estimate at all). Every method is scored on the same pixels: the
nodes of a grid of spacing ``step``; dense maps are read at the nodes.
"""

from __future__ import annotations

import numpy as np

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
