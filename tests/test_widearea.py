"""Wide-area LED tracking (lsmta.widearea): Kalman pieces, association, queues, birth and
death, the tracker on generated observations, bad input, the Stone Soup baseline."""

import cv2
import numpy as np
import pytest

from lsmta.evaluation.track_scores import score_led_tracks
from lsmta.evaluation.widearea import RIG_SEED, fig35_starvation, trial_rig, walking_trial
from lsmta.evaluation.widearea_images import rendered_tracking_trial
from lsmta.synth.widearea import (
    LedCentroidParams,
    ceiling_rig,
    make_clocks,
    observe_leds,
    still_led,
    walking_person,
)
from lsmta.widearea import (
    EstimatorParams,
    FrameIntake,
    Frames,
    RayPool,
    associate,
    ekf_update,
    find_birth,
    innovation_gate,
    kalman_update,
    measurement,
    predict,
    process_noise,
    projection_jacobian,
    ray_distance,
    schedule,
    screen_frame,
    starved,
    track,
    transition,
)


@pytest.fixture(scope="module")
def rig():
    return ceiling_rig(rng=np.random.default_rng(3))


# ----------------------------------------------------------------------------- kalman
def test_transition_matches_stone_soup():
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        ConstantVelocity,
    )

    q, dt = 3e5, 0.023
    F, Q = transition(dt, q)
    ss = CombinedLinearGaussianTransitionModel([ConstantVelocity(q)] * 3)
    perm = [0, 2, 4, 1, 3, 5]      # Stone Soup orders (x, vx, y, vy, z, vz)
    import datetime

    td = datetime.timedelta(seconds=dt)
    F_ss = np.asarray(ss.matrix(time_interval=td))[np.ix_(perm, perm)]
    Q_ss = np.asarray(ss.covar(time_interval=td))[np.ix_(perm, perm)]
    np.testing.assert_allclose(F[0], F_ss, atol=1e-12)
    np.testing.assert_allclose(Q[0], Q_ss, rtol=1e-9, atol=1e-9)


def test_predict_matches_matrices_and_keeps_inputs():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 6))
    A = rng.normal(size=(4, 6, 6))
    P = A @ A.transpose(0, 2, 1)
    x0, P0 = x.copy(), P.copy()
    dt = np.array([0.0, 0.01, 0.02, 0.5])
    F, Q = transition(dt, 2e6)
    x1, P1 = predict(x, P, dt, 2e6)
    np.testing.assert_allclose(x1, np.einsum("mij,mj->mi", F, x))
    np.testing.assert_allclose(P1, F @ P @ F.transpose(0, 2, 1) + Q, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(P, P0)
    with pytest.raises(ValueError, match="dt"):
        predict(x, P, -0.1, 1.0)
    with pytest.raises(ValueError, match="x"):
        predict(x[:, :5], P, 0.1, 1.0)


def test_projection_jacobian_matches_opencv(rig):
    cam = rig[4]
    X = np.array([[100.0, 300.0, 1200.0], [-500.0, 800.0, 700.0]])
    J = projection_jacobian(cam, X)
    K, dist, rvec, tvec = cam.to_opencv()[:4]
    for i, point in enumerate(X):
        _, jac = cv2.projectPoints(point[None], rvec, tvec, K, dist)
        d_dt = jac[:, 3:6]                       # d(pixel)/d(tvec); Xc = R X + t
        np.testing.assert_allclose(J[i], d_dt @ cam.R, rtol=1e-4, atol=1e-6)


def test_ekf_converges_on_a_still_point(rig):
    truth = np.array([200.0, -100.0, 1100.0])
    x = np.array([[230.0, -80.0, 1060.0, 0, 0, 0]])
    P = np.diag([50.0**2] * 3 + [10.0**2] * 3)[None]
    for k in range(40):
        cam = rig[k % 6]
        z = cam.project(truth[None])
        x, P = predict(x, P, 0.01, 1e2)
        x, P, innov = ekf_update(x, P, cam, z, 0.3)
    assert np.linalg.norm(x[0, :3] - truth) < 0.5
    assert np.all(np.isfinite(innov))


def test_lagged_update_uses_the_past_position(rig):
    # a target moving at constant velocity; a centroid of where it was 20 ms ago
    v = np.array([1000.0, 0.0, 0.0])
    X_now = np.array([0.0, 0.0, 1000.0])
    x = np.r_[X_now, v][None]
    P = np.diag([1.0] * 3 + [1.0] * 3)[None]
    z = rig[0].project((X_now - 0.02 * v)[None])
    x1, _, innov = ekf_update(x, P, rig[0], z, 0.3, lag=0.02)
    np.testing.assert_allclose(innov, 0.0, atol=1e-6)
    np.testing.assert_allclose(x1, x, atol=1e-6)
    _, _, innov0 = ekf_update(x, P, rig[0], z, 0.3, lag=0.0)
    assert np.abs(innov0).max() > 1.0       # without the lag it would look like an error


# ----------------------------------------------------------------------------- association
def test_associate_nearest_inside_gate():
    pred = np.array([[10.0, 10.0], [50.0, 50.0], [np.nan, np.nan]])
    obs = np.array([[51.0, 50.0], [10.5, 10.0], [200.0, 200.0]])
    a = associate(pred, obs, 5.0)
    assert dict(zip(a.target.tolist(), a.centroid.tolist())) == {0: 1, 1: 0}
    np.testing.assert_array_equal(a.unassociated, [False, False, True])
    # one-to-one: two targets near one centroid, the nearer wins
    a2 = associate(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[0.9, 0.0]]), 5.0)
    assert a2.target.tolist() == [1]
    # per-target gate
    a3 = associate(pred[:2], obs[:2], np.array([0.1, 5.0]))
    assert a3.target.tolist() == [1]
    with pytest.raises(ValueError, match="gate_px"):
        associate(pred, obs, -1.0)
    with pytest.raises(ValueError, match="observed"):
        associate(pred, obs[:, :1], 5.0)


