"""Compiled kernels of the depth-first SAPM search (:mod:`lsmta.sapm.identify`).

Each gives bitwise what the NumPy/SciPy code it replaces gave (sums in NumPy's order, SciPy's
assignment ported step for step), so that the search labels exactly as before, only without
the per-call overhead of many small NumPy calls per candidate.

numba's cache (``cache=True``) is keyed on this file only: after editing
:func:`lsmta.rigid.fit_one`, which these kernels compile in, clear ``__pycache__``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..rigid import fit_one


@nb.njit(cache=True)
def _np_sum(a):
    """``a.sum()`` of a 1-D float array summed in NumPy's order (sequential below 8
    values, eight running sums up to 128, halves beyond), so that the result is bitwise
    NumPy's (for fewer than 8192 values)."""
    n = a.shape[0]
    if n > 128:
        half = n // 2
        half -= half % 8
        return _np_sum(a[:half]) + _np_sum(a[half:])
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    r = a[:8].copy()
    stop = n - n % 8
    for i in range(8, stop, 8):
        for j in range(8):
            r[j] += a[i + j]
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for i in range(stop, n):
        res += a[i]
    return res


@nb.njit(cache=True)
def fit_error(P, Q, lbar):
    """Rigid fit of (n, 3) ``P`` onto ``Q``: R, t, distances (n,) and their mean over
    ``lbar`` (ē of Eq. 2, as NumPy's ``resid.mean() / lbar``)."""
    R, t, resid = fit_one(P, Q)
    return R, t, resid, _np_sum(resid) / resid.shape[0] / lbar


@nb.njit(cache=True)
def triple_fits(P3, Q, k, qa, qb, lbar):
    """Rigid fits of model points ``P3`` (3, 3) onto the triples (pivot ``k``, ``qa[i]``,
    ``qb[i]``): R (B, 3, 3), t (B, 3) and ē (B,)."""
    B = qa.shape[0]
    R = np.empty((B, 3, 3))
    t = np.empty((B, 3))
    err = np.empty(B)
    Qt = np.empty((3, 3))
    for i in range(B):
        Qt[0] = Q[k]
        Qt[1] = Q[qa[i]]
        Qt[2] = Q[qb[i]]
        R[i], t[i], _, err[i] = fit_error(P3, Qt, lbar)
    return R, t, err


@nb.njit(cache=True)
def _lsap(cost):
    """SciPy's ``linear_sum_assignment`` (shortest augmenting paths, Crouse 2016) ported
    step for step, so that ties are broken as SciPy breaks them: (rows, cols) of the
    assignment of (r, c) ``cost``; +inf entries allowed, NaN and -inf not checked (SciPy
    refuses them; the callers here never produce them)."""
    nr0, nc0 = cost.shape
    transpose = nc0 < nr0
    C = cost.T.copy() if transpose else cost
    nr, nc = C.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    spc = np.empty(nc)
    path = np.full(nc, -1)
    col4row = np.full(nr, -1)
    row4col = np.full(nc, -1)
    SR = np.zeros(nr, np.bool_)
    SC = np.zeros(nc, np.bool_)
    remaining = np.empty(nc, np.int64)
    for cur in range(nr):
        minval = 0.0
        i = cur
        num_rem = nc
        for it in range(nc):
            remaining[it] = nc - it - 1
        SR[:] = False
        SC[:] = False
        spc[:] = np.inf
        sink = -1
        while sink == -1:
            index = -1
            lowest = np.inf
            SR[i] = True
            for it in range(num_rem):
                j = remaining[it]
                r = minval + C[i, j] - u[i] - v[j]
                if r < spc[j]:
                    path[j] = i
                    spc[j] = r
                if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                    lowest = spc[j]
                    index = it
            minval = lowest
            if minval == np.inf:
                raise ValueError("cost matrix is infeasible")
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            SC[j] = True
            num_rem -= 1
            remaining[index] = remaining[num_rem]
        u[cur] += minval
        for i in range(nr):
            if SR[i] and i != cur:
                u[i] += minval - spc[col4row[i]]
        for j in range(nc):
            if SC[j]:
                v[j] -= minval - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            tmp = col4row[i]
            col4row[i] = j
            j = tmp
            if i == cur:
                break
    if transpose:
        order = np.argsort(col4row)
        return col4row[order], order
    return np.arange(nr), col4row


