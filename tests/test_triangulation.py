import numpy as np
import pytest

from conftest import random_camera
from lsmta.synth import triplet_rig
from lsmta.triangulation import intersect_rays, triangulate


def _rig(rng, k=3):
    return [random_camera(rng, name=f"c{i}") for i in range(k)]


def test_exact_on_noise_free_data(rng):
    cams = _rig(rng, 4)
    X = rng.uniform([-800, -500, 0], [800, 500, 1900], (300, 3))
    xy = np.stack([c.project(X) for c in cams])
    res = triangulate(cams, xy)
    assert res.valid.all()
    assert np.abs(res.points - X).max() < 1e-6
    assert np.nanmax(res.reprojection_error) < 1e-6
    assert np.nanmax(res.ray_distance) < 1e-6


def test_missing_observations(rng):
    cams = _rig(rng, 3)
    X = rng.uniform([-500, -500, 200], [500, 500, 1800], (50, 3))
    xy = np.stack([c.project(X) for c in cams])
    xy[0, :20] = np.nan          # seen by two cameras only
    xy[1, :10] = np.nan          # seen by one camera only
    res = triangulate(cams, xy)
    assert list(np.unique(res.n_rays[:10])) == [1] and not res.valid[:10].any()
    assert np.isnan(res.points[:10]).all()
    assert res.valid[10:].all() and np.abs(res.points[10:] - X[10:]).max() < 1e-6
    assert np.isnan(res.reprojection_error[0, :20]).all()


def test_a_position_where_the_lens_folds_is_not_seen(rng):
    cams = _rig(rng, 3)
    X = rng.uniform([-500, -500, 200], [500, 500, 1800], (50, 3))
    xy = np.stack([c.project(X) for c in cams])
    c = cams[0]
    cams[0] = c.replace(k1=0.0, k2=-1.0 / (5 * 0.5 ** 4))     # folds at normalised radius 0.5
    xy[0, :5] = np.array([c.cx, c.cy]) + c.f * np.array([0.9, 0.0])   # past the fold
    assert not cams[0].invertible(xy[0, :5]).any()
    res = triangulate(cams, xy)                                  # raised before
    assert (res.n_rays[:5] == 2).all() and np.isnan(res.reprojection_error[0, :5]).all()
    assert res.valid[:5].all() and np.abs(res.points[:5] - X[:5]).max() < 1e-6


def test_noise_gives_consistent_residuals(rng):
    cams = triplet_rig()
    X = rng.uniform([-500, -500, 200], [500, 500, 1800], (4000, 3))
    sigma = 0.5
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, sigma, (3, 4000, 2))
    res = triangulate(cams, xy)
    # 6 observations, 3 unknowns: E[sum of squared residuals] = 3 sigma^2 over 3 cameras,
    # so the RMS reprojection error per camera is close to sigma
    rms = np.sqrt(np.nanmean(res.reprojection_error**2))
    assert 0.9 * sigma < rms < 1.1 * sigma


def test_near_parallel_rays_are_rejected():
    o = np.array([[[0.0, 0, 0]], [[1.0, 0, 0]]])          # 1 mm baseline
    target = np.array([0.0, 0.0, 10000.0])
    d = target - o
    res = intersect_rays(o, d, min_angle_deg=0.5)
    assert not res.valid[0] and np.isnan(res.points[0]).all()
    assert res.angle_deg[0] < 0.01
    res = intersect_rays(o, d, min_angle_deg=0.0)
    assert res.valid[0] and np.allclose(res.points[0], target, atol=1e-3)


def test_parallel_identical_rays_do_not_crash():
    o = np.zeros((2, 1, 3))
    d = np.tile([0.0, 0.0, 1.0], (2, 1, 1))
    res = intersect_rays(o, d, min_angle_deg=0.0)
    assert not res.valid[0]


@pytest.mark.parametrize("xy, match", [
    (np.zeros((2, 5, 2)), r"xy: expected an array of shape \(3, N, 2\)"),
    (np.full((3, 5, 2), np.inf), "xy: contains infinite"),
])
def test_bad_input(rng, xy, match):
    with pytest.raises(ValueError, match=match):
        triangulate(_rig(rng, 3), xy)
    with pytest.raises(TypeError, match="cameras"):
        triangulate(["not a camera"], np.zeros((1, 1, 2)))


def test_input_not_modified(rng):
    cams = _rig(rng, 2)
    X = rng.uniform([-500, -500, 200], [500, 500, 1800], (10, 3))
    xy = np.stack([c.project(X) for c in cams])
    xy[0, 0] = np.nan
    xy0 = xy.copy()
    triangulate(cams, xy)
    assert np.array_equal(xy, xy0, equal_nan=True)
