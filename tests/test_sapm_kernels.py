"""The compiled kernels of the depth-first SAPM search give bitwise what NumPy and SciPy
give, so that the search labels exactly as it did before they were compiled."""

import numpy as np
from scipy.optimize import linear_sum_assignment

from lsmta.rigid import fit_one
from lsmta.sapm._kernels import _lsap, _np_sum, completion, fit_error


def test_sum_in_numpys_order():
    rng = np.random.default_rng(0)
    for n in [*range(1, 140), 257, 1000]:
        a = rng.random(n) * 10.0 ** rng.uniform(-3, 3, n)
        assert _np_sum(a) == a.sum(), n


def test_assignment_as_scipy_with_ties_and_wide_or_tall_costs():
    rng = np.random.default_rng(1)
    for _ in range(2000):
        d = rng.random((rng.integers(1, 10), rng.integers(1, 30))) * 60
        if rng.random() < 0.5:
            d = np.round(d)                          # many ties
        cost = np.where(d < 30, d, 3e7)
        rows, cols = _lsap(cost)
        want = linear_sum_assignment(cost)
        np.testing.assert_array_equal(rows, want[0])
        np.testing.assert_array_equal(cols, want[1])


def test_completion_as_the_numpy_code_with_pinned_joints():
    rng = np.random.default_rng(2)
    for _ in range(500):
        m, n = int(rng.integers(3, 9)), int(rng.integers(4, 40))
        Q, pred = rng.normal(size=(n, 3)) * 100, rng.normal(size=(m, 3)) * 100
        cand = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
        pin_j = rng.choice(m, int(rng.integers(0, 3)), replace=False).astype(np.int64)
        pin_q = rng.choice(cand, len(pin_j)).astype(np.int64)
        d = np.linalg.norm(pred[:, None] - Q[cand][None], axis=-1)
        cost = np.where(d < 80.0, d, 8e7)
        rows, cols = linear_sum_assignment(cost)
        want = np.full(m, -1)
        keep = cost[rows, cols] < 80.0
        want[rows[keep]] = cand[cols[keep]]
        for j, q in zip(pin_j, pin_q):
            if want[j] != q:
                want[want == q] = -1
            want[j] = q
        np.testing.assert_array_equal(completion(pred, Q, cand, 80.0, pin_j, pin_q), want)


def test_fit_error_is_the_mean_distance_over_lbar():
    rng = np.random.default_rng(3)
    for n in (3, 5, 8, 13):
        P, Q = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        R, t, resid, err = fit_error(P, Q, 7.0)
        R0, t0, resid0 = fit_one(P, Q)
        np.testing.assert_array_equal(R, R0)
        assert err == resid0.mean() / 7.0
