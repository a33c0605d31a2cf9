from dataclasses import replace

import numpy as np
import pytest

from conftest import smaller
from lsmta.evaluation.surface import (
    classify_misses,
    node_truth,
    score_points,
    score_surface,
    seeds_from_truth,
)
from lsmta.matching import (
    GrowParams,
    LSMThresholds,
    MeasureSurfaceParams,
    find_seeds,
    measure_surface,
    peers,
)
from lsmta.synth import Renderer, Scene, make_body, triplet_rig, walk


@pytest.fixture(scope="module")
def triplet():
    """A walking body in front of a half-resolution triplet at 2.5 m: cameras, scene, frame 5."""
    rng = np.random.default_rng(5)
    cams = [smaller(c) for c in triplet_rig(rng=rng, distance=2500.0, baseline=700.0)]
    scene = Scene(make_body(rng=rng, wavelength=(12.0, 50.0)),
                  walk(n_frames=20, start=(-300.0, 0.0)), None)
    return cams, scene, Renderer(scene, cams, noise_sigma=1.0).render(5, rng=rng)


@pytest.mark.slow
def test_seeds_scores_and_sgbm_on_a_small_triplet(triplet):
    small, scene, frame = triplet
    rng = np.random.default_rng(6)
    seeds = seeds_from_truth(scene, small, 5, rng=rng)
    assert seeds.shape[0] == 3 and seeds.shape[1] >= 6
    truth = node_truth(frame, scene, small, step=3, patch=9)
    assert truth["visible"].sum() > 100 and not truth["visible"][~truth["on_body"]].any()
    th = LSMThresholds(max_displacement=3.0, max_sigma_xy=0.3, scale_range=(0.5, 2.0),
                       max_shear=0.5)
    res = measure_surface(frame.images, small, seeds, params=MeasureSurfaceParams(
        grow=GrowParams(step=3, patch=9, thresholds=th), voxel=25.0))
    score = score_surface(res, truth)
    assert 0.6 < score["density"] <= 1.0
    assert score["filtered"]["median_mm"] < 4.0
    assert score["voxel"]["n"] <= score["filtered"]["n"]
    # nothing kept (e.g. a poor-texture run): zero counts and NaN errors, not a crash
    none = replace(res, neighbourhood_ok=np.zeros_like(res.neighbourhood_ok), cloud=None,
                   intersection=replace(res.intersection,
                                        valid=np.zeros_like(res.intersection.valid)))
    empty = score_surface(none, truth)
    assert empty["density"] == 0 and empty["filtered"]["n"] == empty["raw"]["n"] == 0
    assert np.isnan(empty["filtered"]["median_mm"]) and np.isnan(empty["raw"]["gross_target"])
    sg = peers.sgbm(frame.images[0], frame.images[1], small[0], small[1])
    assert len(sg.points) > 100 and sg.seconds > 0
    s = score_points(sg.points, sg.xy_first, node_truth(frame, scene, small, template=0,
                                                        step=3, patch=9), frame, template=0)
    # SGBM covers nearly every grid cell, but is less accurate than LSM and has more gross
    # errors (notebook 03's comparison, on the small triplet)
    assert 0.9 < s["density"] <= 1
    assert score["filtered"]["median_mm"] < s["median_mm"] < 20.0
    assert s["gross"] > score["filtered"]["gross"]
    misses = classify_misses(res, truth, frame)
    assert misses["missed"] == misses["at_depth_jump"] + misses["smooth_missed"]
    assert misses["missed"] <= misses["target"] == int((truth["visible"] & truth["interior"]).sum())


@pytest.mark.slow
def test_find_seeds_agree_with_truth(triplet):
    small, _, frame = triplet
    seeds = find_seeds(frame.images, small, n_seeds=8, patch=9, min_distance=12)
    assert seeds.xy.shape[1] >= 4 and np.all(seeds.score >= 0.8)
    ij = np.rint(seeds.xy[1]).astype(int)
    world = frame.world_xyz[1][ij[:, 1], ij[:, 0]]
    for k in (0, 2):
        err = np.linalg.norm(small[k].project(world) - seeds.xy[k], axis=1)
        assert np.median(err) < 1.0                 # depth sampling: well inside LSM's pull-in
    with pytest.raises(ValueError, match="depth_range"):
        find_seeds(frame.images, small, depth_range=(3000.0, 1000.0))
    # a template lens that folds over inside the frame: corners past the fold are passed over
    c = small[1]
    r_fold = 0.5 * np.hypot(c.width, c.height) / 2 / c.f     # normalised radius of the fold
    folded = [c.replace(k1=0.0, k2=-1.0 / (5 * r_fold ** 4)) if k == 1 else cam
              for k, cam in enumerate(small)]
    grid = np.stack(np.meshgrid(np.arange(c.width), np.arange(c.height)), -1).reshape(-1, 2)
    assert not folded[1].invertible(grid.astype(float)).all()
    seeds = find_seeds(frame.images, folded, n_seeds=8, patch=9, min_distance=12, min_score=-1)
    assert seeds.xy.shape[1] > 0 and folded[1].invertible(seeds.xy[1]).all()
