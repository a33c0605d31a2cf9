"""The streaming wide-area tracker (lsmta.widearea.WideAreaTracker): the same results as the
batch tracker, reads that change nothing, guided detection, cameras that join and leave,
the synchronised per-instant intersection (Fig. 33), bad input."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from lsmta.camera import Camera
from lsmta.evaluation.track_scores import score_led_tracks
from lsmta.evaluation.widearea import walking_trial
from lsmta.synth.calibration import poor_guess
from lsmta.synth.widearea import (
    Clocks,
    LedCentroidParams,
    ceiling_rig,
    circle_led,
    make_clocks,
    observe_leds,
    render_led_video,
    small_camera,
    walking_person,
)
from lsmta.widearea import (
    CameraStatus,
    EstimatorParams,
    Frames,
    FrameStatus,
    JoinParams,
    JoinStatus,
    WideAreaTracker,
    background_threshold,
    calibrate_from_targets,
    detect,
    predict,
    search_frame,
    search_setup,
    track,
)
from lsmta.widearea.intersection import intersect_instants


@pytest.fixture(scope="module")
def walk():
    k = np.arange(8)
    return walking_trial(rng=np.random.default_rng(21), duration=0.9,
                         cameras=list(range(0, 18, 2)),
                         on=np.stack([0.05 + 0.02 * k, 0.6 + 0.02 * k], axis=1))


def _same(a, b, *, counters=True):
    assert len(a.tracks) == len(b.tracks) > 0
    for x, y in zip(a.tracks, b.tracks):
        assert x.id == y.id and x.birth_time == y.birth_time
        assert np.array_equal(x.times, y.times) and np.array_equal(x.states, y.states)
        assert x.death_time == y.death_time or (np.isnan(x.death_time)
                                                and np.isnan(y.death_time))
    for key in a.updates:
        assert np.array_equal(a.updates[key], b.updates[key])
    if counters:
        for key in ("frames_received", "frames_used", "late_dropped", "late_used",
                    "observations_used"):
            assert np.array_equal(getattr(a, key), getattr(b, key))
        assert a.rejected == b.rejected


def test_streaming_tracker_equals_the_batch_tracker(walk):
    fr = walk.frames
    batch = track(walk.cameras, fr)
    tracker = WideAreaTracker(walk.cameras)
    statuses = []
    for f in range(fr.n_frames):
        xy = fr.centroids(f)
        before = xy.copy()
        statuses.append(tracker.feed(fr.camera[f], fr.stamp[f], xy))
        np.testing.assert_array_equal(xy, before)
        if f % 7 == 0:                              # reading changes nothing
            tracker.estimate()
            tracker.predict(tracker.now + 0.02)
            tracker.predict_image(int(fr.camera[f]), fr.stamp[f] + 0.01)
            tracker.result()
    _same(tracker.result(), batch)
    assert FrameStatus.USED_LATE in statuses and FrameStatus.USED in statuses
    # the detection steered by the prediction: the same centroids give the same run
    guided = WideAreaTracker(walk.cameras)
    seen = []
    for f in range(fr.n_frames):
        def found(pred, f=f):
            seen.append(len(pred.ids))
            assert pred.xy.shape == pred.velocity.shape == (len(pred.ids), 2)
            return fr.centroids(f)
        guided.feed_detect(fr.camera[f], fr.stamp[f], found)
    _same(guided.result(), batch, counters=False)
    assert max(seen) >= 6


def test_estimate_prediction_and_image_velocity(walk):
    tracker = WideAreaTracker(walk.cameras)
    fr = walk.frames
    for f in range(fr.n_frames // 2):
        tracker.feed(fr.camera[f], fr.stamp[f], fr.centroids(f))
    e = tracker.estimate()
    assert e.time == tracker.now and len(e.ids) >= 6
    dt = 0.02
    p = tracker.predict(tracker.now + dt)
    np.testing.assert_allclose(p.positions, e.positions + dt * e.states[:, 3:])
    X, P = predict(e.states, e.covariances, dt, tracker.params.accel_density)
    np.testing.assert_allclose(p.states, X)
    np.testing.assert_allclose(p.covariances, P)
    assert np.all(np.trace(P[:, :3, :3], axis1=1, axis2=2)
                  > np.trace(e.covariances[:, :3, :3], axis1=1, axis2=2))
    back = tracker.predict(tracker.now - dt)
    np.testing.assert_allclose(back.positions, e.positions - dt * e.states[:, 3:])
    cam = walk.cameras[3]
    im = tracker.predict_image(3, tracker.now + dt)
    ok = np.isfinite(im.xy).all(axis=1)
    np.testing.assert_allclose(im.xy[ok], cam.project(p.positions[ok]), atol=1e-9)
    # image velocity: the projection's derivative along the target's motion
    h = 1e-4
    ahead = cam.project(p.positions[ok] + h * p.states[ok, 3:])
    np.testing.assert_allclose(im.velocity[ok], (ahead - im.xy[ok]) / h, rtol=1e-3,
                               atol=1e-2)
    assert np.all((im.gate_px >= tracker.params.min_gate_px)
                  & (im.gate_px <= tracker.params.gate_px))


def test_a_camera_joins_and_another_is_dropped_on_a_small_scene():
    rig = ceiling_rig(rng=np.random.default_rng(9))
    scene = circle_led(duration=2.5, radius=600.0, period=1.0)
    clocks = make_clocks(len(rig), rng=np.random.default_rng(1), max_offset=0.002)
    obs = observe_leds(scene, rig, clocks, rng=np.random.default_rng(2),
                       params=LedCentroidParams(reflections=0.0))
    new, gone, stop = 5, 2, 1.0
    start = [c for i, c in enumerate(rig) if i != new]
    index = np.array([i - (i > new) for i in range(len(rig))])
    index[new] = len(start)
    guess = poor_guess([rig[new]], rng=np.random.default_rng(4))[0]
    tracker = WideAreaTracker(start, params=EstimatorParams(camera_timeout=0.2))
    fr = obs.frames
    added = False
    for f in range(fr.n_frames):
        c = int(fr.camera[f])
        if c == gone and fr.stamp[f] > stop:
            continue                                       # camera 2 fails at 1 s
        if c == new and not added:
            if fr.arrival[f] < 0.3:
                continue
            added = True
            assert tracker.add_camera(guess, calibrated=False,
                                      join=JoinParams(min_frames=25, min_pairs=20,
                                                     intrinsics=())) == 17
            assert tracker.camera_status[17] == CameraStatus.JOINING
        tracker.feed(index[c], fr.stamp[f], fr.centroids(f))
    res = tracker.result()
    what = {(e[1], e[2]): e[0] for e in res.camera_events}
    assert (17, "joined") in what and res.camera_status[17] == CameraStatus.ACTIVE
    cal = res.cameras[17]
    X = scene.positions[::40, 0]
    err = np.sqrt(np.mean((cal.project(X) - rig[new].project(X)) ** 2))
    assert err < 0.5 * np.sqrt(np.mean((guess.project(X) - rig[new].project(X)) ** 2))
    # one LED covers too little of the image for the lens: only the pose is resected here;
    # the joined camera's innovations are those of the calibrated cameras
    u = res.updates
    late = u["time"] > what[(17, "joined")]
    innov = np.linalg.norm(u["observed"] - u["predicted"], axis=1)
    rms = [np.sqrt(np.mean(innov[late & (u["camera"] == c)] ** 2)) for c in range(18)
           if (late & (u["camera"] == c)).sum() > 5]
    assert (late & (u["camera"] == 17)).sum() > 10
    assert np.sqrt(np.mean(innov[late & (u["camera"] == 17)] ** 2)) < 1.5 * np.median(rms)
    last = fr.stamp[(fr.camera == gone) & (fr.stamp <= stop)].max()
    assert 0.2 <= what[(index[gone], "dropped")] - last < 0.2 + 0.02   # timeout + a frame
    assert res.camera_status[index[gone]] == CameraStatus.SILENT
    score = score_led_tracks(scene, res, np.arange(0.2, 2.5, 0.01))
    assert score.identity_changes == 0 and score.coverage > 0.98 and score.rms_mm < 10.0
    # a removed camera's frames are refused and counted
    tracker.remove_camera(0)
    assert tracker.feed(0, fr.stamp[-1] + 1.0, np.zeros((0, 2))) == FrameStatus.NOT_ACTIVE
    assert tracker.result().not_active[0] == 1


def test_calibration_against_targets_refuses_too_little():
    rig = ceiling_rig()
    guess = poor_guess([rig[0]], rng=np.random.default_rng(0))[0]
    X = np.array([[0.0, 0.0, 1000.0]])
    few = calibrate_from_targets(guess, [rig[0].project(X)] * 3, [X] * 3)
    assert few.status == JoinStatus.TOO_FEW_PAIRS and few.camera is guess
    with pytest.raises(ValueError, match="positions"):
        calibrate_from_targets(guess, [rig[0].project(X)], [X, X])
    with pytest.raises(TypeError, match="guess"):
        calibrate_from_targets(None, [], [])
    with pytest.raises(ValueError, match="min_pairs"):
        JoinParams(min_pairs=0)


def test_windowed_search_finds_what_the_full_search_finds():
    cam = small_camera(ceiling_rig(rng=np.random.default_rng(7))[3])
    scene = walking_person(duration=0.5, on=np.stack([np.zeros(8), np.full(8, np.inf)], 1))
    video = render_led_video(scene, cam, np.arange(12) / 30, rng=np.random.default_rng(3))
    thr = background_threshold(video.background, 20.0, 60.0)
    inv = np.zeros(video.frames.shape[1:], bool)
    x0, y0, x1, y1 = video.monitor.astype(int)
    inv[y0:y1, x0:x1] = True
    full = detect(video.frames, thr, invalid=inv)
    setup = search_setup(thr, invalid=inv)
    frames_before = video.frames.copy()
    for t in range(len(video.frames)):
        truth = video.true_xy[t][np.isfinite(video.true_xy[t]).all(axis=1)]
        g = search_frame(video.frames[t], setup, windows=truth, rng=np.random.default_rng(t))
        f = full.centroids(t)
        near = np.linalg.norm(f[:, None] - truth[None], axis=2).min(axis=1) < 3 \
            if len(truth) else np.zeros(len(f), bool)
        # every feature at an LED is found, at exactly the full search's centroid
        for c in f[near]:
            assert np.linalg.norm(g.xy - c, axis=1).min() < 1e-9
        assert g.tested < 0.25 * video.frames[t].size
        everything = search_frame(video.frames[t], setup, full=True)
        np.testing.assert_allclose(everything.xy, f, atol=1e-9)
        assert everything.tested == video.frames[t].size
    np.testing.assert_array_equal(video.frames, frames_before)
    # gate-sized windows: half-sizes per window
    one = search_frame(video.frames[0], setup, windows=np.array([[100.0, 100.0]]),
                       half_sizes=[3.0], jitter=(0, 0))
    none = search_frame(video.frames[0], setup, jitter=(0, 0))
    grid_in_window = len(range(100 - 3, 103)) ** 2 - len([r for r in range(97, 103)
                                                           if r % 5 == 0]) ** 2
    assert one.tested - none.tested == grid_in_window


def test_guided_search_at_full_size_matches_the_full_search_where_windows_reach():
    from lsmta.widearea import DetectionParams, Threshold

    # 640 x 480, uint8: small spots in windows (one across two overlapping windows' edges),
    # a wide spot the grid always hits, a blob of ~1000 pixels (the fills' set grows), and a
    # small spot outside every window and off the grid, which only the full search finds
    H, W = 480, 640
    yy, xx = np.mgrid[0:H, 0:W]
    img = np.full((H, W), 40.0)
    spots = [(100.3, 80.6, 0.8), (139.6, 80.2, 0.9), (300.2, 200.7, 3.0), (500.5, 400.5, 12.0),
             (20.0, 470.0, 0.5), (401.0, 51.0, 0.3)]
    for x, y, sig in spots:
        img += 150.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sig ** 2))
    frame = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    bg = np.full((H, W), 40.0)
    params = DetectionParams(max_area=5000)
    setup = search_setup(Threshold(background=bg, threshold=bg + 20.0), params=params)
    full = search_frame(frame, setup, full=True)
    windows = np.array([[120.0, 80.0], [140.0, 90.0], [500.0, 400.0], [20.0, 470.0],
                        [np.nan, 3.0]])
    before = frame.copy()
    g = search_frame(frame, setup, windows=windows, jitter=(0, 0))   # grid: rows, cols 0 mod 5
    np.testing.assert_array_equal(frame, before)
    assert len(full.xy) == 6 and len(g.xy) == 5 and full.area.max() > 500
    missed = np.linalg.norm(full.xy - (401.0, 51.0), axis=1).argmin()
    for i in np.flatnonzero(np.arange(6) != missed):
        j = np.linalg.norm(g.xy - full.xy[i], axis=1).argmin()
        np.testing.assert_allclose(g.xy[j], full.xy[i], atol=1e-6)
        assert g.area[j] == full.area[i]
    # without spots: exactly the grid's and the windows' pixels (each once)
    empty = search_frame(np.full((H, W), 40, np.uint8), setup, windows=windows, jitter=(2, 3))
    from lsmta.widearea import search_mask
    assert empty.tested == search_mask((H, W), 5, (2, 3), windows=windows, window=40).sum()
    assert empty.tested < 0.06 * H * W


def test_tracker_offers_windows_around_centroids_waiting_for_a_partner():
    cams = [small_camera(c) for c in ceiling_rig(rng=np.random.default_rng(7))[:2]]
    tracker = WideAreaTracker(cams)
    seen = []

    def search(found):
        def detect_(pred):
            seen.append(pred.waiting)
            return found
        return detect_

    tracker.feed_detect(0, 0.00, search(np.array([[100.0, 80.0], [200.5, 150.25]])))
    tracker.feed_detect(0, 0.02, search(np.zeros((0, 2))))
    tracker.feed_detect(0, 0.04, search(np.zeros((0, 2))))
    tracker.feed_detect(0, 0.10, search(np.zeros((0, 2))))
    assert len(seen[0]) == 0                               # nothing found yet: nothing waits
    for waiting in seen[1:3]:                               # fresh (within 70 ms): they wait
        np.testing.assert_allclose(waiting, [[100.0, 80.0], [200.5, 150.25]], atol=1e-6)
    assert len(seen[3]) == 0                                # stale: forgotten
    assert len(tracker.predict_image(0, 0.04).waiting) == 0


def test_tracker_offers_the_line_where_a_waiting_ray_s_partner_must_be():
    cams = [small_camera(c) for c in ceiling_rig(rng=np.random.default_rng(7))[:2]]
    gate = EstimatorParams().gate_px
    X = np.array([[300.0, -200.0, 1200.0]])                # an LED in the birth volume
    assert all(c.in_image(c.project(X)).all() for c in cams)
    tracker = WideAreaTracker(cams)
    seen, waiting = {}, {}

    def search(c, found):
        def detect_(pred):
            seen[c], waiting[c] = pred.partners, pred.waiting
            return found
        return detect_

    tracker.feed_detect(0, 0.00, search(0, cams[0].project(X)))  # seen by camera 0 only
    tracker.feed_detect(1, 0.01, search(1, np.zeros((0, 2))))    # camera 1: where to look
    xy = seen[1]
    assert cams[1].in_image(xy).all() and len(xy) > 2
    assert len(np.unique(xy, axis=0)) == len(xy)                   # each point once
    # the LED's image lies on the line, and the points are at most gate_px apart
    assert np.linalg.norm(xy - cams[1].project(X), axis=1).min() < gate / 2 + 0.5
    assert np.linalg.norm(np.diff(xy, axis=0), axis=1).max() <= gate + 1e-6
    # camera 0's own ray still waits (fresh), but it is not offered to camera 0
    tracker.feed_detect(0, 0.02, search(0, np.zeros((0, 2))))
    assert len(waiting[0]) == 1 and len(seen[0]) == 0
    # a ray older than staleness is left out (it is still in the pool: no frame since)
    X2 = np.array([[-200.0, 300.0, 900.0]])
    assert all(c.in_image(c.project(X2)).all() for c in cams)
    staleness = EstimatorParams().staleness
    tracker.feed_detect(0, 0.03, search(0, cams[0].project(X2)))
    tracker.feed_detect(1, 0.04, search(1, np.zeros((0, 2))))
    assert len(seen[1]) > 2                                        # fresh: offered
    tracker.feed_detect(1, 0.03 + staleness + 0.005, search(1, np.zeros((0, 2))))
    assert len(seen[1]) == 0                                       # stale: not offered
    # without a birth volume there is no line
    tracker = WideAreaTracker(cams, params=EstimatorParams(volume=None))
    tracker.feed_detect(0, 0.00, search(0, cams[0].project(X)))
    tracker.feed_detect(1, 0.01, search(1, np.zeros((0, 2))))
    assert len(seen[1]) == 0


def test_partner_band_reaches_a_line_that_only_crosses_an_image_corner():
    # a line whose image in camera 1 cuts off its top-left corner (0.57 px deep), between
    # two of the 64 coarse samples along the birth volume, both outside the image
    cam1 = small_camera(ceiling_rig(rng=np.random.default_rng(7))[1])
    P = np.array([[-0.1, -0.1]])                                 # 0.4 px inside the corner
    C, r = cam1.rays(np.concatenate([P, P + np.array([[1.0, -1.0]]) / np.sqrt(2)]))
    depth = 0.3 * (1000.0 - C[0, 2]) / r[0, 2]
    X = C[0] + depth * r[0]                                     # in the birth volume
    d = (C[1] + depth * r[1]) - X
    d /= np.linalg.norm(d)                                      # its image: along (1, -1)
    cam0 = Camera.look_at(X - 8000.0 * d, X, f=400.0, width=320, height=240)
    lo, hi = np.asarray(EstimatorParams().volume)
    with np.errstate(divide="ignore"):
        a, b = (lo - cam0.C) / d, (hi - cam0.C) / d
    near, far = np.minimum(a, b).max(), np.maximum(a, b).min()
    coarse = cam1.project(cam0.C + np.linspace(near, far, 65)[:, None] * d)
    assert not cam1.in_image(coarse).any()
    tracker = WideAreaTracker([cam0, cam1])
    seen = []

    def search(pred):
        seen.append(pred.partners)
        return np.array([[cam0.cx, cam0.cy]]) if len(seen) == 1 else np.zeros((0, 2))

    tracker.feed_detect(0, 0.00, search)                        # the ray through X
    tracker.feed_detect(1, 0.01, search)
    assert len(seen[1]) >= 1 and cam1.in_image(seen[1]).all()
    assert np.linalg.norm(seen[1] - P, axis=1).max() < 1.0


def test_search_refuses_bad_input():
    thr = background_threshold(np.full((1, 20, 30), 50, np.uint8), 20.0, 60.0)
    setup = search_setup(thr)
    frame = np.zeros((20, 30), np.uint8)
    with pytest.raises(ValueError, match="frame"):
        search_frame(frame[:5], setup)
    with pytest.raises(TypeError, match="frame"):
        search_frame(frame.astype(float), setup)
    with pytest.raises(ValueError, match="jitter"):
        search_frame(frame, setup, jitter=(5, 0))
    with pytest.raises(ValueError, match="windows"):
        search_frame(frame, setup, windows=np.zeros(3))
    with pytest.raises(ValueError, match="half_sizes"):
        search_frame(frame, setup, windows=np.zeros((2, 2)), half_sizes=[3.0])
    with pytest.raises(TypeError, match="setup"):
        search_frame(frame, thr)
    with pytest.raises(ValueError, match="invalid"):
        search_setup(thr, invalid=np.zeros((3, 3), bool))
    with pytest.raises(TypeError, match="threshold"):
        search_setup(frame)


def test_streaming_tracker_refuses_bad_input(walk):
    with pytest.raises(TypeError, match="cameras"):
        WideAreaTracker([])
    with pytest.raises(TypeError, match="params"):
        WideAreaTracker(walk.cameras, params={"sigma_px": 1.0})
    with pytest.raises(ValueError, match="camera_timeout"):
        EstimatorParams(camera_timeout=0.0)
    tracker = WideAreaTracker(walk.cameras)
    assert tracker.feed(99, 0.1, np.zeros((0, 2))) == FrameStatus.REFUSED
    assert tracker.feed("a", 0.1, np.zeros((0, 2))) == FrameStatus.REFUSED
    assert tracker.feed(0, np.nan, np.zeros((0, 2))) == FrameStatus.REFUSED
    assert tracker.feed_detect(0, np.inf, lambda p: np.zeros((0, 2))) == FrameStatus.REFUSED
    r = tracker.result()
    assert r.unknown_camera == 2 and r.nonfinite_stamp == 2
    with pytest.raises(ValueError, match="camera"):
        tracker.predict_image(len(walk.cameras), 0.0)
    with pytest.raises(ValueError, match="camera"):
        tracker.remove_camera(-1)
    with pytest.raises(TypeError, match="camera"):
        tracker.add_camera("cam")
    with pytest.raises(TypeError, match="join"):
        tracker.add_camera(walk.cameras[0], join={"min_frames": 3})
    with pytest.raises(ValueError, match="t"):
        tracker.predict(np.nan)


def test_synchronised_intersection_is_exact_when_synchronised():
    rig = ceiling_rig(rng=np.random.default_rng(5))     # (a mirror-symmetric rig has exact
    # ghost intersections of mirrored LEDs)
    k = np.arange(8)
    scene = walking_person(duration=0.5, on=np.stack([0 * k, np.full(8, np.inf)], axis=1))
    K = len(rig)
    sync = Clocks(rate=np.full(K, 60.0), phase=np.zeros(K), offset=np.zeros(K),
                  latency=np.full(K, 0.005))
    obs = observe_leds(scene, rig, sync, rng=np.random.default_rng(0),
                       params=LedCentroidParams(noise_px=0.0, reflections=0.0))
    times = np.arange(5) / 60.0
    pts = intersect_instants(rig, obs.frames, times, window=1 / 60)
    truth = scene.positions_at(times)
    for t in range(len(times)):
        P = pts.at(t)
        d = np.linalg.norm(truth[t][:, None] - P[None], axis=2)
        seen = obs.visible[np.isclose(obs.true_time, times[t])].sum(axis=0) >= 2
        assert seen.sum() >= 5
        assert (d.min(axis=1)[seen] < 1e-6).all()         # every LED seen twice, exactly
        assert (pts.n_rays[pts.start[t]:pts.start[t + 1]] >= 2).all()
    # unsynchronised by 10 ms: the moving LEDs' rays no longer meet where the LEDs are
    late = Clocks(rate=np.full(K, 60.0), phase=np.random.default_rng(1).uniform(0, 0.01, K),
                  offset=np.zeros(K), latency=np.full(K, 0.005))
    obs2 = observe_leds(scene, rig, late, rng=np.random.default_rng(0),
                        params=LedCentroidParams(noise_px=0.0, reflections=0.0))
    pts2 = intersect_instants(rig, obs2.frames, times + 0.01, window=1 / 60)
    d2 = [np.linalg.norm(scene.positions_at(times + 0.01)[t][:, None] - pts2.at(t)[None],
                         axis=2).min(axis=1) for t in range(len(times))]
    assert np.nanmax(np.concatenate(d2)) > 1.0
    with pytest.raises(ValueError, match="window"):
        intersect_instants(rig, obs.frames, times, window=0.0)
    with pytest.raises(TypeError, match="frames"):
        intersect_instants(rig, obs.frames.xy, times, window=0.01)
    with pytest.raises(ValueError, match="min_rays"):
        intersect_instants(rig, obs.frames, times, window=0.01, min_rays=1)
    assert isinstance(obs.frames, Frames)


def test_a_target_that_dies_for_a_moment_rejoins_under_its_own_identity():
    rig = [small_camera(c) for c in ceiling_rig(rng=0)]
    start, v = np.array([-300.0, 100.0, 1600.0]), np.array([800.0, 0.0, 0.0])
    seen = [c for c in rig if c.in_image(c.project(np.array([start, start + 1.2 * v]))).all()]
    cams = seen[:3]
    assert len(cams) == 3
    t = np.arange(0.0, 1.2, 1 / 60)
    # from 0.4 s to 0.7 s only camera 0 sees the LED: fewer than two cameras, it dies
    gap = (t >= 0.4) & (t < 0.7)

    def run(**kw):
        tr = WideAreaTracker(cams, params=EstimatorParams(**kw))
        for f, s in enumerate(t):
            for k, cam in enumerate(cams):
                xy = cam.project((start + (s + k / 180) * v)[None])
                tr.feed(k, s + k / 180, xy if k == 0 or not gap[f] else np.zeros((0, 2)))
        return tr.result()

    apart = run()
    assert len(apart.tracks) == 2 and np.isfinite(apart.tracks[0].death_time)
    back = run(rejoin=0.4)
    assert len(back.tracks) == 1 and np.isnan(back.tracks[0].death_time)
    trk = back.tracks[0]
    assert trk.id == apart.tracks[0].id
    # not alive while dead; where the LED is before and after
    died, again = apart.tracks[0].death_time, apart.tracks[1].birth_time
    mid = 0.5 * (died + again)
    assert np.isnan(trk.positions_at([mid])).all()
    for s in (0.3, 1.0):
        assert np.linalg.norm(trk.positions_at([s])[0] - (start + s * v)) < 10.0
    # a death longer ago than rejoin, or a birth farther than rejoin_mm, starts a new target
    assert len(run(rejoin=0.4, rejoin_mm=1e-3).tracks) == 2
    assert len(run(rejoin=0.01).tracks) == 2
    with pytest.raises(ValueError, match="rejoin"):
        EstimatorParams(rejoin=-1.0)


def _reference_mask(shape, k, jitter, centres, half, grid="points"):
    """The pixels a search with windows of half-sizes ``half`` tests, in NumPy."""
    H, W = shape
    m = np.zeros((H, W), bool)
    m[jitter[0]::k, slice(jitter[1], None, k) if grid == "points" else slice(None)] = True
    for (x, y), h in zip(centres, half):
        if np.isfinite([x, y]).all():
            x, y, h = int(np.rint(x)), int(np.rint(y)), int(np.ceil(h))
            m[max(y - h, 0):max(y + h, 0), max(x - h, 0):max(x + h, 0)] = True
    return m


@pytest.mark.parametrize("grid", ["points", "rows"])
def test_guided_search_equals_the_full_search_inside_overlapping_windows(grid):
    # many windows of mixed (fractional) sizes, overlapping, cut by the image's edges, one
    # around a NaN: every spot with a tested pixel over threshold is found whole, at the
    # full search's centroid and area; no other feature; the pixels tested counted once
    # (with either grid for new LEDs: one pixel per 5 x 5 block, or one row in 5)
    from lsmta.widearea import DetectionParams, Threshold

    rng = np.random.default_rng(5)
    H, W = 240, 320
    yy, xx = np.mgrid[0:H, 0:W]
    img = np.full((H, W), 40.0)
    for x, y, sig in zip(rng.uniform(-2, W + 2, 40), rng.uniform(-2, H + 2, 40),
                         rng.uniform(0.3, 2.5, 40)):
        img += 150.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sig ** 2))
    frame = np.clip(np.rint(img + rng.normal(0, 2, (H, W))), 0, 255).astype(np.uint8)
    bg = np.full((H, W), 45.0)
    setup = search_setup(Threshold(background=bg, threshold=bg + 20.0),
                         params=DetectionParams(max_area=5000, grid=grid))
    full = search_frame(frame, setup, full=True)
    over = frame > 65
    lab, n_lab = ndimage.label(over, structure=np.ones((3, 3)))
    # an independent reference (the "full" search is the same kernel with k = 1): each
    # spot's centroid weighted by the intensity over the background (+ 1e-9), from labels
    weight = np.maximum(frame - 45.0, 0.0) + 1e-9
    idx = np.arange(1, n_lab + 1)
    total = ndimage.sum(weight, lab, idx)
    ref = np.column_stack([ndimage.sum(weight * xx, lab, idx) / total,
                           ndimage.sum(weight * yy, lab, idx) / total])
    for _ in range(5):
        centres = np.column_stack([rng.uniform(-10, W + 10, 25), rng.uniform(-10, H + 10, 25)])
        centres[3] = np.nan
        half = rng.uniform(1.0, 30.0, 25)
        jit = tuple(int(j) for j in rng.integers(0, 5, 2))
        g = search_frame(frame, setup, windows=centres, half_sizes=half, jitter=jit)
        reached = np.unique(lab[_reference_mask((H, W), 5, jit, centres, half, grid) & over])
        assert len(g.xy) == len(reached) > 5
        for label in reached:                  # each reached spot: the full search's
            ys, xs = np.nonzero(lab == label)
            i = np.argmin(np.hypot(full.xy[:, 0] - xs.mean(), full.xy[:, 1] - ys.mean()))
            j = np.argmin(np.linalg.norm(g.xy - full.xy[i], axis=1))
            np.testing.assert_allclose(g.xy[j], full.xy[i], atol=1e-9)
            np.testing.assert_allclose(g.xy[j], ref[label - 1], atol=1e-9)
            assert g.area[j] == full.area[i] == len(xs)
        empty = search_frame(np.full((H, W), 40, np.uint8), setup, windows=centres,
                             half_sizes=half, jitter=jit)
        assert empty.tested == _reference_mask((H, W), 5, jit, centres, half, grid).sum()
        assert len(empty.xy) == 0


def test_search_refuses_windows_under_a_pixel():
    thr = background_threshold(np.full((1, 20, 30), 50, np.uint8), 20.0, 60.0)
    setup = search_setup(thr)
    frame = np.zeros((20, 30), np.uint8)
    with pytest.raises(ValueError, match="half_sizes"):
        search_frame(frame, setup, windows=np.full((2, 2), 5.0), half_sizes=[3.0, 0.5])
    with pytest.raises(ValueError, match="half_sizes"):
        search_frame(frame, setup, windows=np.full((1, 2), 5.0), half_sizes=[np.nan])
    with pytest.raises(ValueError, match="half_sizes: expected finite"):
        search_frame(frame, setup, windows=np.full((1, 2), 5.0), half_sizes=[np.inf])
    # huge sizes and positions: clipped to the image, not wrapped by the integer conversion
    grid = len(range(0, 20, 5)) * len(range(0, 30, 5))
    f = search_frame(frame, setup, windows=np.full((1, 2), 5.0), half_sizes=[1e300],
                     jitter=(0, 0))
    assert f.tested == frame.size
    f = search_frame(frame, setup, windows=np.array([[1e300, -1e300]]), half_sizes=[2.0],
                     jitter=(0, 0))
    assert f.tested == grid
    # a window around a position that is not finite needs no size
    f = search_frame(frame, setup, windows=np.array([[np.nan, 1.0]]), half_sizes=[0.0],
                     jitter=(0, 0))
    assert f.tested == len(range(0, 20, 5)) * len(range(0, 30, 5))


def test_prediction_says_which_targets_a_camera_has_observed():
    cams = [small_camera(c) for c in ceiling_rig(rng=np.random.default_rng(7))[:3]]
    X = np.array([[300.0, -200.0, 1200.0]])                # an LED in the birth volume
    assert all(c.in_image(c.project(X)).all() for c in cams)
    tracker = WideAreaTracker(cams)
    seen = {}

    def search(c, found):
        def detect_(pred):
            seen[c] = pred
            return found
        return detect_

    tracker.feed_detect(0, 0.00, search(0, cams[0].project(X)))
    tracker.feed_detect(1, 0.01, search(1, cams[1].project(X)))      # born: cameras 0, 1
    tracker.feed_detect(2, 0.02, search(2, np.zeros((0, 2))))
    tracker.feed_detect(0, 0.03, search(0, cams[0].project(X)))
    assert len(seen[2].ids) == 1
    assert not seen[2].observed[0] and seen[0].observed[0]
    assert tracker.predict_image(1, 0.03).observed.tolist() == [True]
    assert tracker.predict_image(2, 0.03).observed.tolist() == [False]
    # windows: the gate plus the margin; at least unobserved_px where not observed
    xy, half = seen[2].windows(margin_px=3.0, unobserved_px=20.0)
    assert half[0] == max(seen[2].gate_px[0] + 3.0, 20.0) == 20.0
    _, half0 = seen[0].windows(margin_px=3.0, unobserved_px=20.0)
    np.testing.assert_allclose(half0, seen[0].gate_px + 3.0)
    np.testing.assert_array_equal(seen[2].windows()[1], seen[2].gate_px + 3.0)
    tracker.feed_detect(2, 0.04, search(2, cams[2].project(X)))      # now camera 2 sees it
    assert tracker.predict_image(2, 0.05).observed.tolist() == [True]
    with pytest.raises(ValueError, match="margin_px"):
        seen[0].windows(margin_px=-1.0)
    with pytest.raises(ValueError, match="unobserved_px"):
        seen[0].windows(unobserved_px=0.0)
    with pytest.raises(ValueError, match="observed"):
        replace(seen[0], observed=np.ones(2, bool)).windows(unobserved_px=20.0)


def test_observed_flags_reset_when_a_camera_is_dropped_or_removed():
    cams = [small_camera(c) for c in ceiling_rig(rng=np.random.default_rng(7))[:3]]
    X = np.array([[300.0, -200.0, 1200.0]])
    tracker = WideAreaTracker(cams, params=EstimatorParams(camera_timeout=0.1))
    t = 0.0
    for _ in range(3):                                       # all three cameras see it
        for c in range(3):
            tracker.feed(c, t, cams[c].project(X))
            t += 0.01
    assert tracker.predict_image(2, t).observed.tolist() == [True]
    while t < 0.3:                                           # camera 2 falls silent
        for c in range(2):
            tracker.feed(c, t, cams[c].project(X))
            t += 0.01
    res = tracker.result()
    assert res.camera_status[2] == CameraStatus.SILENT and len(res.tracks) == 1
    assert tracker.predict_image(2, t).observed.tolist() == [False]
    assert tracker.predict_image(0, t).observed.tolist() == [True]
    tracker.remove_camera(0)
    assert tracker.predict_image(0, t).observed.tolist() == [False]
    assert tracker.predict_image(1, t).observed.tolist() == [True]


def test_row_grid_finds_a_new_spot_the_point_grid_skips_on_its_first_frame():
    # a new LED (no window) one column wide and 5 rows tall at column 203, and a one-pixel
    # LED at (402, 100): with every one of the 25 jitters the row grid (every pixel of one
    # row in 5) finds the tall one on its first frame, at the full search's centroid and
    # area, and the small one whenever its row is a grid row; the thesis's 5 x 5 point grid
    # skips the tall one unless its column is a grid column, and the small one on grid rows
    # off grid columns
    from lsmta.widearea import DetectionParams, Threshold, search_mask

    H, W = 120, 480
    frame = np.full((H, W), 40, np.uint8)
    frame[40:45, 203] = [120, 180, 200, 170, 110]
    frame[100, 402] = 150
    bg = np.full((H, W), 40.0)
    thr = Threshold(background=bg, threshold=bg + 20.0)
    rows = search_setup(thr, params=DetectionParams(grid="rows"))
    points = search_setup(thr, params=DetectionParams(grid="points"))
    full = search_frame(frame, rows, full=True)
    tall = np.argmin(np.abs(full.xy[:, 0] - 203.0))
    assert len(full.xy) == 2 and full.area[tall] == 5
    for jr in range(5):
        for jc in range(5):
            r = search_frame(frame, rows, jitter=(jr, jc))
            p = search_frame(frame, points, jitter=(jr, jc))
            on_row = 100 % 5 == jr
            assert len(r.xy) == 1 + on_row
            np.testing.assert_allclose(r.xy[0], full.xy[tall], atol=1e-9)
            assert r.area[0] == 5
            assert len(p.xy) == (203 % 5 == jc) + (on_row and 402 % 5 == jc)
            mask = search_mask((H, W), 5, (jr, jc), grid="rows")
            assert mask.sum() == len(range(jr, H, 5)) * W
            spots = np.zeros((H, W), bool)       # the found spots' pixels and neighbours,
            spots[40:45, 203] = True              # which the flood fills visit
            spots[100, 402] = on_row
            visited = ndimage.binary_dilation(spots, structure=np.ones((3, 3)))
            assert r.tested == (mask | visited).sum()
    with pytest.raises(ValueError, match="grid"):
        DetectionParams(grid="row")
    with pytest.raises(ValueError, match="grid"):
        search_mask((H, W), 5, (0, 0), grid="lines")


def test_subsampled_detect_with_the_row_grid_finds_every_tall_spot():
    # the batch search (detect, mode="subsampled") with the row grid: a spot at least 5 rows
    # tall is found in every frame, whatever the jitter, also in column 1 (the row grid
    # tests every column of its rows, whatever column offset was drawn), and the pixels
    # tested are the grid rows whole plus the fills' rim; the point grid misses some
    from lsmta.widearea import DetectionParams, Threshold, search_mask

    T, H, W = 12, 60, 80
    frames = np.full((T, H, W), 40, np.uint8)
    frames[:, 20:26, 33] = 200
    frames[:, 40:46, 1] = 200
    bg = np.full((H, W), 40.0)
    thr = Threshold(background=bg, threshold=bg + 20.0)
    before = frames.copy()
    rows = detect(frames, thr, mode="subsampled", rng=0, params=DetectionParams(grid="rows"))
    points = detect(frames, thr, mode="subsampled", rng=0)
    np.testing.assert_array_equal(frames, before)
    assert np.all(np.diff(rows.start) == 2)
    np.testing.assert_allclose(rows.xy, np.tile([[33.0, 22.5], [1.0, 42.5]], (T, 1)),
                               atol=1e-9)
    assert np.diff(points.start).sum() < 2 * T
    visited = ndimage.binary_dilation(frames[0] > 60, structure=np.ones((3, 3)))
    expected = {int((search_mask((H, W), 5, (jr, 0), grid="rows") | visited).sum())
                for jr in range(5)}               # whichever row offset a frame drew
    assert set(rows.tested.tolist()) <= expected


def test_one_opencv_thread_restores_the_count_after_an_error():
    import cv2

    from lsmta.evaluation.widearea_images import one_opencv_thread
    before = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        with pytest.raises(RuntimeError, match="inside"):
            with one_opencv_thread():
                assert cv2.getNumThreads() == 1
                raise RuntimeError("inside")
        assert cv2.getNumThreads() == 2
    finally:
        cv2.setNumThreads(before)


def _band_found(angle, off, half, spacing=15.0):
    """Spots ``off`` px either side of a line of band points ``spacing`` apart at ``angle``
    deg, halfway between two points (the worst place): (spots, found by the full search,
    found by windows of half-size ``half`` around the points)."""
    from lsmta.widearea import DetectionParams, Threshold

    H = W = 200
    bg = np.full((H, W), 40.0)
    setup = search_setup(Threshold(background=bg, threshold=bg + 20.0),
                         params=DetectionParams(grid="rows", k=1000))
    yy, xx = np.mgrid[0:H, 0:W]
    u = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    n = np.array([-u[1], u[0]])
    origin = np.array([100.0, 100.0]) - 4 * spacing * u
    points = origin + spacing * np.arange(9)[:, None] * u        # the band's centres
    mid = origin + spacing * (np.arange(8)[:, None] + 0.5) * u
    spots = np.concatenate([mid + off * n, mid - off * n])
    img = np.full((H, W), 40.0)
    for x, y in spots:
        img += 150.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.6 ** 2))
    frame = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    full = search_frame(frame, setup, full=True)
    g = search_frame(frame, setup, windows=points, half_sizes=np.full(len(points), half),
                     jitter=(0, 0))                               # grid: row 0 only
    return spots, full.xy, g.xy


def _same_place(a, b) -> bool:
    return len(a) == len(b) and np.linalg.norm(a[:, None] - b[None], axis=2).min(0).max() < 1e-9


def test_band_windows_of_the_rule_find_every_spot_near_the_line():
    # the lean rule's band, gate_px / 2 + 3 = 10.5 for points 15 px apart along a line (as
    # ImagePrediction.partners samples the other cameras' rays): windows of that half-size
    # around the points find every spot whose centre is 6 px off the line, halfway between
    # two points (the worst place), whatever the line's direction, as the full search does;
    # windows of half-size 5 find none of them (the check can fail)
    narrow_found = 0
    for angle in (0.0, 30.0, 45.0, 60.0, 90.0, 135.0):
        spots, full, rule = _band_found(angle, 6.0, 15.0 / 2 + 3)
        assert len(full) == len(spots)
        assert _same_place(rule, full)
        narrow_found += len(_band_found(angle, 6.0, 5.0)[2])
    assert narrow_found == 0


def test_band_windows_of_the_rule_reach_7_px_at_45_degrees():
    # the stated reach at the worst direction, sqrt(2) * 10.5 - 7.5 = 7.3 px: spots whose
    # centres are 7 px off a 45-degree line, halfway between two points, all found
    spots, full, rule = _band_found(45.0, 7.0, 15.0 / 2 + 3)
    assert len(full) == len(spots)
    assert _same_place(rule, full)


def test_guided_search_windows_use_the_band():
    # the trial's windows: band_px sets the windows along the waiting rays (None: the gate),
    # in the guided search and in its fixed 40 x 40 comparison alike
    from lsmta.evaluation.widearea_images import guided_search_windows
    from lsmta.widearea import ImagePrediction

    pred = ImagePrediction(camera=0, time=0.0, ids=np.array([1, 2]),
                           xy=np.array([[50.0, 60.0], [90.0, 30.0]]),
                           velocity=np.zeros((2, 2)), gate_px=np.array([4.0, 6.0]),
                           waiting=np.array([[10.0, 10.0]]),
                           partners=np.array([[100.0, 100.0], [110.0, 110.0], [120.0, 120.0]]),
                           observed=np.array([True, False]))
    for band, expect in ((None, 15.0), (10.5, 10.5)):
        xy, half, fixed = guided_search_windows(pred, window=40, gate_px=15.0, band_px=band,
                                                unobserved_px=20.0)
        assert np.array_equal(xy, np.concatenate([pred.xy, pred.waiting, pred.partners]))
        assert np.array_equal(half, [7.0, 20.0, 20.0, expect, expect, expect])
        assert np.array_equal(fixed, [20.0, 20.0, 20.0, expect, expect, expect])
    _, half, _ = guided_search_windows(pred, window=40, gate_px=15.0, band_px=10.5,
                                       unobserved_px=None)
    assert np.array_equal(half[:2], [7.0, 9.0])


def test_guided_search_refuses_a_bad_band():
    from lsmta.evaluation.widearea_images import guided_detection_trial, guided_search_windows
    from lsmta.widearea import ImagePrediction

    pred = ImagePrediction(camera=0, time=0.0, ids=np.zeros(0, int), xy=np.zeros((0, 2)),
                           velocity=np.zeros((0, 2)), gate_px=np.zeros(0))
    assert len(guided_search_windows(pred, window=40, gate_px=15.0, band_px=10)[0]) == 0
    for bad, error in ((0.0, ValueError), (-3.0, ValueError), (np.nan, ValueError),
                       (np.inf, ValueError), (True, TypeError), (np.bool_(True), TypeError),
                       ("wide", TypeError)):
        with pytest.raises(error, match="band_px"):
            guided_search_windows(pred, window=40, gate_px=15.0, band_px=bad)
        with pytest.raises(error, match="band_px"):          # before any rendering
            guided_detection_trial(rng=0, band_px=bad)
    with pytest.raises(TypeError, match="unobserved_px"):
        guided_detection_trial(rng=0, unobserved_px=np.bool_(False))
