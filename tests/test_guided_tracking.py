"""Guided tracking (Davis 2002, Fig. 56): tracking state, enlarged view, a marker placed by
hand and tracked on from there, and the widget driven headless."""

from dataclasses import replace

import matplotlib
import numba
import numpy as np
import pytest
from scipy import ndimage

from lsmta.tracking import TrackerParams, Tracks, TrackStatus, track_points
from lsmta.tracking.guided import (
    MarkerState,
    feature_view,
    last_known,
    resume_from,
    tracking_state,
)

matplotlib.use("Agg")
numba.set_num_threads(1)

VEL = np.array([0.8, -0.45])       # px per frame
T = 12


def _sequence(rng):
    """One camera: a texture translating at ``VEL`` px/frame, ``T`` frames of 120 x 160."""
    img = ndimage.gaussian_filter(rng.normal(size=(120, 160)), 1.5)
    base = 128 + 60 * img / img.std()
    return np.stack([ndimage.shift(base, (VEL[1] * t, VEL[0] * t), order=3, mode="reflect")
                     for t in range(T)])


@pytest.fixture(scope="module")
def lost():
    """Tracks of four points, the third one made lost after frame 2 (as the tracker ends a
    track), and the true positions ``(T, 4, 2)``."""
    rng = np.random.default_rng(3)
    seq = _sequence(rng)
    xy0 = np.array([[50.0, 40.0], [80.0, 60.0], [100.0, 70.0], [70.0, 85.0]])
    truth = xy0[None] + VEL[None, None] * np.arange(T)[:, None, None]
    tracks = track_points([seq], xy0[None], initial_velocity=np.zeros((1, 4, 2)))
    assert tracks.alive.all()
    xy = tracks.xy.copy()
    xy[3:, :, 2] = np.nan
    status, end = tracks.status.copy(), tracks.end.copy()
    status[2], end[2] = TrackStatus.LOST, 2
    return seq, replace(tracks, xy=xy, status=status, end=end), truth


def _small_tracks():
    """Hand-made Tracks of 8 frames, one camera: 0 tracked throughout; 1 missing in 2-3
    and found again in 4; 2 ended after frame 1 (lost with max_gap 2); 3 never started."""
    Tn, N = 8, 4
    alive = np.ones((Tn, N), bool)
    alive[2:4, 1] = False
    alive[2:, 2] = False
    alive[:, 3] = False
    xy = np.where(alive[:, None, :, None], 10.0, np.nan) * np.ones((Tn, 1, N, 2))
    recovered = np.zeros((Tn, N), bool)
    recovered[4, 1] = True
    return Tracks(xy=xy, start=np.array([0, 0, 0, 0]), end=np.array([7, 7, 1, -1]),
                  status=np.array([TrackStatus.ALIVE, TrackStatus.ALIVE, TrackStatus.LOST,
                                   TrackStatus.NOT_STARTED]),
                  retried=np.zeros((Tn, N), bool), added=np.zeros(N, bool),
                  origin=np.full(N, -1), anchor=np.where(alive, 0, -1), recovered=recovered)


def test_tracking_state_codes():
    tr = _small_tracks()
    s = tracking_state(tr, max_gap=2)
    L, R, M, X, N = (MarkerState.LIVE, MarkerState.RECOVERED, MarkerState.MISSING,
                     MarkerState.LOST, MarkerState.NOT_STARTED)
    assert s.shape == (8, 4)
    assert (s[:, 0] == L).all()
    np.testing.assert_array_equal(s[:, 1], [L, L, M, M, R, L, L, L])
    np.testing.assert_array_equal(s[:, 2], [L, L, M, M, X, X, X, X])
    assert (s[:, 3] == N).all()
    placed = np.zeros((8, 4), bool)
    placed[5, 2] = True
    s2 = tracking_state(tr, placed=placed, max_gap=2)
    assert s2[5, 2] == MarkerState.PLACED and s2[6, 2] == M      # searched again after it
    with pytest.raises(ValueError, match="placed"):
        tracking_state(tr, placed=np.zeros((8, 3), bool))
    with pytest.raises(ValueError, match="tracks"):
        tracking_state(tr.xy)


