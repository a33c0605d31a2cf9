"""The growth's census (every LSM attempt and every grid node by outcome) and the precision
rule for which nodes are tried (GrowParams.noise; the surface stage's texture_rule)."""

import numpy as np
import pytest

from conftest import smaller
from lsmta.matching import LSMThresholds, MeasureSurfaceParams, measure_surface
from lsmta.matching.grow import (
    ATTEMPT_OUTCOMES,
    NODE_OUTCOMES,
    AttemptOutcome,
    GrowParams,
    NodeOutcome,
    grow_matches,
)
from lsmta.matching.lsm import THRESHOLD_TESTS, Status
from lsmta.synth import Renderer, Scene, make_body, project_surface_points, triplet_rig, walk
from lsmta.synth.patches import warped_pair
from lsmta.systems import SurfaceParams
from lsmta.systems.surfaces import surface_census

A_TRUE = np.array([[1.03, 0.05], [-0.04, 0.98]])


def test_outcomes_are_int_enums_in_the_census_order():
    # the attempt outcomes follow the threshold tests and LSM's failure statuses by name
    assert ATTEMPT_OUTCOMES == ("accepted",) + THRESHOLD_TESTS + tuple(
        s.name.lower() for s in (Status.MAX_ITERATIONS, Status.DIVERGED, Status.OUTSIDE,
                                 Status.SINGULAR))
    assert [int(o) for o in AttemptOutcome] == list(range(len(ATTEMPT_OUTCOMES)))
    assert NODE_OUTCOMES == ("outside", "masked", "no_texture", "matched", "given_up",
                             "failed_open", "never_reached")


