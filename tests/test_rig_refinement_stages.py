"""The stages of a rig's refinement from its own recording, each on its own: the adjustment
with the given cameras as priors, tie points found guided by the cameras, and tie points
refined by least squares matching (tests/test_rig_refinement.py: the whole, from video files)."""

import numpy as np
import pytest

from conftest import disturbed, random_texture, render_room, rig_cameras
from lsmta.calibration import (
    RefineParams,
    TieLSMParams,
    TieParams,
    TiePoints,
    find_tie_points,
    refine_cameras,
    refine_tie_points,
)
from lsmta.calibration.tie_lsm import HEAD_ON_MARGIN
from lsmta.camera import Camera
from lsmta.matching import Status
from lsmta.systems import RigRefinementParams
from lsmta.triangulation import triangulate


# ------------------------------------------ the adjustment (refine_cameras)
def test_refined_residuals_come_back_to_the_noise(rng):
    cams = rig_cameras()
    X = rng.uniform([-1200, -200, 0], [1200, 1200, 1800], (1200, 3))
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.3, (len(cams), 1200, 2))
    for k, c in enumerate(cams):
        xy[k, ~c.in_image(xy[k]) | (rng.uniform(size=1200) < 0.3)] = np.nan
    xy[0, :30] += rng.uniform(8, 20, (30, 2))                     # gross errors
    given = disturbed(cams, rng)
    keep = xy.copy()
    r = refine_cameras(given, xy)
    assert np.array_equal(xy, keep, equal_nan=True)
    before, after = r.median_residual(before=True), r.median_residual()
    assert (before > 1.5).all(), before
    # 0.3 px per coordinate: a 2-D residual of median ~0.35 px, less the adjusted share
    assert (after < 0.4).all(), after
    assert r.used[0, :30].sum() <= 3                            # gross errors dropped
    assert r.used[0, 30:][np.isfinite(xy[0, 30:, 0])].mean() > 0.97
    # closer to the truth than the file in principal distance and cx (cy trades with the
    # cameras' tilt in this rig, and the priors hold the datum, so neither is comparable)
    for name in ("f", "cx"):
        was = np.abs([getattr(g, name) - getattr(t, name) for g, t in zip(given, cams)])
        now = np.abs([getattr(c, name) - getattr(t, name) for c, t in zip(r.cameras, cams)])
        assert now.mean() < 0.5 * was.mean(), (name, was, now)
    # what a user needs: points that took no part agree with the refined cameras
    Y = rng.uniform([-1000, 0, 100], [1000, 1000, 1700], (300, 3))
    y = np.stack([c.project(Y) for c in cams]) + rng.normal(0, 0.3, (len(cams), 300, 2))
    for rig, limit in ((given, None), (r.cameras, 0.45)):
        err = np.nanmedian(triangulate(list(rig), y).reprojection_error, axis=1)
        assert (err > 1.0).all() if limit is None else (err < limit).all(), err


def test_intrinsics_are_held_where_the_data_does_not_determine_them(rng):
    cams = rig_cameras(n=2)
    # a few points near the image centre say nothing about the distortion
    X = rng.uniform([-150, 300, 600], [150, 500, 800], (40, 3))
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.3, (2, 40, 2))
    r = refine_cameras(cams, xy, params=RefineParams(information_ratio=0.5))
    assert all("k1" not in names for names in r.freed), r.freed
    assert r.ratios.shape == (2, 4) and r.ratio_names == ("cx", "cy", "k1", "k2")


# ---------------------------------------------- tie points (find_tie_points)
def test_tie_points_need_one_image_per_camera():
    cams = rig_cameras(n=2, width=64, height=48)
    with pytest.raises(ValueError, match="frame 0 holds 1 images"):
        find_tie_points([[np.zeros((48, 64), np.uint8)]], cams)
    with pytest.raises(ValueError, match="image 1 of frame 0"):
        find_tie_points([[np.zeros((48, 64), np.uint8), np.zeros((40, 64), np.uint8)]], cams)