def test_feature_view_and_last_known():
    img = np.arange(20 * 30, dtype=float).reshape(20, 30)
    v = feature_view(img, (2.2, 10.6), half=3)
    assert v.patch.shape == (7, 7) and (v.x0, v.y0) == (-1, 8)
    assert np.isnan(v.patch[:, 0]).all() and v.patch[3, 3] == img[11, 2]
    assert v.extent == (-1.5, 5.5, 14.5, 7.5)
    with pytest.raises(ValueError, match="image"):
        feature_view(img[None], (2, 2))
    tr = _small_tracks()
    np.testing.assert_array_equal(last_known(tr, 2, 6), [10.0, 10.0])
    assert np.isnan(last_known(tr, 3, 6)).all()


def test_resume_from_extends_a_lost_track_without_touching_the_input(lost):
    seq, tracks, truth = lost
    before = {f: np.array(getattr(tracks, f)) for f in ("xy", "status", "end", "anchor")}
    rng = np.random.default_rng(0)
    frame = 5
    click = truth[frame, 2] + rng.normal(0.0, 0.5, 2)
    res = resume_from([seq], tracks, 2, frame, click)
    for f, a in before.items():                        # the caller's tracks are unchanged
        np.testing.assert_array_equal(getattr(tracks, f), a)
    new = res.tracks
    assert res.snapped and res.placed[frame, 2] and res.placed.sum() == 1
    assert res.frames_tracked == T - 1 - frame
    assert new.end[2] == T - 1 and new.status[2] == TrackStatus.ALIVE
    assert np.isnan(new.xy[3:frame, 0, 2]).all()         # the gap stays a gap
    np.testing.assert_array_equal(new.xy[:3], tracks.xy[:3])
    np.testing.assert_array_equal(new.xy[:, :, [0, 1, 3]], tracks.xy[:, :, [0, 1, 3]])
    err = np.linalg.norm(new.xy[frame:, 0, 2] - truth[frame:, 2], axis=1)
    assert err.max() < 0.2, err
    state = tracking_state(new, placed=res.placed)
    assert state[frame, 2] == MarkerState.PLACED
    assert (state[frame + 1:, 2] == MarkerState.LIVE).all()
    # without the refinement, every frame inherits the click's error
    raw = resume_from([seq], tracks, 2, frame, truth[frame, 2] + [1.0, 0.0], snap=False)
    assert not raw.snapped
    raw_err = np.linalg.norm(raw.tracks.xy[frame:, 0, 2] - truth[frame:, 2], axis=1)
    assert raw_err.min() > 0.8


def test_resume_from_bad_input(lost):
    seq, tracks, truth = lost
    with pytest.raises(ValueError, match="marker"):
        resume_from([seq], tracks, 4, 5, (10.0, 10.0))
    with pytest.raises(ValueError, match="frame"):
        resume_from([seq], tracks, 2, T, (10.0, 10.0))
    with pytest.raises(ValueError, match="xy"):
        resume_from([seq], tracks, 2, 5, (500.0, 10.0))
    with pytest.raises(ValueError, match="tracks"):
        resume_from([seq[:-1]], tracks, 2, 5, (10.0, 10.0))
    last = resume_from([seq], tracks, 2, T - 1, truth[T - 1, 2])       # the last frame
    assert last.frames_tracked == 0 and last.tracks.end[2] == T - 1


def test_widget_is_built_and_its_button_resumes_headless(lost):
    from lsmta.tracking.guided_ui import GuidedTracker

    seq, tracks, truth = lost
    ui = GuidedTracker(seq, tracks, params=TrackerParams(), half=10)
    assert ui.overview.value[:4] == b"\x89PNG" and ui.enlarged.value[:4] == b"\x89PNG"
    ui.marker.value = 2
    ui.frame.value = 6
    np.testing.assert_allclose([ui.x.value, ui.y.value], tracks.xy[2, 0, 2], atol=0.01)
    ui.x.value, ui.y.value = (float(v) for v in truth[6, 2] + [0.3, -0.2])
    ui.button.click()
    assert len(ui.history) == 1 and ui.tracks is ui.history[0].tracks
    assert ui.tracks.end[2] == T - 1 and tracks.end[2] == 2
    assert ui.state()[6, 2] == MarkerState.PLACED
    assert "placed in frame 6" in ui.message.value
    ui.x.value = 1e4                                   # outside the image: a message
    ui.button.click()
    assert len(ui.history) == 1 and ui.message.value.startswith("not placed")
    fig = ui.static_summary(marker=2, frames=[2, 6, 11], truth=truth[:, 2])
    assert len(fig.axes) == 4
    assert "GuidedTracker" in ui._repr_mimebundle_()["text/plain"]
