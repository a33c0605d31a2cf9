"""The growth's adaptive window (GrowParams.wide_patch, issue #33): a node too weakly textured
for the patch but not for the wide patch is matched with the wide patch, and so is a node whose
patch fails a precision test; on a small generated rectified pair with a weak-texture band
(the truth from the generator)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.matching import DisparityParams, GrowParams, measure_disparity, refine_disparities
from lsmta.matching.disparity import WIDE_PATCH
from lsmta.matching.grow import AttemptOutcome, NodeOutcome, wide_window_nodes
from lsmta.synth.patches import warped_pair

# x_right = 0.96 x + 0.03 y - 4.3 on the same row (rows stay rows: a rectified pair)
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])
BAND = (40, 84)    # rows of the weak texture
#: the growth's precision threshold with DisparityParams' defaults (0.2 px)
MAX_SIGMA_XY = DisparityParams().grow_params().thresholds.max_sigma_xy


@pytest.fixture(scope="module")
def band_pair():
    """A strong texture with a band of rows whose texture (2 grey levels, 10-30 px waves) is
    below the 9 x 9 patch's texture floor at most nodes and above it in 13 x 13 at some."""
    kw = dict(shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), noise_sigma=0.5)
    strong = warped_pair(rng=0, **kw)
    weak = warped_pair(rng=1, amplitude=2.0, wavelength=(10.0, 30.0), **kw)
    band = (np.arange(120) >= BAND[0]) & (np.arange(120) < BAND[1])
    f = np.where(band[:, None], weak.template, strong.template)
    g = np.where(band[:, None], weak.search, strong.search)
    return f, g, strong


def truth_grid(pair, shape, step):
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols] * step
    xy = np.stack([xx.ravel(), yy.ravel()], 1).astype(float)
    return (xy[:, 0] - pair.true_xy(xy)[:, 0]).reshape(rows, cols)


def params(wide, **grow):
    return DisparityParams(grow=replace(DisparityParams().grow, wide_patch=wide, **grow))


def tight(max_sigma_xy):
    """DisparityParams' thresholds with a tighter precision test."""
    return replace(DisparityParams().grow_params().thresholds, max_sigma_xy=max_sigma_xy)


def matched_wide(res):
    """Grid rows and columns of the nodes the wide patch matched (growth and regrowth)."""
    method = np.concatenate([res.grown.method] + [r.method for _, r in res.regrown])
    idx = np.concatenate([res.grown.node_index] + [r.node_index for _, r in res.regrown])
    return idx[method == "wide"].T


