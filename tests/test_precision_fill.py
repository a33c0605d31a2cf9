"""The texture test by a rule (DisparityParams.precision_fill, row_precision_nodes; issue #33
item 1), on small generated images and rectified pairs (the truth from the generator)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.matching import DisparityParams, disparity, measure_disparity
from lsmta.matching.disparity import row_precision_nodes
from lsmta.synth.patches import warped_pair

# x_right = 0.96 x + 0.03 y - 4.3 on the same row: the disparity d = 0.04 x - 0.03 y + 4.3
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])


def test_row_precision_follows_the_row_gradient():
    # a ramp a * x: every pixel's row derivative is a, so sum g_x^2 = patch^2 a^2 and the rule
    # sigma0 / (patch a) <= max_sigma holds from a = sigma0 / (patch max_sigma) = 2 / 1.8 on
    x = np.arange(60, dtype=float)
    for a, expected in ((1.2, True), (1.0, False)):
        img = np.tile(a * x, (40, 1))
        kept = img.copy()
        out = row_precision_nodes(img, patch=9, step=4, sigma0=2.0, max_sigma=0.2)
        assert out.shape == (10, 15) and out.dtype == bool
        assert (out == expected).all()
        assert np.array_equal(img, kept)
    # the row, not the column: horizontal stripes carry no disparity information
    stripes = np.tile(20.0 * (np.arange(40) % 4 >= 2)[:, None], (1, 60))   # period 4 px
    assert not row_precision_nodes(stripes, patch=9, step=4, sigma0=1.0, max_sigma=0.2).any()
    assert row_precision_nodes(stripes.T.copy(), patch=9, step=4, sigma0=1.0,
                               max_sigma=0.2).all()


def test_bad_input_for_the_row_precision():
    img = np.random.default_rng(0).normal(size=(30, 30))
    good = dict(patch=9, step=4, sigma0=1.0, max_sigma=0.2)
    for name, bad in (("patch", 8), ("patch", 3), ("step", 0), ("sigma0", 0.0),
                      ("sigma0", np.nan), ("max_sigma", -0.1)):
        with pytest.raises(ValueError, match=name):
            row_precision_nodes(img, **{**good, name: bad})
    with pytest.raises(ValueError, match="image"):
        row_precision_nodes(np.zeros((4, 4, 3)), **good)
    with pytest.raises(ValueError, match="precision_fill"):
        DisparityParams(precision_fill="yes")
    assert DisparityParams().precision_fill is False


def test_precision_fill_grows_into_nodes_below_the_texture_floor():
    pair = warped_pair(rng=0, shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), r0=5.0, r1=0.9,
                       noise_sigma=2.0)
    f, g = pair.template, pair.search
    grow = replace(DisparityParams().grow, min_texture=25.0)    # most nodes below the floor
    off = measure_disparity(f, g, disparity_range=(0, 16),
                            params=DisparityParams(grow=grow))
    on = measure_disparity(f, g, disparity_range=(0, 16),
                           params=DisparityParams(grow=grow, precision_fill=True))
    rows, cols = on.disparity.shape
    yy, xx = np.mgrid[0:rows, 0:cols] * 4
    xy = np.stack([xx.ravel(), yy.ravel()], 1).astype(float)
    truth = (xy[:, 0] - pair.true_xy(xy)[:, 0]).reshape(rows, cols)
    assert off.density < 0.5 < 0.9 < on.density                 # 0.36 and 0.97 when written
    measured = np.isfinite(off.disparity)
    assert np.array_equal(on.disparity[measured], off.disparity[measured])   # not matched again
    added = np.isfinite(on.disparity) & ~measured
    e = np.abs(on.disparity - truth)[added]
    assert np.median(e) < 0.03 and np.mean(e > 0.3) < 0.01
    assert len(on.regrown) == len(off.regrown) + 1
    # the fill is the automatic seeds' only: the SGBM start keeps its own texture floor
    sg = [measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm",
                            params=DisparityParams(grow=grow, precision_fill=False))]
    with pytest.warns(UserWarning, match="precision_fill"):
        sg.append(measure_disparity(f, g, disparity_range=(0, 16), seeds="sgbm",
                                    params=DisparityParams(grow=grow, precision_fill=True)))
    assert np.array_equal(sg[0].disparity, sg[1].disparity, equal_nan=True)


def test_precision_fill_leaves_a_flat_strip_and_takes_the_pairs_median(monkeypatch):
    pair = warped_pair(rng=0, shape=(120, 160), A=A_RECT, c=(-4.3, 0.0), r0=5.0, r1=0.9,
                       noise_sigma=2.0)
    f, g = pair.template.copy(), pair.search.copy()
    f[40:80], g[40:80] = 100.0, 100.0                 # a flat strip across both images
    grow = replace(DisparityParams().grow, min_texture=25.0)
    seen = []

    def spy(image, **kw):                             # the sigma0 the fill uses
        seen.append(kw["sigma0"])
        return row_precision_nodes(image, **kw)

    monkeypatch.setattr(disparity, "row_precision_nodes", spy)
    off = measure_disparity(f, g, disparity_range=(0, 16), params=DisparityParams(grow=grow))
    on = measure_disparity(f, g, disparity_range=(0, 16),
                           params=DisparityParams(grow=grow, precision_fill=True))
    assert on.density > off.density + 0.2             # the fill works beside the strip
    # nodes whose 9 x 9 patch lies inside the strip (rows 44..75 px: node rows 11..18) have no
    # row gradient: no sigma0 passes them, and they stay unmeasured
    assert np.isnan(on.disparity[11:19]).all()
    # sigma0 is the pair's: the median of the matches before the fill (a constant fails)
    assert seen == [pytest.approx(np.median(off.sigma0[np.isfinite(off.sigma0)]), rel=1e-12)]
    # and the nodes it added pass the rule at that sigma0
    added = np.isfinite(on.disparity) & ~np.isfinite(off.disparity)
    rule = row_precision_nodes(f, patch=grow.patch, step=4, sigma0=seen[0], max_sigma=0.2)
    assert added.any() and rule[added].all()
