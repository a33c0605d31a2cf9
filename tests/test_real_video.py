"""Building blocks for tracking in real video: markers found in a colour frame, detections
grouped across calibrated views, the Pose2Sim demo read with its calibration."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import random_camera
from lsmta.data import load_demo
from lsmta.real import pose2sim_video as rv
from lsmta.tracking.correspondence import match_views
from lsmta.tracking.markers import find_markers

DEMO = Path(__file__).resolve().parents[1] / "data" / "pose2sim_demo"


def test_views_are_grouped_into_the_points_that_explain_them(rng):
    cams = [random_camera(rng, name=f"c{k}") for k in range(3)]
    X = rng.uniform([-300, -300, 700], [300, 300, 1300], (15, 3))
    det, truth = [], []
    for cam in cams:
        xy = cam.project(X)
        order = rng.permutation(len(X))
        clutter = rng.uniform([0, 0], [cam.width, cam.height], (4, 2))
        det.append(np.vstack([xy[order], clutter]))
        truth.append(order)
    grouped = match_views(cams, det, max_ray_distance=5.0, max_px=1.0, min_views=3)
    assert grouped.shape[0] == 3 and grouped.shape[1] >= 15
    # every one of the 15 true points is found, its three detections together
    for i in range(len(X)):
        want = np.stack([cam.project(X[[i]])[0] for cam in cams])       # (K, 2)
        hit = np.all(np.linalg.norm(grouped - want[:, None], axis=2) < 1e-6, axis=0)
        assert hit.sum() == 1, f"point {i} not grouped exactly once"


def test_match_views_bad_input(rng):
    cams = [random_camera(rng) for _ in range(2)]
    det = [np.zeros((3, 2)), np.zeros((3, 2))]
    with pytest.raises(ValueError, match="min_views"):
        match_views(cams, det, min_views=3)
    with pytest.raises(ValueError, match="detections"):
        match_views(cams, det[:1])
    with pytest.raises(ValueError, match="max_px"):
        match_views(cams, det, max_px=-1.0)


def test_markers_are_found_on_skin_at_their_centres(rng):
    img = np.empty((120, 160, 3), np.uint8)
    img[:] = (110, 150, 215)                                # skin, BGR
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    centres = np.array([[40.3, 30.6], [100.0, 60.2], [70.7, 95.4]])
    for x, y in centres:                                    # grey-white discs, r = 3.5 px
        cv2.circle(img, (int(round(x * 16)), int(round(y * 16))), 56, (225, 225, 225), -1,
                   lineType=cv2.LINE_AA, shift=4)
    found = find_markers(img)
    assert len(found) == len(centres)
    d = np.linalg.norm(found[:, None] - centres[None], axis=2).min(axis=0)
    assert d.max() < 0.5
    assert len(find_markers(np.full_like(img, (110, 150, 215)))) == 0   # plain skin: none


def test_find_markers_bad_input():
    with pytest.raises(ValueError, match="image"):
        find_markers(np.zeros((20, 20), np.uint8))
    with pytest.raises(ValueError, match="sigma"):
        find_markers(np.zeros((20, 20, 3), np.uint8), sigma=0.0)


@pytest.mark.skipif(not (DEMO / "cam01.mp4").is_file(), reason="demo videos not copied")
def test_demo_is_read_with_its_calibration():
    demo = load_demo(scale=0.5, frames=3)
    assert demo.fps == pytest.approx(60.0)
    assert len(demo.grey) == len(demo.cameras) == 4
    for g, cam, f in zip(demo.grey, demo.cameras, demo.first):
        assert g.shape[0] == 3 and g.dtype == np.uint8
        assert abs(g.shape[1] - cam.height) <= 1 and abs(g.shape[2] - cam.width) <= 4
        assert f.ndim == 3 and f.shape[2] == 3
    # points projected by the calibration reproject onto themselves
    X = np.array([[0.0, 0.0, 900.0], [100.0, -50.0, 1200.0]])
    xy = np.stack([c.project(X) for c in demo.cameras])[None]
    assert np.nanmax(rv.reprojection_residuals(demo.cameras, xy)) < 1e-3


def test_load_demo_names_a_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_demo(folder=tmp_path)


def test_image_transforms_flip_within_the_image():
    xy = np.array([[0.0, 0.0], [9.0, 4.0], [2.5, 1.0]])
    assert np.array_equal(rv.transform_xy(xy, (10, 5), "identity"), xy)
    assert np.array_equal(rv.transform_xy(xy, (10, 5), "flip_u")[:, 0], [9.0, 0.0, 6.5])
    assert np.array_equal(rv.transform_xy(xy, (10, 5), "flip_v")[:, 1], [4.0, 0.0, 3.0])
    back = rv.transform_xy(rv.transform_xy(xy, (10, 5), "rotate_180"), (10, 5), "rotate_180")
    assert np.array_equal(back, xy)
    with pytest.raises(ValueError, match="kind"):
        rv.transform_xy(xy, (10, 5), "rotate_90")


def test_the_right_reading_scores_far_above_chance_and_a_flip_does_not(rng):
    cams = [random_camera(rng, name=f"c{k}") for k in range(3)]
    X = rng.uniform([-300, -300, 700], [300, 300, 1300], (25, 3))
    det = [np.vstack([cam.project(X), rng.uniform([0, 0], [cam.width, cam.height], (10, 2))])
           for cam in cams]
    sizes = [(cam.width, cam.height) for cam in cams]
    s = rv.score_hypotheses(cams, det, sizes, max_ray_distance=1.0, rng=1)
    assert len(s.names) == 4 * 6 and s.counts.shape == (24, 3)
    right = s.names.index("identity 012")
    assert np.all(s.counts[right] >= 25) and s.z[right].min() > 5
    flipped = s.names.index("flip_v 012")
    assert s.z[flipped].min() < 3
    assert int(np.argmax(s.z.min(axis=1))) == right
    with pytest.raises(ValueError, match="detections, sizes"):
        rv.score_hypotheses(cams, det[:2], sizes)


def test_a_cyan_blob_is_found_at_its_centre_and_rays_meet_at_a_point(rng):
    img = np.full((80, 120, 3), (110, 150, 215), np.uint8)
    cv2.circle(img, (70, 30), 8, (200, 180, 0), -1)          # cyan (BGR)
    cv2.circle(img, (20, 60), 3, (200, 180, 0), -1)          # a smaller one
    assert np.allclose(rv.blob_centre(img), [70, 30], atol=0.1)
    assert np.isnan(rv.blob_centre(np.full_like(img, 128))).all()
    cams = [random_camera(rng) for _ in range(3)]
    X = np.array([[10.0, -20.0, 1000.0]])
    assert rv.pair_ray_distances(cams, np.vstack([c.project(X) for c in cams])).max() < 1e-6


def test_tracks_of_one_marker_stay_paired_at_the_right_time_offset(rng):
    cams = [random_camera(rng) for _ in range(2)]
    T, N = 40, 6
    t = np.arange(T)[:, None, None]
    X = rng.uniform([-200, -200, 900], [200, 200, 1100], (1, N, 3)) + \
        150.0 * np.sin(0.3 * t + rng.uniform(0, 6, (1, N, 3)))        # moving markers, mm
    xy = [np.stack([cam.project(X[k]) for k in range(T)]) for cam in cams]     # (T, N, 2)
    assert rv.persistent_pairs(cams[0], cams[1], xy[0], xy[1], lag=0) == N
    assert rv.persistent_pairs(cams[0], cams[1], xy[0], xy[1], lag=8) < N / 2
    late = np.concatenate([np.full((3, N, 2), np.nan), xy[1][:-3]])   # view b 3 frames late
    assert rv.persistent_pairs(cams[0], cams[1], xy[0], late, lag=3) == N
    with pytest.raises(ValueError, match="xy_b"):
        rv.persistent_pairs(cams[0], cams[1], xy[0], xy[1][:, :, 0])
