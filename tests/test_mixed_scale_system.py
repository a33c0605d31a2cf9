"""The mixed-scale system (issue 18): the pan-tilt rendering, the head as a device, a short
closed loop on a tiny scene checked against the truth, and bad input."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.evaluation import mixed_scale as ms
from lsmta.pantilt import Motor
from lsmta.synth.mixed_scale import SimulatedHead, mixed_scale_scene, render_pantilt_video
from lsmta.systems import MixedScaleParams, capture_mixed_scale, reacquisition_seeds


@pytest.fixture(scope="module")
def tiny():
    scene = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=4)
    # the heads calibrated from their targets' LEDs found in rendered frames, as the system
    # is run by default (the ceiling on the projected route, to keep the test short)
    cal = ms.calibrate_scene(scene, rng=6, heads_from_images=True)
    assert cal.heads_from_images and not cal.ceiling_from_images
    # exact read-back: the stages are checked against the truth without the encoder's 0.1°
    # (its effect is measured in notebook 15; the device's steps are tested below)
    inputs = ms.walk_inputs(scene, cal, rng=7, n_train=120, readback_step=0.0)
    return scene, cal, inputs


@pytest.fixture(scope="module")
def run(tiny):
    scene, cal, inputs = tiny
    frames = [f.copy() for f in inputs.ceiling.frames]
    params = MixedScaleParams(start=0.7)
    cap = capture_mixed_scale(inputs.ceiling, cal.heads, inputs.devices, inputs.identify,
                              inputs.face_model, params=params, progress=False)
    return cap, ms.score_capture(cap, scene, inputs.devices), frames


def test_pantilt_video_draws_the_markers_where_the_head_at_its_angles_sees_them():
    scene = mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2)
    head = scene.heads[0]
    world, normals, anchor = scene.face_at([0.1, 0.1])
    settings = np.array([[-8.0, 0.5], [-8.5, 0.0]])
    video = render_pantilt_video(head, settings, world, normals, anchor, rng=0)
    for f, (p, t) in enumerate(settings):
        xy = head.camera_at(p, t).project(world[f])
        drawn = np.isfinite(video.xy[f, :, 0])
        assert drawn.sum() > 30
        assert np.allclose(video.xy[f, drawn], xy[drawn])
    # half a degree of pan moves the face by about f * 0.5 deg in the image
    shift = np.nanmedian(video.xy[1, :, 0] - video.xy[0, :, 0])
    assert abs(abs(shift) - head.camera.f * np.radians(0.5)) < 5.0


def test_head_device_has_dead_time_rate_limit_and_steps():
    scene = mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2)
    motor = Motor(latency=0.25, max_rate=(80.0, 50.0), quantum=0.1)
    dev = SimulatedHead(scene.heads[0], scene, motor=motor, rng=0)
    dev.command(0.0, (30.0, 10.0))
    assert np.allclose(dev.reached(0.24), 0.0)                  # dead time
    s = dev.reached(0.35)                                       # 0.1 s of motion
    assert s[0] <= 80.0 * 0.1 + 0.1 and s[1] <= 50.0 * 0.1 + 0.1
    assert s[0] > 0
    assert np.allclose(dev.reached(2.0), (30.0, 10.0))
    fixed = SimulatedHead(scene.heads[0], scene, rng=0, fixed=True, start=(5.0, 1.0))
    fixed.command(0.0, (30.0, 10.0))
    assert np.allclose(fixed.reached(2.0), (5.0, 1.0))
    # a head's clock does not go back
    with pytest.raises(ValueError, match="t: expected a time at or after"):
        dev.reached(1.0)
    with pytest.raises(ValueError, match="t: expected a time at or after"):
        dev.command(1.5, (0.0, 0.0))
    dev.command(2.5, (1.0, 1.0))
    with pytest.raises(ValueError, match="t: expected a time at or after"):
        dev.command(2.2, (0.0, 0.0))


def test_short_closed_loop_against_the_truth(tiny, run):
    scene, cal, inputs = tiny
    cap, sc, frames = run
    # the loop ran: the tracker found the LEDs, the heads were commanded, the face came out
    assert len(cap.tracking.tracks) >= scene.leds.n_leds
    assert (cap.head_id >= 0).all()
    assert cap.face.fitted.mean() > 0.9
    # against the truth
    assert sc.both_in_frame > 0.9
    assert sc.face_median_mm < 1.0
    assert np.nanmedian(sc.face_error[sc.measured]) < 0.5
    assert sc.led_rms_mm < 20.0
    assert np.nanmedian(sc.aim_error) < 150.0
    # the heads move: the angles read back follow the commands one motor latency late
    lag = int(round(Motor().latency * cap.params.video_rate))
    now = np.nanmedian(np.abs(cap.settings - cap.commands))
    late = np.nanmedian(np.abs(cap.settings[:, lag:] - cap.commands[:, :-lag]))
    assert now > 0.05 and late < 0.5 * now, (now, late)
    # body and face time-stamped together
    assert cap.body.shape[0] == cap.face.frames.shape[0] == len(cap.times)
    # the system used what the devices reported, frame by frame
    for k, dev in enumerate(inputs.devices):
        rb = np.array(dev.readbacks)
        i = np.abs(rb[None, :, 0] - cap.times[:, None]).argmin(axis=1)
        assert np.array_equal(cap.settings[k], rb[i, 1:])
    # nothing passed in was modified
    assert all(np.array_equal(a, b) for a, b in zip(frames, inputs.ceiling.frames))


def test_bad_input_names_the_argument(tiny):
    scene, cal, inputs = tiny
    feed, heads, devs, ident, fm = (inputs.ceiling, cal.heads, inputs.devices, inputs.identify,
                                    inputs.face_model)

    def call(**kw):
        args = dict(ceiling=feed, heads=heads, devices=devs, identify=ident, face_model=fm)
        args.update(kw)
        return capture_mixed_scale(args.pop("ceiling"), args.pop("heads"), args.pop("devices"),
                                   args.pop("identify"), args.pop("face_model"),
                                   progress=False, **args)

    with pytest.raises(TypeError, match="ceiling"):
        call(ceiling=feed.frames)
    with pytest.raises(TypeError, match="ceiling.cameras"):
        call(ceiling=replace(feed, cameras=feed.cameras[:1]))
    with pytest.raises(ValueError, match=r"ceiling.stamps\[0\]"):
        call(ceiling=replace(feed, stamps=[s[::-1] for s in feed.stamps]))
    with pytest.raises(ValueError, match=r"ceiling.frames\[1\]"):
        call(ceiling=replace(feed, frames=[feed.frames[0], feed.frames[1][:, :10]]
                             + list(feed.frames[2:])))
    with pytest.raises(ValueError, match="ceiling.backgrounds"):
        call(ceiling=replace(feed, backgrounds=feed.backgrounds[:2]))
    with pytest.raises(TypeError, match="heads"):
        call(heads=[h.camera for h in heads])
    with pytest.raises(ValueError, match="devices"):
        call(devices=devs[:1])
    with pytest.raises(TypeError, match=r"devices\[0\]"):
        call(devices=[object(), devs[1]])
    with pytest.raises(TypeError, match=r"identify\[1\]"):
        call(identify=[ident[0], "by hand"])
    with pytest.raises(TypeError, match="face_model"):
        call(face_model=None)

    class Shrinking:     # frames lose two columns after the start's and the first frame's
        def __init__(self, shape):
            self.shape, self.times = shape, set()

        def command(self, t, setting):
            pass

        def grab(self, t):
            self.times.add(t)
            h, w = self.shape
            return np.zeros((h, w if len(self.times) <= 2 else w - 2), np.uint8), np.zeros(2)

    shape = (heads[0].camera.height, heads[0].camera.width)
    with pytest.raises(ValueError, match=r"devices: head 0's grab\(.*as the first frame"):
        call(devices=[Shrinking(shape), Shrinking(shape)])
    with pytest.raises(TypeError, match="params"):
        call(params={"lead": 0.3})
    with pytest.raises(ValueError, match="params.start"):
        call(params=MixedScaleParams(start=100.0))
    for bad, name in ((dict(damping=0.0), "damping"), (dict(lead=-0.1), "lead"),
                      (dict(start=1.0, stop=0.5), "stop"), (dict(video_rate=0.0), "video_rate"),
                      (dict(aim_offset=(0.0, 1.0)), "aim_offset"),
                      (dict(threshold_sigmas=0.0), "threshold_sigmas")):
        with pytest.raises(ValueError, match=name):
            MixedScaleParams(**bad)


def test_reacquisition_seeds_fall_on_drawn_markers_only(tiny, run):
    scene, cal, inputs = tiny
    cap, _, _ = run
    K, F, M = cap.xy.shape[:3]
    frames = np.arange(0, F, 5)
    world, _, _ = scene.face_at(cap.times[frames])
    seeds = reacquisition_seeds(cap.images[:, frames], cal.heads, cap.settings[:, frames],
                                world, np.zeros((K, len(frames), M), bool))
    for k, dev in enumerate(inputs.devices):
        for i, f in enumerate(frames):
            truth = dev.true_xy(cap.times[f], cap.settings[k, f])
            s = seeds[k, i]
            has = np.isfinite(s[:, 0])
            assert has.sum() > 20
            # a seed only where a marker is drawn, within a pixel of its image
            assert np.isfinite(truth[has, 0]).all()
            assert np.nanmax(np.linalg.norm(s[has] - truth[has], axis=1)) < 1.0
    # bad input names the argument
    args = (cap.images[:, :2], cal.heads, cap.settings[:, :2], world[:2],
            np.zeros((K, 2, M), bool))
    for i, name, bad in ((0, "images", cap.images[0, :2]), (1, "heads", cal.heads[:1]),
                         (2, "settings", cap.settings[:, :3]), (3, "face", world[:2, :, :2]),
                         (4, "found", np.zeros((K, 2, M)))):
        with pytest.raises((TypeError, ValueError), match=name):
            reacquisition_seeds(*args[:i], bad, *args[i + 1:])
    # markers already tracked are not restarted
    none = reacquisition_seeds(cap.images[:, :2], cal.heads, cap.settings[:, :2], world[:2],
                               np.ones((K, 2, M), bool))
    assert not np.isfinite(none).any()


def test_the_steering_fields_are_checked_by_the_params():
    for bad, name, error in ((dict(coast=-1.0), "coast", ValueError),
                             (dict(accel_window=-0.1), "accel_window", ValueError),
                             (dict(speed_up="yes"), "speed_up", TypeError),
                             (dict(reacquire=1.5), "reacquire", ValueError)):
        with pytest.raises(error, match=name):
            MixedScaleParams(**bad)
    assert MixedScaleParams(lead=0.2, damping=0.5).steering.damping == 0.5


def test_head_device_reads_back_in_encoder_steps():
    scene = mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2)
    dev = SimulatedHead(scene.heads[0], scene, rng=0)              # thesis: 0.1 deg steps
    exact = SimulatedHead(scene.heads[0], scene, rng=0, readback_step=0.0)
    for d in (dev, exact):
        d.command(0.0, (3.37, 1.23))
    times = (0.3, 0.33, 0.4, 1.5)
    got = np.array([dev.grab(t)[1] for t in times])
    true = dev.true_settings(times)
    assert np.allclose(got / 0.1, np.round(got / 0.1), rtol=0, atol=1e-9)   # on the steps
    assert np.abs(got - true).max() <= 0.05 + 1e-12                       # half a step off
    assert np.abs(got - true).max() > 1e-3           # and not the truth (3.37 is between steps)
    assert np.allclose(true[-1], (3.37, 1.23))
    assert np.array_equal(np.array([exact.grab(t)[1] for t in times]), exact.true_settings(times))
    noisy = SimulatedHead(scene.heads[0], scene, rng=0, readback_step=0.0, readback_noise=0.5)
    noisy.command(0.0, (3.0, 1.0))
    r = np.array([noisy.grab(t)[1] for t in (1.0, 1.1, 1.2)])
    assert np.std(r - noisy.true_settings((1.0, 1.1, 1.2))) > 0.05
    with pytest.raises(ValueError, match="times"):
        dev.true_settings(0.31)                                      # no frame grabbed then
    for bad in (dict(readback_step=-0.1), dict(readback_noise=-1.0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SimulatedHead(scene.heads[0], scene, rng=0, **bad)


def test_head_led_hidden_where_asked():
    scene = mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2,
                              head_hidden=(0.3, 0.5))
    t = np.array([0.25, 0.3, 0.4, 0.499, 0.5, 0.6])
    pos = scene.leds.positions_at(t)
    hidden = ~np.isfinite(pos[:, 0, 0])
    assert hidden.tolist() == [False, True, True, True, False, False]
    assert np.isfinite(pos[:, 1:]).all()                             # the shoulders stay
    assert np.isfinite(scene.leds.positions_at(t, only_on=False)).all()
    plain = mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2)
    assert np.isfinite(plain.leds.positions_at(t)).all()
    for bad in ((0.5, 0.3), (-1.0, 0.2), (0.1,)):
        with pytest.raises(ValueError, match="head_hidden"):
            mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2, head_hidden=bad)


def test_ceiling_calibrated_from_the_led_found_in_rendered_frames_is_close_to_the_truth():
    scene = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=4)
    c = ms.calibrate_ceiling(scene, rng=11, n_survey=200, from_images=True)
    assert c.from_images
    # most of the 200 positions are found in each camera (one feature per frame)
    assert (c.n_points >= 100).all()
    # the detector's centroids are good to a few tenths of a pixel: the fit's own residual
    assert (c.fit_rms_px < 0.35).all()
    # the cameras are near the true ones: image RMS on an independent path, centres, focal lengths
    assert (c.check_rms_px < 0.3).all()
    for cam, true in zip(c.cameras, scene.ceiling):
        assert np.linalg.norm(cam.C - true.C) < 20.0
        assert abs(cam.f - true.f) < 2.0
    # the tape-measured guess is much worse: the resection did the work
    from lsmta.synth.calibration import poor_guess
    guess = poor_guess(scene.ceiling, rng=0, pose_mm=100.0, pose_deg=2.0, f_rel=0.03)
    assert np.mean([np.linalg.norm(g.C - t.C) for g, t in zip(guess, scene.ceiling)]) > 40.0


def test_ceiling_survey_centroids_lie_on_the_true_projections_and_bad_input_errors():
    scene = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=2)
    X = np.array([[0.0, 0.0, 1300.0], [300.0, 200.0, 1100.0], [-400.0, 100.0, 1500.0]])
    X0 = X.copy()
    xy = ms.ceiling_survey_centroids(scene, X, rng=0)
    assert np.array_equal(X, X0)
    true = np.stack([cam.project(X) for cam in scene.ceiling])
    found = np.isfinite(xy).all(axis=2)
    assert found.sum() >= 4
    assert np.abs(xy[found] - true[found]).max() < 0.2
    with pytest.raises(TypeError, match="from_images"):
        ms.calibrate_ceiling(scene, from_images="yes")
    with pytest.raises(ValueError, match="threshold_sigmas"):
        ms.ceiling_survey_centroids(scene, X, threshold_sigmas=0.0)
    with pytest.raises(ValueError, match="X"):
        ms.ceiling_survey_centroids(scene, X[:, :2])
    with pytest.raises(ValueError, match="n_survey"):
        ms.calibrate_ceiling(scene, n_survey=3)


def test_both_ceiling_routes_draw_the_same_survey_start_and_heads():
    """The routes differ only in where the LED's image points come from: the survey's
    noise, the start and the check path are the same draws, and so is everything calibrated
    after the ceiling (the heads)."""
    scene = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=2)
    a = ms.calibrate_scene(scene, rng=11, from_images=False)
    b = ms.calibrate_scene(scene, rng=11, from_images=True, heads_from_images=False)
    assert not a.ceiling_from_images and b.ceiling_from_images
    assert not a.heads_from_images and not b.heads_from_images
    np.testing.assert_array_equal(a.head_rms_px, b.head_rms_px)
    assert not np.array_equal(a.ceiling_fit_rms_px, b.ceiling_fit_rms_px)



class _Recording:
    """A head device that notes the times of the commands sent to it."""

    def __init__(self, device):
        self.device, self.sent = device, []

    def command(self, t, setting):
        self.sent.append(float(t))
        self.device.command(t, setting)

    def grab(self, t):
        return self.device.grab(t)


def test_motor_fit_recovers_the_heads_angles_within_the_encoder_step(tiny, run):
    # issue 39: heads reading back in 0.1° steps; the system recovers their angles from the
    # read-back and its commands (the truth only to score)
    scene, cal, inputs = tiny
    # an exact encoder (the run's read-back off the 0.1° grid): the read-back as it is
    cap0 = run[0]
    assert cap0.params.motor_fit and np.array_equal(cap0.angles, cap0.settings)
    assert cap0.readback_fit is None and "motor_fit not tried" in str(cap0.summary())
    devices, identify = ms.head_devices(scene, rng=11, readback_step=0.1)
    recording = [_Recording(d) for d in devices]
    cap = capture_mixed_scale(inputs.ceiling, cal.heads, recording, identify,
                              inputs.face_model, progress=False, keep_images=False,
                              params=MixedScaleParams(start=0.7, reacquire=0, motor_fit=True))
    # every tick, before the frames too, is 1 / video_rate from the next: the commands'
    # times lie on the frames' grid (the motor's history the fit reads is evenly spaced)
    sent = np.array(recording[0].sent)
    ticks = (sent - cap.times[0]) * cap.params.video_rate
    assert (sent < cap.times[0]).sum() > 12 and np.allclose(ticks, np.round(ticks), atol=1e-6)
    true = np.stack([d.true_settings(cap.times) for d in devices])
    assert np.allclose(cap.settings / 0.1, np.round(cap.settings / 0.1), atol=1e-9)
    assert np.abs(cap.angles - cap.settings).max() <= 0.05 + 1e-9
    assert np.median(np.abs(cap.angles - true)) < 0.5 * np.median(np.abs(cap.settings - true))
    # the fit is kept: which head and axis were fitted, and its residual medians (summary())
    fit = cap.readback_fit
    assert fit.fitted.shape == cap.settings.shape and np.array_equal(fit.angles, cap.angles)
    assert fit.fitted.any(axis=1).all() and np.isfinite(fit.residual_median).all()
    row = next(r["result"] for r in cap.summary() if r["stage"] == "triangulation")
    assert "recovered" in row and "read-back kept" not in row
    # a refused fit is named: the read-back kept on that head and axis
    refused = replace(fit, fitted=fit.fitted & (np.arange(2) == 0))
    row = next(r["result"] for r in replace(cap, readback_fit=refused).summary()
               if r["stage"] == "triangulation")
    assert "read-back kept (fit refused) on head 0 tilt, head 1 tilt" in row
    # the angles it triangulated at are the recovered ones (the read-back study's third row)
    study = ms.exact_readback(cap, scene, devices, cal.heads, face_model=inputs.face_model)
    assert study.face_median_mm[2, 0] < study.face_median_mm[0, 0]
    with pytest.raises(ValueError, match="devices, heads"):
        ms.angle_error_parts(cap, scene, devices * 2, cal.heads * 2,
                             face_model=inputs.face_model)