# ----------------------------------------------------------------------------- management
def test_ray_distance_and_birth(rig):
    point = np.array([300.0, 200.0, 1000.0])
    o, d = [], []
    for cam in rig[:3]:
        oo, dd = cam.rays(cam.project(point[None]))
        o.append(oo[0])
        d.append(dd[0])
    o, d = np.array(o), np.array(d)
    dist, mid = ray_distance(o[:1], d[:1], o[1:], d[1:])
    np.testing.assert_allclose(dist, 0.0, atol=1e-6)
    np.testing.assert_allclose(mid[0, 0], point, atol=1e-6)
    # skew lines 20 mm apart
    dist2, _ = ray_distance([[0, 0, 0.0]], [[1, 0, 0.0]], [[5, -5, 20.0]], [[0, 1, 0.0]])
    assert dist2[0, 0] == pytest.approx(20.0)
    b = find_birth(o[:1], d[:1], 1.0, 0, o[1:], d[1:], np.array([0.99, 0.98]),
                   np.array([1, 2]), tolerance=15.0, staleness=0.07)
    assert len(b.points) == 1
    np.testing.assert_allclose(b.points[0], point, atol=1e-6)
    stale = find_birth(o[:1], d[:1], 1.0, 0, o[1:], d[1:], np.array([0.9, 0.8]),
                       np.array([1, 2]), staleness=0.07)
    assert len(stale.points) == 0
    same_cam = find_birth(o[:1], d[:1], 1.0, 0, o[1:], d[1:], np.array([0.99, 0.99]),
                          np.array([0, 0]))
    assert len(same_cam.points) == 0


def test_starved_needs_two_cameras():
    last = np.array([[0.95, 0.96, -np.inf],    # two cameras recently
                     [0.95, 0.5, -np.inf],     # one camera only
                     [0.5, 0.4, 0.3]])         # nobody recently
    np.testing.assert_array_equal(starved(1.0, last, 0.15), [False, True, True])
    with pytest.raises(ValueError, match="timeout"):
        starved(1.0, last, 0.0)


def test_process_noise_is_the_one_of_transition_and_predict():
    dt = np.array([0.01, 0.2])
    Q2 = process_noise(dt, 4e6)
    np.testing.assert_allclose(Q2[1], 4e6 * np.array([[0.2**3 / 3, 0.2**2 / 2],
                                                      [0.2**2 / 2, 0.2]]))
    _, Q = transition(dt, 4e6)
    np.testing.assert_array_equal(Q[:, [0, 3]][:, :, [0, 3]], Q2)
    x = np.zeros((2, 6))
    _, P = predict(x, np.zeros((2, 6, 6)), dt, 4e6)
    np.testing.assert_array_equal(P, Q)


