"""Wand and board calibration (issue 24): generated wand recordings against the truth, the real
caliscope recording against its own calibration, and clear errors for bad input."""

import numpy as np
import pytest

from lsmta.calibration import WandStatus, calibrate_wand
from lsmta.evaluation.wand import wand_trial
from lsmta.synth.wand import wand_recording

SIZE = (1280, 720)


@pytest.fixture(scope="module")
def trial():
    # 25 frames, each seen by 2-3 of 4 cameras, 10 % of the ends mislabelled, f guessed
    return wand_trial(seed=3, n_frames=25, n_heldout=30, swap_fraction=0.1)


def test_wand_calibration_recovers_the_rig(trial):
    r = trial.result
    assert r.status == WandStatus.OK
    assert r.focal_guessed and any("focal_px not given" in m for m in r.messages)
    assert trial.labels_consistent == 1.0
    # at the floor set by the image noise (the true cameras on the same observations)
    assert r.wand_length_std_percent < 1.5 * trial.floor_std_percent
    assert np.sqrt(np.mean(trial.heldout_error_percent**2)) < 0.5
    assert np.all(trial.centre_error < 40.0)                     # mm, rig of 3.2 m radius
    assert np.all(np.abs(trial.focal_error_percent) < 2.0)
    # residuals at the noise (0.3 px per coordinate -> about 0.42 px 2-D) plus p1, p2 and
    # the principal point, which the wand model leaves out
    assert np.all(r.rms_px < 0.6)
    assert r.wand_points.shape == (25, 2, 3) and r.wand_lengths.shape == (25,)
    # the world frame is the first camera's
    np.testing.assert_allclose(r.cameras[0].C, 0, atol=1e-6)
    np.testing.assert_allclose(r.cameras[0].R, np.eye(3), atol=1e-9)


def test_tie_points_and_given_focal_lengths(trial):
    rec = wand_recording(rng=7, n_frames=25, n_tie=12)
    f = [c.f for c in rec.cameras]
    out = calibrate_wand(rec.xy, rec.length, SIZE, focal_px=f, tie_xy=rec.tie_xy)
    assert not out.focal_guessed
    assert out.tie_points.shape == (rec.tie_xy.shape[1], 3)
    assert out.status == WandStatus.OK


def test_inputs_are_not_modified():
    rec = wand_recording(rng=1, n_frames=20, swap_fraction=0.2)
    xy = rec.xy.copy()
    calibrate_wand(rec.xy, rec.length, SIZE)
    np.testing.assert_array_equal(rec.xy, xy)


def test_bad_input_is_refused_with_clear_errors():
    rec = wand_recording(rng=1, n_frames=20)
    xy, L = rec.xy, rec.length
    with pytest.raises(ValueError, match="wand_xy: .* needs >= 10"):
        calibrate_wand(xy[:, :8], L, SIZE)                           # too few frames
    blind = xy.copy()
    blind[2] = np.nan
    with pytest.raises(ValueError, match="camera cam3 sees the wand in none"):
        calibrate_wand(blind, L, SIZE)
    with pytest.raises(ValueError, match="outside its 640 x 480 px image"):
        calibrate_wand(xy, L, (640, 480))                           # wrong image size
    with pytest.raises(ValueError, match="image_sizes"):
        calibrate_wand(xy, L, [(1280, 720)] * 3)
    half = xy.copy()
    t = np.flatnonzero(np.isfinite(xy[0, :, 0, 0]))[0]
    half[0, t, 0, 1] = np.nan                                        # a NaN half row
    with pytest.raises(ValueError, match="one coordinate NaN"):
        calibrate_wand(half, L, SIZE)
    with pytest.raises(ValueError, match="wand_xy: expected an array of shape"):
        calibrate_wand(xy[..., 0], L, SIZE)
    with pytest.raises(ValueError, match="length"):
        calibrate_wand(xy, -1.0, SIZE)
    with pytest.raises(ValueError, match="distortion"):
        calibrate_wand(xy, L, SIZE, distortion="fisheye")
    with pytest.raises(ValueError, match="focal_px"):
        calibrate_wand(xy, L, SIZE, focal_px=[800.0, 800.0])
    tie = np.full((4, 1, 2), np.nan)
    tie[0, 0] = (100.0, 100.0)
    with pytest.raises(ValueError, match="tie_xy: 1 tie point"):
        calibrate_wand(xy, L, SIZE, tie_xy=tie)


# ---------------------------------------------------------------------- board recordings
def test_caliscope_recording_calibrated_from_its_corners_alone():
    from lsmta.calibration.board import calibrate_board
    from lsmta.camera_files import read_camera_toml
    from lsmta.data import CALISCOPE_DIR
    from lsmta.io import read_caliscope_points
    from lsmta.real.board import board_scores, position_differences

    pts = read_caliscope_points(CALISCOPE_DIR / "xy.csv")
    ref = read_camera_toml(CALISCOPE_DIR / "camera_array.toml", unit="m")
    ours = calibrate_board(pts.xy, pts.board, [c.image_size for c in ref])
    mine, theirs = board_scores(ours.cameras, pts), board_scores(ref, pts)
    # the targets on the same corners: reprojection and board distances
    assert np.all(mine.rms_px <= theirs.rms_px)
    assert mine.distance_rms <= theirs.distance_rms
    dist, _ = position_differences(ours.cameras, ref)
    assert np.all(dist < 30.0)                                      # mm


def test_board_calibration_refuses_bad_input():
    from lsmta.calibration.board import calibrate_board

    board = np.array([[0, 0, 0], [54, 0, 0], [0, 54, 0]], float)
    xy = np.full((2, 3, 3, 2), np.nan)
    with pytest.raises(ValueError, match="image_sizes"):
        calibrate_board(xy, board, [(1280, 720)])
    with pytest.raises(ValueError, match="board: expected a plane"):
        calibrate_board(xy, board + [0, 0, 1], [(1280, 720)] * 2)
    with pytest.raises(ValueError, match="xy: expected an array of shape"):
        calibrate_board(xy[:, :, :2], board, [(1280, 720)] * 2)
