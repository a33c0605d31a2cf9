"""Seeds and growth between a camera and one mounted on its side (issue #40: caliscope's
webcam rig): the search patch through the map the cameras predict (find_seeds' warp)."""

import numpy as np
import pytest
from scipy import ndimage

from lsmta.camera import Camera
from lsmta.matching import GrowParams, LSMThresholds, MeasureSurfaceParams, measure_surface
from lsmta.matching.seeds import find_seeds, predicted_maps
from lsmta.tracking import TrackerParams, TrackStatus, track_points

PLANE_Z = 1000.0         # mm: a textured wall square to the first camera's axis
TEXEL = 2.0              # mm per texture sample


def _texture(rng) -> np.ndarray:
    """A random blob texture (grey levels about 40-210) on the plane, 500 x 500 samples."""
    t = ndimage.gaussian_filter(rng.standard_normal((500, 500)), 2.0)
    return 125 + 85 * t / np.abs(t).max()


def _render(camera: Camera, texture: np.ndarray, shift_mm: float = 0.0) -> np.ndarray:
    """The plane z = PLANE_Z (texture centred on the z axis, moved ``shift_mm`` along x) as
    ``camera`` sees it."""
    grid = np.stack(np.meshgrid(np.arange(camera.width, dtype=float),
                                np.arange(camera.height, dtype=float)), -1).reshape(-1, 2)
    o, d = camera.rays(grid)
    X = o + ((PLANE_Z - o[:, 2]) / d[:, 2])[:, None] * d
    rows = X[:, 1] / TEXEL + texture.shape[0] / 2
    cols = (X[:, 0] - shift_mm) / TEXEL + texture.shape[1] / 2
    img = ndimage.map_coordinates(texture, [rows, cols], order=3, mode="reflect")
    return img.reshape(camera.height, camera.width)


def _rig(roll_deg: float):
    """Two 160 x 120 cameras 150 mm apart looking at the plane; the second turned by
    ``roll_deg`` about its own axis (a camera mounted on its side at 90)."""
    target = np.array([0.0, 0.0, PLANE_Z])
    a = Camera.look_at([-75.0, 0.0, 0.0], target, f=200.0, width=160, height=120,
                       up=(0.0, -1.0, 0.0))
    b = Camera.look_at([75.0, 0.0, 0.0], target, f=200.0, width=160, height=120,
                       up=(0.0, -1.0, 0.0))
    t = np.radians(roll_deg)
    turn = np.array([[np.cos(t), np.sin(t), 0.0], [-np.sin(t), np.cos(t), 0.0], [0, 0, 1]])
    return [a, b.replace(R=turn @ b.R)]


@pytest.fixture(scope="module")
def turned():
    cams = _rig(90.0)
    tex = _texture(np.random.default_rng(3))
    return cams, [_render(c, tex) for c in cams]


def _seed_errors(seeds, cams) -> np.ndarray:
    """Distance (px) of each seed in the search image from the true image of its template
    point on the plane."""
    o, d = cams[0].rays(seeds.xy[0])
    X = o + ((PLANE_Z - o[:, 2]) / d[:, 2])[:, None] * d
    return np.linalg.norm(cams[1].project(X) - seeds.xy[1], axis=1)


def test_predicted_map_of_a_camera_on_its_side():
    cams = _rig(90.0)
    X = np.array([0.0, 0.0, PLANE_Z])
    A = predicted_maps(cams, 0, X, PLANE_Z)[1]
    assert A.shape == (2, 2)
    # a quarter turn, scale about 1 (the same distance and focal length)
    np.testing.assert_allclose(np.abs(A[[0, 1], [1, 0]]), 1.0, atol=0.05)
    np.testing.assert_allclose(A[[0, 1], [0, 1]], 0.0, atol=0.05)