def test_kalman_update_from_the_measurement_equals_ekf_update(rig):
    rng = np.random.default_rng(4)
    x = np.c_[rng.uniform(-500, 500, (3, 3)) + [0, 0, 1200], rng.normal(0, 100, (3, 3))]
    P = np.tile(np.diag([100.0] * 3 + [1e4] * 3), (3, 1, 1))
    h, H = measurement(rig[0], x, lag=0.01)
    z = h + rng.normal(0, 0.5, h.shape)
    a = kalman_update(x, P, H, h, z, sigma_px=0.5)
    b = ekf_update(x, P, rig[0], z, 0.5, lag=0.01)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    with pytest.raises(ValueError, match="H"):
        kalman_update(x, P, H[:, :, :3], h, z, sigma_px=0.5)


def test_innovation_gate_is_n_sigma_of_the_larger_axis_within_limits():
    S = np.array([np.diag([4.0, 1.0]), np.diag([400.0, 1.0]), np.diag([0.01, 0.01])])
    np.testing.assert_allclose(innovation_gate(S, n_sigma=3.0, lower=1.0, upper=15.0),
                               [6.0, 15.0, 1.0])
    with pytest.raises(ValueError, match="S"):
        innovation_gate(np.eye(2), n_sigma=3.0, lower=1.0, upper=15.0)


def test_screening_leaves_the_callers_arrays_and_counts_in_the_intake():
    fr = Frames.from_lists([0, 0, 5, 1], [0.1, 0.05, 0.2, np.nan],
                           [[[1.0, 2.0], [np.nan, 1.0]], [[3.0, 4.0]], [[0.0, 0.0]], []])
    last = np.array([0.2, -np.inf])
    s = screen_frame(fr, 0, 2, last)
    assert s.refused == "backwards_time" and s.xy is None
    np.testing.assert_array_equal(last, [0.2, -np.inf])          # untouched
    s = screen_frame(fr, 0, 2, np.full(2, -np.inf))
    assert s.refused is None and s.nan_centroids == 1 and s.xy.shape == (1, 2)
    intake = FrameIntake.initial(2)
    taken = [intake.take(fr, f) for f in range(fr.n_frames)]
    assert taken[0].shape == (1, 2) and taken[1] is None and taken[2] is None
    assert taken[3] is None
    assert intake.rejected == {"unknown_camera": 1, "backwards_time": 1, "nonfinite_stamp": 1,
                               "empty_frames": 0, "nan_centroids": 1}
    np.testing.assert_array_equal(intake.received, [1, 0])


def test_ray_pool_forgets_stale_and_own_rays(rig):
    pool = RayPool()
    o, d = rig[0].rays(np.array([[320.0, 240.0], [100.0, 100.0]]))
    pool.add(o, d, 0.0, 0)
    pool.add(o[:1], d[:1], 0.05, 1)
    pool.refresh(0.1, 1, 0.07)               # camera 0's rays are stale, camera 1's own
    assert len(pool.stamps) == 0
    pool.add(o, d, 0.2, 2)
    pool.refresh(0.25, 0, 0.07)
    np.testing.assert_array_equal(pool.cameras, [2, 2])


# ----------------------------------------------------------------------------- scheduler
def test_schedule_policies():
    # three cameras, frames every 10 ms, service takes 15 ms: the estimator is overloaded
    cam = np.tile([0, 1, 2], 20)
    t = np.repeat(np.arange(20) * 0.010, 3) + np.tile([0.0, 0.001, 0.002], 20)
    stamp = t + np.where(cam == 0, 0.004, 0.0)           # camera 0's clock runs ahead
    fifo = schedule(t, cam, stamp, "fifo", 0.001)
    np.testing.assert_array_equal(np.sort(fifo.order), np.arange(60))
    assert not fifo.skipped.any()
    newest = schedule(t, cam, stamp, "newest", 0.015)
    assert newest.skipped.any()
    assert np.bincount(cam[newest.order], minlength=3)[1:].sum() <= 2   # B and C starve
    rr = schedule(t, cam, stamp, "round_robin", 0.015)
    served = np.bincount(cam[rr.order], minlength=3)
    assert served.min() >= 5 and served.max() - served.min() <= 1     # cameras in turn
    rnd = schedule(t, cam, stamp, "random_recent", 0.015, rng=np.random.default_rng(0))
    assert (np.bincount(cam[rnd.order], minlength=3) > 2).all()
    assert np.all(np.diff(rnd.started) > 0)
    with pytest.raises(ValueError, match="rng"):
        schedule(t, cam, stamp, "random_recent", 0.015)
    with pytest.raises(ValueError, match="policy"):
        schedule(t, cam, stamp, "lifo", 0.015)


