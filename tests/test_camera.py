import cv2
import numpy as np
import pytest

from conftest import random_camera
from lsmta.camera import Camera, _undistort_error


def _points_in_front(rng, cam, n=500):
    xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n, 2))
    o, d = cam.rays(xy)
    return o + d * rng.uniform(1500, 8000, (n, 1))


@pytest.mark.parametrize("seed", range(10))
def test_projection_agrees_with_opencv(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng)
    X = _points_in_front(rng, cam)
    K, dist, rvec, tvec = cam.to_opencv()
    ref, _ = cv2.projectPoints(X, rvec, tvec, K, dist)
    assert np.abs(cam.project(X) - ref[:, 0]).max() < 1e-6


@pytest.mark.parametrize("seed", range(5))
def test_opencv_round_trip(seed):
    rng = np.random.default_rng(100 + seed)
    cam = random_camera(rng)
    back = Camera.from_opencv(*cam.to_opencv(), cam.image_size)
    X = _points_in_front(rng, cam)
    assert np.abs(back.project(X) - cam.project(X)).max() < 1e-9
    assert np.allclose(back.C, cam.C) and np.allclose(back.R, cam.R)


@pytest.mark.parametrize("seed", range(5))
def test_ray_round_trip_over_whole_image(seed):
    rng = np.random.default_rng(200 + seed)
    cam = random_camera(rng, shear=True)
    grid = cam.pixel_grid(supersample=1)[::7, ::7].reshape(-1, 2)
    corners = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [-0.5, cam.height - 0.5],
                        [cam.width - 0.5, cam.height - 0.5]])
    xy = np.vstack([grid, corners])
    o, d = cam.rays(xy)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    for depth in (500.0, 5000.0, 50000.0):
        assert np.abs(cam.project(o + depth * d) - xy).max() < 1e-6


def test_principal_point_ray_is_optical_axis():
    cam = Camera.look_at([0, -4000, 1000], [0, 0, 1000], f=1000, width=640,
                         height=480).replace(k1=-0.2, p1=1e-3)
    _, d = cam.rays([[cam.cx, cam.cy]])
    assert np.allclose(d[0], cam.R[2])


def test_look_at_orientation():
    cam = Camera.look_at([0, -4000, 1000], [0, 0, 1000], f=1000, width=640, height=480)
    # a point to the right (+X) appears to the right of centre, a point above appears higher
    xy = cam.project([[500, 0, 1000], [0, 0, 1500]])
    assert xy[0, 0] > cam.cx and abs(xy[0, 1] - cam.cy) < 1e-9
    assert xy[1, 1] < cam.cy


def test_shear_has_no_opencv_form(rng):
    cam = random_camera(rng, shear=True)
    with pytest.raises(ValueError, match="b2"):
        cam.to_opencv()


def test_principal_distance_mm():
    cam = Camera.look_at([0, -1, 0], [0, 0, 0], f=1000, width=10, height=10, pixel_size=0.008)
    assert cam.principal_distance_mm == pytest.approx(8.0)


def test_points_behind_camera(rng):
    cam = random_camera(rng)
    behind = cam.C - 1000 * cam.R[2]
    with pytest.raises(ValueError, match="behind"):
        cam.project(behind[None])
    xy = cam.project(np.vstack([behind, _points_in_front(rng, cam, 1)]), behind="nan")
    assert np.isnan(xy[0]).all() and np.isfinite(xy[1]).all()


@pytest.mark.parametrize("bad, match", [
    (np.zeros((5, 2)), r"X: expected an array of shape \(N, 3\)"),
    (np.zeros(3), r"X: expected an array of shape \(N, 3\)"),
    (np.array([[np.nan, 0, 1000]]), "X: contains non-finite"),
    (np.array([["a", "b", "c"]]), "X: expected a real numeric array"),
])
def test_project_bad_input(rng, bad, match):
    cam = random_camera(rng)
    with pytest.raises((ValueError, TypeError), match=match):
        cam.project(bad)


