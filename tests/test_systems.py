"""The LSMTA system from pixels (lsmta.systems): a small generated session end to end,
scored against the generator's truth after the fact, and bad input for every argument."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lsmta.evaluation import body_system as bs
from lsmta.systems import (
    SurfaceParams,
    calibrate_rig,
    capture_body,
    level_rig,
    measure_surfaces,
    rig,
)


@pytest.fixture(scope="module")
def tiny():
    """A 12-frame session at half the image size (quick), and the system run on it."""
    session = bs.arm_wave_session(seed=7, n_frames=12, first=20, scale=0.5,
                                  params=bs.ArmWaveSessionParams(n_bar=60, n_heldout=20))
    videos, bars = session.videos.copy(), session.bar_videos.copy()
    poses = [(c.R.copy(), c.C.copy(), c.f) for c in session.nominal]
    capture = capture_body(session.videos, session.bar_videos, session.bar_length,
                           session.nominal, fps=session.fps, progress=False)
    unchanged = (np.array_equal(videos, session.videos)
                 and np.array_equal(bars, session.bar_videos)
                 and all(np.array_equal(R, c.R) and np.array_equal(C, c.C) and f == c.f
                         for (R, C, f), c in zip(poses, session.nominal)))
    return session, capture, unchanged


@pytest.mark.slow
def test_capture_body_against_the_truth(tiny):
    session, capture, unchanged = tiny
    assert unchanged
    al = bs.world_alignment(capture.cameras, session)
    # calibration: check points, and residuals at the targets' own noise level
    assert bs.calibration_scores(capture.cameras, session)["check_rms"] < 0.3
    assert 0.85 < capture.calibration.rms_over_limit < 1.15
    assert abs(capture.noise.sigma / np.sqrt(session.noise_sigma**2 + 1 / 12) - 1) < 0.1
    # the first frame's surface
    s = bs.score_system_surface(capture.surfaces[0], bs.surface_truth(session, 0), al)
    assert s["density"] > 0.8 and s["filtered"]["median_mm"] < 0.6
    # trajectories at the last frame
    score, part, _ = bs.score_system_tracks(session, capture.tracks, capture.filtered,
                                            alignment=al)
    last, n = bs.last_frame_error(score, capture.filtered.present)
    assert n > 100 and last < 1.5
    # the arm: groups found by their true parts, joints near the truth, a fit near the truth
    start = capture.arm.start
    parts = bs.group_parts(session, start.groups, part)
    for g, want in ((start.torso, "torso"), (start.upper_arm, "upper_arm_r"),
                    (start.forearm, "forearm_r")):
        assert max(parts[g], key=parts[g].get) == want
    truth = bs.session_arm_truth(session)
    err = np.median(bs.joint_position_errors(start, truth, al), axis=0)
    assert err[0] < 20 and err[1] < 20
    assert len(capture.arm.frames) >= 8                  # both segments tracked in most
    fit = bs.score_arm(capture.arm.simplified, start.torso_poses, truth,
                       frames=capture.arm.frames, alignment=al)
    assert fit["max_angle_err_deg"] < 6.0
    assert np.abs(fit["length_err_pct"]).max() < 10.0
    # the summary names every stage with its time
    rows = capture.summary()
    assert [r["stage"] for r in rows] == list(capture.seconds)
    assert all(np.isfinite(r["seconds"]) for r in rows)


@pytest.fixture(scope="module")
def small():
    return bs.arm_wave_session(seed=8, n_frames=4, first=20, scale=0.5,
                               params=bs.ArmWaveSessionParams(n_bar=20, n_heldout=2))


def test_capture_body_bad_input(small):
    s = small
    v, b, L, cams = s.videos, s.bar_videos, s.bar_length, s.nominal
    with pytest.raises(ValueError, match="videos: expected 3 videos"):
        capture_body(v[:2], b, L, cams)
    with pytest.raises(ValueError, match=r"videos: expected an array of shape \(K, T, H, W\)"):
        capture_body(v[0], b, L, cams)
    with pytest.raises(ValueError, match="videos: camera .* but its frames are"):
        capture_body(v[:, :, :-1], b, L, cams)
    with pytest.raises(TypeError, match="videos: expected grey values"):
        capture_body(v.astype(bool), b, L, cams)
    with pytest.raises(ValueError, match="videos: contains non-finite"):
        bad = v.astype(float)
        bad[0, 0, 0, 0] = np.nan
        capture_body(bad, b, L, cams)
    with pytest.raises(ValueError, match="videos: expected at least 3 frames"):
        capture_body(v[:, :2], b, L, cams)
    with pytest.raises(TypeError, match="nominal_cameras"):
        capture_body(v, b, L, ["left", "centre", "right"])
    with pytest.raises(ValueError, match="fps"):
        capture_body(v, b, L, cams, fps=0.0)
    with pytest.raises(ValueError, match="frames: expected consecutive"):
        capture_body(v, b, L, cams, frames=[0, 2, 3])
    with pytest.raises(ValueError, match=r"frames: expected indices in \[0, 3\]"):
        capture_body(v, b, L, cams, frames=range(2, 6))
    with pytest.raises(TypeError, match="params"):
        capture_body(v, b, L, cams, params={"density_every": 2})
    with pytest.raises(ValueError, match="bar_videos: expected 3 videos"):
        capture_body(v, b[:2], L, cams, progress=False)
    with pytest.raises(ValueError, match="bar_videos: expected at least 10 frames"):
        capture_body(v, b[:, :5], L, cams, progress=False)
    with pytest.raises(ValueError, match="bar_length"):
        capture_body(v, b, -400.0, cams, progress=False)
    lv = s.level_videos
    with pytest.raises(ValueError, match="level_videos: expected 3 videos"):
        capture_body(v, b, L, cams, level_videos=lv[:2], progress=False)
    with pytest.raises(ValueError, match="level_videos: expected at least 3 frames"):
        capture_body(v, b, L, cams, level_videos=lv[:, :2], progress=False)
    with pytest.raises(ValueError, match="level_videos: camera .* but its frames are"):
        capture_body(v, b, L, cams, level_videos=lv[:, :, :10], progress=False)
    blank = np.full_like(b, 25)
    blank[0] = b[0]                          # the bar only in one camera
    with pytest.raises(ValueError, match="seen by at least two cameras in 0 of"):
        capture_body(v, blank, L, cams, progress=False)


def test_stage_functions_bad_input(small):
    s = small
    with pytest.raises(ValueError, match="bar_videos: camera .* but its frames are"):
        calibrate_rig(s.bar_videos[:, :, :10], s.bar_length, s.nominal)
    with pytest.raises(ValueError, match=r"frames: expected frame indices in \[0, 3\]"):
        measure_surfaces(s.videos, s.cameras, [0, 9], sigma=2.0)
    with pytest.raises(ValueError, match="sigma"):
        measure_surfaces(s.videos, s.cameras, [0], sigma=-1.0)
    with pytest.raises(ValueError, match="params.template"):
        measure_surfaces(s.videos, s.cameras, [0], sigma=2.0, params=SurfaceParams(template=5))


def test_surfaces_pass_over_where_a_lens_folds(small):
    s = small
    c = s.cameras[1]                                          # the template
    # r (1 + k3 r^6) folds where 1 + 7 k3 r^6 = 0; nearly no distortion well inside that
    r_fold = 0.8 * np.hypot(c.width, c.height) / 2 / c.f
    folded = [cam.replace(k3=cam.k3 - 1.0 / (7 * r_fold ** 6)) if k == 1 else cam
              for k, cam in enumerate(s.cameras)]
    grid = np.stack(np.meshgrid(np.arange(c.width), np.arange(c.height)), -1).reshape(-1, 2)
    inverts = folded[1].invertible(grid.astype(float))
    assert 0 < inverts.mean() < 1                             # folds inside the frame
    res = measure_surfaces(s.videos, folded, [0], sigma=2.0)[0]   # raised before
    assert len(res.points) > 0
    assert folded[1].invertible(res.template_xy[res.neighbourhood_ok]).all()


def _tilted(cameras, deg, axis=(1.0, 0.0, 0.0)):
    """The same rig in a world turned by ``deg`` about ``axis`` (a tape's tilted up)."""
    Q = Rotation.from_rotvec(np.radians(deg) * np.asarray(axis)).as_matrix()
    return [c.replace(R=c.R @ Q.T, C=Q @ c.C) for c in cameras], Q


def test_level_rig_finds_the_vertical(small):
    """A world tilted by 3 degrees comes back level to the spirit level's error (the bar
    stands 0.2 degrees per axis off vertical at each of its places)."""
    s = small
    tilted, _ = _tilted(s.cameras, 3.0, (0.6, 0.8, 0.0))
    before = [(c.R.copy(), c.C.copy()) for c in tilted]
    levelled, lev = level_rig(tilted, s.level_videos, s.bar_length)
    assert all(np.array_equal(R, c.R) and np.array_equal(C, c.C)       # inputs untouched
               for (R, C), c in zip(before, tilted))
    assert lev.n_frames >= 0.8 * s.level_videos.shape[1]
    assert abs(lev.correction_deg - 3.0) < 0.5
    assert lev.spread_deg < 1.0
    # the levelled world's up against the true one: the rig's attitude relative to the truth
    rel = Rotation.from_matrix(np.stack([t.R.T @ c.R for t, c in zip(s.cameras, levelled)]))
    up = rel.mean().as_matrix() @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < 0.5
    # turned, not moved: distances between the cameras are kept
    d = lambda cams: np.linalg.norm(cams[0].C - cams[2].C)               # noqa: E731
    assert abs(d(levelled) - d(tilted)) < 1e-9


def test_level_rig_drops_a_corrupted_frame(small):
    """One frame with camera 0's image from another place: its targets no longer meet, the
    frame is dropped and the up direction stays where the clean frames put it."""
    s = small
    _, clean = level_rig(s.cameras, s.level_videos, s.bar_length)
    bad = s.level_videos.copy()
    bad[0, 0] = s.level_videos[0, -1]
    _, lev = level_rig(s.cameras, bad, s.bar_length)
    assert clean.n_dropped == 0 and lev.n_dropped == 1
    assert lev.n_frames == clean.n_frames - 1
    assert np.degrees(np.arccos(np.clip(lev.up @ clean.up, -1, 1))) < 0.1


def test_robust_direction_ignores_one_bad_direction():
    """Eleven directions 0.2 degrees about +Z and one 20 degrees off: the plain mean moves
    by more than a degree, the robust mean stays with the eleven."""
    rng = np.random.default_rng(0)
    good = np.column_stack([rng.normal(0, np.radians(0.2), (11, 2)), np.ones(11)])
    d = np.vstack([good, [np.sin(np.radians(20.0)), 0.0, np.cos(np.radians(20.0))]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    unit = lambda v: v / np.linalg.norm(v)                              # noqa: E731
    deg = lambda a, b: np.degrees(np.arccos(np.clip(a @ b, -1, 1)))     # noqa: E731
    clean = unit(d[:11].mean(axis=0))
    assert deg(unit(d.mean(axis=0)), clean) > 1.0
    up, inside = rig._robust_direction(d)
    assert deg(up, clean) < 1e-9 and inside.tolist() == [True] * 11 + [False]


@pytest.mark.slow
def test_calibrate_rig_datum_includes_the_levelling():
    """With level_videos the datum maps the adjustment's frame onto the levelled cameras."""
    s = bs.arm_wave_session(seed=8, n_frames=3, first=20, scale=0.5,
                            params=bs.ArmWaveSessionParams(n_bar=60, n_heldout=2))
    cal = calibrate_rig(s.bar_videos, s.bar_length, s.nominal, level_videos=s.level_videos)
    assert cal.level is not None
    Q, t = cal.datum_rotation, cal.datum_translation
    assert np.allclose(Q @ Q.T, np.eye(3), atol=1e-12)
    for b, c in zip(cal.bundle.cameras, cal.cameras):
        assert np.allclose(Q @ b.C + t, c.C, atol=1e-6)
        assert np.allclose(b.R @ Q.T, c.R, atol=1e-12)


def test_score_arm_own_frame_bad_input():
    fit = SimpleNamespace(state=SimpleNamespace(angles=np.zeros((5, 4))))
    truth = SimpleNamespace(angles=np.zeros((10, 4)))
    assert bs.score_arm_own_frame(fit, truth, frames=np.arange(5))["max_angle_err_deg"] == 0.0
    with pytest.raises(ValueError, match="frames: expected the fit's 5 frame indices"):
        bs.score_arm_own_frame(fit, truth, frames=np.arange(4))
    with pytest.raises(ValueError, match=r"frames: expected frame indices in \[0, 9\]"):
        bs.score_arm_own_frame(fit, truth, frames=np.arange(6, 11))
    with pytest.raises(ValueError, match="frames: expected integer"):
        bs.score_arm_own_frame(fit, truth, frames=np.arange(5.0))
    with pytest.raises(ValueError, match="score_frames"):
        bs.score_arm_own_frame(fit, truth, frames=np.arange(5), score_frames=[7])


@pytest.mark.parametrize("kwargs, match", [
    (dict(level_places=-1), "level_places"), (dict(level_places=1.5), "level_places"),
    (dict(level_places=True), "level_places"), (dict(level_deg=-0.1), "level_deg"),
    (dict(level_deg=float("nan")), "level_deg"),
])
def test_arm_wave_session_params_level_bad_input(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        bs.ArmWaveSessionParams(**kwargs)


def test_level_rig_bad_input(small):
    s = small
    with pytest.raises(ValueError, match="level_videos: expected 3 videos"):
        level_rig(s.cameras, s.level_videos[:2], s.bar_length)
    with pytest.raises(ValueError, match="bar_length"):
        level_rig(s.cameras, s.level_videos, 0.0)
    with pytest.raises(TypeError, match="cameras"):
        level_rig(["a", "b", "c"], s.level_videos, s.bar_length)
    tilted, _ = _tilted(s.cameras, 30.0)
    with pytest.raises(ValueError, match=r"level_videos: the bar stands \d+\.\d degrees from"):
        level_rig(tilted, s.level_videos, s.bar_length)
    blank = np.full_like(s.level_videos, 25)
    blank[0] = s.level_videos[0]                    # the bar only in one camera
    with pytest.raises(ValueError, match="level_videos: both targets are intersected in 0"):
        level_rig(s.cameras, blank, s.bar_length)
