"""Least squares matching of tie points on wide-baseline views of a still scene: a still
feature found in several frames is matched once (``groups`` of refine_tie_points), so its
frames agree and a frame whose own match fails takes the feature's best match."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from lsmta.calibration import TiePoints, refine_tie_points
from lsmta.camera import Camera
from lsmta.matching import Status
from lsmta.systems import RigRefinementParams
from lsmta.systems.refinement import _places


def _rig():
    """Three cameras 35 degrees apart (the outer two 70)."""
    cams = []
    for a in np.deg2rad([-35.0, 0.0, 35.0]):
        eye = np.array([3000 * np.sin(a), -3000 * np.cos(a), 1400.0])
        cams.append(Camera.look_at(eye, (0, 400, 700), f=560.0, width=640, height=480,
                                   name=f"cam{len(cams) + 1:02d}").replace(k1=-0.08, k2=0.05))
    return cams


def _surface(cam, xy):
    """Where the rays of ``cam`` through ``xy`` (n, 2) meet the floor (z = 0) or the wall
    (y = 1500), mm."""
    o, d = cam.rays(xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
        t_wall = np.where(d[:, 1] > 0, (1500 - o[:, 1]) / d[:, 1], np.inf)
    return o + np.minimum(t_floor, t_wall)[:, None] * d


def _render(cam, floor_tex, wall_tex):
    P = _surface(cam, cam.pixel_grid().reshape(-1, 2))
    on_wall = np.abs(P[:, 1] - 1500) < 1e-6
    u = (P[:, 0] / 4 + 512).reshape(cam.height, cam.width).astype(np.float32)
    v = (np.where(on_wall, P[:, 2], P[:, 1]) / 4 + 512).reshape(u.shape).astype(np.float32)
    floor, wall = (cv2.remap(t, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
                   for t in (floor_tex, wall_tex))
    return np.where(on_wall.reshape(u.shape), wall, floor).astype(np.float32)


def _texture(rng, size=1024):
    t = cv2.GaussianBlur(rng.uniform(0, 255, (size, size)), (0, 0), 2.0)
    return cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX).astype(np.float32)


@pytest.fixture(scope="module")
def still_scene():
    """A still scene in three frames (each with its own image noise, 2 grey levels) and its
    features found again in every frame, each frame's keypoints a pixel or so off in every
    view (F = 3 frames, n features: 3 n tie points; feature j is tie point j of each frame)."""
    rng = np.random.default_rng(49)
    cams = _rig()
    floor, wall = _texture(rng), _texture(rng)
    clean = [_render(c, floor, wall) for c in cams]
    F = 3
    frames = [[np.clip(g + rng.normal(0, 2.0, g.shape), 0, 255).astype(np.uint8)
               for g in clean] for _ in range(F)]
    X = np.c_[rng.uniform(-900, 900, 90), rng.uniform(0, 1300, 90), np.zeros(90)]
    X[45:, 1], X[45:, 2] = 1500.0, rng.uniform(100, 1500, 45)          # half on the wall
    true = np.stack([c.project(X) for c in cams])
    inside = np.all((true > 25) & (true < [cams[0].width - 26, cams[0].height - 26]),
                    axis=(0, 2))
    true = true[:, inside]
    n = true.shape[1]
    raw = np.concatenate([true + rng.uniform(-0.7, 0.7, true.shape) for _ in range(F)], axis=1)
    frame = np.repeat(np.arange(F), n)
    return cams, frames, raw, frame, n


def _tie(raw, frame):
    K = raw.shape[0]
    return TiePoints(xy=raw, frame=frame, pair_matches=np.zeros((K, K), int),
                     pair_guided=np.zeros((K, K), int))


def test_a_still_feature_is_matched_once_over_its_frames(still_scene):
    cams, frames, raw, frame, n = still_scene
    groups = np.tile(np.arange(n), 3)
    _, first = refine_tie_points(frames, _tie(raw, frame), cams, groups=groups)
    raw = raw.copy()
    bad = np.arange(0, n, 4)           # in frame 1 these start 6 px off in the matched views
    matched = np.arange(len(cams))[:, None] != first.template[n + bad][None]
    raw[:, n + bad] += np.where(matched[..., None], [6.0, -5.0], 0.0)
    tie = _tie(raw, frame)
    keep = raw.copy()
    _, info_alone = refine_tie_points(frames, tie, cams)
    once, info = refine_tie_points(frames, tie, cams, groups=groups)
    assert np.array_equal(tie.xy, keep, equal_nan=True)                   # not modified
    # alone: most of frame 1's bad starts fail (no view of theirs left but the template)
    assert np.isin(n + bad, np.flatnonzero(info_alone.kept)).mean() < 0.5
    # once: one template view and position per feature, every frame at the feature's best
    # match; the bad starts take it
    t = info.template.reshape(3, n)
    assert (t == t[0]).all()
    assert info.kept.all() and info.dropped_points == 0
    xy = once.xy.reshape(len(cams), 3, n, 2)
    ok = np.isfinite(xy[..., 0]).all(axis=1)
    assert ok.mean() > 0.8
    same = np.broadcast_to(xy[:, :1], xy.shape)
    np.testing.assert_array_equal(np.where(ok[:, None, :, None], xy, 0.0),
                                  np.where(ok[:, None, :, None], same, 0.0))
    assert info.shared >= len(bad) and info.summary()["shared"] == info.shared
    # truth: where the template's pixel's surface point lies in each view
    err = []
    for j in range(n):
        P = _surface(cams[t[0, j]], xy[t[0, j], 0, j][None])
        err += [np.linalg.norm(xy[k, 0, j] - cams[k].project(P)[0])
                for k in range(len(cams)) if k != t[0, j] and ok[k, j]]
    assert np.median(err) < 0.1, np.median(err)
    # and they form one still place each (found in three frames), but where two features lie
    # within place_px of each other (a chain, split into its points)
    labels = _places(once.xy, 2.0, once.frame).reshape(3, n)
    assert (labels == labels[0]).all(axis=0).mean() > 0.9
    # the counts: most bad starts still failed as matches of their own, and count as failed
    st = info.status[:, n + bad]
    failed_bad = (st >= 0) & (st != Status.CONVERGED)
    assert failed_bad.sum() > 0.5 * (st >= 0).sum() and info.failed >= failed_bad.sum()


def test_tie_points_alone_are_matched_as_without_groups(still_scene):
    cams, frames, raw, frame, n = still_scene
    tie = _tie(raw[:, :n], frame[:n])
    a, ia = refine_tie_points(frames[:1], tie, cams)
    b, ib = refine_tie_points(frames[:1], tie, cams, groups=np.arange(n))
    np.testing.assert_array_equal(a.xy, b.xy)
    assert ib.shared == 0 and np.array_equal(ia.status, ib.status)


def test_groups_are_checked(still_scene):
    cams, frames, raw, frame, n = still_scene
    tie = _tie(raw, frame)
    with pytest.raises(ValueError, match="groups: expected .* labels"):
        refine_tie_points(frames, tie, cams, groups=np.arange(n))
    with pytest.raises(ValueError, match="groups: expected .* labels"):
        refine_tie_points(frames, tie, cams, groups=np.linspace(0, 1, 3 * n))
    same_frame = np.zeros(3 * n, int)                     # one label twice in a frame
    with pytest.raises(ValueError, match="at most once per frame"):
        refine_tie_points(frames, tie, cams, groups=same_frame)
    with pytest.raises(TypeError, match="lsm_still_once"):
        RigRefinementParams(lsm_still_once=1)
    assert RigRefinementParams().lsm_still_once is False      # an option, off by default
    assert replace(RigRefinementParams(), lsm_still_once=True).lsm_still_once is True


def test_a_larger_patch_takes_over_where_the_patch_holds_no_texture():
    """A point in the middle of a flat disc of radius 16 px in a textured scene: the 21-px
    patch sees no texture and fails; the 41-px patch takes in the texture around it and
    finds the shift the images were made with."""
    from lsmta.calibration.tie_lsm import Start, TieLSMParams, _grown
    from lsmta.matching.spline import SplineImage

    rng = np.random.default_rng(5)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (200, 200)), (0, 0), 2.0)
    yy, xx = np.mgrid[0:200, 0:200].astype(float)
    flat = np.hypot(xx - 100.0, yy - 100.0) < 16.0
    base = np.where(flat, 128.0, 60.0 + 4.0 * (tex - tex.mean()))
    shift = np.array([0.4, -0.7])
    moved = cv2.warpAffine(base, np.float64([[1, 0, shift[0]], [0, 1, shift[1]]]), (200, 200),
                           flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    t_img, s_img = SplineImage(base, "t"), SplineImage(moved, "s")
    t_xy = np.array([[100.0, 100.0]])
    starts = {Start.IDENTITY: (np.eye(2)[None], np.ones(1, bool))}
    small = TieLSMParams(larger_patches=())
    r, _ = _grown(t_img, s_img, t_xy, t_xy.copy(), starts, small.lsm_params(), ())
    assert r.status[0] != Status.CONVERGED
    assert TieLSMParams().larger_patches == ()                # an option, off by default
    grown = TieLSMParams(larger_patches=(41, 61))
    r, _ = _grown(t_img, s_img, t_xy, t_xy.copy(), starts, grown.lsm_params(),
                  grown.larger_patches)
    assert r.status[0] == Status.CONVERGED
    np.testing.assert_allclose(r.xy[0], t_xy[0] + shift, atol=0.05)
    with pytest.raises(ValueError, match="larger_patches"):
        TieLSMParams(larger_patches=(21,))
    with pytest.raises(ValueError, match="larger_patches"):
        TieLSMParams(larger_patches=(40,))
    with pytest.raises(TypeError, match="larger_patches"):
        TieLSMParams(larger_patches=[41])
