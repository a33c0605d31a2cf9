"""Small-scale marker tracking in rendered video (Davis 2002, section 5.1)."""

import numpy as np
import pytest

from lsmta.evaluation import face as ef
from lsmta.synth import face as sf
from lsmta.synth import marker_video as mv
from lsmta.tracking import markers as tm


def _dots(shape, xy, background, sigma=1.3, amp=110.0):
    H, W = shape
    gx, gy = np.meshgrid(np.arange(W), np.arange(H))
    img = background.astype(float).copy()
    for x, y in xy:
        img += amp * np.exp(-((gx - x) ** 2 + (gy - y) ** 2) / (2 * sigma ** 2))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _clip(seq, n):
    """The first ``n`` frames (head motion at the speed of a 150-frame sequence)."""
    return sf.FaceSequence(*(getattr(seq, k)[:n] for k in
                             ("head", "world", "normals", "weights", "R", "t")))


@pytest.fixture(scope="module")
def capture():
    rng = np.random.default_rng(11)
    seq = _clip(sf.face_sequence(sf.face_model(), 150, rng=rng), 30)
    return ef.observe_tracked(seq, rng=np.random.default_rng(12), cameras=[1, 2])


def test_tracking_error_against_truth(capture):
    e = np.linalg.norm(capture.tracked_xy - capture.truth_xy, axis=3)
    sep = e[~capture.crowded]
    assert np.isfinite(sep).sum() > 0.5 * np.isfinite(capture.truth_xy[..., 0]).sum()
    assert np.nanmedian(sep) < 0.3
    assert np.nanpercentile(sep, 90) < 1.0
    assert np.isfinite(capture.observation.points[1:]).all(axis=2).sum(axis=1).min() > 20


def test_stabilisation_recovers_camera_shift():
    rng = np.random.default_rng(3)
    tex = mv.skin_texture((400, 480), rng=rng, contrast=15)
    shifts = np.array([[0.0, 0.0], [6.0, -3.0], [-5.0, 8.0], [9.0, 2.0]])
    pos = np.cumsum(shifts, axis=0)
    base = np.array([[120.0, 100.0], [160.0, 130.0], [200.0, 90.0]])
    frames = []
    for p in pos:
        ox, oy = 80 - int(round(p[0])), 80 - int(round(p[1]))
        bg = tex[oy:oy + 240, ox:ox + 320]
        frames.append(_dots((240, 320), base + np.round(p), bg))
    frames = np.stack(frames)
    before = frames.copy()
    tr = tm.track_markers(frames, base)
    assert np.abs(tr.shift[1:] - shifts[1:]).max() < 0.1
    assert np.abs(tr.xy - (base + np.round(pos)[:, None])).max() < 0.3
    assert np.array_equal(frames, before)
    # the shifts of that run given back: the same result without measuring them again;
    # wrong shifts are used as given (the searches start off and fail)
    again = tm.track_markers(frames, base, shifts=tr.shift)
    assert np.array_equal(again.xy, tr.xy, equal_nan=True) and np.array_equal(again.shift, tr.shift)
    off = tm.track_markers(frames, base, shifts=np.where(np.isfinite(tr.shift), -tr.shift, np.nan))
    assert not np.array_equal(off.status, tr.status)
    with pytest.raises(ValueError, match="shifts: expected an array of shape"):
        tm.track_markers(frames, base, shifts=np.zeros((2, 2)))
    # the sharpness of that run given back: the same result; other numbers are used as given
    # (a frame called much less sharp than the others is skipped as blurred)
    same = tm.track_markers(frames, base, shifts=tr.shift, sharpness=tr.sharpness)
    assert np.array_equal(same.xy, tr.xy, equal_nan=True)
    assert np.array_equal(same.sharpness, tr.sharpness) and not same.blurred.any()
    dull = tm.track_markers(frames, base, sharpness=tr.sharpness * [1, 1, 0.01, 1])
    assert dull.blurred[2] and not np.array_equal(dull.status, tr.status)
    with pytest.raises(ValueError, match="sharpness: expected an array of shape"):
        tm.track_markers(frames, base, sharpness=np.ones(3))
    with pytest.raises(ValueError, match="sharpness: expected non-negative"):
        tm.track_markers(frames, base, sharpness=-tr.sharpness)