def test_census_adds_up_and_names_the_test_that_rejects():
    pair = warped_pair(rng=0, shape=(120, 140), A=A_TRUE, c=(5.3, -3.2), noise_sigma=2.0)
    seeds = np.array([[40.0, 40.0], [100.0, 80.0]])
    approx = pair.true_xy(seeds)
    approx[1] += 40.0                                   # a hopeless seed
    mask = np.zeros(pair.template.shape, dtype=bool)
    mask[:, :100] = True
    res = grow_matches(pair.template, pair.search, seeds, approx, mask=mask,
                       params=GrowParams(step=4, patch=13))
    rows, cols = res.grid_shape
    assert list(res.attempt_census) == list(ATTEMPT_OUTCOMES)
    assert list(res.node_census) == list(NODE_OUTCOMES)
    assert sum(res.attempt_census.values()) == res.n_lsm
    assert sum(res.node_census.values()) == rows * cols
    assert res.node_census["matched"] == len(res)
    assert res.node_census["masked"] > 0
    # the same census node by node: the grid of outcomes, and why the tried ones failed
    assert res.node_outcome.shape == (rows, cols)
    for i, name in enumerate(NODE_OUTCOMES):
        assert (res.node_outcome == i).sum() == res.node_census[name]
    matched = res.node_outcome == NodeOutcome.MATCHED
    assert set(zip(*np.nonzero(matched))) == set(map(tuple, res.node_index))
    failed = np.isin(res.node_outcome, [NodeOutcome.GIVEN_UP, NodeOutcome.FAILED_OPEN])
    assert (res.node_failure[failed] > 0).all()          # a reason other than "accepted"
    assert (res.node_failure[~failed] == -1).all()
    assert (res.node_outcome[:, 100 // 4 + 1:] == NodeOutcome.MASKED).any()
    # the mask, worked out here: nodes right of column 100 px are masked unless outside the
    # image's usable part, and no node left of it is
    cols_px = np.arange(cols) * 4
    outcome_right = res.node_outcome[:, cols_px >= 100]
    assert np.isin(outcome_right, [NodeOutcome.MASKED, NodeOutcome.OUTSIDE]).all()
    assert not (res.node_outcome[:, cols_px < 100] == NodeOutcome.MASKED).any()
    # a sigma0 limit below the images' noise (2 grey levels each) rejects nearly every match,
    # and the census says so
    tight = GrowParams(step=4, patch=13, thresholds=LSMThresholds(max_sigma0=1.0,
                                                                 max_displacement=4.0))
    res = grow_matches(pair.template, pair.search, seeds, pair.true_xy(seeds), params=tight)
    c = res.attempt_census
    assert c["sigma0"] > 0.9 * (res.n_lsm - c["accepted"])
    sigma0 = AttemptOutcome.SIGMA0
    failed = res.node_failure >= 0
    assert (res.node_failure[failed] == sigma0).mean() > 0.9
    assert sum(c.values()) == res.n_lsm


def test_precision_rule_keeps_low_contrast_nodes_the_spread_rule_skipped():
    # a quiet camera (noise 0.1 grey levels) and a faint texture (spread 1.5 grey levels):
    # the 2-grey-level spread rule tries almost nothing; the precision rule tries the patches,
    # and they match to a few hundredths of a pixel (truth from the generator)
    pair = warped_pair(rng=0, shape=(120, 140), A=A_TRUE, c=(5.3, -3.2), noise_sigma=0.1,
                       amplitude=1.5, quantise=False)
    seeds = np.array([[40.0, 40.0], [100.0, 80.0]])
    spread = grow_matches(pair.template, pair.search, seeds, pair.true_xy(seeds),
                          params=GrowParams(step=4, patch=13))
    rule = grow_matches(pair.template, pair.search, seeds, pair.true_xy(seeds),
                        params=GrowParams(step=4, patch=13, noise=0.1))
    assert spread.node_census["no_texture"] > 0.9 * sum(
        v for k, v in spread.node_census.items() if k not in ("outside", "masked"))
    assert len(rule) > 20 * max(len(spread), 1)
    assert rule.node_census["no_texture"] == 0
    err = np.linalg.norm(rule.search_xy - pair.true_xy(rule.template_xy), axis=1)
    assert np.median(err) < 0.05


def test_precision_rule_skips_only_nodes_that_cannot_pass():
    # the right half of both images is noise alone (3 grey levels, a spread above the 2 of
    # the spread rule): the precision rule skips it, and no node there matches when every
    # node is tried
    noise = 3.0
    pair = warped_pair(rng=1, shape=(120, 160), A=A_TRUE, c=(5.3, -3.2), noise_sigma=noise)
    rng = np.random.default_rng(2)
    t, s = pair.template.astype(float), pair.search.astype(float)
    t[:, 80:] = 128 + rng.normal(0, noise, t[:, 80:].shape)
    s[:, 80:] = 128 + rng.normal(0, noise, s[:, 80:].shape)
    seeds = np.array([[40.0, 40.0], [40.0, 80.0]])
    every = grow_matches(t, s, seeds, pair.true_xy(seeds),
                         params=GrowParams(step=4, patch=13, min_texture=0.0))
    rule = grow_matches(t, s, seeds, pair.true_xy(seeds),
                        params=GrowParams(step=4, patch=13, noise=noise))
    spread = grow_matches(t, s, seeds, pair.true_xy(seeds), params=GrowParams(step=4, patch=13))
    assert spread.node_census["no_texture"] == 0          # noise passes the spread rule
    rows, cols = rule.grid_shape
    flat = sum(1 for r in range(rows) for c in range(cols)
               if 80 + 10 <= 4 * c <= 160 - 10 and 10 <= 4 * r <= 120 - 10)
    assert rule.node_census["no_texture"] >= 0.9 * flat
    assert set(map(tuple, rule.node_index)) == set(map(tuple, every.node_index))


@pytest.fixture(scope="module")
def triplet():
    rng = np.random.default_rng(3)
    cams = [smaller(c) for c in triplet_rig(rng=rng, distance=2500.0, baseline=700.0)]
    body = make_body(rng=rng, wavelength=(12.0, 50.0))
    scene = Scene(body, walk(n_frames=20, start=(-300.0, 0.0)), None)
    frame = Renderer(scene, cams, noise_sigma=1.0).render(5, rng=rng)
    part, local = body.sample_surface(n_per_part=20, rng=np.random.default_rng(1),
                                      parts=["torso", "thigh_r"])
    proj = project_surface_points(scene, cams, part, local, frames=5)
    seen = np.flatnonzero(proj.visible[0].all(axis=0))[:6]
    return frame, cams, proj.xy[0][:, seen] + rng.uniform(-0.5, 0.5, (3, len(seen), 2))


def test_surface_census_adds_up(triplet):
    frame, cams, seeds = triplet
    grow = GrowParams(step=4, patch=9, retry_patch=(13,), noise=1.0)
    res = measure_surface(frame.images, cams, seeds, params=MeasureSurfaceParams(grow=grow))
    c = surface_census(res)
    assert len(c["growth"]) == 2 and c["tuples"] > 100
    assert c["tuples"] == c["neighbourhood_dropped"] + c["not_intersected"] + c["kept"]
    assert c["kept"] == int(res.kept.sum())
    for g, grown in zip(c["growth"], res.grown):
        assert sum(g["attempts"].values()) == grown.n_lsm
        assert g["nodes"]["matched"] == len(grown) >= c["tuples"]
        assert g["seeds"] == 6


def test_bad_rule_arguments():
    with pytest.raises(ValueError, match="noise"):
        GrowParams(noise=-1.0)
    with pytest.raises(ValueError, match="texture_rule"):
        SurfaceParams(texture_rule="contrast")
