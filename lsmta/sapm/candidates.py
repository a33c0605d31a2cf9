"""Every whole match of one segment in one frame, found at once (SAPM's local matching,
Section 3.1, vectorised).

The paper builds a candidate table per assumed pivot and tries trial correspondences one
by one. Here the same tests run for all pivots together:

1. a **base triple** of the segment's markers (:attr:`MarkerModel.base_triples`: the
   largest triangle, and for segments of four or more markers also the largest triangle
   without each of its corners, so that any one missing marker is survived) is matched to
   every ordered triple of observed points whose three distances agree with the model's
   to within 2ε of each distance (Eq. 4's relative test, applied to all three sides);
2. each triple gives a rigid motion (Horn's quaternion fit, compiled) and is kept as a
   partial match if its mean residual passes Eq. 2; the segment's markers are carried by
   the motion and each takes the closest observed point within 2 ε l̄_s (Eq. 5); the motion
   is refitted to all markers matched (twice);
3. a match is kept if it passes the matching-quality (Eq. 2, ē_s < ε_s) and size tests
   (Eq. 3, more than β·M_s markers). Identical matches found from several triples are kept
   once.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numba as nb
import numpy as np

from .model import MarkerModel


@dataclass(frozen=True)
class Candidates:
    """Whole matches of one segment, best first (most markers, then smallest ē).

    Attributes
    ----------
    obs : (K, m) int array
        Observed point of each of the segment's markers, -1 where none.
    R, t : (K, 3, 3) and (K, 3) arrays
        Model -> observed motion of each match.
    err : (K,) array
        ē_s of Eq. 2.
    n : (K,) int array
        Markers matched.
    resid : (K, m) array
        Each matched marker's distance from where the motion carries it, mm (NaN where
        none).
    tol : float
        The scale of the scores, mm: ``max(ε_s l̄_s, floor)``.
    """

    obs: np.ndarray
    R: np.ndarray
    t: np.ndarray
    err: np.ndarray
    n: np.ndarray
    resid: np.ndarray
    tol: float = 1.0

    def __len__(self) -> int:
        return len(self.err)

    @cached_property
    def scores(self) -> np.ndarray:
        """(K,) each match's score: the sum over its matched markers of
        ``1 - (r / tol)²``: one for a marker where the motion puts it, less for one off by
        a share of the tolerance, negative beyond it (down to -3 at the gate 2 ε l̄).
        Computed once per instance and read-only (``flags.writeable`` is False)."""
        r = np.where(np.isnan(self.resid), 0.0, self.resid)
        out = np.where(self.obs >= 0, 1.0 - (r / self.tol) ** 2, 0.0).sum(axis=1)
        out.flags.writeable = False
        return out


def _triples(D, d, eps):
    """(K, 3) ordered observed triples (i, j, k) whose distances D[i, j], D[i, k], D[j, k]
    agree with the model's ``d`` = (d_ab, d_ac, d_bc) to within 2ε of each (Eq. 4)."""
    near = [np.abs(D - x) < 2.0 * eps * x for x in d]
    i, j = np.nonzero(near[0])
    if not len(i):
        return np.zeros((0, 3), int)
    ok = near[1][i] & near[2][j]                         # (pairs, N): the third point
    p, k = np.nonzero(ok)
    return np.stack([i[p], j[p], k], axis=1)


@nb.njit(cache=True)
def _top_eigvec(A, v):
    """Unit eigenvector ``v`` (4,) of the largest eigenvalue of the symmetric 4 x 4 ``A``
    (cyclic Jacobi; ``A`` is overwritten)."""
    V = np.eye(4)
    for _ in range(20):
        off = 0.0
        diag = 0.0
        for p in range(4):
            diag += A[p, p] * A[p, p]
            for q in range(p + 1, 4):
                off += A[p, q] * A[p, q]
        if off <= 1e-24 * diag + 1e-300:
            break
        for p in range(3):
            for q in range(p + 1, 4):
                if A[p, q] == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
                tt = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(tt * tt + 1.0)
                s = tt * c
                for k in range(4):
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(4):
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
                for k in range(4):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
    top = 0
    for i in range(1, 4):
        if A[i, i] > A[top, top]:
            top = i
    for k in range(4):
        v[k] = V[k, top]