def test_seeds_through_the_predicted_map(turned):
    cams, images = turned
    kw = dict(template=0, n_seeds=10, patch=9, min_distance=10, depth_range=(600.0, 1600.0))
    square = find_seeds(images, cams, warp="identity", **kw)
    warped = find_seeds(images, cams, warp="auto", **kw)
    good_square = int((_seed_errors(square, cams) < 1.0).sum()) if square.xy.shape[1] else 0
    assert warped.xy.shape[1] >= 5
    assert np.median(_seed_errors(warped, cams)) < 1.0
    assert good_square < warped.xy.shape[1]
    assert warped.A.shape == (2, warped.xy.shape[1], 2, 2)
    np.testing.assert_array_equal(warped.A[0], np.broadcast_to(np.eye(2), warped.A[0].shape))
    with pytest.raises(ValueError, match="warp"):
        find_seeds(images, cams, warp="rotated", **kw)


def test_auto_keeps_the_square_patch_for_an_upright_rig():
    cams = _rig(0.0)
    tex = _texture(np.random.default_rng(4))
    images = [_render(c, tex) for c in cams]
    kw = dict(template=0, n_seeds=10, patch=9, min_distance=10, depth_range=(600.0, 1600.0))
    square = find_seeds(images, cams, warp="identity", **kw)
    auto = find_seeds(images, cams, warp="auto", **kw)
    np.testing.assert_array_equal(square.xy, auto.xy)
    np.testing.assert_array_equal(square.score, auto.score)


def test_growth_starts_from_the_seeds_maps(turned):
    cams, images = turned
    seeds = find_seeds(images, cams, template=0, n_seeds=10, patch=9, min_distance=10,
                       depth_range=(600.0, 1600.0), warp="auto")
    th = LSMThresholds(max_displacement=3.0, max_sigma_xy=0.3, max_shear=0.5)
    params = MeasureSurfaceParams(grow=GrowParams(step=4, patch=9, thresholds=th))
    with_maps = measure_surface(images, cams, seeds.xy, template=0, seeds_A=seeds.A,
                                params=params)
    square = measure_surface(images, cams, seeds.xy, template=0, params=params)
    assert len(with_maps.points) > 200
    assert np.median(np.abs(with_maps.points[:, 2] - PLANE_Z)) < 2.0
    assert len(square.points) < len(with_maps.points) / 4
    with pytest.raises(ValueError, match="seeds_A"):
        measure_surface(images, cams, seeds.xy, template=0, seeds_A=seeds.A[:, :1],
                        params=params)


def test_tracks_start_through_the_predicted_map(turned):
    cams, images = turned
    tex = _texture(np.random.default_rng(3))
    frames = np.stack([[_render(c, tex, 3.0 * t) for t in range(4)] for c in cams])
    seeds = find_seeds(images, cams, template=0, n_seeds=10, patch=9, min_distance=10,
                       depth_range=(600.0, 1600.0), warp="auto")
    params = TrackerParams(template=0, patch=9)
    with_cams = track_points(frames, seeds.xy, params=params, start_cameras=cams)
    plain = track_points(frames, seeds.xy, params=params)
    started = with_cams.status != TrackStatus.NOT_STARTED
    assert started.sum() >= 5
    assert (plain.status != TrackStatus.NOT_STARTED).sum() < started.sum() / 2
    # the tracked points stay on the moving plane: 3 mm a frame along x
    for t in range(4):
        xy = with_cams.xy[t][:, started]
        ok = np.isfinite(xy).all(axis=(0, 2))
        assert ok.sum() >= 5
        o, d = cams[0].rays(xy[0, ok])
        X = o + ((PLANE_Z - o[:, 2]) / d[:, 2])[:, None] * d
        assert np.median(np.linalg.norm(cams[1].project(X) - xy[1, ok], axis=1)) < 0.5
    with pytest.raises(ValueError, match="start_cameras"):
        track_points(frames, seeds.xy, params=params, start_cameras=cams[:1])
