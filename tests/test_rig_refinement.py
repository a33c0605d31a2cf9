"""A camera file's rig refined from its own recording (refine_rig): from video files, the
checks of cameras against videos, places and held-out places, lens models that fold over
(tests/test_rig_refinement_stages.py: the stages on their own)."""

import hashlib
import json
import warnings
from dataclasses import fields, replace

import cv2
import numpy as np
import pytest

from conftest import disturbed, random_texture, render_room, rig_cameras
from lsmta.calibration import RefineParams, TieLSMParams, TieParams
from lsmta.camera import cropped_camera
from lsmta.camera_files import read_camera_toml
from lsmta.io import cameras_for_videos, read_videos
from lsmta.systems import RigRefinementParams, refine_rig
from lsmta.systems.refinement import _folds
from lsmta.triangulation import triangulate


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
@pytest.fixture(scope="module")
def features_once():
    """The tie point search's feature detection (SIFT / ASIFT, the costliest stage: about
    1.4 s of CPU per 640 x 480 frame) run once per distinct image and detector setting in
    this module; a test that searches the same frames again gets the same keypoints and
    descriptors without detecting them again. Detection is deterministic (the same image
    gives the same features, whatever OpenCV's threads), so every result is the one a fresh
    detection gives; an image that differs in any pixel is detected anew (keyed on its
    bytes). Everything after detection (matching, LSM, adjustment, checks) runs in every
    test."""
    import lsmta.calibration.tie_points as tie_points

    detector_of, seen = tie_points._detector, {}

    class Once:
        def __init__(self, detector, setting):
            self.detector, self.setting = detector, setting

        def detectAndCompute(self, image, mask):                 # OpenCV's name
            assert mask is None
            key = (self.setting, image.shape, hashlib.sha1(np.ascontiguousarray(image))
                   .hexdigest())
            if key not in seen:
                seen[key] = self.detector.detectAndCompute(image, None)
            kp, des = seen[key]
            return kp, None if des is None else des.copy()

    def detector(cameras, params):
        found, setting = detector_of(cameras, params)     # (OpenCV detector, its settings)
        return Once(found, setting), setting

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tie_points, "_detector", detector)
        yield seen


@pytest.fixture(scope="module")
def recording(tmp_path_factory, features_once):
    rng = np.random.default_rng(40)
    cams = rig_cameras(n=3)
    floor, wall = random_texture(rng), random_texture(rng)
    folder = tmp_path_factory.mktemp("rig")
    paths = []
    for c in cams:
        path = folder / f"{c.name}.avi"
        out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0,
                              (c.width, c.height))
        for t in range(6):
            out.write(cv2.cvtColor(render_room(c, floor, wall, 9 * t), cv2.COLOR_GRAY2BGR))
        out.release()
        paths.append(path)
    return paths, cams


@pytest.mark.slow
def test_refine_rig_from_video_files(recording, tmp_path):
    paths, cams = recording
    videos = read_videos(paths)
    given = disturbed(cams, np.random.default_rng(7))
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
    assert [v["held_out_still_places"] for v in s.values()] == held_still.tolist()
    assert record["still_search_frames"] == [] and record["unused_places"] == 0
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
    # two frames, the fewest refine_rig takes: the wrong order still yields tie points that
    # pass the band and the pairs' own geometry, and the adjustment on them (the costly
    # part here: it turns the cameras 14-43 degrees) is refused by the turn check
    with pytest.raises(ValueError, match="do not fit the videos"):
        refine_rig(videos, swapped, params=RigRefinementParams(
            n_frames=2, tie=TieParams(n_features=2000, asift_features=300)))


@pytest.mark.slow
def test_lsm_that_keeps_too_few_tie_points_is_refused(recording):
    """Least squares matching that fails everywhere leaves nothing to adjust: a clear error
    naming tie_lsm, not a crash further on."""
    paths, cams = recording
    given = disturbed(cams, np.random.default_rng(7))
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
    given = disturbed(cams, np.random.default_rng(7))
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
    cam = rig_cameras(n=1)[0]                                         # k1 -0.08, k2 0.05: fine
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
    given = disturbed(cams, np.random.default_rng(7))
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
    given = disturbed(cams, np.random.default_rng(7))
    with pytest.raises(ValueError, match="max_rotation_deg"):
        refine_rig(read_videos(paths), given, params=RigRefinementParams(
            n_frames=3, max_rotation_deg=0.01, tie=TieParams(n_features=2000, asift_features=300)))


