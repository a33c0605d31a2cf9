"""The range-of-motion clip through the LSMTA system on a tiny generated studio session
(issue 36, item 2): the full body fitted over the clip from the system's points gives the
build the walk fit starts from; no truth enters the capture or the fits; the lengths are
scored after the fact."""

import numpy as np
import pytest

from conftest import tiny_studio_walk
from lsmta.body.full_fit import BodyShape, FullBodyFitParams
from lsmta.evaluation import walk_full_fit as wf
from lsmta.evaluation import walk_system as ws
from lsmta.evaluation.full_body import length_errors
from lsmta.synth import range_of_motion, walk
from lsmta.systems import capture_recording


@pytest.fixture(scope="module")
def tiny_rom():
    # the studio at 3/4 size (as tests/test_walk_full_fit.py), three walk frames and two
    # frames of each movement of the clip (standing, the movement's extreme); the capture
    # and the fits see nothing but the videos, the bar and the tape-measured cameras
    session, cap, system = tiny_studio_walk(scale=0.75, n_frames=3, rom_per_phase=2)
    gap = float(np.median(np.diff(session.rom_frames)))
    rom = capture_recording(session.rom_videos, cap.calibration.cameras,
                            fps=session.fps / gap, calibration=cap.calibration,
                            params=system.capture(), progress=False)
    fit_params = FullBodyFitParams(n_rounds=2, min_neighbours=2)
    alone = wf.fit_walk(cap, max_points=300, params=fit_params)
    rf = wf.fit_rom(rom, max_points=300, shape=alone.fit.body_shape(), params=fit_params)
    build = rf.walk_fit.fit.body_shape()
    fixed = wf.fit_walk(cap, max_points=300, shape=build,
                        params=FullBodyFitParams(n_rounds=2, min_neighbours=2, fit_shape=False))
    return session, rom, rf, alone, fixed


def test_the_walk_from_the_clips_build(tiny_rom):
    session, rom, rf, alone, fixed = tiny_rom
    assert len(rom.frames) == 12 and rf.walk_fit.frames.tolist() == list(range(12))
    body = session.scene.body
    # after the fact: lengths need no alignment
    before = {k: 100 * (a / b - 1) for k, (a, b) in length_errors(alone.fit, body).items()}
    after = {k: 100 * (a / b - 1) for k, (a, b) in length_errors(fixed.fit, body).items()}
    # measured at these settings (~55 s CPU, nearly all in the fixture; the clip's fit ~2 s):
    # heading -89.9 deg (the truth faces -90); walk alone -> walk with the clip's build held
    # (each clip frame also solved from the rest pose, the last one, the squat's extreme,
    # left out of the shape solve by fit_rom's drop rule): hip width -14.3 -> -11.4 %, trunk
    # -13.3 -> -12.1 %, forearm -23.3 -> -21.6 %, shoulder width 5.4 -> 5.3 %, shank 1.3 ->
    # 3.1 %, thigh -4.8 -> -6.2 %, upper arm 26.8 -> 29.8 % (worse: the clip's raised-arm
    # frames are fitted poorly)
    assert abs(np.degrees(rf.heading) + 90.0) < 10.0        # facing -y, found, not given
    assert abs(after["hip width"]) < abs(before["hip width"]) - 2.0
    assert abs(after["trunk"]) < abs(before["trunk"])
    assert all(abs(v) < 30.0 for v in after.values())
    assert np.allclose(fixed.fit.scales, rf.walk_fit.fit.scales)      # the build kept
    assert fixed.fit.stature == alone.fit.stature
    assert np.isfinite(rf.statures).sum() >= 6
    assert 9 <= rf.walk_fit.fit.shape_frames.sum() < 12      # the drop rule: few frames out