def test_a_twin_of_the_best_candidate_is_not_its_rival():
    """A place found twice (two orientations, or two of ASIFT's tilts) holds two features
    with nearly the same descriptor. The ratio test compares the best candidate with the
    best one elsewhere, so the twin does not reject the match; a rival elsewhere does."""
    from lsmta.calibration.tie_points import _nearest_in_band

    rng = np.random.default_rng(3)
    desc = rng.integers(0, 100, (4, 128)).astype(np.uint8)          # SIFT's: bytes
    da = desc[:1]
    twin = da[0] + np.r_[np.full(20, 2), np.ones(108)].astype(np.uint8)   # squared 188
    db = np.stack([da[0] + 1, twin, desc[1], desc[2]])                  # the best: 128
    xb = np.array([[100.0, 50.0], [100.6, 50.3], [300.0, 50.0], [np.nan, np.nan]])
    line = np.array([[0.0, 1.0, -50.0]])                    # y = 50: every candidate in the band
    for distinct, passes in ((2.0, True), (0.0, False)):
        best, d1, d2 = _nearest_in_band(line, xb, da, db, 5.0, distinct)
        assert best[0] == 0
        assert (np.sqrt(d1[0]) < 0.8 * np.sqrt(d2[0])) == passes, (distinct, d1, d2)
    db[2] = twin                                             # a true rival 200 px away
    best, d1, d2 = _nearest_in_band(line, xb, da, db, 5.0, 2.0)
    assert not np.sqrt(d1[0]) < 0.8 * np.sqrt(d2[0])


def test_asift_ties_views_far_apart_where_sift_does_not(rng):
    """Two cameras 90 degrees apart around a textured floor (and wall), each looking down at
    36 degrees: the floor is foreshortened differently in each view, beyond what SIFT's
    descriptors follow; ASIFT's simulated tilts bring the views together. The tie points
    found must agree with the true cameras (a wrong match would not)."""
    floor = random_texture(rng)
    cams = [Camera.look_at((2200 * np.cos(a), 2200 * np.sin(a), 1600.0), (0, 0, 0), f=500.0,
                           width=480, height=360, name=f"c{k}")
            for k, a in enumerate(np.deg2rad([0.0, 90.0]))]
    images = [[render_room(c, floor, floor, 0) for c in cams]]
    found = {}
    for detector in ("sift", "asift"):
        tie = find_tie_points(images, cams, params=TieParams(detector=detector))
        found[detector] = tie.xy.shape[1]
        if tie.xy.shape[1]:
            err = triangulate(cams, tie.xy).reprojection_error
            assert np.nanmedian(err) < 0.5, (detector, np.nanmedian(err))
    assert found["asift"] >= 50 and found["asift"] > 3 * found["sift"], found
    auto = TieParams()                                       # 90 degrees apart: ASIFT
    assert find_tie_points(images, cams, params=auto).xy.shape[1] == found["asift"]