def test_still_places_are_one_tie_point_and_held_out_by_place(rng):
    from lsmta.systems.refinement import _hold_out, _merged, _places
    cams = rig_cameras(n=3)
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
    cams = rig_cameras(n=4)
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


def test_a_feature_found_twice_in_a_frame_is_one_place(rng):
    """ASIFT finds a feature again under several tilts (SIFT: one keypoint per orientation),
    so one frame may hold a point's tie point twice, a pixel or so apart. Twins (one frame,
    within twin_px in every view they share) are one feature: every 3-D point is one place,
    a still point's frames stay one still place; without joining them the one-point-per-frame
    guard breaks those still places into one-frame places."""
    from lsmta.systems.refinement import _feature_places, _hold_out, _places, _twins
    cams = rig_cameras(n=3)
    n_frames, n_still, n_moving = 4, 60, 20
    still_X = rng.uniform([-1000, 0, 100], [1000, 1200, 1600], (n_still, 3))
    xy, frame, truth = [], [], []
    for t in range(n_frames):
        X = np.r_[still_X, rng.uniform([-300, 200, 200], [300, 600, 1500], (n_moving, 3))]
        ids = np.arange(len(X))
        twin = rng.uniform(size=len(X)) < 0.3                       # found twice
        ids = np.r_[ids, ids[twin]]
        obs = np.stack([c.project(X[ids]) for c in cams])
        obs += rng.normal(0, 0.2, obs.shape)
        obs[:, len(X):] += rng.uniform(-0.5, 0.5, (3, twin.sum(), 2))     # the twins
        xy.append(obs)
        frame.append(np.full(len(ids), t))
        truth.append(np.where(ids < n_still, ids, n_still + t * n_moving + ids - n_still))
    xy, frame, truth = np.concatenate(xy, 1), np.concatenate(frame), np.concatenate(truth)
    keep = xy.copy()
    twins = _twins(xy, frame, 4.0)
    assert len(np.unique(twins)) == len(np.unique(np.c_[truth, frame], axis=0))
    labels = _feature_places(xy, frame, 2.0, 4.0)
    assert np.array_equal(xy, keep, equal_nan=True)
    pairs = set(zip(labels.tolist(), truth.tolist()))
    assert len(pairs) == len(set(labels.tolist())) == len(set(truth.tolist()))
    _, still = _hold_out(labels, frame, np.zeros(n_frames, bool), 3)
    assert still.sum() == n_still
    # the guard alone: the twinned still points fall apart into places of one frame
    _, still_alone = _hold_out(_places(xy, 2.0, frame), frame, np.zeros(n_frames, bool), 3)
    assert still_alone.sum() < n_still - 20, still_alone.sum()
    # two points of one frame farther apart than twin_px stay two features
    far = np.concatenate([xy[:, :1], xy[:, :1] + 5.0], axis=1)
    assert len(np.unique(_twins(far, np.zeros(2, int), 4.0))) == 2



def _refined_on(monkeypatch, videos, cams, xy, frame, params):
    """``refine_rig`` on the given tie points ``xy`` (K, N, 2) of frames ``frame`` (N,) in
    place of those it would find (no LSM), its warnings silenced."""
    import lsmta.systems.refinement as refinement
    from lsmta.calibration import TiePoints
    tie = TiePoints(xy=xy, frame=frame, pair_matches=np.ones((4, 4), int),
                    pair_guided=np.ones((4, 4), int))
    monkeypatch.setattr(refinement, "_tie_points_at_work_size", lambda *a, **k: (tie, tie, None))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return refine_rig(videos, cams, params=params)