def test_wide_window_matches_weak_texture_accurately(band_pair):
    f, g, truth_pair = band_pair
    f0, g0 = f.copy(), g.copy()
    off = measure_disparity(f, g, disparity_range=(0, 16), params=params(None))
    on = measure_disparity(f, g, disparity_range=(0, 16), params=params(WIDE_PATCH))
    assert np.array_equal(f, f0) and np.array_equal(g, g0)              # inputs untouched
    truth = truth_grid(truth_pair, on.disparity.shape, on.step)
    band = slice(BAND[0] // on.step, BAND[1] // on.step)
    # without it the band's nodes are mostly below the texture floor
    assert (off.grown.node_outcome[band] == NodeOutcome.NO_TEXTURE).mean() > 0.5
    assert ((on.grown.node_outcome[band] == NodeOutcome.NO_TEXTURE).sum()
            < (off.grown.node_outcome[band] == NodeOutcome.NO_TEXTURE).sum())
    assert "wide" not in off.grown.method
    r, c = matched_wide(on)
    assert len(r) >= 10                                       # 27 when written
    e = np.abs(on.disparity[r, c] - truth[r, c])
    # each passed sigma_xy <= MAX_SIGMA_XY: none is more than three of those off the truth
    assert np.median(e) < 0.1 and e.max() < 3 * MAX_SIGMA_XY  # 0.07, 0.30 px when written
    assert np.isfinite(on.disparity[band]).mean() > np.isfinite(off.disparity[band]).mean()
    # everywhere: no worse than without it. The worst error may differ by a little (0.05 px
    # allowed): with it some nodes are reached from another neighbour and converge from
    # another start (0.55 px without, 0.52 px with it when written)
    e_all = np.abs(on.disparity - truth)[np.isfinite(on.disparity)]
    e_off = np.abs(off.disparity - truth)[np.isfinite(off.disparity)]
    assert np.median(e_all) < 0.02 and e_all.max() <= e_off.max() + 0.05


def test_wide_window_retries_nodes_failing_the_precision_test(band_pair):
    """On the strong texture alone (every node above the texture floor) with a precision
    test the 9 x 9 patch often fails (sigma_xy <= 0.01 px): the wide matches can only come
    from the retry after a precision failure, in the growth and started at the nodes."""
    f, g = band_pair[2].template, band_pair[2].search
    grow = dict(thresholds=tight(0.01))
    off = measure_disparity(f, g, disparity_range=(0, 16), params=params(None, **grow))
    on = measure_disparity(f, g, disparity_range=(0, 16), params=params(WIDE_PATCH, **grow))
    for res in (off, on):
        assert not (res.grown.node_outcome == NodeOutcome.NO_TEXTURE).any()
    r, c = matched_wide(on)
    assert len(r) >= 20                                       # 42 when written
    # without it, every one of these nodes failed the precision test
    assert np.all(off.grown.node_failure[r, c] == AttemptOutcome.SIGMA_XY)
    assert np.isfinite(on.disparity).sum() > np.isfinite(off.disparity).sum()
    truth = truth_grid(band_pair[2], on.disparity.shape, on.step)
    assert np.median(np.abs(on.disparity[r, c] - truth[r, c])) < 0.03   # 0.004 when written
    start = np.rint(truth)
    ref_off = refine_disparities(f, g, start, disparity_range=(0, 16), params=params(None, **grow))
    ref_on = refine_disparities(f, g, start, disparity_range=(0, 16),
                                params=params(WIDE_PATCH, **grow))
    assert "wide" not in ref_off.grown.method
    assert (ref_on.grown.method == "wide").sum() >= 20        # 42 when written
    assert ref_on.density > ref_off.density


def test_wide_window_only_where_it_fits(band_pair, monkeypatch):
    """With ``partial=False`` the wide patch is tried only where it lies inside the image, for
    the nodes below the texture floor and the nodes retried after a precision failure alike
    (a 7 x 7 main patch fits 3 px from the border, the 13 x 13 one needs 6 px)."""
    import lsmta.matching.grow as grow_module
    import lsmta.matching.refine as refine_module

    tried = []

    def spy(mpgc):
        def wrapped(f, g, t_xy, *args, params, **kw):
            if params.patch == WIDE_PATCH:
                tried.append(np.array(t_xy))
            return mpgc(f, g, t_xy, *args, params=params, **kw)
        return wrapped

    def spy_lean(once):      # the growth's own path for a rectified pair
        def wrapped(f, g, t_xy, t0, A0, weights, model, *args):
            if model.patch == WIDE_PATCH:
                tried.append(np.array(t_xy))
            return once(f, g, t_xy, t0, A0, weights, model, *args)
        return wrapped

    monkeypatch.setattr(grow_module, "mpgc", spy(grow_module.mpgc))
    monkeypatch.setattr(grow_module, "_rectified_once", spy_lean(grow_module._rectified_once))
    monkeypatch.setattr(refine_module, "mpgc", spy(refine_module.mpgc))
    f, g, truth_pair = band_pair
    p = params(WIDE_PATCH, thresholds=tight(0.01), partial=False, patch=7)
    h, w = f.shape
    half = WIDE_PATCH // 2
    for run in (lambda: measure_disparity(f, g, disparity_range=(0, 16), params=p),
                lambda: refine_disparities(f, g, np.rint(truth_grid(truth_pair, (30, 40), 4)),
                                           disparity_range=(0, 16), params=p)):
        tried.clear()
        run()
        xy = np.concatenate(tried)
        assert len(xy) > 0
        assert np.all((xy >= half) & (xy <= np.array([w - 1, h - 1]) - half))


def test_wide_window_nodes_rule():
    """The shared rule: wide-only or precision-failed, unmatched, and where it fits."""
    fail = np.array([AttemptOutcome.SIGMA0, AttemptOutcome.SIGMA_XY, AttemptOutcome.SIGMA_XY,
                     AttemptOutcome.MAX_ITERATIONS, -1, -1, AttemptOutcome.SHEAR])
    matched = np.array([0, 0, 1, 0, 0, 0, 0], bool)
    wide_only = np.array([0, 0, 0, 0, 1, 0, 0], bool)
    got = wide_window_nodes(fail, matched=matched, wide_only=wide_only, fits=np.ones(7, bool))
    assert got.tolist() == [True, True, False, False, True, False, False]
    assert not wide_window_nodes(fail, matched=matched, wide_only=wide_only,
                                 fits=np.zeros(7, bool)).any()


def test_refine_at_sgbm_nodes_uses_the_wide_window(band_pair):
    """refine_disparities (LSM at started nodes, no growth) with the wide window: the
    weakly textured started nodes are tried with it, and those it keeps are accurate."""
    f, g, truth_pair = band_pair
    rows, cols = (119 // 4 + 1, 159 // 4 + 1)
    truth = truth_grid(truth_pair, (rows, cols), 4)
    start = np.rint(truth)                       # a start within 0.5 px at every node
    off = refine_disparities(f, g, start, disparity_range=(0, 16), params=params(None))
    on = refine_disparities(f, g, start, disparity_range=(0, 16), params=params(WIDE_PATCH))
    assert "wide" not in off.grown.method
    wide = on.grown.method == "wide"
    assert wide.sum() >= 10
    r, c = on.grown.node_index[wide].T
    e = np.abs(on.disparity[r, c] - truth[r, c])
    assert np.median(e) < 0.1 and e.max() < 3 * MAX_SIGMA_XY
    assert on.density > off.density


@pytest.mark.parametrize("bad", [4, 8, 12.5, True, 5, 9])
def test_wide_patch_bad_input(bad):
    """Not an odd integer, or not wider than the main patch (9 px)."""
    with pytest.raises(ValueError, match="wide_patch"):
        GrowParams(patch=9, wide_patch=bad)


def test_wide_patch_must_be_wider_than_the_patch():
    with pytest.raises(ValueError, match=r"wide_patch: expected an odd integer > patch"):
        GrowParams(patch=15, wide_patch=13)
    assert GrowParams(patch=15, wide_patch=17).wide_patch == 17
