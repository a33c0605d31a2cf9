"""measure_disparity(seeds="sgbm"): LSM started at OpenCV SGBM's nodes, then growth into the
nodes left open; on small generated rectified pairs (the truth from the generator)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.matching import (
    DisparityParams,
    GrowParams,
    measure_disparity,
    refine_disparities,
    sgbm_start,
)
from lsmta.matching import disparity as disparity_module
from lsmta.matching.peers import sgbm_hh_bytes, stereo_sgbm
from lsmta.synth.patches import warped_pair

# x_right = 0.96 x + 0.03 y - 4.3 on the same row: the disparity is the ramp
# d(x, y) = 0.04 x - 0.03 y + 4.3
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])


@pytest.fixture(scope="module")
def ramp_pair():
    return warped_pair(rng=0, shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), r0=5.0, r1=0.9,
                       noise_sigma=2.0)


def truth_grid(pair, shape, step):
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols] * step
    xy = np.stack([xx.ravel(), yy.ravel()], 1).astype(float)
    return (xy[:, 0] - pair.true_xy(xy)[:, 0]).reshape(rows, cols)


def test_sgbm_start_gives_lsm_disparities_not_sgbm_ones(ramp_pair):
    f, g = ramp_pair.template, ramp_pair.search
    start = sgbm_start(f, g, disparity_range=(0, 16), step=4)
    out = measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm")
    truth = truth_grid(ramp_pair, out.disparity.shape, out.step)
    assert start.shape == out.disparity.shape
    e_sgbm = np.abs(start - truth)[np.isfinite(start)]
    e = np.abs(out.disparity - truth)[np.isfinite(out.disparity)]
    assert out.density > 0.9
    assert np.median(e) < 0.03 < 0.1 < np.median(e_sgbm)      # 0.015 px against 0.11 px
    assert e.max() < 1.0
    # SGBM's disparities come in 1/16 px; LSM's do not
    on_grid = np.isclose(out.disparity * 16, np.rint(out.disparity * 16), atol=1e-6)
    assert on_grid[np.isfinite(out.disparity)].mean() < 0.05
    rc = np.rint(out.seeds.xy[0][:, ::-1] / out.step).astype(int)   # the started nodes
    assert np.array_equal(out.seeds.disparity, start[rc[:, 0], rc[:, 1]])
    r, c = out.grown.node_index.T
    assert np.isfinite(start[r, c]).all()                   # LSM only where SGBM started it


def test_growth_fills_the_nodes_sgbm_left_empty(ramp_pair, monkeypatch):
    """SGBM with a block knocked out: LSM at its other nodes, then the growth from their
    accepted neighbours fills the block (sgbm_fill), accurately; 'none' leaves it empty."""
    f, g = ramp_pair.template, ramp_pair.search

    def holed(left, right, *, disparity_range, step):
        d = sgbm_start(left, right, disparity_range=disparity_range, step=step)
        d[10:20, 12:28] = np.nan
        return d

    monkeypatch.setattr(disparity_module, "sgbm_start", holed)
    runs = {fill: measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm",
                                    params=DisparityParams(sgbm_fill=fill))
            for fill in ("none", "sgbm-empty", "unmeasured")}
    assert not np.isfinite(runs["none"].disparity[10:20, 12:28]).any()
    assert runs["none"].regrown == ()
    truth = truth_grid(ramp_pair, runs["none"].disparity.shape, 4)
    refined = np.isfinite(runs["none"].disparity)
    for fill in ("sgbm-empty", "unmeasured"):
        d = runs[fill].disparity
        assert np.isfinite(d[10:20, 12:28]).mean() > 0.9
        assert np.median(np.abs(d - truth)[10:20, 12:28][np.isfinite(d[10:20, 12:28])]) < 0.03
        assert np.array_equal(d[refined], runs["none"].disparity[refined])  # never matched again
        assert len(runs[fill].regrown) == 1


def test_sgbm_path_has_its_own_settings_and_leaves_the_default_path_alone(ramp_pair):
    f, g = ramp_pair.template, ramp_pair.search
    tight = DisparityParams(sgbm_grow=GrowParams(step=4, patch=9, geometry="row-affine",
                                                 method="inverse", partial=True,
                                                 min_texture=1e6))
    assert np.isnan(measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm",
                                      params=tight).disparity).all()   # no node textured enough
    a = measure_disparity(f, g, disparity_range=(0, 16), params=tight)
    b = measure_disparity(f, g, disparity_range=(0, 16))
    assert np.array_equal(a.disparity, b.disparity, equal_nan=True)


def test_bad_input_for_the_sgbm_start(ramp_pair):
    f, g = ramp_pair.template.copy(), ramp_pair.search.copy()
    for bad in ("SGBM", "grow", 5, np.zeros((2, 3, 2))):
        with pytest.raises(ValueError, match="seeds"):
            measure_disparity(f, g, disparity_range=(0, 16), seeds=bad)
    with pytest.raises(ValueError, match="sgbm_fill"):
        DisparityParams(sgbm_fill="all")
    with pytest.raises(ValueError, match="sgbm_fill"):
        DisparityParams(sgbm_fill=["none"])
    with pytest.raises(TypeError, match="sgbm_grow"):
        DisparityParams(sgbm_grow=3)
    with pytest.raises(ValueError, match="start"):
        refine_disparities(f, g, np.zeros(10), disparity_range=(0, 16))
    # a start grid of another step, or a mask of another size, is refused, not read as this one
    start4 = sgbm_start(f, g, disparity_range=(0, 16), step=4)
    with pytest.raises(ValueError, match="start"):
        refine_disparities(f, g, start4, disparity_range=(0, 16),
                           params=DisparityParams(grow=GrowParams(step=2)))
    with pytest.raises(ValueError, match="mask"):
        refine_disparities(f, g, start4, disparity_range=(0, 16), mask=np.ones((10, 10), bool))
    with pytest.raises(ValueError, match="sgbm_grow"):
        DisparityParams(sgbm_grow=GrowParams(step=2))
    measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm")
    assert np.array_equal(f, ramp_pair.template) and np.array_equal(g, ramp_pair.search)


def test_sgbm_path_follows_the_callers_step(ramp_pair):
    # the SGBM start's growth defaults to the caller's grow (texture floor aside): at step 2
    # its map is on the step-2 grid the automatic path uses
    f, g = ramp_pair.template, ramp_pair.search
    p = DisparityParams(grow=replace(DisparityParams().grow, step=2))
    auto = measure_disparity(f, g, disparity_range=(0, 16), params=p)
    sg = measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm", params=p)
    assert sg.step == auto.step == 2 and sg.disparity.shape == auto.disparity.shape
    assert p.grow_params(sgbm=True).min_texture == disparity_module.SGBM_MIN_TEXTURE


def test_sgbm_start_bounds_its_memory(ramp_pair):
    # above max_bytes the start runs SGBM's 5-path single-pass mode instead of the 8-path one
    f, g = ramp_pair.template, ramp_pair.search
    assert sgbm_hh_bytes((120, 160), 16) == 4 * 120 * (160 - 16) * 16
    hh = sgbm_start(f, g, disparity_range=(0, 16), step=4)
    five = sgbm_start(f, g, disparity_range=(0, 16), step=4, max_bytes=1)
    assert hh.shape == five.shape and np.isfinite(five).mean() > 0.5
    assert not np.array_equal(hh, five, equal_nan=True)          # another mode ran
    truth = truth_grid(ramp_pair, five.shape, 4)
    assert np.nanmedian(np.abs(five - truth)) < 0.5
    with pytest.raises(ValueError, match="max_bytes"):
        sgbm_start(f, g, disparity_range=(0, 16), max_bytes=0)
    with pytest.raises(ValueError, match="mode"):
        stereo_sgbm(f, g, num_disparities=16, mode="3way")