def test_recording_geometry_is_fitted_on_the_adjusted_places_only(rng, monkeypatch):
    """refine_rig checks each view pair against one relative orientation for the recording
    AFTER the hold-out split, fitted on the places it adjusts only: wrong matches (8 px off,
    in a random direction) among those places are kept out of the adjustment, wrong matches
    among the held-out places stay there and are judged as matched, and how far off the
    held-out ones are changes nothing in the adjustment (no leak). The moving subject's
    places are of one frame each, a pair's wrong matches among them too. Ground truth: the
    generator's points."""
    import lsmta.systems.refinement as refinement
    from lsmta.io import Videos
    cams = rig_cameras(n=4)
    xy, frame, truth = _still_and_moving(rng, cams)
    moving = truth >= 150
    wrong = moving & (rng.uniform(size=len(frame)) < 0.3) & np.isfinite(xy[1, :, 0])
    direction = rng.normal(size=(len(frame), 2))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    held_frames = np.isin(frame, [1, 4])                           # hold_out_every = 3
    videos = Videos(paths=tuple(f"cam{k}.mp4" for k in range(4)), frames=tuple(range(6)),
                    fps=30.0, file_sizes=((640, 480),) * 4, sizes=((640, 480),) * 4,
                    scale=1.0, crop=None)

    def run(held_off_px):
        moved = xy.copy()
        off = np.where(held_frames, held_off_px, 8.0)[:, None] * direction
        moved[1, wrong] += off[wrong]
        return _refined_on(monkeypatch, videos, cams, moved, frame,
                           RigRefinementParams(lsm=False, tie=TieParams(recording_geometry=True)))

    ref = run(8.0)
    bad = np.zeros(len(ref.still), bool)
    bad[ref.places[wrong]] = True
    train = ~ref.held_out_places & ~ref.dropped_places
    assert not (ref.inconsistent_places & ~train).any()
    # (a shift along the pair's epipolar line is not off its geometry: most, not all)
    assert bad[train].sum() > 20 and ref.inconsistent_places[bad & train].mean() > 0.8
    assert ref.inconsistent_places[train & ~bad].mean() < 0.02
    held_bad = bad & ref.held_out_places
    assert held_bad.sum() > 10                                    # judged as matched:
    err = triangulate(list(ref.cameras), ref.place_xy[:, held_bad]).reprojection_error
    assert np.nanmedian(np.nanmax(err, axis=0)) > 2.0             # several px off
    assert ref.held_out_all_points == ref.held_out_places.sum()
    assert not RigRefinementParams().tie.recording_geometry                  # off by default
    assert not refinement._off_geometry(cams, ref.place_xy, train,
                                        RigRefinementParams(lsm=False)).any()
    # the held-out wrong matches 20 px off instead: the same adjustment, to the bit (the
    # drop of training places next to held-out points, which by design depends on where
    # those are, switched off in both runs)
    monkeypatch.setattr(refinement, "_near_held_out",
                        lambda xy, labels, held, tol: np.zeros(len(held), bool))
    ref, ref20 = run(8.0), run(20.0)
    assert ref.inconsistent_places.any()
    assert np.array_equal(ref20.inconsistent_places, ref.inconsistent_places)
    for a, b in zip(ref20.cameras, ref.cameras):
        assert np.array_equal(a.C, b.C) and np.array_equal(a.R, b.R) and a.f == b.f
    judged = [r.place_xy[:, r.held_out_places] for r in (ref, ref20)]
    assert not np.array_equal(*judged, equal_nan=True)          # judged where matched