def test_band_search_visits_every_feature_in_the_band():
    """The cell walk gives what testing every feature against every line gives: the nearest
    in the band (lowest index among equals) and the nearest farther than ``distinct``."""
    from lsmta.calibration.tie_points import _nearest_in_band

    rng = np.random.default_rng(11)
    na, nb_, band, distinct = 150, 200, 20.0, 2.0
    da = rng.integers(0, 30, (na, 16)).astype(np.uint8)             # many equal distances
    db = rng.integers(0, 30, (nb_, 16)).astype(np.uint8)
    xb = rng.uniform(-300, 300, (nb_, 2))
    xb[::17] = np.nan
    ang = rng.uniform(0, 2 * np.pi, na)
    lines = np.c_[np.cos(ang), np.sin(ang), rng.uniform(-300, 300, na)]
    lines[::10, :2] = (1.0, 0.0)                                      # vertical and horizontal
    lines[1::10, :2] = (0.0, -1.0)
    best, d1, d2 = _nearest_in_band(lines, xb, da, db, band, distinct)
    with np.errstate(invalid="ignore"):
        inside = np.abs(lines @ np.c_[xb, np.ones(nb_)].T) < band     # (na, nb)
    dist = ((da[:, None].astype(int) - db[None]) ** 2).sum(axis=2)
    for i in range(na):
        d = np.where(inside[i], dist[i], np.inf)
        if not inside[i].any():
            assert best[i] == -1 and np.isinf(d1[i])
            continue
        assert best[i] == int(np.argmin(d)) and d1[i] == d.min()
        far = np.hypot(*(xb - xb[best[i]]).T) > distinct
        assert d2[i] == np.where(far, d, np.inf).min()
    assert (best >= 0).sum() > na / 2


def test_descriptors_must_be_bytes_to_be_matched_exactly():
    """SIFT's descriptors are whole numbers in 0..255 (OpenCV rounds them): they are matched
    as bytes, exactly; anything else is refused rather than rounded."""
    from lsmta.calibration.tie_points import _bytes

    des = np.array([[0.0, 17.0, 255.0]], np.float32)
    assert _bytes(des).dtype == np.uint8 and np.array_equal(_bytes(des), des)
    for bad in ([[0.5, 1.0]], [[-1.0, 3.0]], [[256.0, 0.0]]):
        with pytest.raises(ValueError, match="whole numbers in 0..255"):
            _bytes(np.array(bad, np.float32))


# ------------------------------ least squares matching (refine_tie_points)
def _surface_point(cam, xy):
    """Where the rays of ``cam`` through ``xy`` meet the floor (z = 0) or the wall
    (y = 1500) of ``conftest.render_room``."""
    o, d = cam.rays(xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
        t_wall = np.where(d[:, 1] > 0, (1500 - o[:, 1]) / d[:, 1], np.inf)
    return o + np.minimum(t_floor, t_wall)[:, None] * d


@pytest.fixture(scope="module")
def lsm_scene():
    rng = np.random.default_rng(48)
    cams = rig_cameras(n=3)
    floor, wall = random_texture(rng), random_texture(rng)
    images = [render_room(c, floor, wall, 0) for c in cams]
    X = np.c_[rng.uniform(-900, 900, 160), rng.uniform(0, 1300, 160), np.zeros(160)]
    X[80:, 1], X[80:, 2] = 1500.0, rng.uniform(100, 1500, 80)          # half on the wall
    true = np.stack([c.project(X) for c in cams])
    inside = np.all((true > 20) & (true < [cams[0].width - 21, cams[0].height - 21]), axis=(0, 2))
    true = true[:, inside]
    raw = true + rng.uniform(-1.2, 1.2, true.shape)       # keypoints a pixel or so off
    return cams, images, raw


def test_lsm_moves_tie_points_to_the_template_patch_and_drops_failures(lsm_scene):
    cams, images, raw = lsm_scene
    K, N, _ = raw.shape
    raw = raw.copy()
    raw[1, :3] = [5.0, 5.0]                # the patch leaves view 1: that view fails ...
    raw[1:, 3] = [5.0, 5.0]                # ... and a point left with one view is dropped
    tie = TiePoints(xy=raw, frame=np.zeros(N, int), pair_matches=np.zeros((K, K), int),
                    pair_guided=np.zeros((K, K), int))
    images_in = [g.copy() for g in images]
    out, info = refine_tie_points([images], tie, cams)
    assert all(np.array_equal(g, k) for g, k in zip(images, images_in))     # not modified
    assert np.array_equal(tie.xy, raw, equal_nan=True)
    # the template is the view that sees the surface most nearly head-on (truth: the floor's
    # or the wall's normal) where it clearly does, else the view nearest the mean ray; its
    # position stays; every other view is matched to it
    t = info.template
    P = _surface_point(cams[0], raw[0])
    normal = np.where((np.abs(P[:, 2]) < 1e-6)[:, None], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])
    rays = np.stack([(P - c.C) / np.linalg.norm(P - c.C, axis=1, keepdims=True) for c in cams])
    near_mean = np.argmax(np.einsum("knd,nd->kn", rays, rays.sum(axis=0)), axis=0)
    cos = np.einsum("nd,knd->kn", normal, -rays)
    clear = cos.max(axis=0) >= cos[near_mean, np.arange(N)] + HEAD_ON_MARGIN
    want = np.where(clear, cos.argmax(axis=0), near_mean)
    assert 5 <= clear.sum() < N                          # both rules are at work here
    assert (t == want)[4:].mean() > 0.8, (t == want).mean()
    ok = info.status == Status.CONVERGED
    matched = info.status >= 0
    assert info.matched == int(matched.sum()) == N * (K - 1)
    assert info.failed == int((matched & ~ok).sum()) >= 3
    assert not ok[1, :4].any() and info.dropped_points == int((~info.kept).sum()) >= 1
    assert not info.kept[3] and out.xy.shape[1] == info.kept.sum()
    np.testing.assert_array_equal(out.xy[t[info.kept], np.arange(out.xy.shape[1])],
                                  raw[t[info.kept], np.flatnonzero(info.kept)])
    # truth: where the template's pixel's surface point lies in each view
    err_raw, err_lsm = [], []
    for j in np.flatnonzero(info.kept):
        P = _surface_point(cams[t[j]], raw[t[j], j][None])
        for k in range(K):
            if k != t[j] and ok[k, j]:
                want = cams[k].project(P)[0]
                err_raw.append(np.linalg.norm(raw[k, j] - want))
                err_lsm.append(np.linalg.norm(out.xy[k, np.sum(info.kept[:j])] - want))
    assert len(err_lsm) > 0.8 * 2 * N
    assert np.median(err_raw) > 0.8, np.median(err_raw)
    assert np.median(err_lsm) < 0.1 * np.median(err_raw), (np.median(err_raw),
                                                             np.median(err_lsm))
    assert info.summary()["failed"] == info.failed


