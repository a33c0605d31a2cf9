"""A camera file's rig refined from its own recording: tie points, the adjustment with the
given cameras as priors, held-out places, and the checks of cameras against videos."""

import json
import warnings
from dataclasses import replace

import cv2
import numpy as np
import pytest

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
from lsmta.camera import Camera, cropped_camera
from lsmta.camera_files import read_camera_toml
from lsmta.io import cameras_for_videos, read_videos
from lsmta.matching import Status
from lsmta.systems import RigRefinementParams, refine_rig
from lsmta.systems.refinement import _folds
from lsmta.triangulation import triangulate


def _rig(n=4, width=640, height=480, f=560.0):
    cams = []
    for a in np.deg2rad(np.linspace(-35, 35, n)):
        eye = np.array([3000 * np.sin(a), -3000 * np.cos(a), 1400.0])
        cams.append(Camera.look_at(eye, (0, 400, 700), f=f, width=width, height=height,
                                   name=f"cam{len(cams) + 1:02d}").replace(k1=-0.08, k2=0.05))
    return cams


def _disturbed(cams, rng, *, px=6.0):
    """Cameras a few pixels off: centre moved, principal distance and point changed."""
    out = []
    for c in cams:
        out.append(c.replace(C=c.C + rng.normal(0, 15, 3), f=c.f * (1 + rng.normal(0, 0.008)),
                             cx=c.cx + rng.normal(0, px), cy=c.cy + rng.normal(0, px)))
    return out


def test_refined_residuals_come_back_to_the_noise(rng):
    cams = _rig()
    X = rng.uniform([-1200, -200, 0], [1200, 1200, 1800], (1200, 3))
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.3, (len(cams), 1200, 2))
    for k, c in enumerate(cams):
        xy[k, ~c.in_image(xy[k]) | (rng.uniform(size=1200) < 0.3)] = np.nan
    xy[0, :30] += rng.uniform(8, 20, (30, 2))                     # gross errors
    given = _disturbed(cams, rng)
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
    cams = _rig(n=2)
    # a few points near the image centre say nothing about the distortion
    X = rng.uniform([-150, 300, 600], [150, 500, 800], (40, 3))
    xy = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.3, (2, 40, 2))
    r = refine_cameras(cams, xy, params=RefineParams(information_ratio=0.5))
    assert all("k1" not in names for names in r.freed), r.freed
    assert r.ratios.shape == (2, 4) and r.ratio_names == ("cx", "cy", "k1", "k2")


def test_refine_params_are_checked():
    with pytest.raises(ValueError, match="sigma_px"):
        RefineParams(sigma_px=0)
    with pytest.raises(ValueError, match="groups"):
        RefineParams(groups=(("f",),))
    with pytest.raises(ValueError, match="information_ratio"):
        RefineParams(information_ratio=1.5)
    with pytest.raises(ValueError, match="loss"):
        RefineParams(loss="l2")
    with pytest.raises(ValueError, match="ratio"):
        TieParams(ratio=1.0)
    with pytest.raises(ValueError, match="hold_out_every"):
        RigRefinementParams(hold_out_every=1)
    with pytest.raises(ValueError, match="detector"):
        TieParams(detector="orb")
    with pytest.raises(ValueError, match="max_tilt"):
        TieParams(max_tilt=0)
    with pytest.raises(ValueError, match="distinct_px"):
        TieParams(distinct_px=-1.0)
    with pytest.raises(ValueError, match="tie_max_side"):
        RigRefinementParams(tie_max_side=10)
    with pytest.raises(ValueError, match="max_rotation_deg"):
        RigRefinementParams(max_rotation_deg=0)


# ---------------------------------------------------------------------- from pixels
def _texture(rng, size=1024):
    t = cv2.GaussianBlur(rng.uniform(0, 255, (size, size)), (0, 0), 2.0)
    t = cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX)
    return t.astype(np.float32)


