"""Joined markers checked, completed and filled (lsmta.tracking.join_checks), the marker
stage's use of it (lsmta.systems.markers) and the rigid pair's co-motion rule
(lsmta.real.own_recording)."""

from types import SimpleNamespace

import numpy as np
import pytest

from lsmta.camera import Camera
from lsmta.real.own_recording import moving_pairs, relative_motion, rigid_pair
from lsmta.systems import MarkerParams, capture_markers
from lsmta.systems.markers import silhouette_shares
from lsmta.tracking import join_checks
from lsmta.tracking.blob_follow import FollowParams
from lsmta.tracking.join_checks import (
    Filled,
    attach_views,
    check_dots,
    check_joins,
    fill_gaps,
    silhouette_hits,
    silhouette_share,
)
from lsmta.tracking.view_tracks import join_view_tracks, triangulate_joined
from tests.test_view_tracks import _dot_video, _rig


def _paths(T=30, seed=0):
    """Five points moving each its own way near the origin, (T, 5, 3) mm."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    base = np.array([[-200.0, 0, -100], [150, 80, 120], [0, -60, 250], [220, 40, -200],
                     [-120, 100, 180]])
    return base[None] + 60 * np.sin(0.2 * t + rng.uniform(0, 6, (1, 5, 3)))


def _tracks(cams, X, noise=0.1, seed=1):
    rng = np.random.default_rng(seed)
    T, M, _ = X.shape
    return [c.project(X.reshape(-1, 3)).reshape(T, M, 2) + rng.normal(0, noise, (T, M, 2))
            for c in cams]


def test_two_points_on_one_epipolar_plane_moving_alike_are_ambiguous():
    cams = _rig(2, spread_deg=20.0)                      # a horizontal baseline
    X = _paths()
    # point 5 moves exactly as point 0, 300 mm beside it along the baseline: their images
    # share the epipolar lines in every frame, so either pairing of them meets
    X = np.concatenate([X, X[:, :1] + [300.0, 0, 0]], axis=1)
    xy = _tracks(cams, X)
    J = join_view_tracks(cams, xy, max_px=1.0)
    assert len(J) == 5                                   # 0 and 5 joined, one way or other
    c = check_joins(cams, xy, J.members, max_px=1.0)
    assert c.ambiguous == 1 and len(c.members) == 4 and c.views_out == 0
    assert not np.isin(c.members, [0, 5]).any()         # the rest kept
    before = J.members.copy()
    check_joins(cams, xy, J.members, max_px=1.0)
    assert np.array_equal(J.members, before)             # input unchanged
    # with a looser ratio nothing is ambiguous
    assert check_joins(cams, xy, J.members, max_px=1.0, min_ratio=1.0).ambiguous == 0


def _side_by_side_and_above():
    """Two cameras side by side (a horizontal baseline along x) and one above them."""
    cams = _rig(2, spread_deg=20.0)
    top = Camera.look_at([0.0, -2400.0, 1800.0], [0.0, 0.0, 0.0], f=1200.0, width=800,
                         height=600, name="top")
    return [*cams, top]


def test_a_third_view_confirms_a_marker_whose_pair_is_ambiguous():
    cams = _side_by_side_and_above()
    X = _paths()
    # point 5 moves as point 0, 300 mm beside it along the side-by-side pair's baseline:
    # that pair alone cannot tell them apart, the view above can
    X = np.concatenate([X, X[:, :1] + [300.0, 0, 0]], axis=1)
    xy = _tracks(cams, X)
    right = np.array([[i, i, i] for i in range(6)])
    c = check_joins(cams, xy, right, max_px=1.0)
    assert c.ambiguous == 0 and c.ambiguous_views == 0 and c.views_out == 0
    assert np.array_equal(c.members, right)                # all six kept, with all views
    # without the view above, the pair's rule drops both
    two = check_joins(cams[:2], xy[:2], right[:, :2], max_px=1.0)
    assert two.ambiguous == 2 and not np.isin(two.members, [0, 5]).any()


def test_an_ambiguous_view_of_a_three_view_marker_is_taken_out_not_the_marker():
    cams = _side_by_side_and_above()
    X = _paths()
    # point 5 moves as point 0, 500 mm further along the view above's ray through it: the
    # view above sees the two at one place; the side-by-side pair tells them apart
    ray = X[:, :1] - cams[2].C
    X = np.concatenate([X, X[:, :1] + 500.0 * ray / np.linalg.norm(ray, axis=2,
                                                                   keepdims=True)], axis=1)
    xy = _tracks(cams, X)
    right = np.array([[i, i, i] for i in range(6)])
    c = check_joins(cams, xy, right, max_px=1.0)
    assert c.ambiguous_views == 2 and c.ambiguous == 0 and len(c.members) == 6
    assert np.array_equal(c.members[[0, 5], 2], [-1, -1])     # the view above out of both
    assert np.array_equal(c.members[1:5], right[1:5])          # the rest untouched


def test_a_wrong_view_is_taken_out_and_its_track_attached_where_it_belongs():
    cams = _rig(3, spread_deg=40.0)
    X = _paths()
    xy = _tracks(cams, X)
    members = np.array([[i, i, i] for i in range(5)])
    members[4, 2] = -1                                   # point 4: views 0 and 1 only
    wrong = members.copy()
    wrong[0, 2] = 4                                      # point 0 given point 4's track
    free = np.delete(wrong, 0, axis=0)                   # (view 2's track 0 now free)
    assert not np.isin(0, free[:, 2])
    c = check_joins(cams, xy, wrong, max_px=2.0)
    assert c.views_out == 1 and c.ambiguous == 0 and c.members[0, 2] == -1
    m, attached = attach_views(cams, xy, c.members, max_px=2.0)
    assert attached == 2 and np.array_equal(m, np.array([[i, i, i] for i in range(5)]))
    # a view never joined (the two others 80 degrees apart joined it) is attached too
    m2, n2 = attach_views(cams, xy, np.array([[i, i, -1] for i in range(5)]), max_px=2.0)
    assert n2 == 5 and np.array_equal(m2[:, 2], np.arange(5))


def test_attaching_in_chunks_of_markers_gives_the_same(monkeypatch):
    cams = _rig(3, spread_deg=40.0)
    xy = _tracks(cams, _paths())
    members = np.array([[i, i, -1] for i in range(5)])
    whole = attach_views(cams, xy, members, max_px=2.0)
    monkeypatch.setattr(join_checks, "_CHUNK", 1)          # one marker at a time
    parts = attach_views(cams, xy, members, max_px=2.0)
    assert whole[1] == parts[1] == 5 and np.array_equal(whole[0], parts[0])


def test_markers_below_the_floor_are_dropped_only_when_a_floor_is_given():
    cams = _rig(2, spread_deg=30.0)
    X = _paths()
    X[:, :, 2] += 200.0
    X[:, 3:, 2] -= 500.0                                 # two points 100-500 mm under z = 0
    xy = _tracks(cams, X)
    members = np.array([[i, i] for i in range(5)])
    c = check_joins(cams, xy, members, max_px=1.0, floor_mm=0.0, floor_margin_mm=50.0)
    assert c.below_floor == 2 and np.array_equal(c.members[:, 0], [0, 1, 2])
    assert check_joins(cams, xy, members, max_px=1.0).below_floor == 0
    up_down = check_joins(cams, xy, members, max_px=1.0, floor_mm=0.0, up=(0, 0, -1))
    assert up_down.below_floor == 3                      # turned over: the other three


def test_a_lost_dot_is_found_at_the_projection_and_a_missing_one_is_not():
    cams = _rig(2, spread_deg=20.0)
    T = 16
    t = np.arange(T)[:, None, None]
    X = np.array([[-150.0, 0, -80], [120, 60, 100]])[None] + \
        np.array([6.0, 0, 4.0]) * t                      # steady motion, 7 mm per frame
    stacks = _dot_video(cams, X, size=(600, 800))
    stacks[1][12, :, :] = 40                             # frame 12: view 1 shows no dot
    truth = [c.project(X.reshape(-1, 3)).reshape(T, 2, 2) for c in cams]
    xy = [a.copy() for a in truth]
    xy[0][5:9, 0] = np.nan                               # view 0 lost marker 0 (blur)
    xy[1][11:14, 1] = np.nan                             # view 1 lost marker 1
    members = np.array([[0, 0], [1, 1]])
    given = [a.copy() for a in xy]
    out, found = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(xy, given))
    assert found[5:9, 0, 0].all() and found[[11, 13], 1, 1].all()
    assert not found[12, 1, 1] and np.isnan(out[1][12, 1]).all()   # no dot: stays empty
    err = np.linalg.norm(out[0][5:9, 0] - truth[0][5:9, 0], axis=1)
    assert err.max() < 0.5
    assert found.sum() == 6
    # the search near the projection comes first: the line is not searched where it finds
    _, first = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0, line_px=48.0)
    assert np.array_equal(first, found) and (first[[11, 13], 1, 1] == Filled.NEAR).all()
    moved = [s.copy() for s in stacks]
    moved[0][5:9] = np.roll(stacks[0][5:9], 8, axis=2)   # view 0's dots 8 px to the right
    _, near = fill_gaps(moved, cams, xy, members, radius=4, search_px=4.0, max_px=20.0)
    _, wide = fill_gaps(moved, cams, xy, members, radius=4, search_px=12.0, max_px=20.0)
    assert not near[5:9, 0, 0].any() and wide[5:9, 0, 0].all()
    # a free track of view 0 (joined to no marker) holds marker 0's dot: not taken
    extra = [np.concatenate([xy[0], np.full((T, 1, 2), np.nan)], axis=1), xy[1]]
    extra[0][5:9, 2] = truth[0][5:9, 0]
    _, taken = fill_gaps(stacks, cams, extra, members, radius=4, max_px=1.0)
    assert not taken[5:9, 0, 0].any() and taken[[11, 13], 1, 1].all()
    xyz, _, _ = triangulate_joined(cams, out, members)
    assert np.isfinite(xyz[:, 0]).all() and np.isnan(xyz[12, 1]).all()


def test_the_stage_records_its_checks_and_the_peer_shares_them():
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(8)[:, None, None]
    base = np.array([[-250.0, 0, -150], [0, 120, 140], [250, -80, -20], [-100, 60, 150]])
    X = base[None] + np.array([25.0, 0, 15.0]) * np.sin(0.3 * t + np.arange(4)[:, None])
    stacks = _dot_video(cams, X)
    first = [s[0] for s in stacks]
    p = MarkerParams(detector="blobs", max_px=1.0, min_motion_mm=5.0)
    a = capture_markers(stacks, cams, first, params=p)
    assert set(a.joins) == {"ambiguous", "ambiguous_views", "below_floor", "views_out",
                            "attached", "not_dot_views", "not_dots", "off_subject", "filled",
                            "filled_line", "filled_reach", "residual_out",
                            "residual_views_out"}
    assert a.joins["not_dots"] == a.joins["not_dot_views"] == 0     # rendered dots
    assert a.joins["residual_out"] == a.joins["residual_views_out"] == 0
    assert len(a.members) == 4 and a.joins["ambiguous"] == 0
    b = capture_markers(stacks, cams, first, params=p, like=a)
    assert np.array_equal(a.members, b.members) and b.joins["attached"] == a.joins["attached"]
    off = capture_markers(stacks, cams, first, params=MarkerParams(
        detector="blobs", max_px=1.0, min_motion_mm=5.0, check=False))
    assert off.joins == dict.fromkeys(a.joins, 0)
    floor = capture_markers(stacks, cams, first, params=MarkerParams(
        detector="blobs", max_px=1.0, min_motion_mm=5.0, floor_mm=0.0))
    assert floor.joins["below_floor"] == 1 and len(floor.members) == 3   # the z = -150 one


def test_the_rigid_pair_must_move_together():
    rng = np.random.default_rng(4)
    T = 60
    s = np.arange(T)
    swing = np.stack([300 * np.sin(0.2 * s), 0 * s, 80 * np.clip(np.sin(0.2 * s), 0, None)], 1)
    heel, toe = np.array([0.0, 0, 60]), np.array([180.0, 0, 40])
    a = heel + swing + rng.normal(0, 1, (T, 3))
    b = toe + swing + rng.normal(0, 1, (T, 3))
    other = heel + [0, 120, 0] + 0.2 * swing + rng.normal(0, 1, (T, 3))   # another segment
    assert relative_motion(a, b) < 0.05 and relative_motion(a, other) > 1.0
    X = np.stack([a, b, other], axis=1)
    assert rigid_pair(X).markers == (0, 1)
    d = np.median(np.linalg.norm(a - other, axis=1))
    assert 60 < d < 250 and rigid_pair(X[:, [0, 2]]) is None      # a span, not together
    assert rigid_pair(X[:, [0, 2]], max_relative=5.0).markers == (0, 1)
    still = np.tile(heel, (T, 1))
    assert relative_motion(still, still) == np.inf        # no common motion
    gone = np.full((T, 3), np.nan)
    assert np.isnan(relative_motion(a, gone))
    # every moving pair with what the rule looks at: the still marker 3 is left out
    capture = SimpleNamespace(moving=np.array([True, True, True, False]),
                              xyz=np.stack([a, b, other, still], axis=1),
                              members=np.array([[0, 1], [1, 2], [2, -1], [3, 3]]))
    pairs = moving_pairs(capture)
    assert [p["markers"] for p in pairs] == [[0, 1], [0, 2], [1, 2]]
    assert [p["same_views"] for p in pairs] == [True, False, False]
    assert pairs[0]["relative_motion"] == relative_motion(a, b) and pairs[0]["frames_both"] == T
    assert abs(pairs[0]["median_mm"] - np.median(np.linalg.norm(a - b, axis=1))) < 1e-9


def test_bad_input():
    cams = _rig(2)
    X = _paths(T=6)
    xy = _tracks(cams, X)
    members = np.array([[i, i] for i in range(5)])
    with pytest.raises(ValueError, match="members"):
        check_joins(cams, xy, members[:, :1])
    with pytest.raises(ValueError, match="members"):
        attach_views(cams, xy, members.astype(float))
    with pytest.raises(ValueError, match="min_ratio"):
        check_joins(cams, xy, members, min_ratio=0.5)
    with pytest.raises(ValueError, match="floor_margin_mm"):
        check_joins(cams, xy, members, floor_mm=0.0, floor_margin_mm=-1.0)
    with pytest.raises(ValueError, match="up"):
        check_joins(cams, xy, members, up=(0, 0, 0))
    with pytest.raises((TypeError, ValueError), match="floor_mm"):
        check_joins(cams, xy, members, floor_mm="floor")
    with pytest.raises((TypeError, ValueError), match="floor_mm"):
        check_joins(cams, xy, members[:0], floor_mm=float("nan"))    # checked up front
    for share in (0.0, 1.5):
        with pytest.raises(ValueError, match="min_shared"):
            check_joins(cams, xy, members, min_shared=share)
    with pytest.raises(ValueError, match="max_px"):
        attach_views(cams, xy, members, max_px=0.0)
    with pytest.raises(ValueError, match="min_shared"):
        attach_views(cams, xy, members, min_shared=1.5)
    stacks = [np.zeros((6, 600, 800), np.uint8)] * 2
    with pytest.raises(ValueError, match="stacks"):
        fill_gaps(stacks[:1], cams, xy, members)
    with pytest.raises(ValueError, match="stacks"):
        fill_gaps([s[:3] for s in stacks], cams, xy, members)
    with pytest.raises(ValueError, match=r"stacks\[1\]: expected \(T, 600, 800\)"):
        fill_gaps([stacks[0], np.zeros((6, 300, 400), np.uint8)], cams, xy, members)
    with pytest.raises(ValueError, match="radius"):
        fill_gaps(stacks, cams, xy, members, radius=0)
    with pytest.raises(ValueError, match="search_px"):
        fill_gaps(stacks, cams, xy, members, search_px=0.0)
    with pytest.raises(ValueError, match="max_gap"):
        fill_gaps(stacks, cams, xy, members, max_gap=-1)
    with pytest.raises(ValueError, match="min_contrast"):
        fill_gaps(stacks, cams, xy, members, min_contrast=0.0)
    with pytest.raises(TypeError, match="check"):
        MarkerParams(check="yes")
    with pytest.raises(ValueError, match="min_ratio"):
        MarkerParams(min_ratio=0.5)
    with pytest.raises(ValueError, match="floor_mm"):
        MarkerParams(floor_mm=float("nan"))
    with pytest.raises(ValueError, match="fill_search_px"):
        MarkerParams(fill_search_px=0.0)
    for share in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="silhouette"):
            MarkerParams(silhouette=share)
    with pytest.raises(ValueError, match="silhouette_px"):
        MarkerParams(silhouette_px=-1.0)
    with pytest.raises(ValueError, match=r"masks: expected a \(6, 600, 800\) bool"):
        silhouette_hits(cams[0], X, np.ones((6, 300, 400), bool))
    with pytest.raises(ValueError, match="masks"):
        silhouette_hits(cams[0], X, np.ones((6, 600, 800)))          # not bool
    with pytest.raises(ValueError, match="xyz"):
        silhouette_hits(cams[0], X[..., :2], np.ones((6, 600, 800), bool))
    with pytest.raises(ValueError, match="inside, seen"):
        silhouette_share(np.ones((2, 6, 5), bool), np.ones((2, 6, 4), bool))
    with pytest.raises(ValueError, match="stacks: expected 2 frame stacks"):
        silhouette_shares(stacks[:1], cams, xy, members)
    with pytest.raises(ValueError, match="min_seen"):
        silhouette_share(np.ones((2, 6, 5), bool), np.ones((2, 6, 5), bool), min_seen=0.0)
    with pytest.raises(ValueError, match="max_relative"):
        rigid_pair(X, max_relative=0.0)
    with pytest.raises(ValueError, match="b"):
        relative_motion(X[:, 0], X[:3, 1])


def test_silhouette_hits_see_only_what_the_frame_holds():
    cam = _rig(1, spread_deg=0.0)[0]                        # at (0, -3000, 0), looking at 0
    masks = np.zeros((4, cam.height, cam.width), bool)
    masks[[0, 2], 280:320, 380:420] = True                  # the subject around the centre
    masks[1, 10:12, 10:12] = True                           # frame 1: a 4-px speck elsewhere
    before = masks.copy()                                   # frame 3: empty (nothing moved)
    X = np.array([[[0.0, 0, 0], [600.0, 0, 0], [3000.0, 0, 0], [0, -4000.0, 0],
                   [np.nan, 0, 0]]] * 4)                    # on, off, out of frame, behind, none
    inside, seen = silhouette_hits(cam, X, masks)
    assert np.array_equal(seen, [[True, True, False, False, False]] * 3 + [[False] * 5])
    assert np.array_equal(inside, [[True] + [False] * 4, [False] * 5, [True] + [False] * 4,
                                   [False] * 5])
    # a mask below min_area is not judged either
    assert not silhouette_hits(cam, X, masks, min_area=5)[1][1].any()
    # the least share over the views that see a marker in >= min_seen of its frames and in
    # >= min_positions frames
    other = np.zeros_like(inside)
    i2, s2 = np.stack([inside, other]), np.stack([seen, seen])
    s2[1, :2, 0] = False                                     # view 1 sees marker 0 in frame 2 only
    share = silhouette_share(i2, s2)
    assert share[0] == 2 / 3 and share[1] == 0.0 and np.isnan(share[2:]).all()
    assert silhouette_share(i2, s2, min_seen=0.3, min_positions=1)[0] == 0.0   # view 1 judges
    # a marker seen in only 2 frames is not judged (NaN: kept)
    assert np.isnan(silhouette_share(i2[:, :2], s2[:, :2])).all()
    assert np.array_equal(X, np.array([[[0.0, 0, 0], [600.0, 0, 0], [3000.0, 0, 0],
                                        [0, -4000.0, 0], [np.nan, 0, 0]]] * 4), equal_nan=True)
    assert np.array_equal(masks, before)


def _off_subject_scene(T=16, still_from=None, view2_shift=(0.0, 0.0, 0.0)):
    """Three views of four dots moving together (the subject) and a fifth dot at W, 800 mm
    off them, shown by views 0 and 1 only: their tracks meet at W as a wrong join of two
    dots whose rays cross off the subject would, and view 2 sees background there. From
    frame ``still_from`` on, everything stands still; view 2 shows the subject shifted by
    ``view2_shift`` mm (its masks then miss the others' subject)."""
    cams = _rig(3, spread_deg=40.0)
    t = np.arange(T)[:, None, None]
    t = t if still_from is None else np.minimum(t, still_from)
    sway = np.array([40.0, 0, 25.0]) * np.sin(0.3 * t)
    S = np.array([[-120.0, 0, -100], [0, 60, 120], [120, -40, -20], [-60, 30, 140]])[None] + sway
    W = np.array([[-300.0, -600, -250]])[None] + sway[:, :1] * [1, 0, -1]
    both = np.concatenate([S, W], axis=1)
    stacks = [_dot_video([c], X)[0] for c, X in zip(cams, (both, both, S + view2_shift))]
    return cams, stacks, S, W


def _right_and_wrong(cams, stacks, S, W):
    """The markers (checked without the silhouette) at the subject's dots and at W."""
    base = dict(detector="blobs", max_px=1.0, min_motion_mm=5.0)
    first = [s[0] for s in stacks]
    off = capture_markers(stacks, cams, first, params=MarkerParams(**base, silhouette=None))
    xyz = np.nanmedian(off.xyz, axis=0)
    right = [off.members[np.argmin(np.linalg.norm(xyz - X, axis=1))] for X in S[-1]]
    wrong = off.members[np.linalg.norm(xyz - W[-1, 0], axis=1) < 20]
    return base, first, off, right, wrong


def _kept(on, rows) -> bool:
    return all(any(np.array_equal(r, row) for row in on.members) for r in rows)


def test_a_moving_marker_off_the_subject_is_dropped_and_the_right_ones_kept():
    cams, stacks, S, W = _off_subject_scene()
    w2 = cams[2].project(W[:, 0])
    assert ((w2 >= 0) & (w2 < [800, 600])).all()               # view 2's frame holds it
    assert np.linalg.norm(w2[:, None] - cams[2].project(S.reshape(-1, 3)).reshape(
        len(S), -1, 2), axis=2).min() > 80                     # on its background
    first = [s[0] for s in stacks]
    base = dict(detector="blobs", max_px=1.0, min_motion_mm=5.0)
    off = capture_markers(stacks, cams, first, params=MarkerParams(**base, silhouette=None))
    xyz = np.nanmedian(off.xyz, axis=0)
    wrong = np.flatnonzero(np.linalg.norm(xyz - W[0, 0], axis=1) < 20)
    assert len(wrong) == 1 and off.moving[wrong[0]] and off.joins["off_subject"] == 0
    assert np.array_equal(off.members[wrong[0]] >= 0, [True, True, False])
    shares = silhouette_shares(stacks, cams, off.view_xy, off.members,
                               params=MarkerParams(**base))
    right = np.setdiff1d(np.flatnonzero(off.moving), wrong)
    assert len(right) == 4 and shares[wrong[0]] < 0.5 and np.all(shares[right] >= 0.9)
    on = capture_markers(stacks, cams, first, params=MarkerParams(**base))
    assert on.joins["off_subject"] == 1 and len(on.members) == len(off.members) - 1
    assert np.array_equal(on.members, np.delete(off.members, wrong, axis=0))
    # the peer shares the check's outcome and count
    klt = capture_markers(stacks, cams, first, params=MarkerParams(**base), like=on)
    assert klt.joins["off_subject"] == 1 and np.array_equal(klt.members, on.members)


def test_a_still_subject_or_a_frozen_view_keeps_the_right_markers():
    # the subject stands still from frame 12 on: 5 of the 8 sampled frames (0, 5, ..., 35)
    # have empty masks in every view; they are not judged (before: the right markers' share
    # fell to 3/8 and all were dropped), the 3 moving ones still catch the wrong join
    cams, stacks, S, W = _off_subject_scene(T=40, still_from=12)
    base, first, off, right, wrong = _right_and_wrong(cams, stacks, S, W)
    assert len(right) == 4 and len(wrong) == 1
    with pytest.warns(RuntimeWarning, match=r"view 'v2'.s subject mask is empty .* in 5 of its 8"):
        on = capture_markers(stacks, cams, first, params=MarkerParams(**base))
    assert _kept(on, right) and not _kept(on, wrong) and on.joins["off_subject"] == 1
    # view 2 frozen (its first frame throughout): no mask there, its frames not judged; the
    # right markers are kept (before: all dropped), and the wrong join too: views 0 and 1
    # hold it on a moving dot, only view 2 could tell (the check's limit)
    cams, stacks, S, W = _off_subject_scene()
    stacks[2] = np.repeat(stacks[2][:1], len(stacks[2]), axis=0)
    base, first, off, right, wrong = _right_and_wrong(cams, stacks, S, W)
    with pytest.warns(RuntimeWarning, match=r"view 'v2'.s subject mask is empty"):
        on = capture_markers(stacks, cams, first, params=MarkerParams(**base))
    assert _kept(on, right) and on.joins["off_subject"] == 0


def test_a_check_that_drops_most_moving_markers_warns():
    # view 2's subject 400 mm aside: every marker lands off its masks
    cams, stacks, S, W = _off_subject_scene(view2_shift=(400.0, 0.0, 0.0))
    first = [s[0] for s in stacks]
    with pytest.warns(RuntimeWarning, match=r"silhouette check: 5 of the 5 moving markers .*"
                                            r"more than half"):
        on = capture_markers(stacks, cams, first, params=MarkerParams(
            detector="blobs", max_px=1.0, min_motion_mm=5.0))
    assert on.joins["off_subject"] == 5 and not on.moving.any()


def _square_scene(d, T=31):
    """Two views of a moving point X and a 60-px square of the subject beside it: in view 0
    the point lies ``d`` px right of the square's right edge, in view 1 at its centre.
    Markers: 0 X; 1 a still point; 2 never seen; 3 a moving point 400 mm above X seen in
    the first two sampled frames only (off the squares there)."""
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(T, dtype=float)
    X = np.stack([-300 + 20 * t, 0 * t, 0 * t], axis=1)
    pts = np.stack([X, np.tile([0.0, 0, 300], (T, 1)), np.full((T, 3), np.nan),
                    X + [0, 0, 400]], axis=1)                        # (T, 4, 3)
    xy, stacks = [], []
    for k, cam in enumerate(cams):
        p = cam.project(np.nan_to_num(pts).reshape(-1, 3)).reshape(T, 4, 2)
        p[:, 2] = np.nan
        p[:, 3][np.r_[0:2, 7:T]] = np.nan                              # seen in frames 2..6
        xy.append(p)
        v = np.zeros((T, cam.height, cam.width), np.uint8)
        for i, (x, y) in enumerate(np.rint(p[:, 0]).astype(int)):
            if k == 0:
                v[i, y - 30:y + 31, x - d - 60:x - d] = 200
            else:
                v[i, y - 40:y + 41, x - 40:x + 41] = 200
        stacks.append(v)
    return cams, stacks, xy, np.array([[j, j] for j in range(4)])


def test_the_silhouette_radius_is_used_and_unjudged_markers_kept():
    for d, r, share in ((7, 10, 1.0), (12, 10, 0.0), (12, 14, 1.0)):
        cams, stacks, xy, members = _square_scene(d)
        for p in (MarkerParams(silhouette_px=r), MarkerParams(sigma=r / 6)):   # px, 6 sigma
            got = silhouette_shares(stacks, cams, xy, members, params=p)
            assert got[0] == share, (d, r, p.silhouette_px, got)
            # still, never seen, and seen in 2 sampled frames (0 and 5): not judged, kept
            assert np.isnan(got[1:]).all()
    got = silhouette_shares(stacks, cams, xy, members, params=p, min_positions=1)
    assert got[3] == 0.0                                   # judged on its 2 positions
    # a clip of 2 frames (fewer than 3 sampled): nothing judged
    two = silhouette_shares([s[:2] for s in stacks], cams, [a[:2] for a in xy], members)
    assert np.isnan(two).all()
    with pytest.raises(ValueError, match="silhouette_px"):
        MarkerParams(silhouette_px=0.0)


def _turning_dots():
    """Two views; marker 0 turns sharply at frame 10, after which view 0 lost it (view 1
    holds it), so that an extrapolation is about 17 px off in view 0."""
    cams = _rig(2, spread_deg=20.0)
    T = 16
    t = np.arange(T, dtype=float)
    v = np.where(t[:, None] < 10, [[6.0, 0, 4.0]], [[-40.0, 0, 4.0]])
    X = np.stack([np.array([-150.0, 0, -80]) + np.cumsum(v, axis=0) - v[0],
                  np.array([120.0, 60, 100]) + 6.0 * t[:, None] * [1, 0, 0]], axis=1)
    stacks = _dot_video(cams, X, size=(600, 800))
    truth = [c.project(X.reshape(-1, 3)).reshape(T, 2, 2) for c in cams]
    xy = [a.copy() for a in truth]
    xy[0][10:, 0] = np.nan
    return cams, X, stacks, truth, xy, np.array([[0, 0], [1, 1]])


def test_the_surround_test_keeps_a_dot_and_refuses_a_fold():
    """A bright fold (3 px wide) through the projection passes the peak-over-median floor
    but not ``min_surround``; the real dots are taken either way."""
    cams = _rig(2, spread_deg=20.0)
    T = 16
    X = np.array([[-150.0, 0, -80], [120, 60, 100]])[None] + \
        np.array([6.0, 0, 4.0]) * np.arange(T)[:, None, None]
    stacks = _dot_video(cams, X, size=(600, 800))
    truth = [c.project(X.reshape(-1, 3)).reshape(T, 2, 2) for c in cams]
    xy = [a.copy() for a in truth]
    xy[0][5:9, 0] = np.nan                               # view 0 lost marker 0
    xy[1][11:14, 1] = np.nan                             # view 1 lost marker 1 (its dot there)
    yy, xx = np.mgrid[:600, :800]
    for t in range(5, 9):                                # view 0: its dot gone, a fold there
        x, y = truth[0][t, 0]
        fold = 40 + 180 * np.exp(-((xx - x) ** 2) / (2 * 1.2 ** 2)) * (np.abs(yy - y) < 40)
        stacks[0][t] = np.where(np.hypot(xx - x, yy - y) < 45, fold, stacks[0][t])
    members = np.array([[0, 0], [1, 1]])
    given = [s.copy() for s in stacks]
    _, plain = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0)
    out, strict = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0, min_surround=15.0)
    assert plain[5:9, 0, 0].all()                        # the old floor takes the fold
    assert not strict[5:9, 0, 0].any() and np.isnan(out[0][5:9, 0]).all()
    assert strict[11:14, 1, 1].all() and np.array_equal(strict[11:14], plain[11:14])
    assert all(np.array_equal(a, b) for a, b in zip(stacks, given))
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="min_surround"):
            fill_gaps(stacks, cams, xy, members, min_surround=bad)