def test_bad_input_with_a_capture(tiny_rom):
    session, rom, rf, alone, fixed = tiny_rom
    with pytest.raises(TypeError, match="params"):
        wf.fit_rom(rom, params={})
    with pytest.raises(TypeError, match="shape"):
        wf.fit_rom(rom, shape="build")
    with pytest.raises(TypeError, match="shape"):
        wf.fit_walk(rom, shape=(1700.0,))
    with pytest.raises(ValueError, match="heading"):
        wf.fit_walk(rom, heading=np.nan)
    with pytest.raises(ValueError, match="max_points"):
        wf.fit_rom(rom, max_points=0)


def test_rom_clip_frames_cover_every_movement():
    motion = range_of_motion(n_frames=200)
    frames = ws.rom_clip_frames(motion, 4)
    assert len(frames) == 24 and np.all(np.diff(frames) > 0)
    for k, (name, a, b) in enumerate(motion.phases):
        assert np.all((frames[4 * k:4 * k + 4] >= a) & (frames[4 * k:4 * k + 4] < b)), name
        assert frames[4 * k] == a                          # each movement's standing start
    with pytest.raises(ValueError, match="per_phase"):
        ws.rom_clip_frames(motion, 0)
    with pytest.raises(ValueError, match="phases"):
        ws.rom_clip_frames(walk(n_frames=10), 2)


def test_rom_heading_across_the_widest_axis_the_way_the_feet_point():
    rng = np.random.default_rng(0)
    body = rng.normal(size=(2000, 3)) * [200.0, 60.0, 0.0] + [0.0, 0.0, 900.0]
    shanks = rng.normal(size=(200, 3)) * [100.0, 30.0, 50.0] + [0.0, 0.0, 300.0]
    feet = rng.normal(size=(100, 3)) * [100.0, 40.0, 10.0] + [0.0, -80.0, 30.0]  # toward -y
    pts = np.vstack([body, shanks, feet])
    h = wf.rom_heading([pts], stature=1700.0)
    assert abs(np.degrees(h) + 90.0) < 5.0
    flipped = pts * [1.0, -1.0, 1.0]
    assert abs(np.degrees(wf.rom_heading([flipped], stature=1700.0)) - 90.0) < 5.0
    with pytest.raises(ValueError, match="feet"):
        wf.rom_heading([body], stature=1700.0)
    with pytest.raises(ValueError, match="stature"):
        wf.rom_heading([pts], stature=0.0)
    with pytest.raises(ValueError, match="points"):
        wf.rom_heading([], stature=1700.0)
    with pytest.raises(ValueError, match=r"points\[0\]"):
        wf.rom_heading([pts[:, :2]], stature=1700.0)


def test_bad_input_of_the_new_arguments():
    with pytest.raises(ValueError, match="rom_per_phase"):
        ws.WalkSessionParams(rom_per_phase=1)
    with pytest.raises(ValueError, match="rom_per_phase"):
        ws.WalkSessionParams(rom_per_phase=-2)
    with pytest.raises(ValueError, match="rom_clip"):
        ws.WalkSessionParams(rom_per_phase=2, rom_clip=10)
    with pytest.raises(ValueError, match="rom_per_phase"):   # a movement's frames twice
        ws.WalkSessionParams(rom_per_phase=5, rom_clip=24)
    with pytest.raises(TypeError, match="fit_shape"):
        FullBodyFitParams(fit_shape=1)
    with pytest.raises(ValueError, match="stature"):
        BodyShape.template(-1.0)
    with pytest.raises(ValueError, match="scales"):
        BodyShape(stature=1700.0, scales=np.ones(3), limb_shape=np.ones((10, 8)))
    shape = BodyShape.template(1700.0)
    with pytest.raises(ValueError, match="limb_shape"):
        BodyShape(stature=1700.0, scales=shape.scales, limb_shape=np.ones((3, 8)))
    scales = np.ones(len(shape.scales))
    assert BodyShape(stature=1700.0, scales=scales, limb_shape=shape.limb_shape).scales is not \
        scales                                               # the input is copied