def _render(cam, floor_tex, wall_tex, shift):
    """A floor (z = 0) and a wall (y = 1500) with random texture, seen by ``cam``; the
    textures slide by ``shift`` px per frame (a moving scene: frames hold new points)."""
    xy = cam.pixel_grid().reshape(-1, 2)
    o, d = cam.rays(xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
        t_wall = np.where(d[:, 1] > 0, (1500 - o[:, 1]) / d[:, 1], np.inf)
    P = o + np.minimum(t_floor, t_wall)[:, None] * d
    on_wall = t_wall < t_floor
    u = (P[:, 0] / 4 + 512 + shift).reshape(cam.height, cam.width).astype(np.float32)
    v = (np.where(on_wall, P[:, 2], P[:, 1]) / 4 + 512).reshape(u.shape).astype(np.float32)
    floor, wall = (cv2.remap(tex, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
                   for tex in (floor_tex, wall_tex))
    out = np.where(on_wall.reshape(u.shape), wall, floor)
    return out.reshape(cam.height, cam.width).astype(np.uint8)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rng = np.random.default_rng(40)
    cams = _rig(n=3)
    floor, wall = _texture(rng), _texture(rng)
    folder = tmp_path_factory.mktemp("rig")
    paths = []
    for c in cams:
        path = folder / f"{c.name}.avi"
        out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0,
                              (c.width, c.height))
        for t in range(6):
            out.write(cv2.cvtColor(_render(c, floor, wall, 9 * t), cv2.COLOR_GRAY2BGR))
        out.release()
        paths.append(path)
    return paths, cams


@pytest.mark.slow
def test_refine_rig_from_video_files(recording, tmp_path):
    paths, cams = recording
    videos = read_videos(paths)
    given = _disturbed(cams, np.random.default_rng(7))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = refine_rig(videos, given, params=RigRefinementParams(
            n_frames=6, tie=TieParams(n_features=2000, asift_features=300)))
    few_still = [str(w.message) for w in caught if "min_still_held" in str(w.message)]
    assert len(few_still) == len(caught) <= 1, [str(w.message) for w in caught]  # generalises
    # the textures slide: the scene moves, held-out still places are too few to judge alone
    held_still = np.isfinite(r.place_xy[:, r.held_out_places & r.still, 0]).sum(axis=1)
    assert r.held_out_kind == ("still places" if held_still.min() >= 10 else "all places")
    assert bool(few_still) == (r.held_out_kind == "all places")
    chosen = {"still places": (r.held_out_still_after, r.held_out_still_points),
              "all places": (r.held_out_all_after, r.held_out_all_points)}[r.held_out_kind]
    np.testing.assert_array_equal(r.held_out_after, chosen[0])
    assert r.held_out_points == chosen[1]
    before = r.adjustment.median_residual(before=True)
    after = r.adjustment.median_residual()
    assert (before > 1.5).all(), before
    assert (after < 0.5).all(), after
    # the held-out places agree better with the refined cameras
    assert (r.held_out_after < 0.6 * r.held_out_before).all(), (r.held_out_before,
                                                                 r.held_out_after)
    s = r.summary()
    assert list(s) == ["cam01", "cam02", "cam03"] and s["cam01"]["freed"][0] == "f"
    # written where other tools read it, and read back
    written = r.save(tmp_path / "out")
    back = read_camera_toml(written["cameras"], unit="mm")
    X = np.array([[0.0, 400.0, 700.0], [500.0, 900.0, 100.0]])
    for a, b in zip(back, r.cameras):
        np.testing.assert_allclose(a.project(X), b.project(X), atol=1e-6)
    record = json.loads(written["summary"].read_text())
    assert record["cameras"] == json.loads(json.dumps(s))
    assert record["held_out_frames"] == [f for f, h in zip(r.frames, r.held_out) if h]
    assert record["dropped_places"] == int(r.dropped_places.sum())
    assert not (r.dropped_places & r.held_out_places).any()
    assert record["held_out_all_points"] == r.held_out_all_points >= r.held_out_still_points
    assert s["cam01"]["held_out_all_after_px"] == float(r.held_out_all_after[0])
    # the positions as found and as matched: the same places, the same views
    assert r.lsm is not None and r.raw_tie_points.xy.shape[1] >= r.tie_points.xy.shape[1]
    assert r.raw_place_xy.shape == r.place_xy.shape
    np.testing.assert_array_equal(np.isfinite(r.raw_place_xy), np.isfinite(r.place_xy))
    moved = np.linalg.norm(r.raw_place_xy - r.place_xy, axis=-1)
    assert np.nanmax(moved) > 0.05                                       # LSM moved them
    # a refinement whose distortion folds over inside the frame is not used
    assert r.folded == () and not any(v["folds"] for v in s.values()) and r.improved
    assert record["folded"] == [] and record["used_refined"] is True
    folding = list(r.cameras)
    folding[1] = folding[1].replace(k1=-0.5, k2=0.0)
    assert _folds(folding[1]) and not _folds(r.cameras[1])
    bad = replace(r, cameras=tuple(folding), folded=("cam02",))
    assert not bad.improved and bad.chosen is bad.given
    assert bad.summary()["cam02"]["folds"] and not bad.summary()["cam01"]["folds"]


@pytest.mark.slow
def test_cameras_that_do_not_fit_are_refused(recording):
    paths, cams = recording
    videos = read_videos(paths)
    swapped = [cams[2], cams[0], cams[1]]                   # the wrong order
    with pytest.raises(ValueError, match="do not fit the videos"):
        refine_rig(videos, swapped, params=RigRefinementParams(
            n_frames=3, tie=TieParams(n_features=2000, asift_features=300)))


@pytest.mark.slow
def test_lsm_that_keeps_too_few_tie_points_is_refused(recording):
    """Least squares matching that fails everywhere leaves nothing to adjust: a clear error
    naming tie_lsm, not a crash further on."""
    paths, cams = recording
    given = _disturbed(cams, np.random.default_rng(7))
    with pytest.raises(ValueError, match=r"tie_lsm: least squares matching .* kept \d+ of"):
        refine_rig(read_videos(paths), given, params=RigRefinementParams(
            n_frames=3, tie=TieParams(n_features=2000, asift_features=300),
            tie_lsm=TieLSMParams(max_sigma_px=1e-9)))


@pytest.mark.slow
def test_without_lsm_and_with_a_refined_lens_that_folds(recording, monkeypatch):
    """lsm=False adjusts the tie points as found; a refined camera whose distortion folds
    over inside its frame (forced here on cam02) is named, recorded, and not used."""
    import lsmta.systems.refinement as refinement

    adjust = refinement.refine_cameras

    def folding(*args, **kwargs):
        out = adjust(*args, **kwargs)
        cams = list(out.cameras)
        cams[1] = cams[1].replace(k1=-0.5, k2=0.0)
        return replace(out, cameras=tuple(cams))

    monkeypatch.setattr(refinement, "refine_cameras", folding)
    paths, cams = recording
    given = _disturbed(cams, np.random.default_rng(7))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = refine_rig(read_videos(paths), given, params=RigRefinementParams(
            n_frames=3, lsm=False, tie=TieParams(n_features=2000, asift_features=300)))
    assert r.lsm is None and r.raw_tie_points is r.tie_points
    np.testing.assert_array_equal(r.raw_place_xy, r.place_xy)
    assert r.folded == ("cam02",)
    assert any("cam02" in str(w.message) and "cannot be inverted" in str(w.message)
               for w in caught), [str(w.message) for w in caught]
    assert not r.improved and r.chosen is r.given
    assert r.summary()["cam02"]["folds"] and not r.summary()["cam01"]["folds"]


def test_a_lens_that_folds_inside_the_frame_is_found():
    """_folds checks a grid over the whole frame, corners included."""
    cam = _rig(n=1)[0]                                         # k1 -0.08, k2 0.05: fine
    assert not _folds(cam)
    # k1 = -0.5 at f = 560: the model folds at a distorted radius of 0.54 (305 px), inside
    # the 640 x 480 frame (corners 400 px out) but not in its centre
    bent = cam.replace(k1=-0.5, k2=0.0)
    assert _folds(bent)
    grid = np.stack(np.meshgrid(np.arange(0, 640, 8), np.arange(0, 480, 8)), -1).reshape(-1, 2)
    r = np.hypot(*(grid - [bent.cx, bent.cy]).T)
    fails = ~bent.invertible(grid.astype(float))
    assert fails.any() and r[fails].min() > 300 and not fails[r < 300].any()
    assert not _folds(bent.replace(width=480, height=360, cx=239.5, cy=179.5))


@pytest.mark.slow
def test_frames_in_memory_give_the_same_tie_points(recording):
    """Frames already loaded are used instead of decoding the sampled ones again: the same
    frames, so the same tie points (the adjustment after them is deterministic); stacks that
    are not the videos' frames are refused."""
    from lsmta.systems.refinement import _tie_points_at_work_size

    paths, cams = recording
    videos = read_videos(paths)
    given = _disturbed(cams, np.random.default_rng(7))
    params = RigRefinementParams(n_frames=3, tie=TieParams(n_features=2000, asift_features=300))
    stacks = videos.load(progress=False)
    kept = [s.copy() for s in stacks]
    for i in range(videos.n_frames):
        assert all(np.array_equal(s[i], f) for s, f in zip(stacks, videos.read(i)))
    picks = np.array([0, 2, 5])
    a, a_same, a_info = _tie_points_at_work_size(videos, given, picks, params)
    b = _tie_points_at_work_size(videos, given, picks, params, stacks)[0]
    assert a_same is a and a_info is None                   # without lsm: (raw, raw, None)
    assert np.isfinite(a.xy).all(axis=-1).sum() > 100                        # not vacuous
    np.testing.assert_array_equal(a.xy, b.xy)
    assert all(np.array_equal(s, k) for s, k in zip(stacks, kept))           # unchanged
    with pytest.raises(ValueError, match="stacks: expected the videos' frames"):
        refine_rig(videos, given, params=params, stacks=[s[:2] for s in stacks])


def test_tie_points_need_one_image_per_camera():
    cams = _rig(n=2, width=64, height=48)
    with pytest.raises(ValueError, match="frame 0 holds 1 images"):
        find_tie_points([[np.zeros((48, 64), np.uint8)]], cams)
    with pytest.raises(ValueError, match="image 1 of frame 0"):
        find_tie_points([[np.zeros((48, 64), np.uint8), np.zeros((40, 64), np.uint8)]], cams)


def test_camera_sizes_are_checked_against_the_videos(recording):
    paths, cams = recording
    videos = read_videos(paths, scale=0.5, crop=(20, 10, 620, 470))
    wide = [c.replace(width=c.width + 8) for c in cams]
    with pytest.raises(ValueError, match=r"cam01.avi is 640 x 480 but its camera \(cam01\) "
                                         r"is 648 x 480; .*mismatch='crop'"):
        cameras_for_videos(wide, videos)
    fitted = cameras_for_videos(wide, videos, mismatch="crop")
    assert [(c.width, c.height) for c in fitted] == [(300, 230)] * 3
    # a point lands where the cropped, halved frame shows it
    X = np.array([[100.0, 500.0, 900.0]])
    full = cams[0].project(X)[0]
    want = ((full[0] - 20 + 0.5) * 0.5 - 0.5, (full[1] - 10 + 0.5) * 0.5 - 0.5)
    np.testing.assert_allclose(fitted[0].project(X)[0], want, atol=1e-9)
    with pytest.raises(ValueError, match="2 cameras for 3 videos"):
        cameras_for_videos(cams[:2], videos)
    narrow = [c.replace(width=c.width - 8) for c in cams]
    with pytest.raises(ValueError, match="order of the cameras"):
        cameras_for_videos(narrow, videos, mismatch="crop")
    with pytest.raises(ValueError, match="window"):
        cropped_camera(cams[0], 600, 0, 100, 480)


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
    floor = _texture(rng)
    cams = [Camera.look_at((2200 * np.cos(a), 2200 * np.sin(a), 1600.0), (0, 0, 0), f=500.0,
                           width=480, height=360, name=f"c{k}")
            for k, a in enumerate(np.deg2rad([0.0, 90.0]))]
    images = [[_render(c, floor, floor, 0) for c in cams]]
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



@pytest.mark.slow
def test_tie_points_found_at_a_working_size_come_back_to_the_frames(recording):
    """Frames halved (the right and bottom edge cut to an even size first): the tie points,
    scaled back, lie where the true cameras put them; and a turn limit the adjustment must
    exceed refuses the cameras with that reason."""
    from lsmta.systems.refinement import _tie_points_at_work_size
    paths, cams = recording
    videos = read_videos(paths, crop=(0, 0, 639, 479))              # odd sizes
    fitted = cameras_for_videos(cams, videos, mismatch="crop")
    params = RigRefinementParams(tie_max_side=320,
                                 tie=TieParams(n_features=2000, asift_features=300))
    tie = _tie_points_at_work_size(videos, fitted, np.array([0, 3]), params)[0]
    assert tie.xy.shape[1] > 100
    err = triangulate(fitted, tie.xy).reprojection_error
    assert np.nanmedian(err) < 0.3, np.nanmedian(err)
    given = _disturbed(cams, np.random.default_rng(7))
    with pytest.raises(ValueError, match="max_rotation_deg"):
        refine_rig(read_videos(paths), given, params=RigRefinementParams(
            n_frames=3, max_rotation_deg=0.01, tie=TieParams(n_features=2000, asift_features=300)))


def test_still_places_are_one_tie_point_and_held_out_by_place(rng):
    from lsmta.systems.refinement import _hold_out, _merged, _places
    cams = _rig(n=3)
    n_frames, n_still, n_moving = 5, 60, 20
    still_X = rng.uniform([-1000, 0, 100], [1000, 1200, 1600], (n_still, 3))
    hidden = rng.integers(0, 4, n_still)             # the view a still point is hidden from
    xy, frame, truth = [], [], []
    for t in range(n_frames):
        X = np.r_[still_X, rng.uniform([-300, 200, 200], [300, 600, 1500], (n_moving, 3))]
        obs = np.stack([c.project(X) for c in cams]) + rng.normal(0, 0.3, (3, len(X), 2))
        off = np.r_[hidden, rng.integers(0, 4, n_moving)]
        obs[off[off < 3], np.flatnonzero(off < 3)] = np.nan           # some seen by two
        keep = rng.uniform(size=len(X)) < 0.8                         # not found every time
        xy.append(obs[:, keep])
        frame.append(np.full(keep.sum(), t))
        truth.append(np.where(np.arange(len(X)) < n_still, np.arange(len(X)),
                              n_still + t * n_moving + np.arange(len(X)) - n_still)[keep])
    xy, frame, truth = np.concatenate(xy, 1), np.concatenate(frame), np.concatenate(truth)
    keep_xy = xy.copy()
    labels = _places(xy, 2.0)
    assert np.array_equal(xy, keep_xy, equal_nan=True)
    # one place per 3-D point: the still ones' repeats joined, moving ones alone
    pairs = set(zip(labels.tolist(), truth.tolist()))
    assert len(pairs) == len(set(labels.tolist())) == len(set(truth.tolist()))
    assert labels[0] == 0 and np.all(np.diff(np.unique(labels, return_index=True)[1]) > 0)
    merged = _merged(xy, labels)
    assert merged.shape == (3, labels.max() + 1, 2)
    p = labels[truth == 7][0]                        # a still point: the median of its repeats
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)               # its hidden view
        np.testing.assert_allclose(merged[:, p], np.nanmedian(xy[:, truth == 7], axis=1))
    held_frames = np.arange(n_frames) % 3 == 1
    held, still = _hold_out(labels, frame, held_frames, 3)
    first_truth = np.array([truth[labels == q][0] for q in range(labels.max() + 1)])
    assert np.array_equal(still, first_truth < n_still)
    # every third still place, all its repeats; moving places exactly those of held frames
    assert held[still].sum() == len(range(1, still.sum(), 3))
    moving_frame = np.array([frame[labels == q][0] for q in np.flatnonzero(~still)])
    assert np.array_equal(held[~still], held_frames[moving_frame])