def test_a_dot_one_view_holds_is_found_along_the_epipolar_line_only():
    cams, X, stacks, truth, xy, members = _turning_dots()
    given = [a.copy() for a in xy]
    _, near = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0)
    out, line = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0, line_px=48.0)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(xy, given))
    assert not near[10:, 0, 0].any()                     # the projection is too far off
    assert line[10:, 0, 0].all() and line[10, 0, 0] == Filled.LINE   # then near (velocity)
    assert np.linalg.norm(out[0][10:, 0] - truth[0][10:, 0], axis=1).max() < 0.5
    # frame 12 of view 0: its dot moved 10 px across the epipolar line: not taken
    o, d = cams[1].rays(truth[1][12, :1])
    ends = cams[0].project(np.concatenate([o + 2500 * d, o + 3500 * d]))
    u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    off = truth[0][12, 0] + 10.0 * np.array([-u[1], u[0]])
    moved = [s.copy() for s in stacks]
    moved[0][12] = _dot_video(cams[:1], np.array([[X[12, 1], X[12, 1]]]))[0][0]   # only 1
    yy, xx = np.mgrid[:600, :800]
    r2 = (xx - off[0]) ** 2 + (yy - off[1]) ** 2
    moved[0][12] = np.clip(moved[0][12] + 180 * np.exp(-r2 / 12.5) * (r2 < 200), 0, 255)
    _, across = fill_gaps(moved, cams, xy, members, radius=4, max_px=1.0, line_px=48.0)
    assert line[12, 0, 0] and not across[12, 0, 0]
    # a short reach along the line misses the turn's first frame as the plain search does
    _, short = fill_gaps(stacks, cams, xy, members, radius=4, max_px=1.0, line_px=1.0)
    assert not short[10, 0, 0]