# ----------------------------------------------------------------------------- tracker
def test_fig35_discard_late_starves_and_tolerance_cures():
    trial = fig35_starvation(rng=np.random.default_rng(1), duration=1.0)
    np.testing.assert_allclose(trial.used_discard, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(trial.used_tolerant, [1.0, 1.0, 1.0])
    assert trial.tracks_discard == 0 and trial.tracks_tolerant == 1
    assert trial.rms_tolerant < 10.0


def test_trials_take_their_rig(rig):
    default = trial_rig(None)
    np.testing.assert_array_equal([c.C for c in default],
                                  [c.C for c in ceiling_rig(rng=RIG_SEED)])
    assert trial_rig(rig[:4]) == list(rig[:4])
    with pytest.raises(TypeError, match="rig"):
        trial_rig([1, 2])


def test_walking_person_short(rig):
    k = np.arange(8)
    w = walking_trial(rng=np.random.default_rng(5), duration=1.2,
                      on=np.stack([0.05 + 0.02 * k, 0.9 + 0.02 * k], axis=1))
    s = w.score_ours
    assert s.identity_changes == 0
    assert s.rms_mm < 10.0
    assert np.nanmax(s.birth_delay) <= 0.070 + 1 / 30
    assert np.all(s.death_delay <= 0.150 + 0.010)     # timeout + clock offsets (±4 ms)
    assert s.coverage > 0.95
    assert s.never_born == 0 and s.never_deleted == 0
    assert w.metrics_ours["siap_completeness"] > 0.9


def test_score_counts_failed_births_and_deaths():
    from lsmta.synth.widearea import LedScene
    from lsmta.widearea import TrackingResult, WideAreaTrack

    t = np.linspace(0.0, 1.0, 101)
    pos = np.zeros((101, 2, 3))
    pos[:, 1, 0] = 1000.0                       # LED 1 is 1 m from LED 0
    scene = LedScene("two", t, pos, np.tile([0.0, 0.0, -1.0], (101, 2, 1)),
                     on=np.array([[0.0, 0.5], [0.0, 0.5]]))
    # one track on LED 0 that never dies; nothing on LED 1
    trk = WideAreaTrack(id=0, times=np.array([0.0]), states=np.zeros((1, 6)),
                        birth_time=0.0, death_time=np.nan)
    z = np.zeros(1)
    res = TrackingResult((trk,), z, z, z, z, z, 0, 0, 0, 0, 0)
    s = score_led_tracks(scene, res, np.arange(0.0, 1.0, 0.05))
    assert s.never_born == 1 and s.never_deleted == 1
    assert np.isnan(s.birth_delay[1]) and np.isnan(s.death_delay[0])
    assert s.coverage == pytest.approx(0.5)


def _frames(rig, rng):
    cams = rig[:6]
    obs = observe_leds(still_led(duration=0.6), cams, make_clocks(6, rng=rng), rng=rng,
                       params=LedCentroidParams(reflections=0.0))
    return cams, obs


def test_bad_input_is_counted_not_fatal(rig):
    cams, obs = _frames(rig, np.random.default_rng(2))
    fr = obs.frames
    clean = track(cams, fr)
    n = 30
    cents = [fr.centroids(f) for f in range(fr.n_frames)]
    cents[5] = np.r_[cents[5], [[np.nan, np.nan]]]
    cam = np.r_[fr.camera[:n], 17, fr.camera[n - 1], fr.camera[n:], 0]
    stamp = np.r_[fr.stamp[:n], 0.1, fr.stamp[n - 1], fr.stamp[n:], np.inf]
    cents = cents[:n] + [np.ones((1, 2)), np.ones((2, 2))] + cents[n:] + [np.ones((1, 2))]
    xy_copy = [c.copy() for c in cents]
    bad = track(cams, Frames.from_lists(cam, stamp, cents))
    assert bad.unknown_camera == 1
    assert bad.backwards_time == 1
    assert bad.nonfinite_stamp == 1
    assert bad.nan_centroids == 1
    assert len(bad.tracks) == len(clean.tracks) == 1
    np.testing.assert_allclose(bad.tracks[0].states, clean.tracks[0].states)
    for a, b in zip(cents, xy_copy):
        np.testing.assert_array_equal(a, b)
    empty = track(cams, Frames.from_lists([0, 1], [0.0, 0.01], [np.zeros((0, 2))] * 2))
    assert empty.empty_frames == 2 and not empty.tracks


def test_tracker_argument_errors(rig):
    cams, obs = _frames(rig, np.random.default_rng(2))
    with pytest.raises(TypeError, match="cameras"):
        track([], obs.frames)
    with pytest.raises(TypeError, match="frames"):
        track(cams, obs.frames.xy)
    with pytest.raises(ValueError, match="sigma_px"):
        EstimatorParams(sigma_px=0.0)
    with pytest.raises(ValueError, match="start"):
        Frames(camera=np.array([0]), stamp=np.array([0.0]), start=np.array([1, 1]),
               xy=np.zeros((0, 2)))
    with pytest.raises(ValueError, match="camera"):
        Frames(camera=np.array([0.5]), stamp=np.array([0.0]), start=np.array([0, 0]),
               xy=np.zeros((0, 2)))


def test_generator_truth_and_visibility(rig):
    rng = np.random.default_rng(4)
    scene = walking_person(duration=0.6)
    obs = observe_leds(scene, rig, make_clocks(18, rng=rng), rng=rng,
                       params=LedCentroidParams(reflections=0.0, noise_px=0.0))
    # every centroid with a truth label lies on the projection of that LED at capture time
    fr = obs.frames
    f = int(np.argmax(np.diff(fr.start)))
    xy = fr.centroids(f)
    labels = obs.truth[fr.start[f]:fr.start[f + 1]]
    X = scene.positions_at([obs.true_time[f]])[0]
    proj = rig[fr.camera[f]].project(X[labels])
    np.testing.assert_allclose(xy, proj, atol=1e-9)
    assert 0.2 < obs.visible.mean() < 1.0        # occlusion, dim LEDs and LEDs off
    # without clutter, every frame holds exactly one centroid per visible LED, labelled so
    counts = np.diff(fr.start)
    np.testing.assert_array_equal(counts, obs.visible.sum(axis=1))
    for g in range(0, fr.n_frames, 50):
        np.testing.assert_array_equal(np.sort(obs.truth[fr.start[g]:fr.start[g + 1]]),
                                      np.flatnonzero(obs.visible[g]))
    # an LED that is off, or projects outside the image, is never visible
    pos = scene.positions_at(obs.true_time)                      # (F, N, 3)
    off = ~np.isfinite(pos).all(axis=2)
    assert not obs.visible[off].any()
    for k, cam in enumerate(rig):
        rows = np.flatnonzero(fr.camera == k)
        p = pos[rows]
        inside = cam.in_image(cam.project(np.where(off[rows, :, None], 0.0, p).reshape(-1, 3),
                                          behind="nan")).reshape(len(rows), -1)
        assert not obs.visible[rows][~inside].any()


def test_stonesoup_baseline_tracks_a_still_led(rig):
    from lsmta.widearea.peers import stonesoup_track

    cams, obs = _frames(rig, np.random.default_rng(6))
    res = stonesoup_track(cams, obs.frames)
    score = score_led_tracks(still_led(duration=0.6), res, np.arange(0.2, 0.6, 0.02))
    assert len(res.tracks) == 1
    assert score.rms_mm < 5.0


# ----------------------------------------------------------------------------- detection
def _spot_frames(centres, shape=(60, 80), peak=200.0, sigma=1.0, base=40.0):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    out = []
    for cs in centres:
        img = np.full(shape, base)
        for x, y in cs:
            img += peak * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))
        out.append(img)
    return np.array(out)