def test_refine_rig_settings_for_places_are_checked():
    with pytest.raises(ValueError, match="place_px"):
        RigRefinementParams(place_px=0.0)
    with pytest.raises(ValueError, match="min_still_held"):
        RigRefinementParams(min_still_held=0)


def _still_and_moving(rng, cams, *, n_frames=6, n_still=150, n_moving=40, noise=0.3):
    """Tie points of still points seen in views that change from frame to frame (each found
    in a view with probability 0.6, kept where seen in two) and of moving points; with the
    frame and the 3-D point of each."""
    K = len(cams)
    still_X = rng.uniform([-1000, 0, 100], [1000, 1200, 1600], (n_still, 3))
    xy, frame, truth = [], [], []
    for t in range(n_frames):
        X = np.r_[still_X, rng.uniform([-300, 200, 200], [300, 600, 1500], (n_moving, 3))]
        obs = np.stack([c.project(X) for c in cams]) + rng.normal(0, noise, (K, len(X), 2))
        found = rng.uniform(size=(K, len(X))) < 0.6
        obs[~found] = np.nan
        keep = found.sum(axis=0) >= 2
        xy.append(obs[:, keep])
        frame.append(np.full(keep.sum(), t))
        truth.append(np.where(np.arange(len(X)) < n_still, np.arange(len(X)),
                              n_still + t * n_moving + np.arange(len(X)) - n_still)[keep])
    return np.concatenate(xy, 1), np.concatenate(frame), np.concatenate(truth)