def test_tie_lsm_settings_are_checked():
    with pytest.raises(ValueError, match="patch"):
        TieLSMParams(patch=20)
    with pytest.raises(ValueError, match="max_scale"):
        TieLSMParams(max_scale=1.0)
    with pytest.raises(ValueError, match="max_shift_px"):
        TieLSMParams(max_shift_px=0)
    with pytest.raises(TypeError, match="lsm"):
        RigRefinementParams(lsm=1)
    with pytest.raises(TypeError, match="tie_lsm"):
        RigRefinementParams(tie_lsm=None)


def test_the_plane_start_is_the_local_affine_map_between_wide_views(lsm_scene):
    from lsmta.calibration.tie_lsm import Start, _plane_starts
    cams, images, raw = lsm_scene
    P = _surface_point(cams[0], raw[0])                       # on the floor or the wall
    normal = np.where((np.abs(P[:, 2]) < 1e-6)[:, None], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])
    A, taken = _plane_starts(cams[0], cams[2], raw[0], P, normal, 10, 3.0)   # 70 deg apart
    assert taken.mean() > 0.7
    # where a pixel 8 px off the point lies in the other view: the map predicts it
    d = np.array([6.0, -5.0])
    want = cams[2].project(_surface_point(cams[0], raw[0] + d)) - cams[2].project(P)
    err = np.linalg.norm(np.einsum("nij,j->ni", A, d) - want, axis=1)[taken]
    err_identity = np.linalg.norm(d - want, axis=1)[taken]
    assert np.median(err) < 0.1 * np.median(err_identity), (np.median(err),
                                                             np.median(err_identity))
    # a point near where the template's lens model folds: no start there, and no error
    c = cams[0]
    folded = c.replace(k1=0.0, k2=-1.0 / (5 * 0.5 ** 4))   # no distorted radius beyond 0.4
    at = np.array([[c.cx + c.f * 0.4 - 4.0, c.cy]])            # invertible; +10 px is not
    assert folded.invertible(at).all() and not folded.invertible(at + [10.0, 0.0]).any()
    A1, taken1 = _plane_starts(folded, cams[2], at, P[:1], normal[:1], 10, 3.0)
    assert not taken1.any() and np.array_equal(A1[0], np.eye(2))
    # in refine_tie_points: some kept matches started from it; without it, none
    K, N, _ = raw.shape
    tie = TiePoints(xy=raw, frame=np.zeros(N, int), pair_matches=np.zeros((K, K), int),
                    pair_guided=np.zeros((K, K), int))
    _, on = refine_tie_points([images], tie, cams)
    _, off = refine_tie_points([images], tie, cams, params=TieLSMParams(plane_start=False))
    ok_on = on.status == Status.CONVERGED
    assert (on.start[ok_on] == Start.PLANE).sum() > 0.1 * ok_on.sum()
    assert not (off.start == Start.PLANE).any()
    assert on.summary()["starts"]["plane"] == int((on.start == Start.PLANE).sum())
    with pytest.raises(TypeError, match="plane_start"):
        TieLSMParams(plane_start=1)