def test_relearn_threshold_ignores_small_spots_not_large_areas():
    from lsmta.widearea import detect, relearn_threshold

    rng = np.random.default_rng(4)
    frames = np.full((3, 40, 50), 80.0) + rng.normal(0, 1, (3, 40, 50))
    yy, xx = np.mgrid[:40, :50]
    frames[:, 5:25, 30:48] = 200.0                       # a lamp, 20 x 18 px
    led = 150.0 * np.exp(-((xx - 10) ** 2 + (yy - 30) ** 2) / (2 * 0.9**2))
    frames_led = frames + led                             # an LED in view while relearning
    thr = relearn_threshold(frames_led, 20.0, 60.0)
    assert thr.threshold[30, 10] < 110.0                  # the LED did not enter the background
    assert thr.threshold[15, 40] > 215.0                  # the lamp did
    det = detect(frames_led[0], thr)
    assert len(det.xy) == 1 and np.allclose(det.xy[0], [10, 30], atol=0.1)
    np.testing.assert_array_equal(frames_led, frames + led)   # input untouched
    with pytest.raises(ValueError, match="spot_px"):
        relearn_threshold(frames, 20.0, 60.0, spot_px=2)
    with pytest.raises(ValueError, match="grow_px"):
        relearn_threshold(frames, 20.0, 60.0, grow_px=-1)


