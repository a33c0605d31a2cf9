"""The growth's fast paths (issue #33 item 4) give what the general code gives: the rectified
pair's lean matcher against mpgc, the compiled candidates against a numpy reference, the
texture test by box filters against the per-patch spread; and the disparities of a generated
pair do not depend on them."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from lsmta.matching import DisparityParams, RectifiedPair, measure_disparity, mpgc
from lsmta.matching.grow import (
    ATTEMPT_OUTCOMES,
    FAR,
    HORIZONTAL,
    VERTICAL,
    _candidates,
    _Matcher,
    _options,
    _patch_spread,
    _spread,
    _tally,
)
from lsmta.matching.spline import SplineImage
from lsmta.synth.patches import warped_pair

A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])


@pytest.fixture(scope="module")
def rectified():
    return warped_pair(rng=3, shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), r0=5.0, r1=0.9,
                       noise_sigma=2.0)


def test_lean_rectified_matcher_equals_mpgc(rectified):
    f, g = SplineImage(rectified.template), SplineImage(rectified.search)
    opts = _options(DisparityParams().grow_params(), RectifiedPair())
    matcher = _Matcher(f, [g], opts, None)
    rng = np.random.default_rng(5)
    n = 400
    xy = np.c_[rng.integers(0, 40, n) * 4, rng.integers(0, 30, n) * 4].astype(float)  # borders
    t0 = xy[:, 0] - rectified.true_xy(xy)[:, 0] + rng.normal(0.0, 1.5, n)
    A0 = np.tile(np.eye(2), (n, 1, 1, 1))
    for params in [p for p, _ in opts.attempts] + [opts.seed]:          # seed: no thresholds
        lean = matcher._rectified(xy, t0, A0, params)
        ref = mpgc(f, [g], xy, t0, RectifiedPair(), initial_A=A0, params=params)
        views = [ref.image(0)]
        code = _tally(dict.fromkeys(ATTEMPT_OUTCOMES, 0), ref.status, params.thresholds, views)
        assert np.array_equal(lean.ok, ref.ok)
        assert np.array_equal(lean.failure, code)
        assert len(set(code.tolist())) > 2            # several outcomes were compared
        for name, want in (("t", ref.t), ("sigma_t", ref.sigma_t), ("sigma0", ref.sigma0),
                           ("xy", ref.xy.transpose(1, 0, 2)),
                           ("A", ref.A.transpose(1, 0, 2, 3)),
                           ("sigma_xy", ref.sigma_xy.transpose(1, 0, 2))):
            np.testing.assert_array_equal(getattr(lean, name), want, err_msg=name)


def _candidates_reference(frontier, state, usable, cell, directions, *, same_cell):
    """The numpy version the compiled one replaced."""
    rows, cols = state.shape
    fr = np.argwhere(frontier)
    cands, parents = [], []
    for dc, dr in directions:
        nb = fr + (dr, dc)
        inside = (nb[:, 0] >= 0) & (nb[:, 0] < rows) & (nb[:, 1] >= 0) & (nb[:, 1] < cols)
        nb, par = nb[inside], fr[inside]
        keep = usable[nb[:, 0], nb[:, 1]] & (state[nb[:, 0], nb[:, 1]] == 0)
        if same_cell:
            keep &= cell[nb[:, 0], nb[:, 1]] == cell[par[:, 0], par[:, 1]]
        cands.append(nb[keep])
        parents.append(par[keep])
    cand, par = np.concatenate(cands), np.concatenate(parents)
    _, first = np.unique(cand[:, 0] * cols + cand[:, 1], return_index=True)
    return cand[first], par[first]


def test_compiled_candidates_equal_the_reference():
    rng = np.random.default_rng(11)
    for _ in range(60):
        rows, cols = rng.integers(1, 25, 2)
        frontier = rng.random((rows, cols)) < rng.random()
        state = rng.integers(0, 3, (rows, cols)).astype(np.int8)
        usable = rng.random((rows, cols)) < 0.8
        cell = rng.integers(0, 4, (rows, cols))
        for directions in (HORIZONTAL, VERTICAL, HORIZONTAL + VERTICAL + FAR):
            for same_cell in (True, False):
                got = _candidates(frontier, state, usable, cell, directions,
                                  same_cell=same_cell)
                want = _candidates_reference(frontier, state, usable, cell, directions,
                                             same_cell=same_cell)
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


@pytest.mark.parametrize("scale", [1.0, 1 / 255])
def test_texture_test_by_box_filters_equals_the_patch_spread(scale):
    # grey levels in half steps: many patches sit exactly on a limit of 0.5, 1 or 2
    rng = np.random.default_rng(2)
    image = np.round(rng.random((45, 60)) * rng.choice([1, 4, 8], (45, 60))) / 2 * scale
    f = SplineImage(image)
    H, W = image.shape
    gr, gc = np.mgrid[0:(H - 1) // 2 + 1, 0:(W - 1) // 2 + 1]
    flat = np.stack([gc * 2, gr * 2], axis=-1).reshape(-1, 2).astype(float)
    for size in (5, 9):
        hp = size // 2
        interior = ((gc * 2 >= hp) & (gc * 2 <= W - 1 - hp) & (gr * 2 >= hp)
                    & (gr * 2 <= H - 1 - hp))
        for usable in (rng.random(gr.shape) < 0.9, interior):
            for limit in (0.0, 0.5, 1.0, 2.0):
                opts = SimpleNamespace(min_texture=limit * scale)
                got = _spread(f, opts, usable, flat, usable.shape, size)
                u = usable.ravel()
                x, y = flat[u, 0].astype(int), flat[u, 1].astype(int)
                spread = np.zeros(len(flat))
                spread[u] = _patch_spread(image, x, y, hp, masked=not interior[usable].all())
                want = spread >= limit * scale
                assert np.array_equal(got, want.reshape(usable.shape))


def test_disparities_unchanged_by_a_second_identical_call(rectified):
    """The grid is a pure function of the pair (no state kept between calls)."""
    params = replace(DisparityParams(), n_seeds=10)
    one = measure_disparity(rectified.template, rectified.search, disparity_range=(0, 12),
                            params=params)
    two = measure_disparity(rectified.template, rectified.search, disparity_range=(0, 12),
                            params=params)
    assert one.density > 0.5
    np.testing.assert_array_equal(one.disparity, two.disparity)
