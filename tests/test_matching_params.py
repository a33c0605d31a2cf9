"""The matchers' settings classes: every field checked with an error naming it, and the
defaults (``params=XParams()``) the same numbers as no ``params`` at all."""

from dataclasses import fields, replace

import numpy as np
import pytest

from lsmta.matching import (
    DisparityParams,
    GrowParams,
    LSMParams,
    LSMThresholds,
    MeasureSurfaceParams,
    RectifiedPair,
    correlation_search,
    grow_joint,
    grow_matches,
    lsm,
    lsm_multi,
    measure_disparity,
    measure_surface,
    mpgc,
)
from lsmta.synth import triplet_rig
from lsmta.synth.patches import warped_pair


@pytest.fixture(scope="module")
def pair():
    return warped_pair(rng=np.random.default_rng(0), shape=(120, 150),
                       A=[[1.03, 0.05], [-0.04, 0.98]], c=(5.3, -3.2), r0=5.0, r1=0.9,
                       noise_sigma=2.0)


@pytest.fixture(scope="module")
def rectified():
    return warped_pair(rng=0, shape=(120, 160), A=[[0.96, 0.03], [0.0, 1.0]], c=(-4.3, 0.0),
                       r0=5.0, r1=0.9, noise_sigma=2.0)


def _same(a, b):
    """Every array field of two results (dataclasses, or lists of them) is identical."""
    if isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y)
        return
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) and x.dtype != object:
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f.name


@pytest.mark.parametrize("cls, field, value", [
    (LSMParams, "patch", 12),
    (LSMParams, "geometry", "projective"),
    (LSMParams, "radiometry", "gamma"),
    (LSMParams, "method", "newton"),
    (LSMParams, "max_iter", 0),
    (LSMParams, "max_iter", 2.5),
    (LSMParams, "tol", 0.0),
    (LSMParams, "max_displacement", -1.0),
    (LSMParams, "max_vif", 0.0),
    (LSMParams, "robust", -1.0),
    (LSMParams, "support", np.nan),
    (LSMParams, "partial", "yes"),
    (LSMParams, "thresholds", dict(max_sigma0=3.0)),
    (GrowParams, "step", 0),
    (GrowParams, "patch", 4),
    (GrowParams, "retry_patch", (9, 4)),
    (GrowParams, "thresholds", 0.1),
    (GrowParams, "geometry", "projective"),
    (GrowParams, "max_attempts", 0),
    (GrowParams, "min_texture", -1.0),
    (GrowParams, "close_holes", None),
    (GrowParams, "shift", -1),
    (GrowParams, "robust", 0.0),
    (GrowParams, "robust_patch", 6),
    (GrowParams, "method", "newton"),
    (GrowParams, "support", -2.0),
    (GrowParams, "partial", 1),
    (GrowParams, "max_iter", True),
    (GrowParams, "tol", -1e-4),
    (GrowParams, "reach", "far"),
    (MeasureSurfaceParams, "grow", dict(step=4)),
    (MeasureSurfaceParams, "enhance", "clahe"),
    (MeasureSurfaceParams, "neighbourhood", None),
    (MeasureSurfaceParams, "max_position", 0.0),
    (MeasureSurfaceParams, "max_affine", -0.1),
    (MeasureSurfaceParams, "neighbourhood_statistic", "mode"),
    (MeasureSurfaceParams, "max_reprojection", 0.0),
    (MeasureSurfaceParams, "voxel", -5.0),
    (MeasureSurfaceParams, "joint", "yes"),
    (DisparityParams, "grow", None),
    (DisparityParams, "n_seeds", 0),
])
def test_a_bad_field_is_refused_by_name(cls, field, value):
    with pytest.raises((ValueError, TypeError), match=f"^{field}: expected"):
        cls(**{field: value})


def test_robust_needs_more_iterations_than_its_ramp():
    with pytest.raises(ValueError, match="max_iter: expected more than 3"):
        LSMParams(robust=5.0, max_iter=3)
    with pytest.raises(ValueError, match="max_iter: expected more than 3"):
        GrowParams(robust=5.0, max_iter=3)
    assert LSMParams(robust=5.0, max_iter=4).max_iter == 4