def test_fill_gaps_refuses_a_bad_line_reach():
    cams, _, stacks, _, xy, members = _turning_dots()
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ValueError, match="line_px"):
            fill_gaps(stacks, cams, xy, members, line_px=bad)
    for bad in (0.0, -1.0):
        with pytest.raises(ValueError, match="fill_line"):
            MarkerParams(fill_line=bad)
    with pytest.raises((TypeError, ValueError), match="fill_line"):
        MarkerParams(fill_line="wide")
    for bad in (True, False):
        with pytest.raises(TypeError, match="fill_line"):
            MarkerParams(fill_line=bad)
    assert MarkerParams().fill_search() == (12.0, 48.0)
    assert MarkerParams(fill_line=None, fill_search_px=5.0).fill_search() == (5.0, None)


def test_capture_markers_searches_the_line_by_default(monkeypatch):
    """The stage passes the line's reach to the fill: with ``fill_line=None`` the turned
    marker's dots in view 0 stay lost, by default they are found (on the line)."""
    cams, X, stacks, truth, xy, members = _turning_dots()
    tracks = {id(s): a for s, a in zip(stacks, xy)}
    monkeypatch.setattr("lsmta.systems.markers.track_view",
                        lambda s, d, params=None: tracks[id(s)].copy())
    first = [s[0] for s in stacks]
    p = dict(detector="blobs", silhouette=None, min_motion_mm=5.0)
    off = capture_markers(stacks, cams, first, params=MarkerParams(fill_line=None, **p))
    on = capture_markers(stacks, cams, first, params=MarkerParams(**p))
    assert MarkerParams().fill_line is not None
    j = [i for i, m in enumerate(on.members) if m[0] == 0][0]
    assert np.isnan(off.xy[10:, 0, j]).all() and off.joins["filled_line"] == 0
    assert np.linalg.norm(on.xy[10:, 0, j] - truth[0][10:, 0], axis=1).max() < 0.5
    assert on.joins["filled_line"] >= 1 and on.joins["filled"] >= 6