@nb.njit(cache=True)
def _fit_rows(P, Q, n, R, t, work):
    """Least-squares rigid motion of the first ``n`` rows of ``P`` onto ``Q`` into ``R``,
    ``t`` (Horn's unit quaternion; ``work`` (5, 4) scratch); returns the mean residual."""
    p0 = p1 = p2 = q0 = q1 = q2 = 0.0
    for i in range(n):
        p0 += P[i, 0]
        p1 += P[i, 1]
        p2 += P[i, 2]
        q0 += Q[i, 0]
        q1 += Q[i, 1]
        q2 += Q[i, 2]
    p0, p1, p2, q0, q1, q2 = p0 / n, p1 / n, p2 / n, q0 / n, q1 / n, q2 / n
    sxx = sxy = sxz = syx = syy = syz = szx = szy = szz = 0.0
    for i in range(n):
        a0, a1, a2 = P[i, 0] - p0, P[i, 1] - p1, P[i, 2] - p2
        b0, b1, b2 = Q[i, 0] - q0, Q[i, 1] - q1, Q[i, 2] - q2
        sxx += a0 * b0
        sxy += a0 * b1
        sxz += a0 * b2
        syx += a1 * b0
        syy += a1 * b1
        syz += a1 * b2
        szx += a2 * b0
        szy += a2 * b1
        szz += a2 * b2
    A = work[:4]
    A[0, 0], A[0, 1], A[0, 2], A[0, 3] = sxx + syy + szz, syz - szy, szx - sxz, sxy - syx
    A[1, 1], A[1, 2], A[1, 3] = sxx - syy - szz, sxy + syx, szx + sxz
    A[2, 2], A[2, 3] = -sxx + syy - szz, syz + szy
    A[3, 3] = -sxx - syy + szz
    for i in range(4):
        for j in range(i):
            A[i, j] = A[j, i]
    v = work[4]
    _top_eigvec(A, v)
    w, x, y, z = v[0], v[1], v[2], v[3]
    R[0, 0], R[1, 1], R[2, 2] = (w * w + x * x - y * y - z * z, w * w - x * x + y * y - z * z,
                                 w * w - x * x - y * y + z * z)
    R[0, 1], R[1, 0] = 2 * (x * y - w * z), 2 * (x * y + w * z)
    R[0, 2], R[2, 0] = 2 * (x * z + w * y), 2 * (x * z - w * y)
    R[1, 2], R[2, 1] = 2 * (y * z - w * x), 2 * (y * z + w * x)
    t[0] = q0 - (R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2)
    t[1] = q1 - (R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2)
    t[2] = q2 - (R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2)
    total = 0.0
    for i in range(n):
        r = 0.0
        for a in range(3):
            d = Q[i, a] - (R[a, 0] * P[i, 0] + R[a, 1] * P[i, 1] + R[a, 2] * P[i, 2]) - t[a]
            r += d * d
        total += np.sqrt(r)
    return total / n


