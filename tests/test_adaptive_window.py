"""The growth's adaptive window (GrowParams.wide_patch, issue #33): a node too weakly textured
for the patch but not for the wide patch is matched with the wide patch; on a small generated
rectified pair with a weak-texture band (the truth from the generator)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.matching import DisparityParams, GrowParams, measure_disparity, refine_disparities
from lsmta.matching.disparity import WIDE_PATCH
from lsmta.matching.grow import METHODS, NodeOutcome
from lsmta.synth.patches import warped_pair

# x_right = 0.96 x + 0.03 y - 4.3 on the same row (rows stay rows: a rectified pair)
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])
BAND = (40, 84)    # rows of the weak texture


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


def params(wide):
    return DisparityParams(grow=replace(DisparityParams().grow, wide_patch=wide))


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
    wide = np.concatenate([on.grown.method] + [r.method for _, r in on.regrown]) == "wide"
    idx = np.concatenate([on.grown.node_index] + [r.node_index for _, r in on.regrown])
    assert wide.sum() >= 10                                   # 27 when written
    r, c = idx[wide].T
    e = np.abs(on.disparity[r, c] - truth[r, c])
    assert np.median(e) < 0.1 and e.max() < 0.6               # the same thresholds hold
    assert np.isfinite(on.disparity[band]).mean() > np.isfinite(off.disparity[band]).mean()
    # everywhere: still within the accuracy of the growth without it
    e_all = np.abs(on.disparity - truth)[np.isfinite(on.disparity)]
    assert np.median(e_all) < 0.02 and e_all.max() < 1.0


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
    assert np.median(e) < 0.1 and e.max() < 0.6
    assert on.density > off.density


def test_wide_is_a_method_label():
    assert METHODS[-1] == "wide"


@pytest.mark.parametrize("bad", [4, 8, 12.5, True, 5, 9])
def test_wide_patch_bad_input(bad):
    """Not an odd integer, or not wider than the main patch (9 px)."""
    with pytest.raises(ValueError, match="wide_patch"):
        GrowParams(patch=9, wide_patch=bad)


def test_wide_patch_must_be_wider_than_the_patch():
    with pytest.raises(ValueError, match=r"wide_patch: expected an odd integer > patch"):
        GrowParams(patch=15, wide_patch=13)
    assert GrowParams(patch=15, wide_patch=17).wide_patch == 17
