"""Seeds and growth between a camera and one mounted on its side (issue #40: caliscope's
webcam rig): the search patch through the map the cameras predict (find_seeds' warp)."""

import numpy as np
import pytest
from scipy import ndimage

from lsmta.camera import Camera
from lsmta.camera_files import read_camera_file
from lsmta.data import POSE2SIM_DIR
from lsmta.matching import GrowParams, LSMThresholds, MeasureSurfaceParams, measure_surface
from lsmta.matching.seeds import (
    AUTO_SCALE,
    AUTO_TURN_DEG,
    WARPS,
    find_seeds,
    predicted_maps,
    warped_images,
)
from lsmta.synth import ring_rig, studio_rig, triplet_rig
from lsmta.systems import view_groups, working_distance
from lsmta.systems.surfaces import seed_residual
from lsmta.tracking import TrackerParams, TrackStatus, track_points

PLANE_Z = 1000.0         # mm: a textured wall square to the first camera's axis
TEXEL = 2.0              # mm per texture sample


def _texture(rng, grain: float = 2.0) -> np.ndarray:
    """A random blob texture (grey levels about 40-210) on the plane, 500 x 500 samples
    smoothed over ``grain`` samples (2 mm each; a camera pixel spans 5 mm on the plane)."""
    t = ndimage.gaussian_filter(rng.standard_normal((500, 500)), grain)
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
    A = predicted_maps(cams, 0, X)[1]
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
    np.testing.assert_array_equal(auto.A, np.broadcast_to(np.eye(2), auto.A.shape))


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


def test_predicted_maps_checks_its_input():
    cams = _rig(90.0)
    X = np.array([0.0, 0.0, PLANE_Z])
    with pytest.raises(ValueError, match="X: expected .*3"):
        predicted_maps(cams, 0, X[:2])
    with pytest.raises(ValueError, match="X: expected points in front"):
        predicted_maps(cams, 0, -X)
    with pytest.raises(ValueError, match="X: contains non-finite"):
        predicted_maps(cams, 0, np.full(3, np.nan))
    with pytest.raises(ValueError, match="template"):
        predicted_maps(cams, 2, X)
    with pytest.raises(TypeError, match="cameras"):
        predicted_maps(cams[:1], 0, X)
    # the maps follow X's shape
    assert predicted_maps(cams, 0, np.tile(X, (4, 5, 1)))[1].shape == (4, 5, 2, 2)


def test_warped_images_checks_warp():
    cams = _rig(90.0)
    assert [warped_images(cams, 0, PLANE_Z, warp=w) for w in WARPS] == [set(), {1}, {1}]
    with pytest.raises(ValueError, match=r"warp: expected one of \['identity'"):
        warped_images(cams, 0, PLANE_Z, warp="bogus")
    with pytest.raises(ValueError, match="depth"):
        warped_images(cams, 0, -PLANE_Z)


def _auto_depths(cams, template: int) -> list:
    """The depths the auto rule is asked at by the capture's surfaces: the middle inverse
    depth of their seed range (0.6 and 1.6 times the working distance), and its ends."""
    d = working_distance(cams, template)
    return [0.6 * d, 2.0 / (1.0 / (0.6 * d) + 1.0 / (1.6 * d)), 1.6 * d]


@pytest.mark.parametrize("rig", ["pose2sim", "triplet", "ring", "studio"])
def test_auto_warps_no_camera_of_the_upright_rigs(rig):
    """The Pose2Sim demo's cameras as read and the synthetic rigs: every view group keeps the
    square patch (their seeds and tracks as before the warp)."""
    cams = {"pose2sim": lambda: read_camera_file(POSE2SIM_DIR / "Calib.qca.txt"),
            "triplet": lambda: triplet_rig(rng=1), "ring": lambda: ring_rig(rng=1),
            "studio": lambda: studio_rig(rng=1)}[rig]()
    groups = view_groups(cams)
    assert groups
    for g in groups:
        sub = [cams[k] for k in g.cameras]
        t = g.cameras.index(g.template)
        for depth in _auto_depths(sub, t):
            assert warped_images(sub, t, depth) == set(), (rig, g.cameras, depth)


def _good_seeds(cams, images, warp: str) -> int:
    """Seeds found within a pixel of the truth, 9 px patches."""
    seeds = find_seeds(images, cams, template=0, n_seeds=10, patch=9, min_distance=10,
                       depth_range=(600.0, 1600.0), warp=warp)
    return int((_seed_errors(seeds, cams) < 1.0).sum()) if seeds.xy.shape[1] else 0


def test_the_square_patch_holds_within_the_auto_thresholds():
    """Why AUTO_TURN_DEG and AUTO_SCALE: on a texture of about two pixels' grain the square
    9 px patch still correlates at 20 deg roll and at 1.25 scale (auto keeps it), and no
    longer at 45 deg or at scale 2 (auto predicts the map, which finds the seeds)."""
    tex = _texture(np.random.default_rng(3), grain=4.0)
    assert 20.0 < AUTO_TURN_DEG < 45.0 and 1.25 < AUTO_SCALE < 2.0
    for roll, works in ((20.0, True), (45.0, False)):
        cams = _rig(roll)
        images = [_render(c, tex) for c in cams]
        assert warped_images(cams, 0, PLANE_Z) == (set() if works else {1})
        square = _good_seeds(cams, images, "identity")
        assert (square >= 8) if works else (square <= 2), (roll, square)
        assert _good_seeds(cams, images, "auto") >= 8
    for f, works in ((250.0, True), (400.0, False)):          # scale only: f / 200
        cams = _rig(0.0)
        cams[1] = cams[1].replace(f=f)
        images = [_render(c, tex) for c in cams]
        assert warped_images(cams, 0, PLANE_Z) == (set() if works else {1})
        square = _good_seeds(cams, images, "identity")
        assert (square >= 8) if works else (square <= 2), (f, square)
        assert _good_seeds(cams, images, "auto") >= 5


def test_seed_residual_names_seeds_A(turned):
    cams, images = turned
    seeds = find_seeds(images, cams, template=0, n_seeds=10, patch=9, min_distance=10,
                       depth_range=(600.0, 1600.0), warp="auto")
    with_maps = seed_residual(images, seeds.xy, template=0, patch=9, seeds_A=seeds.A)
    square = seed_residual(images, seeds.xy, template=0, patch=9)
    assert with_maps < 10.0 and (np.isnan(square) or square > with_maps)
    with pytest.raises(ValueError, match="seeds_A"):
        seed_residual(images, seeds.xy, template=0, patch=9, seeds_A=seeds.A[:, :1])
    with pytest.raises(ValueError, match="seeds_xy"):
        seed_residual(images, seeds.xy[:1], template=0, patch=9)