@pytest.mark.parametrize("kwargs, match", [
    ({"f": -1.0}, "f: expected a positive"),
    ({"width": 10.5}, "width"),
    ({"R": np.diag([1.0, 1.0, -1.0])}, "R: expected a proper rotation"),
    ({"C": [0.0, 0.0]}, r"C: expected an array of shape \(3,\)"),
    ({"k1": np.inf}, "k1: contains non-finite"),
])
def test_camera_bad_construction(kwargs, match):
    args = dict(f=1000.0, cx=0.0, cy=0.0, width=10, height=10, R=np.eye(3), C=np.zeros(3))
    args.update(kwargs)
    with pytest.raises((ValueError, TypeError), match=match):
        Camera(**args)


def test_inputs_not_modified_and_camera_immutable(rng):
    cam = random_camera(rng)
    X = _points_in_front(rng, cam, 20)
    X0 = X.copy()
    xy = cam.project(X)
    xy0 = xy.copy()
    cam.rays(xy)
    assert np.array_equal(X, X0) and np.array_equal(xy, xy0)
    R = np.eye(3)
    c2 = Camera(f=1000, cx=0, cy=0, width=10, height=10, R=R, C=np.zeros(3))
    R[0, 0] = 5.0  # the camera keeps its own copy
    assert c2.R[0, 0] == 1.0
    with pytest.raises(ValueError):
        c2.R[0, 0] = 2.0


def test_undistort_refuses_fold_over():
    cam = Camera(f=1000, cx=0, cy=0, width=10, height=10, R=np.eye(3), C=np.zeros(3), k1=-0.5)
    # x (1 - 0.5 x^2) peaks at 0.544 for x = 0.816: larger distorted values have no preimage
    with pytest.raises(ValueError, match="folds over"):
        cam.undistort([[0.7, 0.0]])


def test_in_lens_inside_the_fold_and_in_front():
    cam = Camera(f=1000, cx=0, cy=0, width=10, height=10, R=np.eye(3), C=np.zeros(3), k1=-0.5)
    # the radial map x (1 - 0.5 x^2) turns back at x = 0.816 (normalised): beyond, a point
    # still projects, onto a pixel of another ray
    X = np.array([[0.5, 0.0, 1.0], [0.8, 0.0, 1.0], [0.9, 0.0, 1.0], [0.5, 0.0, -1.0]])
    assert cam.in_lens(X).tolist() == [True, True, False, False]
    assert cam.replace(k1=0.0).in_lens(X).tolist() == [True, True, True, False]


def test_field_camera_for_every_other_row(rng):
    # notebook 00's recipe for interlaced cameras processed on one field (rows 0, 2, 4, ...)
    cam = random_camera(rng)
    half = cam.replace(f=cam.f / 2, b1=1 + 2 * cam.b1, cy=cam.cy / 2, height=cam.height // 2)
    X = _points_in_front(rng, cam)
    full, field = cam.project(X), half.project(X)
    assert np.abs(field[:, 0] - full[:, 0]).max() < 1e-9
    assert np.abs(field[:, 1] - full[:, 1] / 2).max() < 1e-9


def test_from_opencv_takes_no_field_that_comes_from_opencv(rng):
    cam = random_camera(rng)
    with pytest.raises(TypeError, match="k1"):
        Camera.from_opencv(*cam.to_opencv(), cam.image_size, k1=0.1)


@pytest.mark.parametrize("seed", range(3))
def test_undistort_error_is_the_numpy_forms(seed):
    # the compiled check of Newton's result: _distort's distance and _unfolded's test, bit
    # for bit, on points inside and past the fold and on non-finite ones
    rng = np.random.default_rng(seed)
    cam = random_camera(rng).replace(k1=-0.3, k2=0.01 * seed, k3=-0.01, p1=1e-3, p2=-2e-3)
    xy = np.concatenate([rng.uniform(-2.0, 2.0, (2000, 2)), [[np.nan, 0.0], [np.inf, 1.0]]])
    xd = rng.uniform(-0.5, 0.5, len(xy))
    yd = rng.uniform(-0.5, 0.5, len(xy))
    x, y = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
    back = cam._distort(x, y)
    with np.errstate(invalid="ignore"):
        want = np.where(cam._unfolded(x, y), np.hypot(back[:, 0] - xd, back[:, 1] - yd), np.inf)
    got = _undistort_error(x, y, xd, yd, cam.k1, cam.k2, cam.k3, cam.p1, cam.p2)
    assert np.isinf(want).sum() > 2 and np.isfinite(want).sum() > 100
    assert np.array_equal(got, want)
