"""The baseline a user might try instead of SAPM: the whole model as one rigid body.

Iterative closest point with optimal one-to-one assignment: start from the four proper
alignments of the principal axes of model and pose, then alternate SciPy's
``linear_sum_assignment`` (Hungarian) with an SVD rigid fit until the assignment stops
changing; keep the start with the smallest mean distance. It ignores articulation, which
is what the comparison in notebook 08 is meant to show.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_points
from ..rigid import apply_rigid, fit_rigid
from .model import MarkerModel


@dataclass(frozen=True)
class GlobalAssignment:
    """Result of :func:`global_assignment`.

    Attributes
    ----------
    labels : (N,) int array
        Model marker per observed point, -1 where unassigned (more points than markers,
        or NaN rows).
    rotation, translation : (3, 3) and (3,) arrays
        The one rigid motion, model -> observed.
    mean_distance : float
        Mean distance of assigned pairs after the fit, mm.
    seconds : float
    """

    labels: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    mean_distance: float
    seconds: float


def _principal_frame(points):
    c = points.mean(axis=0)
    _, _, Vt = np.linalg.svd(points - c, full_matrices=False)
    if np.linalg.det(Vt) < 0:
        Vt[2] *= -1
    return c, Vt


def global_assignment(model: MarkerModel, observed, *, max_iter: int = 50) -> GlobalAssignment:
    """Label ``observed`` (N, 3) mm by one global rigid fit plus optimal assignment."""
    t0 = time.perf_counter()
    Q = as_points(observed, "observed", allow_nan=True)
    keep = np.flatnonzero(~np.isnan(Q).any(axis=1))
    if len(keep) < 3:
        raise ValueError(f"observed: expected at least 3 points without NaN, got {len(keep)}")
    Qk, P = Q[keep], model.points
    cp, Fp = _principal_frame(P)
    cq, Fq = _principal_frame(Qk)
    best = None
    for flip in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        R = Fq.T @ np.diag(flip) @ Fp
        t = cq - R @ cp
        prev = None
        for _ in range(max_iter):
            d = np.linalg.norm(apply_rigid(R, t, P)[:, None] - Qk[None], axis=-1)
            rows, cols = linear_sum_assignment(d)
            if prev is not None and np.array_equal(cols, prev):
                break
            prev = cols
            R, t = fit_rigid(P[rows], Qk[cols])
        cost = np.linalg.norm(apply_rigid(R, t, P[rows]) - Qk[cols], axis=-1).mean()
        if best is None or cost < best[0]:
            best = (cost, R, t, rows, cols)
    cost, R, t, rows, cols = best
    labels = np.full(len(Q), -1)
    labels[keep[cols]] = rows
    return GlobalAssignment(labels=labels, rotation=R, translation=t, mean_distance=float(cost),
                            seconds=time.perf_counter() - t0)
