"""Filters in matching space: the neighbourhood filter of the LSMTA paper (Section 2.2).

Neighbouring matches on a smooth surface have similar affine parameters, and each
neighbour's match, moved by its own affine matrix, predicts where a node should match.
A match that disagrees with the mean of its neighbours' predictions, or whose affine
matrix differs from their mean, is an outlier.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .grow import GrowResult


@dataclass(frozen=True)
class NeighbourhoodCheck:
    """Per-match result of :func:`neighbourhood_filter`.

    Attributes
    ----------
    keep : (N,) bool array
    n_neighbours : (N,) int array
        Matched nodes among the 8 grid neighbours.
    position_residual : (N,) array
        Distance (px) between the match and the neighbours' mean prediction.
    affine_residual : (N,) array
        Frobenius norm of ``A`` minus the neighbours' mean ``A``.
    predicted_xy : (N, 2) array
        The neighbours' mean prediction (NaN without neighbours), a start for re-matching.
    mean_A : (N, 2, 2) array
        The neighbours' mean (or median) affine matrix.
    """

    keep: np.ndarray
    n_neighbours: np.ndarray
    position_residual: np.ndarray
    affine_residual: np.ndarray
    predicted_xy: np.ndarray
    mean_A: np.ndarray


def neighbourhood_filter(result: GrowResult, *, max_position: float = 0.5,
                         max_affine: float = 0.1, min_neighbours: int = 2,
                         statistic: str = "mean") -> NeighbourhoodCheck:
    """Compare every match with its matched grid neighbours (8-neighbourhood).

    Parameters
    ----------
    result : GrowResult
    max_position : float
        Largest accepted distance from the neighbours' mean prediction, pixels.
    max_affine : float
        Largest accepted Frobenius distance of ``A`` from the neighbours' mean.
    min_neighbours : int
        Matches with fewer matched neighbours are removed (isolated matches).
    statistic : {"mean", "median"}
        How the neighbours' predictions and affine matrices are combined. The paper's
        mean mixes both sides of an occlusion border; the element-wise median follows
        the majority of the neighbours, which at a border are mostly on the node's side.
    """
    if statistic not in ("mean", "median"):
        raise ValueError(f"statistic: expected 'mean' or 'median', got {statistic!r}")
    rows, cols = result.grid_shape
    r, c = result.node_index[:, 0], result.node_index[:, 1]
    n = len(result)
    grid = np.full((rows + 2, cols + 2), -1, dtype=np.int64)
    grid[r + 1, c + 1] = np.arange(n)
    preds = np.full((8, n, 2), np.nan)               # each neighbour's prediction
    As = np.full((8, n, 2, 2), np.nan)
    k = 0
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            j = grid[r + 1 + dr, c + 1 + dc]
            has = j >= 0
            jj = j[has]
            offset = result.template_xy[has] - result.template_xy[jj]
            preds[k, has] = result.search_xy[jj] + np.einsum("nij,nj->ni", result.A[jj], offset)
            As[k, has] = result.A[jj]
            k += 1
    count = np.isfinite(preds[..., 0]).sum(axis=0)
    combine = np.nanmean if statistic == "mean" else np.nanmedian
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # nodes without neighbours
        pred = combine(preds, axis=0)
        mean_A = combine(As, axis=0)
    pos_res = np.linalg.norm(result.search_xy - pred, axis=1)
    aff_res = np.linalg.norm((result.A - mean_A).reshape(n, 4), axis=1)
    keep = (count >= min_neighbours) & (pos_res <= max_position) & (aff_res <= max_affine)
    return NeighbourhoodCheck(keep=keep, n_neighbours=count, position_residual=pos_res,
                              affine_residual=aff_res, predicted_xy=pred, mean_A=mean_A)
