"""The all-round studio rig and the LSMTA system on a tiny generated walk (issue 36, item 1)."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from conftest import tiny_studio_walk
from lsmta.camera import scaled_camera
from lsmta.evaluation import walk_system as ws
from lsmta.synth import Renderer, Scene, make_body, studio_rig, triplet_rig, walk
from lsmta.synth.calibration import bar_track, poor_guess, render_bar_images
from lsmta.synth.surface import distance_to_body
from lsmta.systems import BodySystemParams, FilterParams, capture_walk, view_groups
from lsmta.systems.rig import calibrate_rig


def test_studio_rig_cameras_look_at_the_subject():
    target = np.array([0.0, 0.0, 950.0])
    cams = studio_rig(target=target)
    assert len(cams) == 8 and len({c.name for c in cams}) == 8
    for c in cams:
        xy = c.project(target[None])[0]
        assert np.hypot(xy[0] - (c.width - 1) / 2, xy[1] - (c.height - 1) / 2) < 2.0
        assert np.hypot(*(c.C[:2] - target[:2])) == pytest.approx(3500.0)
    # two rows on four poles: a pole's cameras stand one above the other
    assert [round(c.C[2]) for c in cams] == [800, 2000] * 4
    assert np.allclose(cams[0].C[:2], cams[1].C[:2])
    # each pole is one view group (neighbouring poles look ~90 degrees apart)
    groups = view_groups(cams)
    assert [g.cameras for g in groups] == [(0, 1), (2, 3), (4, 5), (6, 7)]
    six = studio_rig(n=6, rows=1, rng=3)
    assert len(six) == 6 and len({tuple(np.round(c.C)) for c in six}) == 6


def test_studio_rig_sees_every_body_part_twice():
    cams = [scaled_camera(c, 0.25) for c in studio_rig(rng=1)]
    motion = walk(n_frames=21, start=(-650.0, 0.0))
    scene = Scene(body=make_body(rng=1), motion=motion, backdrop=20.0)
    renderer = Renderer(scene, cams, noise_sigma=0.0)
    for t in (0, 10, 20):
        part_id = renderer.render(t).part_id                    # (K, H, W)
        seen = [(part_id == p).reshape(len(cams), -1).any(axis=1).sum()
                for p in range(len(scene.body.parts))]
        assert min(seen) >= 2, dict(zip(scene.body.names, seen))


@pytest.mark.parametrize("kwargs, match", [
    (dict(n=7, rows=2), "rows"), (dict(heights=(800.0,)), "heights"),
    (dict(heights=("a", "b")), "heights"), (dict(radius=-1.0), "radius"),
    (dict(n=1), "n"), (dict(f=0.0), "f"), (dict(target=(0, 0)), "target")])
def test_studio_rig_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        studio_rig(**kwargs)


def test_walk_session_bad_input():
    with pytest.raises(ValueError, match="rig"):
        ws.WalkSessionParams(rig="dome")
    with pytest.raises(ValueError, match="scale"):
        ws.WalkSessionParams(scale=0.0)
    with pytest.raises(ValueError, match="n_frames"):
        ws.walk_session(n_frames=2)
    with pytest.raises(TypeError, match="params"):
        ws.walk_session(params={"rig": "studio"})


@pytest.fixture(scope="module")
def tiny_walk():
    # the cheapest run that still calibrates the studio well: half-size images, 60 bar
    # positions, 3 processed frames of 4 (frames= given), 12 seeds per surface
    session, cap, _ = tiny_studio_walk(scale=0.5, n_frames=4, frames=slice(1, 4))
    return session, cap


def test_capture_walk_measures_the_whole_visible_body(tiny_walk):
    session, cap = tiny_walk
    assert cap.arm is None and len(cap.views) == 4            # one view group per pole
    assert list(cap.frames) == [1, 2, 3]
    assert list(cap.seconds) == ["calibration", "view groups", "image noise", "surfaces",
                                 "tracking", "trajectories"]
    # scored after the fact: the system saw only videos, bar videos and tape-measured cameras
    # (measured at these settings: check median 0.097 mm, 445 points per frame, to the skin
    # 2.5 mm, from the seen skin 41 mm, 8 segments covered in every frame)
    assert cap.calibration.rms_over_limit < 1.5                # 0.99 measured
    al, check = ws.check_alignment(cap.cameras, session)
    assert np.nanmedian(check) < 0.3
    score = ws.score_walk(cap, session, al, rng=0)
    s = score.summary()
    assert s["points_per_frame_median"] >= 300
    assert s["to_truth_median_mm"] < 4.0
    assert s["from_truth_median_mm"] < 55.0
    assert s["segments_covered_min"] >= 6
    # points from every side of the body: all four poles' groups in every processed frame
    for t in range(len(cap.frames)):
        pts, group = cap.points_at(t)
        assert pts.shape == (len(group), 3) and len(np.unique(group)) == 4
    # processed frame t is the session's frame cap.frames[t]: its points lie on that frame's
    # skin, not on the next frame's (the body moves ~50 mm a frame)
    pts = al.points(cap.points_at(0)[0])
    poses = session.scene.body.part_poses(session.scene.motion, frames=[1, 2])
    near = [np.median(np.abs(distance_to_body(session.scene.body, p, pts))) for p in poses]
    assert near[0] < 4.0 < near[1]


def test_capture_walk_defaults_to_the_walking_settings(tiny_walk, monkeypatch):
    # capture_walk without params runs BodySystemParams.walking(); given params are kept
    import lsmta.systems.body as body_module

    session, _ = tiny_walk
    got = []
    monkeypatch.setattr(body_module, "capture_body", lambda *a, **kw: got.append(kw["params"]))
    capture_walk(session.videos, session.bar_videos, session.bar_length, session.nominal,
                 fps=session.fps, progress=False)
    mine = BodySystemParams(density_every=3)
    capture_walk(session.videos, session.bar_videos, session.bar_length, session.nominal,
                 fps=session.fps, progress=False, params=mine)
    assert got[0] == BodySystemParams.walking()
    assert got[0].filters == FilterParams.walking() and got[1].filters == FilterParams()
    assert got[1] == replace(mine, arm=None)


def test_walking_settings_on_the_tiny_walk(tiny_walk):
    # BodySystemParams.walking() (its filters, seeds 50 mm apart, up to 200) against the
    # fixture's settings (notebook 05's filters, its own seed count), both calibrated from
    # the same bar video, on the same tiny walk (half size, 3 frames): more points (from the
    # filters and the seeds together), still on the skin (after the fact).
    # Measured: 488 points per frame against 445, to the skin 2.45 mm against 2.53, but
    # from the seen skin 42.3 mm against 41.0 (at half size a forearm is ~10 px wide; the
    # full-size gains are experiments/results/walk_cover.json's), so no claim on that.
    session, cap = tiny_walk
    params = replace(BodySystemParams.walking(), density_every=2, reject_k=4.0)
    walking = capture_walk(session.videos, session.bar_videos, session.bar_length,
                           session.nominal, fps=session.fps, progress=False,
                           frames=slice(1, 4), params=params)
    before = ws.score_walk(cap, session, ws.check_alignment(cap.cameras, session)[0],
                           rng=0).summary()
    after = ws.score_walk(walking, session, ws.check_alignment(walking.cameras, session)[0],
                          rng=0).summary()
    assert after["points_per_frame_median"] > 1.05 * before["points_per_frame_median"]
    assert after["to_truth_median_mm"] < 3.0
    assert after["segments_covered_min"] >= 6


def test_capture_walk_bad_input(tiny_walk):
    session, cap = tiny_walk
    with pytest.raises(ValueError, match="t: expected"):
        cap.points_at(len(cap.frames))
    with pytest.raises(ValueError, match="t: expected"):
        cap.points_at(-1)
    with pytest.raises(ValueError, match="max_angle_deg"):
        BodySystemParams(max_angle_deg=0.0)
    with pytest.raises(ValueError, match="max_angle_deg"):
        BodySystemParams(max_angle_deg=200.0)
    with pytest.raises(TypeError, match="arm"):
        BodySystemParams(arm="none")
    with pytest.raises(TypeError, match="params"):
        capture_walk(session.videos, session.bar_videos, session.bar_length, session.nominal,
                     params={"density_every": 2})


@pytest.mark.parametrize("rig, seed", [("studio", 0), ("studio", 1), ("studio", 2),
                                       ("triplet", 0)])
def test_bar_calibrates_the_studio_and_the_triplet(rig, seed):
    # cameras facing each other name the bar's ends the other way round (and may rename
    # them partway): the rig is still calibrated from the bar alone (rms within the LSM's
    # limit), no body rendered. The studio at full size (its bar targets are too small at
    # half size for 3.5 m away), the triplet at half size, as notebook 14.
    rng = np.random.default_rng(seed)
    if rig == "studio":
        cams, n = studio_rig(rng=seed), 25
    else:
        cams, n = [scaled_camera(c, 0.5) for c in triplet_rig(rng=seed)], 60
    bar = bar_track(n=n, rng=rng, length=800.0, center=(0.0, 0.0, 950.0),
                    half_size=(1000.0, 700.0, 500.0))
    videos = np.stack([render_bar_images(c, bar, rng=rng, noise=2.0) for c in cams])
    nominal = poor_guess(cams, rng=rng, pose_mm=30.0, pose_deg=2.0, f_rel=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        cal = calibrate_rig(videos, 800.0, nominal, reject_k=4.0)
    assert cal.rms_over_limit < 1.5
