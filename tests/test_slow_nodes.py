"""The slow nodes' attempt (GrowParams.slow, issue #33 item 3) and the per-node census of the
LSM at given starts (refine_at_nodes), on small generated rectified pairs (the truth from the
generator)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.matching import (
    DisparityParams,
    GrowParams,
    LSMThresholds,
    measure_disparity,
    refine_disparities,
    sgbm_start,
)
from lsmta.matching.grow import (
    SLOW_MIN_MATCHES,
    SLOW_TOL_SHARE,
    AttemptOutcome,
    NodeOutcome,
    slow_limit,
    slow_params,
)
from lsmta.matching.lsm import LSMParams
from lsmta.synth.patches import warped_pair

# x_right = 0.96 x + 0.03 y - 4.3 on the same row: the disparity d = 0.04 x - 0.03 y + 4.3
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])


@pytest.fixture(scope="module")
def ramp_pair():
    return warped_pair(rng=0, shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), r0=5.0, r1=0.9,
                       noise_sigma=2.0)


def truth_grid(pair, shape, step=4):
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols] * step
    xy = np.stack([xx.ravel(), yy.ravel()], 1).astype(float)
    return (xy[:, 0] - pair.true_xy(xy)[:, 0]).reshape(rows, cols)


def short(slow: bool) -> DisparityParams:
    # 4 iterations: many nodes are still moving (MAX_ITERATIONS), the slow nodes' case
    return DisparityParams(grow=replace(DisparityParams().grow, max_iter=4, slow=slow))


def test_slow_limits_follow_the_accepted_matches():
    model = LSMParams(patch=9, thresholds=LSMThresholds(max_sigma_xy=0.2, max_sigma0=20.0))
    slow = slow_params(model)
    assert slow.tol == pytest.approx(SLOW_TOL_SHARE * 0.2) and slow.patch == 9
    s0 = np.repeat([1.0, 2.0, 3.0, np.nan, 50.0], 10)
    sxy = np.repeat([0.05, 0.01, 0.03, 0.02, 0.5], 10)
    kept = s0.copy(), sxy.copy()
    lim = slow_limit(slow, s0, sxy).thresholds
    assert lim.max_sigma0 == pytest.approx(2.5)           # the median of 1, 2, 3, 50
    assert lim.max_sigma_xy == pytest.approx(0.04)        # of 0.05, 0.01, 0.03, 0.5
    assert np.array_equal(s0, kept[0], equal_nan=True) and np.array_equal(sxy, kept[1])
    # the limits only ever tighten the thresholds
    n = SLOW_MIN_MATCHES
    lim = slow_limit(slow, [100.0] * n, [1.0] * n).thresholds
    assert (lim.max_sigma0, lim.max_sigma_xy) == (20.0, 0.2)
    # too few matches (NaN not counted) set no limits: no slow node is tried
    assert slow_limit(slow, [1.0] * (n - 1) + [np.nan], [0.1] * n) is None
    assert slow_limit(slow, [], []) is None


def test_bad_input_for_the_slow_nodes():
    with pytest.raises(ValueError, match="model"):
        slow_params(LSMParams(patch=9))                  # no thresholds to set tol by
    slow = slow_params(LSMParams(patch=9, thresholds=LSMThresholds()))
    with pytest.raises(ValueError, match="accepted_sigma_xy"):
        slow_limit(slow, [1.0, 2.0], [0.1])
    with pytest.raises(ValueError, match="slow"):
        GrowParams(slow="yes")
    assert GrowParams().slow is False and DisparityParams().grow.slow is False


def test_slow_nodes_are_matched_accurately_and_only_with_the_option(ramp_pair):
    f, g = ramp_pair.template, ramp_pair.search
    for seeds in (None, "sgbm"):
        off = measure_disparity(f, g, disparity_range=(0, 16), seeds=seeds, params=short(False))
        on = measure_disparity(f, g, disparity_range=(0, 16), seeds=seeds, params=short(True))
        truth = truth_grid(ramp_pair, on.disparity.shape)
        assert "slow" not in off.grown.method
        n_slow = (on.grown.method == "slow").sum()
        assert n_slow > 0                                 # 7 and 64 when written
        assert on.density > off.density
        r, c = on.grown.node_index[on.grown.method == "slow"].T
        assert np.abs(on.disparity[r, c] - truth[r, c]).max() < 0.2
        assert sum(on.grown.attempt_census.values()) == on.grown.n_lsm


def test_grown_slow_nodes_pass_the_medians_of_the_matches_before_them(ramp_pair):
    # in the growth the limits are the medians of the call's main and retry matches accepted
    # before the slow attempt: those of an earlier wave (the slow nodes take the next wave's
    # number); each growth call (the first, the reseed round, the SGBM start's front) its own
    f, g = ramp_pair.template, ramp_pair.search
    checked = 0
    for seeds in (None, "sgbm"):
        res = measure_disparity(f, g, disparity_range=(0, 16), seeds=seeds, params=short(True))
        growths = [a for _, a in res.regrown] + ([res.grown] if seeds is None else [])
        for gr in growths:
            slow = gr.method == "slow"
            for w in np.unique(gr.wave[slow]):
                before = ~slow & (gr.wave < w)
                assert before.sum() >= SLOW_MIN_MATCHES
                now = slow & (gr.wave == w)
                assert gr.sigma0[now].max() <= np.median(gr.sigma0[before])
                assert (np.nanmax(gr.sigma_xy[now], axis=1).max()
                        <= np.median(np.nanmax(gr.sigma_xy[before], axis=1)))
                checked += now.sum()
    assert checked > 5


def test_refined_slow_nodes_fit_and_are_as_precise_as_a_typical_match(ramp_pair):
    f, g = ramp_pair.template, ramp_pair.search
    start = sgbm_start(f, g, disparity_range=(0, 16), step=4)
    res = refine_disparities(f, g, start, disparity_range=(0, 16), params=short(True)).grown
    slow = res.method == "slow"
    assert slow.sum() > 10
    others = ~slow
    assert res.sigma0[slow].max() <= np.median(res.sigma0[others])
    assert res.sigma_xy[slow].max() <= np.median(res.sigma_xy[others].max(axis=1))


def test_refine_census_node_by_node(ramp_pair):
    f, g = ramp_pair.template, ramp_pair.search
    start = sgbm_start(f, g, disparity_range=(0, 16), step=4)
    start[:5] = np.nan                                    # five rows not started
    mask = np.ones(f.shape, bool)
    mask[:, :40] = False                                  # ten columns masked
    out = refine_disparities(f, g, start, disparity_range=(0, 16), mask=mask,
                             params=short(False)).grown
    o, why = out.node_outcome, out.node_failure
    assert o.shape == why.shape == start.shape
    assert (o[:5] == NodeOutcome.NEVER_REACHED).all()
    assert (o[5:, :10][np.isfinite(start[5:, :10])] == NodeOutcome.MASKED).all()
    assert (o == NodeOutcome.MATCHED).sum() == len(out) == out.node_census["matched"]
    assert set(zip(*np.nonzero(o == NodeOutcome.MATCHED))) == set(map(tuple, out.node_index))
    failed = o == NodeOutcome.GIVEN_UP
    assert failed.sum() == out.node_census["failed"] > 0
    assert (why[failed] >= 0).all() and (why[~failed] == -1).all()
    # after 4 iterations most failures are nodes still moving, and the record says so
    assert (why[failed] == AttemptOutcome.MAX_ITERATIONS).mean() > 0.5
    textured = DisparityParams(grow=GrowParams(step=4, patch=9, min_texture=1e6))
    none = refine_disparities(f, g, start, disparity_range=(0, 16), params=textured).grown
    assert (none.node_outcome[np.isfinite(start)] == NodeOutcome.NO_TEXTURE).all()