def test_background_threshold_and_lighting_test():
    from lsmta.widearea import background_threshold, needs_new_threshold

    bg = np.zeros((3, 4, 5))
    bg[1, 2, 3] = 50.0
    thr = background_threshold(bg, 20.0, 30.0)
    assert thr.threshold[2, 3] == 70.0 and thr.threshold[0, 0] == 30.0
    ex = np.zeros_like(bg, bool)
    ex[1, 2, 3] = True
    assert background_threshold(bg, 20.0, 30.0, exclude=ex).threshold[2, 3] == 30.0
    assert not needs_new_threshold(np.zeros((4, 5)), thr, fraction=0.01)
    assert needs_new_threshold(np.full((4, 5), 40.0), thr, fraction=0.01)
    with pytest.raises(ValueError, match="frames"):
        background_threshold(np.zeros(5), 1.0, 1.0)


def test_noise_threshold_finds_a_dim_led_the_fixed_floor_misses():
    from lsmta.widearea import background_threshold, detect, noise_threshold

    rng = np.random.default_rng(3)
    H, W = 48, 64
    room = 30.0 + 5.0 * np.sin(np.arange(W) / 9.0)[None] + np.zeros((H, W))

    def shoot(n, spot=0.0):
        return np.clip(np.rint(room + spot + rng.normal(0, 2.0, (n, H, W))), 0, 255).astype(
            np.uint8)

    empty = shoot(20)
    kept = empty.copy()
    yy, xx = np.mgrid[0:H, 0:W]
    # a far camera's LED: 23 grey levels at its peak over a background of about 30
    spot = 23.0 * np.exp(-((xx - 40.3) ** 2 + (yy - 20.6) ** 2) / (2 * 0.9**2))
    led = shoot(10, spot)
    fixed = detect(led, background_threshold(empty, 20.0, 60.0))
    assert len(fixed.xy) == 0                           # under the floor of 60
    thr = noise_threshold(empty, sigmas=5.0)
    # the offset is 5 noise levels measured in the frames (noise 2, rounding included)
    offset = np.median(thr.threshold - thr.background)
    assert 9.5 < offset < 10.8
    found = detect(led, thr)
    assert np.all(np.diff(found.start) == 1)            # once in every frame
    assert np.allclose(found.xy, [40.3, 20.6], atol=0.4)
    # noise alone: no false detection in 200 frames of empty room
    assert len(detect(shoot(200), thr).xy) == 0
    ex = np.zeros_like(empty, bool)
    ex[:, 5, 7] = True                                  # excluded in every frame
    assert noise_threshold(empty, sigmas=5.0, exclude=ex).threshold[5, 7] >= empty.max()
    np.testing.assert_array_equal(empty, kept)            # input untouched
    with pytest.raises(ValueError, match="sigmas"):
        noise_threshold(empty, sigmas=0.0)
    with pytest.raises(ValueError, match="frames"):
        noise_threshold(empty[:1], sigmas=5.0)
    with pytest.raises(ValueError, match="exclude"):
        noise_threshold(empty, sigmas=5.0, exclude=ex[:3])


