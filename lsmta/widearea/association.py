"""Association of one camera frame's centroids with the targets (Davis 2002, §3.4): each
target's predicted position is projected into the camera and paired with the nearest
centroid inside a gate. The one-to-one assignment uses SciPy's Hungarian solver
(``scipy.optimize.linear_sum_assignment``) on the gated pixel distances, so two targets
never take the same centroid."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_points


@dataclass(frozen=True)
class Association:
    """Pairs of targets and centroids.

    Attributes
    ----------
    target : (A,) int array
        Target indices.
    centroid : (A,) int array
        Centroid indices, paired with ``target``.
    distance : (A,) array
        Their pixel distances.
    unassociated : (N,) bool array
        Centroids that no target took (candidates for a birth).
    """

    target: np.ndarray
    centroid: np.ndarray
    distance: np.ndarray
    unassociated: np.ndarray


def innovation_gate(S, *, n_sigma: float, lower: float, upper: float) -> np.ndarray:
    """Per-target gate, px: ``n_sigma`` times the larger semi-axis of each innovation
    ellipse ``S`` (A, 2, 2) in px², kept within [``lower``, ``upper``] px."""
    S = np.asarray(S, dtype=float)
    if S.ndim != 3 or S.shape[1:] != (2, 2):
        raise ValueError(f"S: expected an (A, 2, 2) array of covariances, got {S.shape}")
    tr, det = S[:, 0, 0] + S[:, 1, 1], np.linalg.det(S)
    big_axis = np.sqrt(0.5 * tr + np.sqrt(np.maximum(0.25 * tr**2 - det, 0.0)))
    return np.clip(n_sigma * big_axis, lower, upper)


def associate(predicted, observed, gate_px: float) -> Association:
    """Pair projected targets with observed centroids, nearest first, inside a gate.

    Parameters
    ----------
    predicted : (M, 2) array
        Projected target positions in pixels; NaN for targets outside this camera's view.
    observed : (N, 2) array
        Centroids in pixels.
    gate_px : float or (M,) array
        Largest accepted distance in pixels, for all targets or per target.

    Returns
    -------
    Association
    """
    pred = as_points(predicted, "predicted", 2, allow_nan=True)
    obs = as_points(observed, "observed", 2)
    gate = np.broadcast_to(np.asarray(gate_px, dtype=float), (len(pred),))
    if not (np.isfinite(gate).all() and np.all(gate > 0)):
        raise ValueError("gate_px: expected positive pixel distances")
    empty = np.zeros(0, np.int64)
    if len(pred) == 0 or len(obs) == 0:
        return Association(target=empty, centroid=empty, distance=np.zeros(0),
                           unassociated=np.ones(len(obs), bool))
    d = np.linalg.norm(pred[:, None, :] - obs[None, :, :], axis=2)
    d = np.where(np.isfinite(d), d, np.inf)
    big = 1e6 * (gate.max() + d[np.isfinite(d)].max(initial=0.0) + 1.0)
    cost = np.where(d <= gate[:, None], d, big)
    rows, cols = linear_sum_assignment(cost)
    keep = cost[rows, cols] < big
    rows, cols = rows[keep], cols[keep]
    free = np.ones(len(obs), bool)
    free[cols] = False
    return Association(target=rows.astype(np.int64), centroid=cols.astype(np.int64),
                       distance=d[rows, cols], unassociated=free)