def test_blurred_frame_detected_and_tracks_survive():
    rng = np.random.default_rng(5)
    seq = _clip(sf.face_sequence(sf.face_model(), 150, rng=rng), 20)
    cap = ef.observe_tracked(seq, rng=np.random.default_rng(6), cameras=[1, 2],
                             blur_frames=[10])
    st = cap.status[0]
    assert (st[10] == tm.MarkerStatus.BLURRED).all()
    assert (st[[f for f in range(1, 20) if f != 10]] != tm.MarkerStatus.BLURRED).all()
    tracked = np.isin(st, (tm.MarkerStatus.TRACKED, tm.MarkerStatus.SECOND_SEARCH)).sum(axis=1)
    assert tracked[11] >= tracked[9] - 3
    e = np.linalg.norm(cap.tracked_xy[0, 11] - cap.truth_xy[0, 11], axis=1)
    assert np.nanmedian(e[~cap.crowded[0, 11]]) < 0.3
    # without the retry the blurred frame is tracked and markers are lost in it
    video = mv.render_marker_video(
        [sf.face_cameras(seq.t[f])[1] for f in range(20)], seq.world,
        np.ones((20, seq.world.shape[1]), bool), seq.t, rng=np.random.default_rng(7),
        blur_frames=[10], blur_length=15)
    start = video.xy[0]
    a = tm.track_markers(video.images, start)
    b = tm.track_markers(video.images, start, params=tm.MarkerTrackingParams(blur_retry=0))
    assert a.blurred[10] and not b.blurred.any()
    assert np.isfinite(a.xy[-1]).all(axis=1).sum() > np.isfinite(b.xy[-1]).all(axis=1).sum()


def test_second_search_rescues_fast_marker():
    rng = np.random.default_rng(8)
    bg = mv.skin_texture((120, 400), rng=rng, contrast=3)
    steps = np.arange(1, 13) * 2.5                   # accelerating: 2.5 .. 30 px/frame
    x = 20 + np.concatenate([[0.0], np.cumsum(steps)])
    truth = np.stack([x, np.full_like(x, 60.0)], axis=1)
    frames = np.stack([_dots(bg.shape, [p], bg) for p in truth])
    both_p = tm.MarkerTrackingParams(window=7, levels=1, stabilise=False)
    plain_p = tm.MarkerTrackingParams(window=7, levels=1, stabilise=False, second_search=False)
    plain = tm.track_markers(frames, truth[:1], params=plain_p)
    both = tm.track_markers(frames, truth[:1], params=both_p)
    assert (plain.status[:, 0] == tm.MarkerStatus.LOST).any()
    assert (both.status[:, 0] == tm.MarkerStatus.SECOND_SEARCH).any()
    assert not (both.status[:, 0] == tm.MarkerStatus.LOST).any()
    assert np.abs(both.xy[:, 0] - truth).max() < 0.3


def test_bad_input():
    img = np.zeros((3, 40, 40), np.uint8)
    with pytest.raises(ValueError, match="images"):
        tm.track_markers(img[0], [[10.0, 10.0]])
    with pytest.raises(TypeError, match="images"):
        tm.track_markers(np.full((2, 20, 20), "a"), [[10.0, 10.0]])
    with pytest.raises(ValueError, match="initial_xy"):
        tm.track_markers(img, [10.0, 10.0])
    with pytest.raises(ValueError, match="initial_xy"):
        tm.track_markers(img, [[np.inf, 10.0]])
    with pytest.raises(ValueError, match="window"):
        tm.MarkerTrackingParams(window=8)
    with pytest.raises(ValueError, match="seeds"):
        tm.track_markers(img, [[10.0, 10.0]], seeds=np.zeros((2, 1, 2)))
    with pytest.raises(ValueError, match="visible"):
        cam = sf.face_cameras([0.0, 0.0, 1650.0])[0]
        mv.render_marker_video([cam], np.zeros((1, 2, 3)), np.ones((1, 3), bool),
                               np.zeros((1, 3)), rng=np.random.default_rng(0))
    start = np.array([[10.0, 10.0]])
    tm.track_markers(img, start)
    assert start.tolist() == [[10.0, 10.0]]


def test_merged_blobs_split_into_their_dots():
    rng = np.random.default_rng(3)
    bg = np.full((80, 120), 80.0) + rng.normal(0, 2.0, (80, 120))
    single, pair = (20.3, 20.6), [(60.0, 40.2), (63.6, 41.5)]      # pair 3.8 px apart
    crowd = [(95.0, 20.0), (98.0, 20.5), (96.2, 23.4)]                # three dots touching
    img = _dots(bg.shape, [single, *pair, *crowd], bg)
    blobs = tm.find_blobs(img.astype(float), sigma=1.5, spacing=5)
    before = blobs.copy()
    r = tm.split_merged_blobs(img, blobs, radius=3)
    assert np.array_equal(blobs, before)                # the caller's array untouched

    def near(p):
        return np.linalg.norm(r.xy - p, axis=1)

    # the single dot: one dot, round (spread well below the 2.5 px that splits)
    i = int(np.argmin(near(single)))
    assert near(single)[i] < 0.3 and r.spread[i] < 1.0 and not r.split[i]
    # the pair: one blob, found as one or two at its centroid, now two dots on the pair
    assert np.linalg.norm(blobs - pair[0], axis=1).min() > 1.0
    for p in pair:
        j = int(np.argmin(near(p)))
        assert near(p)[j] < 0.5 and r.split[j] and abs(r.spread[j] - 3.8) < 0.8
    # the crowd of three is not split into halves between its dots
    in_crowd = np.linalg.norm(r.xy - np.mean(crowd, axis=0), axis=1) < 5
    assert in_crowd.any() and not r.split[in_crowd].any()
    assert len(r.xy) == len(r.spread) == len(r.brightness) == len(r.split)
    # the halves of a split blob share its brightness: each carries half
    halves = np.flatnonzero(r.split)
    assert np.isfinite(r.brightness[halves]).all()
    assert r.brightness[halves].sum() < 1.5 * r.brightness[i]
    # a blob found twice is kept once
    twice = tm.split_merged_blobs(img, np.r_[blobs[:1], blobs[:1] + 0.3], radius=3)
    assert len(twice.xy) == 1
    empty = tm.split_merged_blobs(img, np.zeros((0, 2)))
    assert empty.xy.shape == (0, 2) and empty.spread.shape == (0,)
    with pytest.raises(ValueError, match="xy: expected an array of shape"):
        tm.split_merged_blobs(img, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="image: expected an \\(H, W\\) grey image"):
        tm.split_merged_blobs(img[None], blobs)
    with pytest.raises(ValueError, match="min_separation"):
        tm.split_merged_blobs(img, blobs, min_separation=0.0)