def _line_scene(pred_off=(30.0, 0.0, 20.0)):
    """Two views, a marker view 1 holds at ``held``, a prediction off its ray; returns the
    cameras, the held pixel, the prediction, and the line in view 0 (start ``c`` at the
    prediction moved onto the ray, unit direction ``u``, unit normal ``n``)."""
    cams = _rig(2, spread_deg=20.0)
    X0 = np.array([-40.0, 20.0, 30.0])
    held = cams[1].project(X0[None])[0]
    pred = X0 + np.array(pred_off)
    o, d = cams[1].rays(held[None])
    d = d[0] / np.linalg.norm(d[0])
    on = o[0] + d * np.dot(pred - o[0], d)
    c, c2 = cams[0].project(np.stack([on, on + 50.0 * d]))
    u = (c2 - c) / np.linalg.norm(c2 - c)
    return cams, held, pred, c, u, np.array([-u[1], u[0]])


def _dots_image(points, size=(600, 800)):
    yy, xx = np.mgrid[:size[0], :size[1]]
    img = np.full(size, 40.0)
    for x, y in points:
        r2 = (xx - x) ** 2 + (yy - y) ** 2
        img += 180 * np.exp(-r2 / (2 * 2.5 ** 2)) * (r2 < 200)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_the_line_takes_the_nearest_dot_only_with_a_clear_lead_on_the_line():
    cams, held, pred, c, u, n = _line_scene()

    def dot(points, others=None, max_px=2.0):
        return join_checks._line_dot(cams[0], _dots_image(points), cams[1], held, pred,
                                     np.zeros((0, 2)) if others is None else others, 4, 48.0,
                                     max_px, (15.0, None))

    q = dot([c + 10 * u, c + 25 * u])                     # the next at 2.5 times: taken
    assert q is not None and np.linalg.norm(q - (c + 10 * u)) < 0.5
    assert dot([c + 12 * u, c + 22 * u]) is None          # the next within twice: none
    assert dot([c - 12 * u, c + 22 * u]) is None          # either side of the projection
    # a decoy 5 px across the line, nearer than the dot on it: not taken
    q = dot([c + 5 * u + 5 * n, c + 20 * u])
    assert q is not None and np.linalg.norm(q - (c + 20 * u)) < 0.5
    q = dot([c + 3 * u - 6 * n, c + 20 * u])
    assert q is not None and np.linalg.norm(q - (c + 20 * u)) < 0.5
    # another marker's known dot on the line is set aside before the nearest is chosen
    q = dot([c + 12 * u, c + 22 * u], others=(c + 12 * u)[None])
    assert q is not None and np.linalg.norm(q - (c + 22 * u)) < 0.5
    assert dot([c + 60 * u]) is None                      # beyond the reach