def test_held_out_places_have_no_training_piece_next_to_them(rng):
    """A still point matched in different views in different frames splits into several
    places; the training places next to a held-out one (in any view) are dropped, so no
    held-out still point has a training point within place_px in any view."""
    from lsmta.systems.refinement import _hold_out, _near_held_out, _places
    cams = _rig(n=4)
    xy, frame, truth = _still_and_moving(rng, cams)
    tol = 2.0
    labels = _places(xy, tol, frame)
    n = labels.max() + 1
    split = sum(len(np.unique(labels[truth == s])) > 1 for s in range(150))
    assert split > 10, split                     # the case the guard is for does occur
    for p in range(n):                           # one point per frame, within tol per view
        g = np.flatnonzero(labels == p)
        assert len(np.unique(frame[g])) == len(g)
        d = np.linalg.norm(xy[:, g, None] - xy[:, None, g], axis=-1)
        assert not (d > tol).any()
    held, still = _hold_out(labels, frame, np.arange(6) % 3 == 1, 3)
    keep_xy = xy.copy()
    dropped = _near_held_out(xy, labels, held, tol)
    assert np.array_equal(xy, keep_xy, equal_nan=True)
    assert not (dropped & held).any() and dropped.any()
    test = held[labels] & still[labels]

    def next_to_held(train):
        return any((np.linalg.norm(a[np.isfinite(a[:, 0])][:, None]
                                   - b[np.isfinite(b[:, 0])][None], axis=-1) <= tol).any()
                   for a, b in zip(xy[:, test], xy[:, train]))

    assert next_to_held(~held[labels])                  # without the drop: leaks
    assert not next_to_held(~held[labels] & ~dropped[labels])


