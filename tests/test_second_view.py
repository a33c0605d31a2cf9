"""The image test of frames one view holds a marker in (lsmta.tracking.second_view)."""

import numpy as np
import pytest

from lsmta.tracking.second_view import hidden_frames
from tests.test_view_tracks import _dot_video, _rig


def _steady_dots():
    """Two views, two markers moving steadily; view 0 lost marker 0 from frame 10 (view 1
    holds it)."""
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(16, dtype=float)[:, None]
    X = np.stack([np.array([-150.0, 0, -80]) + t * [6.0, 3.0, 4.0],
                  np.array([120.0, 60, 100]) + t * [6.0, 0, 0]], axis=1)
    stacks = _dot_video(cams, X, size=(600, 800))
    truth = [c.project(X.reshape(-1, 3)).reshape(16, 2, 2) for c in cams]
    xy = [a.copy() for a in truth]
    xy[0][10:, 0] = np.nan
    return cams, X, stacks, truth, xy, np.array([[0, 0], [1, 1]])


def test_a_frame_is_hidden_only_where_no_other_view_shows_a_dot_on_the_line():
    cams, X, stacks, truth, xy, members = _steady_dots()    # view 0 lost marker 0 at 10
    given = [a.copy() for a in xy]
    shown = hidden_frames(stacks, cams, xy, members, radius=4, max_px=1.0)
    assert shown.shape == (16, 2) and not shown.any()      # its dot is there in view 0
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(xy, given))
    # view 0's frames 10-15 without marker 0's dot (hidden behind something)
    gone = [s.copy() for s in stacks]
    gone[0][10:] = _dot_video(cams[:1], X[10:, 1:])[0]
    hid = hidden_frames(gone, cams, xy, members, radius=4, max_px=1.0)
    assert hid[10:, 0].all() and not hid[:10].any() and not hid[:, 1].any()
    # a dot 10 px across the epipolar line (another marker, say) does not count
    o, d = cams[1].rays(truth[1][12, :1])
    ends = cams[0].project(np.concatenate([o + 2500 * d, o + 3500 * d]))
    u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    for across, hidden in ((10.0, True), (0.5, False)):
        off = truth[0][12, 0] + across * np.array([-u[1], u[0]])
        moved = [s.copy() for s in gone]
        yy, xx = np.mgrid[:600, :800]
        r2 = (xx - off[0]) ** 2 + (yy - off[1]) ** 2
        moved[0][12] = np.clip(moved[0][12] + 180 * np.exp(-r2 / 12.5) * (r2 < 200), 0, 255)
        got = hidden_frames(moved, cams, xy, members, radius=4, max_px=1.0)
        assert got[12, 0] == hidden, across
    # nothing held by one view: nothing judged
    both = hidden_frames(gone, cams, truth, members, radius=4, max_px=1.0)
    assert not both.any()


def test_hidden_frames_refuses_bad_input():
    cams, X, stacks, truth, xy, members = _steady_dots()
    with pytest.raises(ValueError, match="members"):
        hidden_frames(stacks, cams, xy, members.astype(float))
    with pytest.raises(ValueError, match="stacks"):
        hidden_frames(stacks[:1], cams, xy, members)
    with pytest.raises(ValueError, match="max_px"):
        hidden_frames(stacks, cams, xy, members, max_px=0.0)


def _with_dot(stack, t, xy):
    """A copy of ``stack`` with a dot like _dot_video's added at ``xy`` in frame ``t``."""
    out = stack.copy()
    yy, xx = np.mgrid[:out.shape[1], :out.shape[2]]
    r2 = (xx - xy[0]) ** 2 + (yy - xy[1]) ** 2
    out[t] = np.clip(out[t] + 180 * np.exp(-r2 / 12.5) * (r2 < 200), 0, 255)
    return out


def test_a_dot_on_the_line_beyond_the_reach_does_not_count():
    cams, X, stacks, truth, xy, members = _steady_dots()    # view 0 lost marker 0 at 10
    gone = [s.copy() for s in stacks]
    gone[0][10:] = _dot_video(cams[:1], X[10:, 1:])[0]      # and its dot is gone there
    speed = np.linalg.norm([6.0, 3.0, 4.0])                  # its step, mm per frame
    o, d = cams[1].rays(truth[1][12, :1])
    d = d[0] / np.linalg.norm(d[0])
    s12 = float(np.dot(X[12, 0] - o[0], d))                  # its depth on view 1's ray
    # frame 12 is 3 frames from frame 9, its nearest 3-D frame: the reach is 3 steps
    for along, hidden in ((0.0, False), (10 * speed, True)):
        dot = cams[0].project((o[0] + (s12 + along) * d)[None])[0]
        assert 20 < dot[0] < 780 and 20 < dot[1] < 580     # inside view 0's frame
        moved = [_with_dot(gone[0], 12, dot), gone[1]]
        got = hidden_frames(moved, cams, xy, members, radius=4, max_px=1.0)
        assert got[12, 0] == hidden, along


def test_no_two_consecutive_3d_frames_nothing_judged_and_stacks_unchanged():
    cams, X, stacks, truth, xy, members = _steady_dots()
    gone = [s.copy() for s in stacks]
    gone[0][10:] = _dot_video(cams[:1], X[10:, 1:])[0]
    given = [s.copy() for s in gone]
    assert hidden_frames(gone, cams, xy, members, radius=4, max_px=1.0)[10:, 0].all()
    assert all(np.array_equal(a, b) for a, b in zip(gone, given))
    # view 0 holds marker 0 in every other frame only: no step measured, nothing judged
    odd = [a.copy() for a in xy]
    odd[0][1::2, 0] = np.nan
    got = hidden_frames(gone, cams, odd, members, radius=4, max_px=1.0)
    assert not got[:, 0].any()
    assert all(np.array_equal(a, b) for a, b in zip(gone, given))
