"""The pan-tilt heads calibrated from their targets' LEDs found in rendered frames
(lsmta.evaluation.head_survey, issue 37): centroids on the true projections, parameters
near the true head's, both routes drawing the same survey, and bad input."""

import numpy as np
import pytest

from lsmta.evaluation.head_survey import calibrate_head, head_target_centroids
from lsmta.synth.mixed_scale import mixed_scale_scene
from lsmta.synth.pantilt import calibration_sweeps, render_target_frames


@pytest.fixture(scope="module")
def scene():
    return mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=2)


def test_centroids_found_in_rendered_frames_lie_on_the_true_projections(scene):
    head = scene.heads[0]
    d = calibration_sweeps(head, rng=3, points_per_setting=3, pans=(-20, 0, 30), tilts=(-10, 5),
                           image_sigma=0.0, world_sigma=0.0, depth=(2000.0, 4000.0))
    X = np.array(d.X_true)
    X0 = X.copy()
    xy = head_target_centroids(head, d.pan, d.tilt, X, rng=0)
    assert np.array_equal(X, X0)
    found = np.isfinite(xy).all(axis=1)
    assert found.sum() >= len(X) - 1
    # the detector's centroid of a 0.9 px spot in 2 grey levels of noise: a few hundredths
    assert np.abs(xy[found] - d.xy_true[found]).max() < 0.15


def test_head_calibrated_from_rendered_targets_is_close_to_the_true_head(scene):
    for k, head in enumerate(scene.heads):
        c = calibrate_head(head, rng=20 + k, from_images=True)
        assert c.from_images
        # the default survey is the projected route's: 200 target LEDs, 20 per sweep setting
        assert c.n_points == 200 + 19 * 20
        # nearly every LED is found (one feature in its frame)
        assert c.n_used >= 0.95 * c.n_points
        # the fit's own residual: the 0.3 mm survey noise at 2-4 m, a few tenths of a pixel
        assert c.fit_rms_px < 0.6
        # against the true head, on held-out settings: a quarter of a pixel at f = 3000 px
        assert c.check_rms_px < 0.25
        assert np.linalg.norm(c.model.camera.C - head.camera.C) < 5.0
        assert abs(c.model.camera.f - head.camera.f) < 8.0
        # the axes' directions within 0.1° (the home orientation trades off against the
        # principal point, a few tenths of a degree on either route: not checked alone)
        for a, b in ((c.model.pan_axis, head.pan_axis), (c.model.tilt_axis, head.tilt_axis)):
            assert np.degrees(np.arccos(np.clip(a @ b, -1, 1))) < 0.1


def test_biased_centroids_fail_the_bound():
    """The bound above can fail: image points off by half a pixel (a detector's bias) give
    a head off by more than it allows on held-out settings."""
    from lsmta.pantilt import calibrate, calibrate_intrinsics
    from lsmta.synth.pantilt import intrinsic_target
    head = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=2).heads[0]
    t = intrinsic_target(head, rng=1, n=60, image_sigma=0.0, world_sigma=0.1)
    s = calibration_sweeps(head, rng=2, points_per_setting=6, image_sigma=0.0,
                           world_sigma=0.3, depth=(2000.0, 4000.0))
    # a bias that grows across the image (a scale error of the centroids)
    bias = lambda xy: xy + 0.004 * (xy - [320.0, 240.0])     # noqa: E731
    intr = calibrate_intrinsics(t.X, bias(t.xy), head.camera.image_size, distortion=("k1",))
    fit = calibrate(intr.model, s.pan, s.tilt, s.X, bias(s.xy), kind="general")
    held = calibration_sweeps(head, rng=4, points_per_setting=5, image_sigma=0.0,
                              world_sigma=0.0, depth=(2000.0, 4000.0))
    e = fit.model.project(held.X_true, held.pan, held.tilt) - held.xy_true
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) > 0.25


def test_both_head_routes_draw_the_same_survey(scene):
    """With noise-free projections the projected route differs from the rendered one only
    by the detector's centroid error (a few hundredths of a pixel): the same target, sweeps
    and survey noise are drawn, and the two heads nearly coincide."""
    head = scene.heads[1]
    a = calibrate_head(head, rng=9, from_images=False, n_target=60, points_per_setting=6,
                       image_sigma=0.0)
    b = calibrate_head(head, rng=9, from_images=True, n_target=60, points_per_setting=6)
    assert not a.from_images and b.from_images
    assert a.n_points == b.n_points == 60 + 19 * 6
    # by default both routes take the same survey (the rendered one's is checked above)
    assert calibrate_head(head, rng=9, from_images=False).n_points == 200 + 19 * 20
    assert np.linalg.norm(a.model.camera.C - b.model.camera.C) < 1.0
    assert abs(a.check_rms_px - b.check_rms_px) < 0.05
    # the survey's 0.3 mm noise keeps both off the true head
    assert not np.allclose(b.model.camera.C, head.camera.C, atol=0.05)


def test_target_frames_and_bad_input(scene):
    head = scene.heads[0]
    cam = head.camera_at(0.0, 0.0)
    X = np.array([[0.0, 300.0, 1650.0]])
    v = render_target_frames(cam, X, rng=0, n_background=2)
    assert v.frames.shape == (1, cam.height, cam.width) and v.frames.dtype == np.uint8
    assert v.background.shape == (2, cam.height, cam.width)
    with pytest.raises(TypeError, match="head"):
        head_target_centroids(cam, [0.0], [0.0], X)
    with pytest.raises(ValueError, match="pan"):
        head_target_centroids(head, [0.0, 1.0], [0.0], X)
    with pytest.raises(ValueError, match="threshold_sigmas"):
        head_target_centroids(head, [0.0], [0.0], X, threshold_sigmas=0.0)
    with pytest.raises(TypeError, match="from_images"):
        calibrate_head(head, from_images="yes")
    with pytest.raises(ValueError, match="X"):
        render_target_frames(cam, X[:, :2])
    with pytest.raises(TypeError, match="camera"):
        render_target_frames(head, X)
