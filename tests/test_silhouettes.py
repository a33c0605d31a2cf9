"""Silhouettes from a background model, contours and snakes (issue 25, Fig. 16)."""

import numpy as np
import pytest

from lsmta.silhouettes import (
    SilhouetteParams,
    SnakeParams,
    learn_background,
    mask_contour,
    predict_contour,
    silhouettes,
    track_contours,
)

H, W, T = 120, 260, 7
A, B = 30.0, 20.0


def _blob(step):
    """A moving filled ellipse: masks (T, H, W), centres (T, 2), points inside it (T, N, 2)
    that move with it (the projected trajectories)."""
    yy, xx = np.mgrid[0:H, 0:W]
    cx = 40.0 + step * np.arange(T)
    cy = 60.0 + 2.0 * np.arange(T)
    masks = np.stack([((xx - a) / A) ** 2 + ((yy - b) / B) ** 2 <= 1 for a, b in zip(cx, cy)])
    rng = np.random.default_rng(0)
    ang, rad = rng.uniform(0, 2 * np.pi, 30), np.sqrt(rng.uniform(0, 1, 30))
    pts = np.stack([cx[:, None] + A * rad * np.cos(ang), cy[:, None] + B * rad * np.sin(ang)], -1)
    return masks, np.stack([cx, cy], 1), pts


def _distance(contour, centre):
    """Distance of contour points to the true ellipse (first order, exact enough here)."""
    x, y = (contour - centre).T
    g = np.sqrt((x / A) ** 2 + (y / B) ** 2)
    return np.abs(g - 1) * np.hypot(x, y) / g


@pytest.mark.parametrize("step", [9.0, 20.0])
def test_snake_prediction_on_a_moving_blob(step):
    masks, centres, pts = _blob(step)
    first = mask_contour(masks[0], n_points=100)
    with_pred = track_contours(masks.astype(float), first, tracks=pts)
    without = track_contours(masks.astype(float), first)
    err_pred = [np.median(_distance(c, m)) for c, m in zip(with_pred.contours, centres)]
    err_prev = [np.median(_distance(c, m)) for c, m in zip(without.contours, centres)]
    assert max(err_pred) < 0.2                     # sub-pixel on every frame
    assert (with_pred.n_predictors[1:] == 30).all() and with_pred.n_predictors[0] == 0
    # the predicted start already lies on the blob (the motion is a translation)
    assert np.median(_distance(with_pred.starts[3], centres[3])) < 0.5
    if step > 15:       # beyond the snake's capture range: lost without the prediction
        assert max(err_prev) > 5.0
    else:
        assert max(err_prev) < 0.5


def test_predict_contour_weights_nearby_points_and_ignores_missing():
    c = np.stack([np.cos(np.linspace(0, 2 * np.pi, 20, endpoint=False)),
                  np.sin(np.linspace(0, 2 * np.pi, 20, endpoint=False))], 1) * 10
    before = np.array([[10.0, 0.0], [-10.0, 0.0], [0.0, 0.0]])
    after = before + np.array([[2.0, 0.0], [0.0, 0.0], [np.nan, np.nan]])
    p = predict_contour(c, before, after, sigma=2.0)
    assert p[0, 0] == pytest.approx(12.0, abs=1e-6)          # next to the moving point
    assert p[10, 0] == pytest.approx(-10.0, abs=1e-6)        # next to the still one
    none = predict_contour(c, before, np.full_like(before, np.nan))
    np.testing.assert_array_equal(none, c)


def test_background_silhouette_is_the_largest_region_with_holes_filled():
    rng = np.random.default_rng(1)
    empty = 100 + rng.normal(0, 2, (40, 60, 80))
    img = 100 + rng.normal(0, 2, (60, 80))
    img[10:50, 20:50] = 160
    img[25:30, 30:35] = 100           # clothing that matches the wall: a hole
    img[5:8, 70:73] = 160             # a small distractor
    bg = learn_background(empty)
    assert np.median(bg.spread) == pytest.approx(2.0, rel=0.1)
    m = silhouettes(img[None], bg)[0]
    assert m[10:50, 20:50].all() and not m[5:8, 70:73].any()
    assert m.sum() - 40 * 30 <= 3         # at most a noise pixel or two on the edge


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="frames"):
        learn_background(np.zeros((2, 5, 5)))
    with pytest.raises(ValueError, match="mask"):
        mask_contour(np.zeros((5, 5), bool))
    with pytest.raises(ValueError, match="first"):
        track_contours(np.zeros((2, 9, 9)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="tracks"):
        track_contours(np.zeros((2, 9, 9)), np.ones((10, 2)), tracks=np.zeros((3, 4, 2)))
    with pytest.raises(ValueError, match="gamma"):
        SnakeParams(gamma=0)
    with pytest.raises(ValueError, match="closing"):
        SilhouetteParams(closing=-1)
    c = np.ones((10, 2))
    before = np.zeros((3, 2))
    predict_contour(c, before, before)
    assert (c == 1).all() and (before == 0).all()        # inputs untouched


def test_true_silhouette_and_contour_score_on_the_walk():
    from lsmta.evaluation.silhouettes import run_contour_trial, silhouette_walk

    data = silhouette_walk(n_frames=3, n_empty=4, scale=0.25, supersample=3)
    assert data.true_masks.shape == (3, 3 * data.camera.height, 3 * data.camera.width)
    trial = run_contour_trial(data, n_points=150)
    assert (trial.mask_iou > 0.8).all()
    assert np.median(trial.median_predicted) < 1.0