def test_detect_full_gives_subpixel_centroids_and_respects_masks():
    from lsmta.widearea import Threshold, detect

    truth = [[(20.3, 30.6), (60.7, 12.2)], [(21.1, 31.4)], []]
    frames = _spot_frames(truth)
    bg = np.full(frames.shape[1:], 40.0)
    # a low threshold (2.5 % of the peak) keeps nearly the whole spot: the intensity centroid
    # is then unbiased; higher thresholds truncate the spot and bias it by a few 0.01 px
    thr = Threshold(background=bg, threshold=bg + 5.0)
    frames_copy = frames.copy()
    det = detect(frames, thr)
    np.testing.assert_array_equal(frames, frames_copy)
    assert np.diff(det.start).tolist() == [2, 1, 0]
    for t, cs in enumerate(truth):
        got = det.centroids(t)
        for c in cs:
            assert np.linalg.norm(got - c, axis=1).min() < 0.02
    invalid = np.zeros(frames.shape[1:], bool)
    invalid[5:20, 50:70] = True                       # masks the second spot of frame 0
    masked = detect(frames, thr, invalid=invalid)
    assert np.diff(masked.start).tolist() == [1, 1, 0]
    with pytest.raises(ValueError, match="mode"):
        detect(frames, thr, mode="sparse")
    with pytest.raises(ValueError, match="threshold"):
        detect(frames[:, :10], thr)
    with pytest.raises(ValueError, match="invalid"):
        detect(frames, thr, invalid=invalid[:5])


def test_subsampled_search_tests_fewer_pixels_and_finds_predicted_spots():
    from lsmta.widearea import Threshold, detect, search_mask

    # a one-pixel spot the grid may miss, but the window around its prediction finds
    truth = [[(40.0, 25.0)]] * 4
    frames = _spot_frames(truth, sigma=0.3)
    bg = np.full(frames.shape[1:], 40.0)
    thr = Threshold(background=bg, threshold=bg + 30.0)
    full = detect(frames, thr)
    sub = detect(frames, thr, mode="subsampled", rng=np.random.default_rng(0),
                 predicted=[np.array([[41.0, 26.0]])] * 4)
    assert (sub.tested < full.tested).all()
    for t in range(4):
        np.testing.assert_allclose(sub.centroids(t), full.centroids(t), atol=1e-9)
    m = search_mask((60, 80), 5, (1, 2), windows=np.array([[40.0, 30.0]]), window=10)
    assert m[1::5, 2::5].all() and m[25:35, 35:45].all()
    assert m.sum() == 12 * 16 + 100 - m[25:35, 35:45][(np.arange(25, 35) % 5 == 1)[:, None]
                                                        & (np.arange(35, 45) % 5 == 2)].sum()
    with pytest.raises(TypeError, match="rng"):
        detect(frames, thr, mode="subsampled", rng="0")


def test_rendered_video_detected_at_truth():
    from lsmta.synth.widearea import LedVideoParams, render_led_video, small_camera
    from lsmta.widearea import background_threshold, detect

    rng = np.random.default_rng(8)
    cam = small_camera(ceiling_rig(rng=np.random.default_rng(7))[0])
    video = render_led_video(still_led(duration=0.3), cam, np.arange(5) / 30, rng=rng,
                             params=LedVideoParams(monitor_flicker=0.0, reflections=0.0))
    thr = background_threshold(video.background, 20.0, 60.0)
    det = detect(video.frames, thr)
    for t in range(5):
        assert np.linalg.norm(det.centroids(t) - video.true_xy[t, 0], axis=1).min() < 0.3


def test_rendered_video_does_not_depend_on_its_block_size(monkeypatch):
    """render_led_video renders blocks of frames with the random numbers of a whole-video
    rendering: frame by frame, in blocks, or all at once, the same frames and background."""
    from lsmta.synth import widearea as sw

    cam = sw.small_camera(ceiling_rig(rng=np.random.default_rng(7))[0])
    params = sw.LedVideoParams(monitor_flicker=0.5, reflections=0.5, n_background=3)
    videos = []
    for block in (1, 4, 100):
        monkeypatch.setattr(sw, "_BLOCK", block)
        videos.append(sw.render_led_video(still_led(duration=0.3), cam, np.arange(9) / 30,
                                          rng=np.random.default_rng(2), lighting_change=5,
                                          params=params))
    for v in videos[1:]:
        assert np.array_equal(v.frames, videos[0].frames)
        assert np.array_equal(v.background, videos[0].background)
        assert np.array_equal(v.true_xy, videos[0].true_xy, equal_nan=True)
    assert (videos[0].frames[5:].mean() > videos[0].frames[:5].mean())   # the lights went up