def test_the_marker_stage_tests_its_fills_for_dots_by_default(monkeypatch):
    """``MarkerParams.fill_dot`` (default True) passes the follower's contrast floor to the
    fill as ``min_surround``; False passes None; a non-bool is refused."""
    cams, X, stacks, truth, xy, members = _turning_dots()
    tracks = {id(s): a for s, a in zip(stacks, xy)}
    monkeypatch.setattr("lsmta.systems.markers.track_view",
                        lambda s, d, params=None: tracks[id(s)].copy())
    seen = []

    def spy(*args, **kwargs):
        seen.append(kwargs["min_surround"])
        return fill_gaps(*args, **kwargs)

    monkeypatch.setattr("lsmta.systems.markers.fill_gaps", spy)
    first = [s[0] for s in stacks]
    p = dict(detector="blobs", silhouette=None, min_motion_mm=5.0)
    on = capture_markers(stacks, cams, first, params=MarkerParams(**p))
    capture_markers(stacks, cams, first, params=MarkerParams(fill_dot=False, **p))
    assert MarkerParams().fill_dot is True
    assert seen == [FollowParams().min_contrast, None]
    assert on.joins["filled_line"] >= 1                 # the rendered dots pass the test
    for bad in (1, None, "yes"):
        with pytest.raises(TypeError, match="fill_dot"):
            MarkerParams(fill_dot=bad)