def test_fields_are_normalised_and_the_settings_stay_frozen():
    g = GrowParams(retry_patch=np.int64(9), step=4.0, shift=np.int64(2))
    assert g.retry_patch == (9,) and type(g.step) is int and type(g.shift) is int
    assert GrowParams(retry_patch=[9, 5]).retry_patch == (9, 5)
    assert hash(g) == hash(replace(g))                  # frozen, hashable: usable as a key
    with pytest.raises(AttributeError):
        g.step = 8
    assert GrowParams().lsm_thresholds() == LSMThresholds(max_displacement=4.0)
    th = LSMThresholds(max_sigma0=3.0)
    assert GrowParams(step=8, thresholds=th).lsm_thresholds() is th
    # the disparity's thresholds follow its step unless given
    d = DisparityParams(grow=replace(DisparityParams().grow, step=2)).grow_params()
    assert d.thresholds == LSMThresholds(max_displacement=2.0, max_sigma_xy=0.2,
                                         scale_range=(0.5, 2.0), max_shear=0.5)


def test_params_of_the_wrong_class_are_refused(pair):
    pts = np.array([[60.0, 60.0]])
    with pytest.raises(TypeError, match="params: expected LSMParams"):
        lsm(pair.template, pair.search, pts, pts, params=GrowParams())
    with pytest.raises(TypeError, match="params: expected GrowParams"):
        grow_matches(pair.template, pair.search, pts, pts, params=LSMParams())
    with pytest.raises(TypeError, match="params: expected MeasureSurfaceParams"):
        measure_surface([pair.template] * 3, triplet_rig(), np.zeros((3, 1, 2)),
                        params=GrowParams())


def test_default_params_give_the_same_numbers(pair, rectified):
    rng = np.random.default_rng(1)
    t = rng.uniform(25, 95, (60, 2))
    s = pair.true_xy(t) + rng.uniform(-0.8, 0.8, t.shape)
    f, g = pair.template, pair.search
    _same(lsm(f, g, t, s), lsm(f, g, t, s, params=LSMParams()))
    _same(lsm_multi(f, [g, g], t, [s, s + 0.2]),
          lsm_multi(f, [g, g], t, [s, s + 0.2], params=LSMParams()))
    seeds = np.array([[40.0, 40.0], [110.0, 80.0]])
    approx = pair.true_xy(seeds) + 0.5
    _same(grow_matches(f, g, seeds, approx),
          grow_matches(f, g, seeds, approx, params=GrowParams()))
    rf, rg = rectified.template, rectified.search
    d0 = t[:, 0] - rectified.true_xy(t)[:, 0] + 0.3
    _same(mpgc(rf, rg, t, d0, RectifiedPair()),
          mpgc(rf, rg, t, d0, RectifiedPair(), params=LSMParams()))
    _same(grow_joint(rf, [rg], seeds, rectified.true_xy(seeds)[None], RectifiedPair()),
          grow_joint(rf, [rg], seeds, rectified.true_xy(seeds)[None], RectifiedPair(),
                     params=GrowParams()))
    a = measure_disparity(rf, rg, disparity_range=(0, 12))
    b = measure_disparity(rf, rg, disparity_range=(0, 12), params=DisparityParams())
    _same(a, b)
    _same(a.grown, b.grown)
    cams = triplet_rig()[:2]
    xy = np.stack([seeds, approx])
    a = measure_surface([f, g], cams, xy, template=0)
    b = measure_surface([f, g], cams, xy, template=0, params=MeasureSurfaceParams())
    _same(a, b)
    _same(a.grown, b.grown)
    assert len(a.grown[0]) > 100


def test_an_explicit_setting_is_the_keyword_it_replaced(pair):
    """A setting changes what it always changed: a shift-only model, the robust cut-off."""
    rng = np.random.default_rng(2)
    t = rng.uniform(25, 95, (40, 2))
    s = pair.true_xy(t) + 0.4
    shift = lsm(pair.template, pair.search, t, s, params=LSMParams(geometry="shift"))
    assert np.all(shift.A == np.eye(2))                # A stays at its start
    full = lsm(pair.template, pair.search, t, s)
    assert not np.array_equal(shift.xy, full.xy)
    rob = lsm(pair.template, pair.search, t, s, params=LSMParams(robust=8.0))
    assert np.all(rob.weight_share < 1.0) and np.all(full.weight_share == 1.0)


def test_correlation_radius_is_an_integer():
    img = np.random.default_rng(0).normal(size=(40, 40))
    with pytest.raises(ValueError, match=r"radius: expected an integer >= 1 \(pixels\)"):
        correlation_search(img, img, [[20.0, 20.0]], [[20.0, 20.0]], patch=7, radius=0)
