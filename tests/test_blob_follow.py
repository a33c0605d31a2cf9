"""Markers followed on their blobs (lsmta.tracking.blob_follow) and the marker stage's use of
it with either 2-D tracker (lsmta.systems.markers)."""

import cv2
import numpy as np
import pytest
from scipy import ndimage

from lsmta.real.own_recording import marker_scores
from lsmta.systems import MarkerParams, Tracker2D, capture_markers
from lsmta.systems.markers import track_view
from lsmta.tracking.blob_follow import (
    FollowParams,
    FollowStatus,
    dot_centre,
    dot_contrast,
    dot_surround,
    follow_blobs,
)
from lsmta.tracking.klt import track_klt
from tests.test_view_tracks import _dot_video, _rig


def _marker_clip(T=40, texture=8.0, seed=0, hide=None):
    """Two bright dots (sigma 1.6 px) moving over a fixed smooth texture (skin and cloth
    under a moving marker; the dots stay over 15 px apart), JPEG-compressed; ``hide`` =
    (first, last) frames in which the second dot is covered. Returns the frames and the
    dots' true positions (T, 2, 2)."""
    rng = np.random.default_rng(seed)
    H, W = 96, 128
    bg = cv2.GaussianBlur(rng.uniform(0, 255, (H, W)).astype(np.float32), (0, 0), 2.0)
    bg = (bg - bg.mean()) / bg.std() * texture + 100
    yy, xx = np.mgrid[:H, :W]
    t = np.arange(T)
    truth = np.stack([np.stack([30 + 1.6 * t, 40 + 0.8 * t], 1),
                      np.stack([90 - 1.2 * t, 20 + 0.3 * t], 1)], axis=1)
    frames = []
    for k in range(T):
        im = bg.copy()
        for i, (x, y) in enumerate(truth[k]):
            if hide is not None and i == 1 and hide[0] <= k <= hide[1]:
                continue
            im += 110 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.6 ** 2))
        im = np.clip(im + rng.normal(0, 2, im.shape), 0, 255).astype(np.uint8)
        _, buf = cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, 70])
        frames.append(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
    return np.array(frames), truth


def _klt_step(frames):
    def step(t, xy, predicted):
        return track_klt([frames[t:t + 2]], xy[None]).xy[1, 0]
    return step


@pytest.mark.parametrize("tracker", [Tracker2D.LSMTA, Tracker2D.KLT])
def test_following_keeps_the_track_on_the_dot(tracker):
    frames, truth = _marker_clip()
    followed = track_view(frames, truth[0], params=MarkerParams(tracker=tracker, sigma=1.2))
    err = np.linalg.norm(followed - truth, axis=2)
    assert np.isfinite(err).all() and err.max() < 2.0 and np.median(err) < 0.5


def test_plain_klt_drifts_where_following_does_not():
    frames, truth = _marker_clip()
    plain = track_view(frames, truth[0], params=MarkerParams(tracker=Tracker2D.KLT,
                                                             follow=None))
    err = np.linalg.norm(plain - truth, axis=2)
    # the template tracker loses a dot or ends pixels off it over the texture
    assert (~np.isfinite(err)).any() or np.nanmax(err) > 3.0


def test_a_covered_marker_is_reacquired_near_its_prediction():
    frames, truth = _marker_clip(hide=(15, 18))
    fp = FollowParams(sigma=1.2)
    r = follow_blobs(frames, truth[0], _klt_step(frames), params=fp)
    assert np.all(r.status[15:19, 1] == FollowStatus.LOST)
    back = np.flatnonzero(r.status[19:, 1] == FollowStatus.REACQUIRED)
    assert back.size and np.isfinite(r.xy[19 + back[0]:, 1]).all()
    err = np.linalg.norm(r.xy[19:, 1] - truth[19:, 1], axis=1)
    assert err.max() < 2.0
    never = follow_blobs(frames, truth[0], _klt_step(frames),
                         params=FollowParams(sigma=1.2, reacquire_px=0.0))
    assert not np.isfinite(never.xy[19:, 1]).any()       # without it, lost for good


def test_a_step_onto_plain_skin_is_lost_and_two_on_one_dot_keep_one():
    frames, truth = _marker_clip()

    def away(t, xy, predicted):                          # a tracker that jumps off the dot
        return xy + 20.0

    r = follow_blobs(frames, truth[0], away, params=FollowParams(reacquire_px=0.0))
    assert not np.isfinite(r.xy[1:]).any()

    def both_on_first(t, xy, predicted):
        return xy[:1] + np.array([[0.3, 0.0], [2.0, 0.0]])[:len(xy)]

    r = follow_blobs(frames, truth[0], both_on_first, params=FollowParams(reacquire_px=0.0))
    assert np.isfinite(r.xy[1, 0]).all() and not np.isfinite(r.xy[1, 1]).any()
    c = dot_contrast(frames[0], truth[0])
    assert np.all(c > 60) and np.isnan(dot_contrast(frames[0], [[0.0, 0.0]])).all()


def test_bad_input():
    frames, truth = _marker_clip(T=3)
    with pytest.raises(ValueError, match="radius"):
        FollowParams(radius=0)
    with pytest.raises(ValueError, match="reacquire_px"):
        FollowParams(reacquire_px=-1.0)
    with pytest.raises(ValueError, match="max_gap"):
        FollowParams(max_gap=-2)
    with pytest.raises(ValueError, match="min_contrast"):
        FollowParams(min_contrast=0.0)
    with pytest.raises(ValueError, match="keep_contrast"):
        FollowParams(keep_contrast=1.0)
    with pytest.raises(TypeError, match="step"):
        follow_blobs(frames, truth[0], None)
    with pytest.raises(TypeError, match="params"):
        follow_blobs(frames, truth[0], lambda t, xy, p: xy, params={"radius": 3})
    with pytest.raises(ValueError, match="frames"):
        follow_blobs(frames[0], truth[0], lambda t, xy, p: xy)
    with pytest.raises(ValueError, match="start_xy"):
        follow_blobs(frames, truth[0, 0], lambda t, xy, p: xy)
    with pytest.raises(TypeError, match="follow"):
        MarkerParams(follow={"radius": 3})
    before = frames.copy()
    follow_blobs(frames, truth[0], lambda t, xy, p: xy)
    assert np.array_equal(frames, before)


def test_the_same_markers_tracked_again_and_their_pair_scored():
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(6)[:, None, None]
    base = np.array([[-250.0, 0, -150], [0, 120, -150], [250, -80, -150], [-250, 60, 150]])
    X = base[None] + np.array([25.0, 0, 15.0]) * np.sin(0.3 * t)       # one rigid body
    stacks = _dot_video(cams, X)
    first = [s[0] for s in stacks]
    params = MarkerParams(detector="blobs", max_px=1.0, min_motion_mm=5.0)
    a = capture_markers(stacks, cams, first, params=params)
    b = capture_markers(stacks, cams, first, like=a,
                        params=MarkerParams(detector="blobs", tracker=Tracker2D.KLT))
    assert np.array_equal(a.members, b.members) and np.array_equal(a.moving, b.moving)
    assert all(np.array_equal(x, y) for x, y in zip(a.detections, b.detections))
    s = marker_scores(b, pair=(0, 1))
    assert s["pair"] == (0, 1) and s["pair_frames"] == 6 and s["pair_std_mm"] < 5.0
    with pytest.raises(ValueError, match="pair"):
        marker_scores(b, pair=(0, 99))
    # other positions of the same markers (e.g. the filtered ones): their pair's spread
    moved = b.xyz.copy()
    moved[:, 0, 0] += [0.0, 4.0, 0.0, 4.0, 0.0, 4.0]                 # marker 0 jitters 4 mm
    d = np.linalg.norm(moved[:, 0] - moved[:, 1], axis=1)
    o = marker_scores(b, pair=(0, 1), xyz=moved)
    assert o["pair_std_mm"] == pytest.approx(np.std(d)) and o["pair_std_mm"] > s["pair_std_mm"]
    assert o["residual_px"] == s["residual_px"] and o["share_min"] == s["share_min"]
    assert marker_scores(b, pair=(0, 1), xyz=b.xyz) == s
    assert not np.array_equal(moved, b.xyz)                          # b.xyz not modified
    with pytest.raises(ValueError, match="xyz"):
        marker_scores(b, xyz=moved[:, :2])
    with pytest.raises(ValueError, match="like"):
        capture_markers(stacks, cams, first, params=params, like="a")


def _scene(kind):
    """60 x 80 grey frame of one shape at x = 40.3 (y = 30.6 for the dot)."""
    yy, xx = np.mgrid[:60, :80]
    if kind == "dot":                                    # sigma 2.5 px, 180 above 40
        return 40 + 180 * np.exp(-((xx - 40.3) ** 2 + (yy - 30.6) ** 2) / (2 * 2.5 ** 2))
    if kind == "edge":                                   # blurred step, 40 | 200
        return ndimage.gaussian_filter(np.where(xx >= 40, 200.0, 40.0), 1.5)
    if kind == "line":                                   # a bright fold, 3 px wide
        return 40 + 180 * np.exp(-((xx - 40.3) ** 2) / (2 * 1.2 ** 2))
    return np.full((60, 80), 200.0)                      # flat bright skin


def test_dot_surround_takes_a_dot_and_not_an_edge_a_fold_or_flat_skin():
    dot = _scene("dot")
    q = dot_centre(dot, [[40.0, 30.0]], radius=4)
    assert dot_surround(dot, q, radius=4)[0] > 100       # its contrast, about 135
    for kind in ("edge", "line", "flat"):
        img = _scene(kind)
        given = img.copy()
        # anywhere across it, 3 px either side of the edge or fold
        xy = np.stack([np.linspace(37.0, 43.0, 13), np.full(13, 30.0)], axis=1)
        assert np.all(dot_surround(img, xy, radius=4) <= 1.0), kind
        assert np.array_equal(img, given)
    # the fold passes the peak-over-median test the fill used alone
    fold = _scene("line")
    assert dot_contrast(fold, dot_centre(fold, [[40.0, 30.0]], radius=4), radius=4)[0] > 100
    # no surround inside the frame, or no position: NaN
    assert np.isnan(dot_surround(dot, [[3.0, 30.0], [np.nan, 30.0]], radius=4)).all()
    assert dot_surround(dot, np.zeros((0, 2))).shape == (0,)


def test_dot_surround_refuses_bad_input():
    img = _scene("dot")
    with pytest.raises(ValueError, match="xy"):
        dot_surround(img, [[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="image"):
        dot_surround(np.zeros((2, 60, 80)), [[40.0, 30.0]])
    with pytest.raises(ValueError, match="radius"):
        dot_surround(img, [[40.0, 30.0]], radius=0)
    with pytest.raises(ValueError, match="rays"):
        dot_surround(img, [[40.0, 30.0]], rays=3)
    with pytest.raises(TypeError, match="xy"):
        dot_surround(img, [["a", "b"]])


def test_a_real_dot_beside_a_bright_stripe_is_refused():
    """The documented limit of dot_surround: anything as bright as the dot within its
    surround's ring (here a stripe 5-6 px from a dot's centre) brings the score below the
    marker stage's floor (15); 8 px away the dot scores most of its contrast again."""
    yy, xx = np.mgrid[:60, :80]
    dot = 40 + 100 * np.exp(-((xx - 40.3) ** 2 + (yy - 30.6) ** 2) / (2 * 1.5 ** 2))
    q = dot_centre(dot, [[40.0, 30.0]], radius=4)
    alone = dot_surround(dot, q, radius=4)[0]
    assert alone > 60
    for gap, refused in ((5.0, True), (6.0, True), (8.0, False)):
        img = dot + 100 * np.exp(-((xx - 40.3 - gap) ** 2) / (2 * 1.2 ** 2))
        assert dot_contrast(img, q, radius=4)[0] > 15       # the peak test still passes
        assert (dot_surround(img, q, radius=4)[0] < 15) == refused, gap


@pytest.mark.parametrize("rays", [5, 6, 16])
def test_dot_surround_core_is_centred_whatever_rays(rays):
    """On a plane of grey levels (bilinear exact there) the core's mean is the level at the
    position, so the score is minus the steepest direction's rise to the ring's mean
    distance, 1.25 radius (a core leaning towards some directions would move it)."""
    yy, xx = np.mgrid[:60, :80]
    img = 100 + 2.0 * yy + 0.5 * xx
    ang = 2 * np.pi * np.arange(rays) / rays
    rise = 1.25 * 4 * np.max(0.5 * np.cos(ang) + 2.0 * np.sin(ang))
    got = dot_surround(img, [[40.2, 30.7]], radius=4, rays=rays)[0]
    assert got == pytest.approx(-rise, abs=1e-9)