def _patch(img, kind, x, y):
    """Draw a non-dot at (x, y) in place: ``"edge"`` (bright to the right of a vertical
    edge through it) or ``"skin"`` (a bright patch 50 px across, slightly shaded)."""
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    near = np.hypot(xx - x, yy - y) < 25
    if kind == "edge":
        img[near & (xx >= x)] = 200
    else:
        img[near] = np.clip(190 + 0.3 * (xx - x) + 0.2 * (yy - y), 0, 255)[near]


def _dots_and_patches(T=10, skin_frames=()):
    """Three views (two side by side, one above); marker 0 a dot in every view, 1 an edge
    and 2 skin in views 0 and 1, 3 a dot in views 0 and 1 but skin in view 2; marker 0's
    dot in view 0 replaced by skin in ``skin_frames``."""
    cams = _side_by_side_and_above()
    t = np.arange(T)[:, None, None]
    base = np.array([[-200.0, 0, -100], [150, 80, 120], [0, -60, 250], [220, 40, -200]])
    X = base[None] + np.array([8.0, 0, 5.0]) * t
    stacks = _dot_video(cams, X[:, [0, 3]], size=(600, 800))
    xy = [c.project(X.reshape(-1, 3)).reshape(T, 4, 2) for c in cams]
    for k in range(3):
        for f in range(T):
            for j, kind in ((1, "edge"), (2, "skin"), (3, "skin") if k == 2 else (None, None)):
                if j is not None and (k < 2 or j == 3):
                    _patch(stacks[k][f], kind, *xy[k][f, j])
    for f in skin_frames:
        _patch(stacks[0][f], "skin", *xy[0][f, 0])
    members = np.array([[0, 0, 0], [1, 1, -1], [2, 2, -1], [3, 3, 3]])
    return cams, stacks, xy, members


def test_tracks_on_dots_are_kept_and_on_edges_or_skin_taken_out():
    cams, stacks, xy, members = _dots_and_patches()
    given = ([s.copy() for s in stacks], [a.copy() for a in xy], members.copy())
    d = check_dots(stacks, cams, xy, members, radius=4, min_surround=15.0)
    assert np.array_equal(d.members, [[0, 0, 0], [3, 3, -1]])   # skin view of 3 taken out
    assert d.dropped == 2 and d.views_out == 1                  # the edge and the skin
    assert np.allclose(d.shares[0], 1.0) and np.allclose(d.shares[3], [1, 1, 0])
    assert np.allclose(d.shares[1:3, :2], 0.0) and np.isnan(d.shares[1:3, 2]).all()
    assert all(np.array_equal(a, b) for a, b in zip(stacks, given[0]))
    assert all(np.array_equal(a, b) for a, b in zip(xy, given[1]))
    assert np.array_equal(members, given[2])                    # inputs unchanged


def test_a_dot_track_must_be_on_its_dot_in_at_least_the_share_of_its_frames():
    """Marker 0's view 0 on skin in 4 of 10 frames: kept at 0.5; in 6 of 10: taken out (the
    marker keeps its two other views); a lost frame is not counted."""
    cams, stacks, xy, members = _dots_and_patches(skin_frames=range(4))
    d = check_dots(stacks, cams, xy, members)
    assert d.shares[0, 0] == pytest.approx(0.6) and d.members[0, 0] == 0
    assert check_dots(stacks, cams, xy, members, min_share=0.7).members[0, 0] == -1
    cams, stacks, xy, members = _dots_and_patches(skin_frames=range(6))
    d = check_dots(stacks, cams, xy, members)
    assert d.shares[0, 0] == pytest.approx(0.4) and np.array_equal(d.members[0], [-1, 0, 0])
    xy[0][6:8, 0] = np.nan                                     # lost in two dot frames
    assert check_dots(stacks, cams, xy, members).shares[0, 0] == pytest.approx(2 / 8)