def test_one_elongated_dot_is_not_split():
    # a single dot stretched (sigma 2.2 x 1.0 px) or motion-blurred (sigma 1.3 px, 6 px of
    # motion) spreads like two dots 2.7 px apart, but its profile has one maximum: one dot.
    # Two dots 3.8 px apart in the same image are still split
    rng = np.random.default_rng(5)
    H, W = 60, 150
    gx, gy = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    img = np.full((H, W), 80.0) + rng.normal(0, 2.0, (H, W))
    c, s = np.cos(0.5), np.sin(0.5)
    u, v = (gx - 30.2) * c + (gy - 29.7) * s, -(gx - 30.2) * s + (gy - 29.7) * c
    img += 120.0 * np.exp(-u**2 / (2 * 2.2**2) - v**2 / (2 * 1.0**2))
    blur = sum(np.exp(-((gx - 75.4 - a * np.cos(0.3)) ** 2 + (gy - 30.1 - a * np.sin(0.3)) ** 2)
                      / (2 * 1.3**2)) for a in np.linspace(-3.0, 3.0, 25))
    img += 120.0 * blur / blur.max()
    pair = [(118.0, 30.2), (121.6, 31.5)]                          # 3.8 px apart
    img = _dots((H, W), pair, img)
    blobs = tm.find_blobs(img.astype(float), sigma=1.5, spacing=5)
    r = tm.split_merged_blobs(img, blobs, radius=3)
    for p in ((30.2, 29.7), (75.4, 30.1)):
        near = np.linalg.norm(r.xy - p, axis=1)
        assert (near < 5).sum() == 1 and near.min() < 0.5
        assert r.spread[near.argmin()] >= 2.5 and not r.split[near.argmin()]  # spread, one max
    for p in pair:
        near = np.linalg.norm(r.xy - p, axis=1)
        assert near.min() < 0.5 and r.split[near.argmin()]
    # not measured (window outside the image): NaN, not a round 0
    edge = tm.split_merged_blobs(img, np.array([[1.0, 1.0]]), radius=3)
    assert np.isnan(edge.spread).all() and np.isnan(edge.brightness).all()
    with pytest.raises(ValueError, match="radius"):
        tm.split_merged_blobs(img, blobs, radius=3.5)
    assert len(tm.split_merged_blobs(img, blobs, radius=3.0, iterations=2.0).xy) == len(r.xy)
    with pytest.raises(ValueError, match="max_dip"):
        tm.split_merged_blobs(img, blobs, max_dip=1.5)


def test_low_contrast_streak_stays_one_dot():
    # a dim streak (sigma 1.3 px, 10 px long, 25-40 grey levels over noise of 4) has a flat
    # top whose noise alone makes two maxima with a shallow dip: the dip must be deeper
    # than three times the profile's noise, so it stays one dot. Two dots 3.8 px apart,
    # as dim and as noisy, are still split
    rng = np.random.default_rng(7)
    gx, gy = np.meshgrid(np.arange(40, dtype=float), np.arange(40, dtype=float))

    def draw(centres, amp):
        g = sum(np.exp(-((gx - x) ** 2 + (gy - y) ** 2) / (2 * 1.3 ** 2)) for x, y in centres)
        return 80.0 + amp * g / g.max() + rng.normal(0, 4.0, gx.shape)

    one, two = 0, 0
    for _ in range(60):
        c, a = 20 + rng.uniform(-0.5, 0.5, 2), rng.uniform(0, np.pi)
        d = np.array([np.cos(a), np.sin(a)])
        img = draw(c + np.linspace(-5, 5, 41)[:, None] * d, rng.uniform(25, 40))
        one += not tm.split_merged_blobs(img, c[None], radius=3).split.any()
        img = draw(c + np.array([[-1.9], [1.9]]) * d, rng.uniform(60, 80))
        two += tm.split_merged_blobs(img, c[None], radius=3).split.all()
    assert one >= 58 and two >= 58