def test_moving_points_that_pass_one_another_form_no_still_place():
    """Points of frames 0, 2 and 4 each within place_px of the next in every view, but
    3.6 px from end to end, and two points of one frame joined through a third: no place
    of two frames comes out of them (pixels alone cannot tell them from a still point)."""
    from lsmta.systems.refinement import _hold_out, _places
    base = np.array([[100.0, 200.0], [300.0, 150.0], [420.0, 380.0]])          # 3 views
    step = np.array([1.8, 0.0])
    chain = np.stack([base + i * step for i in range(3)], axis=1)         # frames 0, 2, 4
    far = np.array([[500.0, 50.0], [40.0, 60.0], [600.0, 400.0]])
    pair = np.stack([far, far + [3.0, 0.0], far + [1.5, 0.0]], axis=1)   # frames 1, 1, 3
    xy = np.concatenate([chain, pair], axis=1)
    frame = np.array([0, 2, 4, 1, 1, 3])
    labels = _places(xy, 2.0, frame)
    assert len(np.unique(labels)) == 6
    _, still = _hold_out(labels, frame, np.zeros(5, bool), 3)
    assert not still.any()
    # the pairs alone (what was joined before the guard) are within 2 px in every view
    assert np.all(np.linalg.norm(chain[:, 1] - chain[:, 0], axis=-1) <= 2.0)
    assert np.all(np.linalg.norm(pair[:, 2] - pair[:, 0], axis=-1) <= 2.0)
    assert len(np.unique(_places(xy[:, :2], 2.0, frame[:2]))) == 1         # two: one place


def test_too_few_held_out_still_places_judge_on_all_places_with_a_warning(rng):
    from lsmta.systems.refinement import _judged_on
    still_xy = rng.uniform(0, 600, (3, 12, 2))
    still_xy[2, 3:] = np.nan                                  # the third camera sees 3
    assert _judged_on(still_xy, 3, ["a", "b", "c"]) == "still places"
    with pytest.warns(UserWarning, match=r"c see\(s\) fewer than min_still_held = 4"):
        assert _judged_on(still_xy, 4, ["a", "b", "c"]) == "all places"


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


# ------------------------------------------------------- least squares matching
def _surface_point(cam, xy):
    """Where the rays of ``cam`` through ``xy`` meet the floor (z = 0) or the wall
    (y = 1500) of :func:`_render`."""
    o, d = cam.rays(xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
        t_wall = np.where(d[:, 1] > 0, (1500 - o[:, 1]) / d[:, 1], np.inf)
    return o + np.minimum(t_floor, t_wall)[:, None] * d


@pytest.fixture(scope="module")
def lsm_scene():
    rng = np.random.default_rng(48)
    cams = _rig(n=3)
    floor, wall = _texture(rng), _texture(rng)
    images = [_render(c, floor, wall, 0) for c in cams]
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