def test_refine_tie_points_checks_its_arguments(lsm_scene):
    cams, images, raw = lsm_scene
    K, N, _ = raw.shape

    def tie(frame):
        return TiePoints(xy=raw, frame=frame, pair_matches=np.zeros((K, K), int),
                         pair_guided=np.zeros((K, K), int))

    with pytest.raises(ValueError, match="tie.frame"):
        refine_tie_points([images], tie(np.full(N, -1)), cams)
    with pytest.raises(ValueError, match="tie.frame"):
        refine_tie_points([images], tie(np.zeros(N - 1, int)), cams)
    with pytest.raises(TypeError, match="params"):
        refine_tie_points([images], tie(np.zeros(N, int)), cams, params=RigRefinementParams())
    with pytest.raises(ValueError, match="frames: image 1 of frame 0"):
        refine_tie_points([[images[0], images[1][:-2], images[2]]], tie(np.zeros(N, int)), cams)


def test_tie_points_under_a_build_read_their_features_back(rng, monkeypatch, tmp_path):
    """Under ``lsmta reproduce`` a frame's features are kept for the next notebook: the same
    frames give the same tie points, to the bit, from the kept features (one file per
    image), which are read (emptied, they give no tie points); other settings are other
    features."""
    from lsmta.build_cache import CACHE_ENV
    cams = rig_cameras(n=2)
    floor, wall = random_texture(rng), random_texture(rng)
    images = [[render_room(c, floor, wall, 0) for c in cams]]
    monkeypatch.delenv(CACHE_ENV, raising=False)
    plain = find_tie_points(images, cams, params=TieParams(detector="sift"))
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    kept = [find_tie_points(images, cams, params=TieParams(detector="sift")) for _ in range(2)]
    files = sorted((tmp_path / "tie_features").glob("*.npz"))
    assert len(files) == 2 and plain.xy.shape[1] > 0
    for t in kept:
        for name in ("xy", "frame", "pair_matches", "pair_guided"):
            assert np.array_equal(getattr(t, name), getattr(plain, name), equal_nan=True)
    for f in files:
        np.savez(f, xy=np.zeros((0, 2)), des=np.zeros((0, 128), np.uint8))
    assert find_tie_points(images, cams, params=TieParams(detector="sift")).xy.shape[1] == 0
    find_tie_points(images, cams, params=TieParams(detector="sift", n_features=500))
    assert len(list((tmp_path / "tie_features").glob("*.npz"))) == 4