@nb.njit(cache=True)
def _complete(P, base, tr, Q, free, eps, lbar, beta):
    """For each start triple: fit, partial-match test, completion (Eq. 5) and refit twice,
    and the tests of Eqs. 2-3. Returns obs (K, m), R (K, 3, 3), t (K, 3), err (K,),
    n (K,), ok (K,)."""
    K, m, N = len(tr), len(P), len(Q)
    gate = 2.0 * eps * lbar
    obs = np.full((K, m), -1)
    Rs = np.zeros((K, 3, 3))
    ts = np.zeros((K, 3))
    err = np.full(K, np.inf)
    n = np.zeros(K, np.int64)
    ok = np.zeros(K, np.bool_)
    Pm = np.empty((m, 3))
    Qm = np.empty((m, 3))
    R = np.empty((3, 3))
    t = np.empty(3)
    x = np.empty(3)
    best = np.empty(m)
    new = np.empty(m, np.int64)
    work = np.empty((5, 4))
    for k in range(K):
        for q in range(3):
            Pm[q] = P[base[k, q]]
            Qm[q] = Q[tr[k, q]]
        if _fit_rows(Pm, Qm, 3, R, t, work) >= eps * lbar:     # not a partial match (Eq. 2)
            continue
        for _ in range(2):                               # complete (Eq. 5), refit
            for i in range(m):
                best[i] = gate
                new[i] = -1
                for a in range(3):
                    x[a] = R[a, 0] * P[i, 0] + R[a, 1] * P[i, 1] + R[a, 2] * P[i, 2] + t[a]
                for j in range(N):
                    if free[j]:
                        d = np.sqrt((Q[j, 0] - x[0]) ** 2 + (Q[j, 1] - x[1]) ** 2
                                    + (Q[j, 2] - x[2]) ** 2)
                        if d < best[i]:
                            best[i] = d
                            new[i] = j
            for i in range(m):                           # a point claimed twice: the closer
                for i2 in range(i + 1, m):
                    if new[i] >= 0 and new[i] == new[i2]:
                        if best[i] <= best[i2]:
                            new[i2] = -1
                        else:
                            new[i] = -1
            c = 0
            for i in range(m):
                if new[i] >= 0:
                    Pm[c] = P[i]
                    Qm[c] = Q[new[i]]
                    c += 1
            if c < 3:
                break
            err[k] = _fit_rows(Pm, Qm, c, R, t, work) / lbar
            n[k] = c
            obs[k] = new
        Rs[k] = R
        ts[k] = t
        ok[k] = err[k] < eps and n[k] > beta * m
    return obs, Rs, ts, err, n, ok


def segment_candidates(model: MarkerModel, s: int, Q, D, *, eps: float, beta: float,
                       limit: int, free=None, floor: float = 0.0) -> Candidates:
    """Whole matches of segment ``s`` among the observed points ``Q`` (N, 3) (pairwise
    distances ``D`` (N, N)), at most ``limit``, best first. ``free`` (N,) bool: points
    that may be used (default all); ``floor``: the least scale of the scores, mm (see
    :attr:`Candidates.scores`)."""
    m = model.members[s]
    P = np.ascontiguousarray(model.points[m])
    N = len(Q)
    free = np.ones(N, bool) if free is None else free
    Dm = np.where(free[:, None] & free[None, :], D, np.inf)
    starts, rows = [], []
    for a, b, c in model.base_triples[s]:
        d = (np.linalg.norm(P[a] - P[b]), np.linalg.norm(P[a] - P[c]),
             np.linalg.norm(P[b] - P[c]))
        tr = _triples(Dm, d, eps)
        starts.append(tr)
        rows.append(np.broadcast_to([a, b, c], tr.shape))
    tr, base = np.concatenate(starts), np.ascontiguousarray(np.concatenate(rows))
    obs, R, t, err, n, ok = _complete(P, base, tr, np.ascontiguousarray(Q, dtype=float), free,
                                      float(eps), float(model.mean_length[s]), float(beta))
    keep = np.flatnonzero(ok)
    if len(keep):                                       # each match once: rows as keys
        key = ((obs[keep] + 1) * (N + 1) ** np.arange(len(m))).sum(axis=1)
        _, first = np.unique(key, return_index=True)
        keep = keep[first]
        keep = keep[np.lexsort((err[keep], -n[keep]))][:limit]
    obs, R, t = obs[keep], R[keep], t[keep]
    pred = np.einsum("kij,mj->kmi", R, P) + t[:, None]
    resid = np.where(obs >= 0, np.linalg.norm(Q[np.maximum(obs, 0)] - pred, axis=2), np.nan)
    return Candidates(obs=obs, R=R, t=t, err=err[keep], n=n[keep], resid=resid,
                      tol=max(float(eps * model.mean_length[s]), float(floor)))
