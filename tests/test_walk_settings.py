"""The LSMTA system's settings for a walking person (issue 36's coverage): the trajectory
filters keep a swinging limb that notebook 05's values cut, still cut a gross jump, and the
seeds' spacing follows the subject's scale in the image. No rendering: synthetic
trajectories and a monkeypatched seed search."""

from __future__ import annotations

import warnings
from dataclasses import asdict

import numpy as np
import pytest

from lsmta.camera import Camera
from lsmta.matching import Seeds
from lsmta.systems import BodySystemParams, FilterParams, SurfaceParams
from lsmta.systems import surfaces as surfaces_module
from lsmta.systems.surfaces import measure_surfaces, seed_spacing_px, working_distance
from lsmta.tracking import Trajectories, apply_filters

FPS = 25.0


def _walk_like(rng):
    """A trunk of 60 points moving at 1.3 m/s, a foot of 30 points that swings (forward
    speed 1.3 m/s plus a swing peaking at 3.2 m/s, so up to 4.5 m/s, with ~50 m/s² of
    acceleration), and one trunk point that jumps 400 mm for good in frame 10 (a wrong
    match): (T, N, 3) mm and the index groups."""
    T = 20
    t = np.arange(T) / FPS
    trunk = rng.uniform(-150, 150, (60, 3)) + [0.0, 0.0, 1200.0]
    foot = rng.uniform(-40, 40, (30, 3)) + [0.0, 300.0, 100.0]
    x = np.empty((T, 90, 3))
    x[:, :60] = trunk[None] + (1300.0 * t)[:, None, None] * [1.0, 0.0, 0.0]
    w = 2 * np.pi * 0.9                                    # a swing about every 1.1 s
    swing = 3200.0 / w * (1 - np.cos(w * t))               # speed 3200 sin(w t), mm/s
    x[:, 60:] = foot[None] + ((1300.0 * t + swing)[:, None, None] * [1.0, 0.0, 0.0])
    x[10:, 5] += [0.0, 400.0, 0.0]
    return x, np.arange(60), np.arange(60, 90)


def test_walking_filters_keep_a_swinging_foot_and_cut_a_jump():
    x, trunk, foot = _walk_like(np.random.default_rng(0))
    tr = Trajectories(x, FPS)
    assert np.nanmax(tr.step_speed[:, foot]) > 4000.0       # faster than notebook 05's limit
    paper = apply_filters(tr, **asdict(FilterParams()))
    walking = apply_filters(tr, **asdict(FilterParams.walking()))
    # the threshold filter: notebook 05's 2 m/s cuts every foot trajectory early, the
    # walking limits keep the foot whole, and the trunk
    assert (paper[0].cut_frame[foot] >= 0).all() and paper[0].removed[foot].mean() > 0.5
    assert walking[0].trajectories.present[:, foot].all()
    assert walking[0].trajectories.present[:, np.setdiff1d(trunk, [5])].all()
    # the wrong match is still cut where it jumps (10 m/s between two frames)
    assert not walking[-1].trajectories.present[10:, 5].any()
    # after all three filters most of the foot is left (the uniformity filter, which pools
    # a frame either side, still cuts some accelerating points), against almost none
    kept = walking[-1].trajectories.present[:, foot].mean()
    assert kept > 0.5 and paper[-1].trajectories.present[:, foot].mean() < 0.2 * kept


def test_walking_settings():
    f = FilterParams.walking()
    assert f.max_speed == 6000.0 and f.max_acceleration == 100000.0 and f.voxel == 75.0
    assert FilterParams() != f                              # notebook 05's stay the default
    p = BodySystemParams.walking()
    assert p.filters == f and p.arm is None
    assert p.surface.seed_spacing_mm == 50.0 and p.surface.n_seeds == 200
    assert BodySystemParams().surface.seed_spacing_mm is None   # capture_body unchanged
    assert p.capture().filters == f


def _pair():
    cams = [Camera.look_at((x, -3500.0, 1000.0), (0.0, 0.0, 1000.0), f=952.4, width=160,
                           height=120) for x in (-300.0, 300.0)]
    return cams


def test_seed_spacing_follows_the_scale():
    cams = _pair()
    d = working_distance(cams, 0)
    assert seed_spacing_px(cams[0], d, None) == 25
    assert seed_spacing_px(cams[0], d, 50.0) == round(50.0 * 952.4 / d)      # 13 px
    assert seed_spacing_px(cams[0], 2 * d, 50.0) == round(25.0 * 952.4 / d)  # farther: closer
    assert seed_spacing_px(cams[0], d, 1.0) == 3                              # at least 3 px


def test_measure_surfaces_passes_the_spacing_to_the_seed_search(monkeypatch):
    cams = _pair()
    asked = []

    def no_seeds(images, cameras, **kw):                   # records, finds nothing
        asked.append(kw["min_distance"])
        K = len(cameras)
        return Seeds(xy=np.zeros((K, 0, 2)), score=np.zeros(0), depth=np.zeros(0),
                     A=np.zeros((K, 0, 2, 2)))

    monkeypatch.setattr(surfaces_module, "find_seeds", no_seeds)
    videos = np.random.default_rng(1).integers(0, 255, (2, 1, 120, 160)).astype(np.uint8)
    d = working_distance(cams, 0)
    for spacing, px in ((None, 25), (50.0, round(50.0 * 952.4 / d))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = measure_surfaces(videos, cams, [0], sigma=1.0, params=SurfaceParams(
                template=0, seed_spacing_mm=spacing))
        assert out == {} and asked[-1] == px


def test_walking_settings_bad_input():
    for bad in (0.0, -5.0, float("nan")):
        with pytest.raises(ValueError, match="seed_spacing_mm"):
            SurfaceParams(seed_spacing_mm=bad)
    with pytest.raises((TypeError, ValueError), match="seed_spacing_mm"):
        SurfaceParams(seed_spacing_mm="wide")
    with pytest.raises(TypeError, match="seed_spacing_mm"):
        SurfaceParams(seed_spacing_mm=True)
    for given in (np.float32(50.0), np.array(50.0)):              # stored as a float
        got = SurfaceParams(seed_spacing_mm=given).seed_spacing_mm
        assert type(got) is float and got == 50.0
    cams = _pair()
    with pytest.raises(ValueError, match="spacing_mm"):
        seed_spacing_px(cams[0], 3500.0, -1.0)
    with pytest.raises(ValueError, match="distance"):
        seed_spacing_px(cams[0], 0.0, 50.0)
