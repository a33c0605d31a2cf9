"""Least-squares rigid motion between corresponding point sets (Arun, Huang & Blostein 1987).

The SVD solution of ``min_{R, t} sum_i |q_i - R p_i - t|^2`` with a proper rotation
(Kabsch's sign correction). The kernel is compiled with numba: SAPM scores hundreds of
small candidate correspondences per pose, where NumPy's per-call overhead would dominate.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def fit_one(P, Q):
    """Rigid fit of one correspondence: ``P``, ``Q`` (n, 3) float64 -> R (3, 3), t (3,),
    distances |q_i - R p_i - t| (n,). Compiled into other modules' cached kernels
    (``lsmta.sapm``): after editing it, clear their ``__pycache__``."""
    n = P.shape[0]
    pc = np.zeros(3)
    qc = np.zeros(3)
    for i in range(n):
        pc += P[i]
        qc += Q[i]
    pc /= n
    qc /= n
    H = np.zeros((3, 3))
    for i in range(n):
        for a in range(3):
            for b in range(3):
                H[a, b] += (P[i, a] - pc[a]) * (Q[i, b] - qc[b])
    U, _, Vt = np.linalg.svd(H)
    V = Vt.T
    if np.linalg.det(V @ U.T) < 0:
        V[:, 2] = -V[:, 2]
    R = V @ U.T
    t = qc - R @ pc
    resid = np.empty(n)
    for i in range(n):
        resid[i] = np.sqrt(((Q[i] - R @ P[i] - t) ** 2).sum())
    return R, t, resid


@nb.njit(cache=True)
def _fit_batch(P, Q):
    B = P.shape[0]
    R = np.empty((B, 3, 3))
    t = np.empty((B, 3))
    for b in range(B):
        R[b], t[b], _ = fit_one(P[b], Q[b])
    return R, t


def fit_rigid(source, target):
    """Rotations and translations that best carry ``source`` onto ``target``.

    Parameters
    ----------
    source, target : (..., n, 3) arrays
        Corresponding points (n >= 3 for a unique rotation; fewer give *a* minimiser), mm.
        The leading dimensions are a batch. Not modified.

    Returns
    -------
    R : (..., 3, 3) array
        Proper rotations (det +1).
    t : (..., 3) array
        Translations, mm, so that ``target ≈ source @ R.T + t``.
    """
    p = np.asarray(source, dtype=float)
    q = np.asarray(target, dtype=float)
    if p.shape != q.shape or p.ndim < 2 or p.shape[-1] != 3 or p.shape[-2] < 1:
        raise ValueError(f"source, target: expected two arrays of the same shape (..., n, 3), "
                         f"got {p.shape} and {q.shape}")
    lead = p.shape[:-2]
    R, t = _fit_batch(np.ascontiguousarray(p.reshape(-1, *p.shape[-2:])),
                      np.ascontiguousarray(q.reshape(-1, *q.shape[-2:])))
    return R.reshape(*lead, 3, 3), t.reshape(*lead, 3)


def apply_rigid(R, t, points):
    """``points @ R.T + t`` for (..., 3, 3) rotations, (..., 3) translations and
    (..., n, 3) points."""
    return np.asarray(points) @ np.swapaxes(R, -1, -2) + np.asarray(t)[..., None, :]