def test_vectorised_subsampled_matches_full_on_wide_spots_and_counts_tests():
    from lsmta.widearea import Threshold, detect

    # an image size not divisible by k (the grid's last row/column depends on the jitter),
    # spots wider than k so that the grid always hits them, one at the image border
    shape, k = (61, 83), 5
    truth = [[(20.3, 30.6), (60.7, 12.2)], [(81.5, 59.2)], [], [(40.0, 40.0)]]
    frames = _spot_frames(truth, shape=shape, sigma=2.0)
    bg = np.full(shape, 40.0)
    thr = Threshold(background=bg, threshold=bg + 20.0)
    full = detect(frames, thr)
    sub = detect(frames, thr, mode="subsampled", rng=np.random.default_rng(5))
    assert np.diff(sub.start).tolist() == np.diff(full.start).tolist() == [2, 1, 0, 1]
    for t in range(len(truth)):
        np.testing.assert_allclose(sub.centroids(t), full.centroids(t), atol=1e-9)
    # the empty frame tests exactly its jittered grid
    grids = {len(range(a, shape[0], k)) * len(range(b, shape[1], k))
             for a in range(k) for b in range(k)}
    assert sub.tested[2] in grids
    # frames with a spot test the grid plus the grown neighbourhoods, far fewer than all
    assert (sub.tested[[0, 1, 3]] > min(grids)).all()
    assert (sub.tested < 0.3 * full.tested).all()
    # masks hold in the sub-sampled search too
    invalid = np.zeros(shape, bool)
    invalid[25:36, 15:26] = True                      # the spot at (20.3, 30.6)
    masked = detect(frames, thr, mode="subsampled", invalid=invalid,
                    rng=np.random.default_rng(5))
    assert np.diff(masked.start).tolist() == [1, 1, 0, 1]
    kept = full.centroids(0)[np.linalg.norm(full.centroids(0) - (20.3, 30.6), axis=1) > 5]
    np.testing.assert_allclose(masked.centroids(0), kept, atol=1e-9)
    # integer frames are compared with integer thresholds: same features as in floats
    frames8 = np.rint(frames).astype(np.uint8)
    thr_frac = Threshold(background=bg, threshold=bg + 20.5)
    for mode in ("full", "subsampled"):
        a = detect(frames8, thr_frac, mode=mode, rng=np.random.default_rng(1))
        b = detect(frames8.astype(float), thr_frac, mode=mode, rng=np.random.default_rng(1))
        np.testing.assert_array_equal(a.start, b.start)
        np.testing.assert_allclose(a.xy, b.xy, atol=1e-9)


def test_subsampled_previous_windows_follow_a_spot_the_grid_misses():
    from lsmta.widearea import Threshold, detect

    # frame 0: a wide spot (the grid finds it); then a one-pixel spot nearby, which only the
    # window around the previous frame's feature can be relied on to find
    big = _spot_frames([[(40.0, 25.0)]], sigma=2.0)
    small = _spot_frames([[(42.0, 27.0)]] * 5, sigma=0.3)
    frames = np.concatenate([big, small])
    bg = np.full(frames.shape[1:], 40.0)
    thr = Threshold(background=bg, threshold=bg + 30.0)
    full = detect(frames, thr)
    for seed in range(4):
        sub = detect(frames, thr, mode="subsampled", rng=np.random.default_rng(seed),
                     predicted="previous")
        for t in range(len(frames)):
            np.testing.assert_allclose(sub.centroids(t), full.centroids(t), atol=1e-9)
    with pytest.raises(ValueError, match="predicted"):
        detect(frames, thr, mode="subsampled", rng=np.random.default_rng(0), predicted="next")
    with pytest.raises(ValueError, match="predicted"):
        detect(frames, thr, mode="subsampled", rng=np.random.default_rng(0),
               predicted=[np.zeros((0, 2))])


def test_rendered_images_detected_and_tracked_in_3d():
    trial = rendered_tracking_trial(rng=np.random.default_rng(11), n_cameras=5, duration=1.0,
                                    hold=0.2, modes=("subsampled",))
    r = trial.results["subsampled"]
    # one LED: one target, followed all the time, within the thesis's ~10 mm
    assert r["tracks"] == 1
    assert r["coverage"] == 1.0
    assert r["rms_mm"] < 10.0
    assert r["tested_fraction"] < 0.2
    # the truth comes from the generator: the LED moves ~1.2 m over the scored window
    assert np.linalg.norm(trial.truth[-1] - trial.truth[0]) > 500.0
    assert trial.frames["subsampled"].n_frames > 3 * 25