@nb.njit(cache=True)
def completion(pred, Q, cand, reach, pin_j, pin_q):
    """Closest-neighbour completion (Eq. 5): the observed point assigned to each predicted
    marker.

    Parameters
    ----------
    pred : (m, 3) array
        The segment's markers carried by the current motion, mm.
    Q : (N, 3) array
        Observed points, mm.
    cand : (n,) int array
        The observed points that may be assigned.
    reach : float
        A pair at least this far apart (mm) is not assigned.
    pin_j, pin_q : (p,) int arrays
        Members whose point is known (a joint the parent identified) and that point: it
        stays theirs and nobody else's.

    Returns
    -------
    (m,) int array
        Observed index per member, -1 where none.
    """
    m, n = pred.shape[0], cand.shape[0]
    cost = np.empty((m, n))
    far = 1e6 * reach
    for i in range(m):
        for j in range(n):
            x = pred[i, 0] - Q[cand[j], 0]
            y = pred[i, 1] - Q[cand[j], 1]
            z = pred[i, 2] - Q[cand[j], 2]
            d = np.sqrt(x * x + y * y + z * z)
            cost[i, j] = d if d < reach else far
    rows, cols = _lsap(cost)
    new = np.full(m, -1)
    for r, c in zip(rows, cols):
        if cost[r, c] < reach:
            new[r] = cand[c]
    for p in range(pin_j.shape[0]):
        j, q = pin_j[p], pin_q[p]
        if new[j] != q:
            for i in range(m):
                if new[i] == q:
                    new[i] = -1
        new[j] = q
    return new


@nb.njit(cache=True)
def complete_match(P, Q, cand, R, t, reach, pin_j, pin_q, lbar, eps, beta):
    """Closest-neighbour completion (Eq. 5) from a partial match's motion ``R``, ``t``,
    repeated with the refitted motion until it settles (at most three times), then the
    trimming of pairs off by more than ε l̄ and the quality (Eq. 2) and size (Eq. 3)
    tests.

    Parameters
    ----------
    P : (m, 3) array
        The segment's model markers, mm.
    Q, cand, reach, pin_j, pin_q
        As :func:`completion`.
    R : (3, 3) array
    t : (3,) array
        The partial match's motion (model to observed, mm).
    lbar, eps, beta : float
        l̄_s (mm), ε_s and β.

    Returns
    -------
    passed : bool
        False where fewer than 3 points were assigned or a test failed.
    obs : (m,) int array
        Observed index per member, -1 where none.
    R : (3, 3) array
    t : (3,) array
    err : float
        The motion of the last fit and its ē.
    fits : int
        Rigid fits computed.
    """
    m = P.shape[0]
    pinned = np.zeros(m, np.bool_)
    pinned[pin_j] = True
    obs = np.full(m, -1)
    err = np.inf
    fits = 0
    resid = np.empty(0)
    for _ in range(3):
        new = completion(P @ np.ascontiguousarray(R.T) + t, Q, cand, reach, pin_j, pin_q)
        idx = np.flatnonzero(new >= 0)
        if idx.shape[0] < 3:
            return False, obs, R, t, err, fits
        R, t, resid, err = fit_error(P[idx], Q[new[idx]], lbar)
        fits += 1
        if np.array_equal(new, obs):
            break
        obs = new
    while True:
        ok = np.flatnonzero(obs >= 0)
        worst = np.argmax(resid)
        if (resid[worst] <= eps * lbar or ok.shape[0] - 1 <= max(2.0, beta * m)
                or pinned[ok[worst]]):
            break
        obs[ok[worst]] = -1
        idx = np.flatnonzero(obs >= 0)
        R, t, resid, err = fit_error(P[idx], Q[obs[idx]], lbar)
        fits += 1
    passed = not (err >= eps or np.count_nonzero(obs >= 0) <= beta * m)
    return passed, obs, R, t, err, fits