def test_a_pair_matches_of_all_frames_agree_with_one_geometry(rng):
    """The cameras do not move during a recording: a pair's matches of every frame are
    checked against one essential matrix fitted to them all. A wrong match (8 px off its
    epipolar line) is dropped, the true ones kept; a pair matched in one frame only is left
    as it is."""
    from lsmta.calibration.tie_points import _one_geometry
    cams = rig_cameras(n=3)
    found = []
    for t in range(3):
        X = rng.uniform([-800, 0, 200], [800, 1000, 1500], (40, 3))
        feats = []
        for c in cams:
            xy = c.project(X) + rng.normal(0, 0.2, (40, 2))
            feats.append((xy, np.zeros((40, 128), np.uint8)))
        feats[1][0][5] += [6.0, -6.0]                             # frame t's wrong match
        m = np.c_[np.arange(40), np.arange(40)]
        matches = {(0, 1): m.copy()}
        if t == 0:
            matches[(0, 2)] = m.copy()
        found.append((feats, matches))
    out = _one_geometry(found, cams, TieParams())
    for t, (_, matches) in enumerate(out):
        kept = set(matches[0, 1][:, 0].tolist())
        assert 5 not in kept and len(kept) >= 37, (t, sorted(set(range(40)) - kept))
    assert np.array_equal(out[0][1][0, 2], found[0][1][0, 2])
    assert np.array_equal(found[0][1][0, 1], np.c_[np.arange(40), np.arange(40)])   # unchanged
    with pytest.raises(TypeError, match="recording_geometry"):
        TieParams(recording_geometry=1)


def test_a_frame_pair_left_with_too_few_matches_gives_none(rng):
    """After the recording's one geometry, a frame's pair with fewer than min_matches
    inliers left gives no matches at all (as a pair's own fit does): frame 1's 20 matches
    hold 10 wrong ones, 10 true ones are too few."""
    from lsmta.calibration.tie_points import _one_geometry
    cams = rig_cameras(n=2)
    found = []
    for t, n in enumerate((40, 20)):
        X = rng.uniform([-800, 0, 200], [800, 1000, 1500], (n, 3))
        feats = [(c.project(X) + rng.normal(0, 0.2, (n, 2)), np.zeros((n, 128), np.uint8))
                 for c in cams]
        if t == 1:
            feats[1][0][:10] += rng.choice([-1, 1], (10, 2)) * rng.uniform(6, 12, (10, 2))
        found.append((feats, {(0, 1): np.c_[np.arange(n), np.arange(n)]}))
    out = _one_geometry(found, cams, TieParams())
    assert (0, 1) not in out[1][1]
    assert len(out[0][1][0, 1]) >= 38
    out = _one_geometry(found, cams, TieParams(min_matches=8))
    assert 8 <= len(out[1][1][0, 1]) <= 10


def test_recording_inliers_of_chained_tie_points(rng):
    """recording_inliers: a point off its pair's one geometry fails, the true ones pass; a
    pair with fewer than min_matches points gives none; inputs unchanged, shapes checked."""
    from lsmta.calibration import recording_inliers
    cams = rig_cameras(n=3)
    X = rng.uniform([-800, 0, 200], [800, 1000, 1500], (60, 3))
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.2, (3, 60, 2))
    xy[2, :50] = np.nan                                 # view 2 shares 10 points only
    xy[1, 3] += [7.0, -7.0]
    keep = xy.copy()
    ok = recording_inliers(cams, xy)
    assert np.array_equal(xy, keep, equal_nan=True)
    assert not ok[3] and not ok[50:].any()              # pairs with view 2: too few
    assert ok[:50].sum() >= 47
    assert recording_inliers(cams, xy, params=TieParams(min_matches=8))[50:].sum() >= 9
    with pytest.raises(ValueError, match=r"xy: expected \(3, N, 2\)"):
        recording_inliers(cams, xy[:2])