def test_check_dots_names_its_bad_input():
    cams, stacks, xy, members = _dots_and_patches(T=3)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="min_share"):
            check_dots(stacks, cams, xy, members, min_share=bad)
    with pytest.raises(ValueError, match="min_surround"):
        check_dots(stacks, cams, xy, members, min_surround=0.0)
    with pytest.raises(ValueError, match="radius"):
        check_dots(stacks, cams, xy, members, radius=0)
    with pytest.raises(ValueError, match="stacks"):
        check_dots(stacks[:2], cams, xy, members)
    with pytest.raises(ValueError, match="stacks"):
        check_dots([s[:2] for s in stacks], cams, xy, members)
    with pytest.raises(ValueError, match="members"):
        check_dots(stacks, cams, xy, members[:, :2])
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="dot_share"):
            MarkerParams(dot_share=bad)


def test_the_marker_stage_drops_a_marker_on_skin_and_counts_it(monkeypatch):
    """``MarkerParams.dot_share`` (default 0.5): the stage drops the skin and edge markers
    and takes out the skin view, counted; None keeps them."""
    cams, stacks, xy, members = _dots_and_patches()
    tracks = {id(s): a for s, a in zip(stacks, xy)}
    monkeypatch.setattr("lsmta.systems.markers.track_view",
                        lambda s, d, params=None: tracks[id(s)].copy())
    monkeypatch.setattr("lsmta.systems.markers.join_view_tracks",
                        lambda *a, **k: SimpleNamespace(members=members.copy()))
    first = [s[0] for s in stacks]
    p = dict(detector="blobs", silhouette=None, min_motion_mm=5.0, max_px=1.0)
    on = capture_markers(stacks, cams, first, params=MarkerParams(**p))
    assert MarkerParams().dot_share == 0.5
    assert on.joins["not_dots"] == 2 and on.joins["not_dot_views"] == 1
    assert np.array_equal(on.members, [[0, 0, 0], [3, 3, -1]])
    off = capture_markers(stacks, cams, first, params=MarkerParams(dot_share=None, **p))
    assert off.joins["not_dots"] == off.joins["not_dot_views"] == 0 and len(off.members) == 4


def _reappearing_dot(decoy_mm=None):
    """Two views; marker 0 moves 8 mm a frame, turning while view 0 cannot see it (frames
    10-23, longer than the fill's ``max_gap``), and shows again in view 0 from frame 24
    (its track there stays lost); view 1 holds it throughout. With ``decoy_mm``, view 0
    shows instead, from frame 24, a dot that far along view 1's ray: on the epipolar line,
    beyond the marker's reach."""
    cams = _rig(2, spread_deg=20.0)
    T = 30
    t = np.arange(T, dtype=float)
    v = np.where(t[:, None] < 10, [[8.0, 0, 0]], [[0.0, 0, 8.0]])
    v = np.where(t[:, None] >= 17, [[-8.0, 0, 0]], v)
    X = np.stack([np.array([-150.0, 0, -80]) + np.cumsum(v, axis=0) - v[0],
                  np.array([120.0, 60, 100]) + 6.0 * t[:, None] * [1, 0, 0]], axis=1)
    stacks = _dot_video(cams, X, size=(600, 800))
    truth = [c.project(X.reshape(-1, 3)).reshape(T, 2, 2) for c in cams]
    shown = X.copy()
    shown[10:24, 0] = X[10:24, 1]                       # view 0: marker 0's dot hidden
    if decoy_mm is not None:
        o, d = cams[1].rays(truth[1][24:, 0])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        shown[24:, 0] = X[24:, 0] + decoy_mm * d
    stacks[0] = _dot_video(cams[:1], shown, size=(600, 800))[0]
    xy = [a.copy() for a in truth]
    xy[0][10:, 0] = np.nan
    return cams, X, stacks, truth, xy, np.array([[0, 0], [1, 1]])


def test_the_reach_search_finds_a_dot_back_after_a_long_gap_and_nothing_beyond_it():
    cams, X, stacks, truth, xy, members = _reappearing_dot()
    given = [a.copy() for a in xy]
    kw = dict(radius=4, max_px=1.0, line_px=48.0, min_surround=15.0)
    _, plain = fill_gaps(stacks, cams, xy, members, **kw)
    out, grown = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(xy, given))
    assert not plain[10:, 0, 0].any()                   # 14 frames on: out of reach
    assert not grown[10:24, 0, 0].any()                 # no dot there: stays empty
    assert grown[24, 0, 0] == Filled.REACH and grown[25:, 0, 0].all()
    assert np.linalg.norm(out[0][24:, 0] - truth[0][24:, 0], axis=1).max() < 0.5
    assert np.array_equal(grown[:, 1], plain[:, 1])     # the held marker untouched
    # a dot on the line 300 mm deeper than the marker: farther than 8 mm x 14 frames
    cams, X, stacks, truth, xy, members = _reappearing_dot(decoy_mm=300.0)
    _, decoy = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert not decoy[:, 0, 0].any()
    # within reach (60 mm along the ray, less than 8 mm x 14) it would be taken: the
    # reach is what refuses it, not the image
    cams, X, stacks, truth, xy, members = _reappearing_dot(decoy_mm=60.0)
    _, near = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert near[24, 0, 0] == Filled.REACH
    with pytest.raises(TypeError, match="grow"):
        fill_gaps(stacks, cams, xy, members, grow="yes")


def test_the_reach_search_keeps_every_fill_the_other_searches_make():
    """A three-view marker intersected in frame 20 only, between gaps of 15 and 14 frames
    (longer than ``max_gap``): view 2's dot there is found near the projection with or
    without the reach search (the reach search only adds)."""
    cams = _rig(3, spread_deg=20.0)
    T = 40
    t = np.arange(T, dtype=float)[:, None]
    X = np.stack([np.array([-150.0, 0, -80]) + t * [6.0, 0, 4.0],
                  np.array([120.0, 60, 100]) + t * [6.0, 0, 0]], axis=1)
    truth = [c.project(X.reshape(-1, 3)).reshape(T, 2, 2) for c in cams]
    shown = X.copy()
    shown[5:35, 0] = X[5:35, 1]                         # views 1, 2: marker 0's dot hidden ...
    shown[20, 0] = X[20, 0]                             # ... but in frame 20
    stacks = [_dot_video(cams[:1], X)[0]] + [_dot_video([c], shown)[0] for c in cams[1:]]
    xy = [a.copy() for a in truth]
    for k in (1, 2):
        xy[k][5:35, 0] = np.nan
    xy[1][20, 0] = truth[1][20, 0]                      # view 1 holds it in frame 20
    members = np.array([[0, 0, 0], [1, 1, 1]])
    kw = dict(radius=4, max_px=1.0, line_px=48.0, min_surround=15.0)
    _, plain = fill_gaps(stacks, cams, xy, members, **kw)
    out, grown = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert plain[20, 2, 0] == Filled.NEAR and grown[20, 2, 0] == Filled.NEAR
    assert np.array_equal(grown[plain > 0], plain[plain > 0])
    assert np.linalg.norm(out[2][20, 0] - truth[2][20, 0]) < 0.5


