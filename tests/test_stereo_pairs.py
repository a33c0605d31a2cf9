"""The bundled Middlebury pairs (lsmta.data.load_stereo_pair) and the per-pair comparison
of notebook 16 (lsmta.real.stereo.compare_on_pair)."""

import numpy as np
import pytest

from lsmta.data import STEREO_PAIRS, load_stereo_pair
from lsmta.real import stereo

SHAPES = {"cones": (375, 450), "teddy": (375, 450), "art": (370, 463), "tsukuba": (288, 384)}
# the truth's range in px, as the sources document it (Tsukuba: 5-14 px; the others from
# their scale factors and the largest stored value)
RANGES = {"cones": (5.5, 55.0), "teddy": (12.5, 52.75), "art": (24.33, 74.67),
          "tsukuba": (5.0, 14.0)}


def _photometric_error(pair, sign):
    """Median |left(x, y) - right(x - sign d, y)| over the scored pixels (grey levels)."""
    ys, xs = np.nonzero(np.isfinite(pair.disparity) & pair.nonoccluded)
    xr = np.rint(xs - sign * pair.disparity[ys, xs]).astype(int)
    inside = (xr >= 0) & (xr < pair.left.shape[1])
    left = pair.left[ys[inside], xs[inside]].astype(float)
    right = pair.right[ys[inside], xr[inside]].astype(float)
    return float(np.median(np.abs(left - right)))


@pytest.mark.parametrize("name", list(STEREO_PAIRS))
def test_pair_shapes_types_and_truth_range(name):
    pair = load_stereo_pair(name)
    assert pair.name == name
    assert pair.left.shape == pair.right.shape == pair.disparity.shape == SHAPES[name]
    assert pair.left.dtype == pair.right.dtype == np.uint8
    assert pair.disparity.dtype == np.float64 and pair.nonoccluded.dtype == bool
    d = pair.disparity[np.isfinite(pair.disparity)]
    lo, hi = RANGES[name]
    assert abs(d.min() - lo) < 0.01 and abs(d.max() - hi) < 0.01
    # the truth sits on its stated steps, and the search range covers it
    assert np.allclose(d / pair.truth_step, np.rint(d / pair.truth_step))
    assert pair.disparity_range[0] == 0 and pair.disparity_range[1] % 16 == 0
    assert d.max() < pair.disparity_range[1]
    assert 0.7 < pair.nonoccluded.mean() < 0.9


@pytest.mark.parametrize("name", list(STEREO_PAIRS))
def test_left_and_right_are_not_swapped(name):
    """With the truth, left pixels land on matching right pixels at x - d; the swapped
    reading (x + d) lands far off. Tsukuba's file names look swapped: this is its check."""
    pair = load_stereo_pair(name)
    right_way, swapped = _photometric_error(pair, +1), _photometric_error(pair, -1)
    assert right_way <= 4 and swapped > 3 * right_way


def test_tsukuba_mask_hides_what_the_right_camera_cannot_see():
    """The derived mask: a pixel whose right-image position a nearer pixel to its right
    covers is marked occluded, and the border without truth is not scored."""
    pair = load_stereo_pair("tsukuba")
    assert not pair.nonoccluded[~np.isfinite(pair.disparity)].any()
    known = np.isfinite(pair.disparity)
    assert 0.005 < 1 - pair.nonoccluded[known].mean() < 0.1


def test_unknown_pair_is_refused():
    with pytest.raises(ValueError, match="name"):
        load_stereo_pair("venus")


def test_compare_on_pair_scores_all_methods_on_the_same_nodes():
    pair = load_stereo_pair("tsukuba")
    run = stereo.compare_on_pair(pair, repeats=1)
    assert tuple(run.maps) == stereo.METHODS
    truth, scored = pair.grid(4)
    assert run.n_scored == int(scored.sum())
    for method, m in run.maps.items():
        assert m.shape == truth.shape
        s = run.scores[method]
        assert s["n"] == int((scored & np.isfinite(m)).sum())
    assert run.scores["ours"]["density"] > 0.3 and run.scores["ours"]["bad1"] < 0.1
    start = run.scores["ours, SGBM start"]
    assert start["density"] > 0.3 and start["bad1"] < 0.1
    assert set(run.targets()) == {"median", "bad1", "density", "time"}
    assert set(run.targets(method="ours, SGBM start")) == {"median", "bad1", "density", "time"}
    assert run.ratio("ours") == run.time_ratio > 0 and run.ratio("BM", cpu=False) > 0
    with pytest.raises(ValueError, match="method"):
        run.targets(method="BM")
    with pytest.raises(ValueError, match="repeats"):
        stereo.compare_on_pair(pair, repeats=0)
