"""Density check of surface tracking (LSMTA paper, Fig. 9): where have tracks thinned out?

The template image is divided into square cells; a cell that holds fewer than
``min_per_cell`` live tracks but candidate points from that frame's surface measurement
receives candidates until it is full again. Candidates closer than ``min_distance`` pixels
to a live track are skipped, so a point is never tracked twice.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_array, as_int


def sparse_candidates(tracked_xy, candidate_xy, *, cell: float = 16.0, min_per_cell: int = 2,
                      min_distance: float = 3.0) -> np.ndarray:
    """Indices of the candidates that fill the sparse cells of the template image.

    Parameters
    ----------
    tracked_xy : (N, 2) array
        Positions of the live tracks in the template image (pixels; NaN rows are ignored).
    candidate_xy : (M, 2) array
        Positions of the new frame's measured surface points in the template image.
    cell : float
        Cell size in pixels.
    min_per_cell : int
        A cell with fewer live tracks than this is sparse.
    min_distance : float
        Skip candidates closer than this (pixels) to a live track.

    Returns
    -------
    (A,) int array
        Indices into ``candidate_xy`` of the points to add, in the candidates' order.
    """
    tracked = as_array(tracked_xy, "tracked_xy", shape=(None, 2), allow_nan=True)
    cand = as_array(candidate_xy, "candidate_xy", shape=(None, 2), allow_nan=True)
    if not cell > 0:
        raise ValueError(f"cell: expected a positive cell size in pixels, got {cell}")
    as_int(min_per_cell, "min_per_cell")
    tracked = tracked[np.isfinite(tracked).all(axis=1)]
    good = np.flatnonzero(np.isfinite(cand).all(axis=1))
    if good.size == 0:
        return good
    if len(tracked):
        d, _ = cKDTree(tracked).query(cand[good])
        good = good[d >= min_distance]
    if good.size == 0:
        return good
    key_t = np.floor(tracked / cell).astype(np.int64)
    key_c = np.floor(cand[good] / cell).astype(np.int64)
    # count live tracks per cell, then give each sparse cell its missing candidates
    code = lambda k: k[:, 0] * 1_000_003 + k[:, 1]  # noqa: E731
    ct, nt = np.unique(code(key_t), return_counts=True) if len(tracked) else (
        np.zeros(0, np.int64), np.zeros(0, np.int64))
    cc = code(key_c)
    pos = np.searchsorted(ct, cc)
    have = np.zeros(len(cc), dtype=np.int64)
    hit = (pos < len(ct)) & (ct[np.minimum(pos, len(ct) - 1)] == cc) if len(ct) else \
        np.zeros(len(cc), bool)
    have[hit] = nt[pos[hit]]
    # rank of each candidate within its cell (in the candidates' order)
    order = np.argsort(cc, kind="stable")
    sorted_cc = cc[order]
    first = np.searchsorted(sorted_cc, sorted_cc, side="left")
    rank = np.empty(len(cc), dtype=np.int64)
    rank[order] = np.arange(len(cc)) - first
    take = rank < (min_per_cell - have)
    # candidates of one cell must not crowd each other either
    chosen = good[take]
    if len(chosen) > 1 and min_distance > 0:
        keep = np.ones(len(chosen), bool)
        tree = cKDTree(cand[chosen])
        for i, j in sorted(tree.query_pairs(min_distance)):
            if keep[i] and keep[j]:
                keep[j] = False
        chosen = chosen[keep]
    return chosen