def _edge_of_reach(mm):
    """The reappearing dot's scene with view 0 showing, in frame 24 only, a dot on view 1's
    ray ``mm`` from the marker's last intersected point (frame 9): 15 frames of its fastest
    step (8 mm) make a reach of 120 mm."""
    cams, X, stacks, truth, xy, members = _reappearing_dot()
    o, d = cams[1].rays(truth[1][24, :1])
    o, d = o[0], d[0] / np.linalg.norm(d[0])
    s0 = float(np.dot(X[9, 0] - o, d))
    p2 = float(np.sum((X[9, 0] - o - s0 * d) ** 2))
    P = o + d * (s0 + np.sqrt(mm ** 2 - p2))
    shown = X.copy()
    shown[10:, 0] = X[10:, 1]                           # view 0: marker 0's dot hidden ...
    shown[24, 0] = P                                    # ... but this one in frame 24
    stacks[0] = _dot_video(cams[:1], shown, size=(600, 800))[0]
    return cams, stacks, xy, members, cams[0].project(P[None])[0]


def test_the_reach_is_the_fastest_step_times_the_frames_since_the_last_point():
    kw = dict(radius=4, max_px=1.0, line_px=48.0, min_surround=15.0, grow=True)
    cams, stacks, xy, members, q = _edge_of_reach(116.0)      # 14 steps would miss it
    assert 20 < q[0] < 780 and 20 < q[1] < 580
    out, inside = fill_gaps(stacks, cams, xy, members, **kw)
    assert inside[24, 0, 0] == Filled.REACH and np.linalg.norm(out[0][24, 0] - q) < 0.5
    assert not inside[:24, 0, 0].any() and not inside[25:, 0, 0].any()
    # 4 mm beyond the reach (16 steps would take it): its dot lies in the searched disc
    # (1 px beyond the projected piece's end, the disc reaches 4 px beyond), the point
    # intersected with it is refused as out of reach
    cams, stacks, xy, members, q = _edge_of_reach(124.0)
    _, beyond = fill_gaps(stacks, cams, xy, members, **kw)
    assert not beyond[:, 0, 0].any()


def test_the_reach_search_finds_a_dot_in_the_backward_pass():
    """The reappearing dot's scene played backwards: the marker is intersected only after
    its gap, so only the backward pass can reach its dot (frame 5, 15 frames before)."""
    cams, X, stacks, truth, xy, members = _reappearing_dot()
    stacks = [s[::-1].copy() for s in stacks]
    xy = [a[::-1].copy() for a in xy]
    truth = [a[::-1] for a in truth]
    kw = dict(radius=4, max_px=1.0, line_px=48.0, min_surround=15.0)
    _, plain = fill_gaps(stacks, cams, xy, members, **kw)
    out, grown = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert not plain[:20, 0, 0].any()
    assert grown[5, 0, 0] == Filled.REACH and grown[:5, 0, 0].all()
    assert not grown[6:20, 0, 0].any()
    assert np.linalg.norm(out[0][:6, 0] - truth[0][:6, 0], axis=1).max() < 0.5


def test_the_reach_search_needs_the_line():
    """``grow`` without ``line_px`` searches nothing more (as documented)."""
    cams, X, stacks, truth, xy, members = _reappearing_dot()
    kw = dict(radius=4, max_px=1.0, min_surround=15.0)
    _, plain = fill_gaps(stacks, cams, xy, members, **kw)
    _, grown = fill_gaps(stacks, cams, xy, members, grow=True, **kw)
    assert np.array_equal(plain, grown) and not (grown == Filled.REACH).any()


def test_the_piece_of_a_ray_within_a_ball_stops_at_the_camera():
    cam = _rig(2, spread_deg=20.0)[0]
    xy = np.array([400.0, 300.0])                       # the principal point: the axis
    o, d = cam.rays(xy[None])
    o, d = o[0], d[0] / np.linalg.norm(d[0])
    ends = join_checks.ray_piece(cam, xy, o + 3000 * d + [0, 0, 30.0], 50.0)
    assert np.allclose(np.linalg.norm(ends - (o + 3000 * d), axis=1), 40.0)
    near = join_checks.ray_piece(cam, xy, o + 100 * d, 300.0)   # the ball holds the camera
    assert np.allclose(near, [o, o + 400 * d])
    assert join_checks.ray_piece(cam, xy, o + 3000 * d + [0, 0, 60.0], 50.0) is None
    assert join_checks.ray_piece(cam, xy, o - 500 * d, 300.0) is None   # behind it
    with pytest.raises(ValueError, match="r:"):
        join_checks.ray_piece(cam, xy, o, -1.0)
    with pytest.raises(ValueError, match="centre"):
        join_checks.ray_piece(cam, xy, o[:2], 1.0)


def test_marker_speeds_are_the_fastest_step_of_each_marker():
    t = np.arange(6, dtype=float)[:, None]
    X = np.stack([t * [3.0, 4.0, 0.0], t * [1.0, 0, 0] + [0, 0, 5.0]], axis=1)   # 5, 1 mm
    X[3, 1] = [5.0, 0, 5.0]                             # a step of 3 mm, from frame 2
    X[:, 1][[4]] = np.nan                               # frames 3-5 held only 3 and 5
    speeds = join_checks.marker_speeds(X)
    assert np.allclose(speeds, [5.0, 3.0])
    assert np.isnan(join_checks.marker_speeds(np.full((4, 1, 3), np.nan))).all()
    assert np.isnan(join_checks.marker_speeds(X[:1])).all()
    given = X.copy()
    join_checks.marker_speeds(X)
    assert np.array_equal(X, given, equal_nan=True)
    with pytest.raises(ValueError, match="xyz"):
        join_checks.marker_speeds(X[..., :2])


def test_the_marker_stage_searches_the_reach_by_default(monkeypatch):
    cams, X, stacks, truth, xy, members = _reappearing_dot()
    tracks = {id(s): a for s, a in zip(stacks, xy)}
    monkeypatch.setattr("lsmta.systems.markers.track_view",
                        lambda s, d, params=None: tracks[id(s)].copy())
    first = [s[0] for s in stacks]
    p = dict(detector="blobs", silhouette=None, min_motion_mm=5.0, min_shared=0.3)
    off = capture_markers(stacks, cams, first, params=MarkerParams(fill_reach=False, **p))
    on = capture_markers(stacks, cams, first, params=MarkerParams(**p))
    assert MarkerParams().fill_reach and off.joins["filled_reach"] == 0
    assert on.joins["filled_reach"] >= 1 and on.joins["filled"] >= off.joins["filled"] + 6
    with pytest.raises(TypeError, match="fill_reach"):
        MarkerParams(fill_reach=1)