def test_frames_between_the_sampled_ones_are_searched_for_still_places_only(rng, monkeypatch):
    """``still_between``: frames between the sampled ones (none of them a sampled one) give
    tie points that join places like any other, so more still points are matched in two
    frames; a place of one of those frames alone (the moving subject's) is neither adjusted
    nor held out, so where its points lie changes nothing in the adjustment, and the moving
    subject's hold-out split is that of the sampled frames. Ground truth: the generator's
    points."""
    from lsmta.io import Videos
    from lsmta.systems.refinement import _between
    assert _between(np.array([0, 4, 7, 11]), 1).tolist() == [2, 6, 9]
    assert _between(np.array([0, 2, 3, 10]), 2).tolist() == [1, 5, 8]     # narrow gaps
    assert _between(np.array([0, 33, 66, 99]), 0).tolist() == []
    with pytest.raises(ValueError, match="still_between"):
        RigRefinementParams(still_between=-1)
    cams = rig_cameras(n=4)
    xy, frame, truth = _still_and_moving(rng, cams, n_frames=7, noise=0.2)
    search_frame = frame >= 4                       # frames 2, 6, 9 (after 0, 4, 7, 11)
    moving_search = (truth >= 150) & search_frame
    direction = rng.normal(size=(len(frame), 2))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    videos = Videos(paths=tuple(f"cam{k}.mp4" for k in range(4)), frames=tuple(range(12)),
                    fps=30.0, file_sizes=((640, 480),) * 4, sizes=((640, 480),) * 4,
                    scale=1.0, crop=None)

    def run(off_px, between=1, keep=None):
        keep = np.ones(len(frame), bool) if keep is None else keep
        moved = xy.copy()
        moved[1, moving_search] += off_px * direction[moving_search]
        fr = frame[keep]
        return _refined_on(monkeypatch, videos, cams, moved[:, keep], fr, RigRefinementParams(
            lsm=False, n_frames=4, still_between=between))

    ref = run(0.0)
    assert ref.frames == (0, 4, 7, 11, 2, 6, 9)
    assert ref.still_search.tolist() == [False] * 4 + [True] * 3
    assert ref.held_out.tolist() == [False, True] + [False] * 5       # the sampled split
    frames_of = [set(frame[ref.places == p].tolist()) for p in range(len(ref.still))]
    assert ref.unused_places.tolist() == [len(f) == 1 and min(f) >= 4 for f in frames_of]
    assert ref.unused_places[ref.places[moving_search]].all()
    assert ref.unused_places.sum() > 50
    assert not (ref.unused_places & (ref.held_out_places | ref.dropped_places)).any()
    # still points seen in one sampled frame and some frames between are still places now
    alone = run(0.0, between=0, keep=~search_frame)
    assert alone.frames == (0, 4, 7, 11) and not alone.unused_places.any()
    assert ref.still.sum() > alone.still.sum() + 5, (ref.still.sum(), alone.still.sum())
    # the moving places of the frames between move 30 px in one view: the same adjustment
    ref30 = run(30.0)
    assert np.array_equal(ref30.held_out_places, ref.held_out_places)
    for a, b in zip(ref30.cameras, ref.cameras):
        assert np.array_equal(a.C, b.C) and np.array_equal(a.R, b.R) and a.f == b.f


@pytest.mark.slow
def test_refine_rig_under_a_build_reads_the_kept_result(recording, monkeypatch, tmp_path):
    """Under ``lsmta reproduce`` a second call with the same arguments (notebook 21 after 17)
    reads the first call's result: the same cameras and residuals to the bit, read-only
    arrays still read-only, shared parts still shared; other settings are another call."""
    from lsmta.build_cache import CACHE_ENV, READS_FILE
    paths, cams = recording
    given = disturbed(cams, np.random.default_rng(7))
    params = RigRefinementParams(n_frames=3, lsm=False,
                                 tie=TieParams(n_features=2000, asift_features=300))
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    videos = read_videos(paths)
    refine_rig(videos, given, params=params)       # from the files: never kept (paths only)
    assert not (tmp_path / "rig_refinement").exists()
    stacks = videos.load()
    first, again = (refine_rig(videos, given, params=params, stacks=stacks) for _ in range(2))
    assert len(list((tmp_path / "rig_refinement").glob("*.pkl"))) == 1
    assert len((tmp_path / "rig_refinement" / READS_FILE).read_text().splitlines()) == 1
    assert first is not again and again.raw_tie_points is again.tie_points
    for name in ("held_out_before", "held_out_after", "place_xy", "still", "held_out_places"):
        a, b = getattr(first, name), getattr(again, name)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
        assert a.flags.writeable == b.flags.writeable, name
    for a, b in zip(first.chosen, again.chosen, strict=True):       # every camera field
        for f in fields(a):
            assert np.array_equal(getattr(a, f.name), getattr(b, f.name)), f.name
    refine_rig(videos, given, params=replace(params, hold_out_every=4), stacks=stacks)
    assert len(list((tmp_path / "rig_refinement").glob("*.pkl"))) == 2
