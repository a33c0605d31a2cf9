"""Markers detected again in key frames (lsmta.tracking.redetect) and the marker stage's
MarkerParams.redetect."""

import numpy as np
import pytest

from lsmta.systems import MarkerParams, Tracker2D, capture_markers
from lsmta.tracking.redetect import redetected_tracks, tracks_from_starts
from tests.test_view_tracks import _dot_video, _rig


def _short_tracker(frames, xy):
    """A tracker that holds still points for 6 frames, then loses them."""
    out = np.full((len(frames), len(xy), 2), np.nan)
    out[:6] = np.asarray(xy, float)[None]
    return out


def test_pieces_start_where_a_marker_is_seen_and_merge_into_the_track_they_meet():
    frames = np.zeros((20, 40, 40))
    dots = np.array([[10.0, 10.0], [30.0, 30.0]])

    def detect(t):                        # dot 1 is seen from frame 9 on
        return dots if t >= 9 else dots[:1]

    one, _ = redetected_tracks(frames, detect, _short_tracker, every=100, radius=2.0)
    assert one.shape[1] == 1 and np.isfinite(one[:6, 0, 0]).all() and np.isnan(one[6:]).all()
    xy, starts = redetected_tracks(frames, detect, _short_tracker, every=4, radius=2.0)
    # dot 0: held in key frame 4 (skipped); lost in 8: a piece 3-13 meets track 0 in 3-5 and
    # fills 6-13; held in 12; lost in 16: a piece 11-19 fills 14-19. Dot 1: seen first in key
    # frame 12, a new track (7-17: 6 frames each way), held in 16 (skipped)
    assert xy.shape[1] == 2
    assert np.isfinite(xy[:, 0, 0]).all() and np.allclose(xy[:, 0], dots[0])
    assert np.flatnonzero(np.isfinite(xy[:, 1, 0])).tolist() == list(range(7, 18))
    assert starts[:, :2].tolist() == [[0, 0], [0, 8], [1, 12], [0, 16]]
    again = tracks_from_starts(frames, starts, _short_tracker)
    assert np.array_equal(again, xy, equal_nan=True)


def _late_dot_scene(T=16, late=7):
    """Two views, three moving dots far apart; dot 2 appears only from frame ``late``."""
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(T)[:, None, None]
    X = np.array([[-200.0, 0, -100], [150, 60, 120], [250, -50, -220]])[None] + \
        np.array([30.0, 0, 20.0]) * np.sin(0.3 * t + np.arange(3)[:, None])
    stacks = _dot_video(cams, X)
    hidden = _dot_video(cams, X[:, :2])
    for k in range(2):
        stacks[k][:late] = hidden[k][:late]
    return cams, X, stacks


_PARAMS = MarkerParams(detector="blobs", max_px=1.0, min_motion_mm=20.0, min_shared=0.3)


def test_the_stage_joins_a_late_marker_only_with_redetection_and_klt_follows_its_starts():
    cams, X, stacks = _late_dot_scene()
    first = [s[0] for s in stacks]
    given = [s.copy() for s in stacks]
    plain = capture_markers(stacks, cams, first, params=_PARAMS)
    p = MarkerParams(**{**_PARAMS.__dict__, "redetect": 4})
    m = capture_markers(stacks, cams, first, params=p)
    assert all(np.array_equal(a, b) for a, b in zip(stacks, given))
    assert plain.starts is None and len(plain.members) == 2
    assert len(m.members) == 3 and m.starts is not None
    assert [len(s) for s in m.starts] == [3, 3]               # the late dot at key frame 8
    late = int(np.argmin(np.linalg.norm(np.nanmedian(m.xyz, axis=0) - X[10, 2], axis=1)))
    assert np.isfinite(m.xyz[7:, late]).all()
    assert np.linalg.norm(m.xyz[7:, late] - X[7:, 2], axis=1).max() < 3.0
    k = capture_markers(stacks, cams, first, like=m,
                        params=MarkerParams(**{**p.__dict__, "tracker": Tracker2D.KLT}))
    assert all(a.shape == b.shape for a, b in zip(k.view_xy, m.view_xy))
    assert np.array_equal(k.members, m.members) and k.starts is m.starts
    assert np.isfinite(k.xyz[7:, late]).all()


def test_redetection_refuses_bad_input():
    cams, X, stacks = _late_dot_scene()
    for bad in (0, -3, 2.5):
        with pytest.raises((ValueError, TypeError), match="redetect"):
            MarkerParams(redetect=bad)
    with pytest.raises(ValueError, match="^colour: expected a callable"):
        capture_markers(stacks, cams, [s[0] for s in stacks],
                        params=MarkerParams(detector="skin", redetect=4))
    with pytest.raises(TypeError, match="^colour: expected a callable"):
        capture_markers(stacks, cams, [s[0] for s in stacks],
                        params=MarkerParams(**{**_PARAMS.__dict__, "redetect": 4}), colour=3)
    frames = stacks[0]
    none = np.zeros((0, 2))
    with pytest.raises(ValueError, match="every"):
        redetected_tracks(frames, lambda t: none, _short_tracker, every=0, radius=4.0)
    with pytest.raises(ValueError, match="radius"):
        redetected_tracks(frames, lambda t: none, _short_tracker, every=4, radius=0.0)
    with pytest.raises(TypeError, match="track"):
        redetected_tracks(frames, lambda t: none, None, every=4, radius=4.0)
    with pytest.raises(ValueError, match="detect"):
        redetected_tracks(frames, lambda t: np.zeros((3, 3)), _short_tracker, every=4,
                          radius=4.0)
    with pytest.raises(ValueError, match="frames"):
        redetected_tracks(frames[0], lambda t: none, _short_tracker, every=4, radius=4.0)
    with pytest.raises(ValueError, match="starts"):
        tracks_from_starts(frames, np.array([[0, 99, 10.0, 10.0]]), _short_tracker)
    with pytest.raises(ValueError, match="starts"):
        tracks_from_starts(frames, np.array([[0.5, 0, 10.0, 10.0]]), _short_tracker)
