"""Geometrically constrained matching (mpgc), constrained growth, rectified pairs, and the
inverse compositional / partial-patch options of lsm, against generated truth."""

from dataclasses import fields

import numpy as np
import pytest

from conftest import smaller
from lsmta.data import load_cones
from lsmta.matching import (
    CameraGeometry,
    DisparityParams,
    GrowParams,
    LSMParams,
    LSMThresholds,
    MeasureSurfaceParams,
    RectifiedPair,
    Status,
    find_disparity_seeds,
    grow_joint,
    grow_matches,
    lsm,
    measure_disparity,
    measure_surface,
    mpgc,
)
from lsmta.real import stereo
from lsmta.synth import triplet_rig
from lsmta.synth.patches import PlanarTexture, warped_pair
from lsmta.triangulation import triangulate

# a rectified pair: x_right = 0.96 x + 0.03 y - 4.3 on the same row, so the disparity is a
# ramp d(x, y) = 0.04 x - 0.03 y + 4.3
A_RECT = np.array([[0.96, 0.03], [0.0, 1.0]])


@pytest.fixture(scope="module")
def rectified():
    return warped_pair(rng=0, shape=(200, 240), A=A_RECT, c=(-4.3, 0.0),
                       r0=5.0, r1=0.9, noise_sigma=2.0)


def ramp(pair, xy):
    return xy[:, 0] - pair.true_xy(xy)[:, 0]


@pytest.fixture(scope="module")
def plane_triplet():
    """A slanted textured plane seen by the (half-size) triplet rig, noise 1 grey level; the
    truth is the plane itself."""
    rng = np.random.default_rng(7)
    cams = [smaller(c) for c in triplet_rig(rng=rng, distance=2500.0, baseline=700.0)]
    origin = np.array([0.0, 0.0, 950.0])
    normal = np.array([0.3, -1.0, 0.25])
    normal /= np.linalg.norm(normal)
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    texture = PlanarTexture.random(rng=rng, wavelength=(20.0, 80.0))   # mm on the plane

    def intersect(cam, xy):
        o, d = cam.rays(xy)
        s = ((origin - o) @ normal) / (d @ normal)
        return o + s[:, None] * d

    images = []
    for cam in cams:
        yy, xx = np.mgrid[0:cam.height, 0:cam.width]
        sub = np.array([-0.25, 0.25])
        acc = np.zeros(xx.shape)
        for dy in sub:
            for dx in sub:
                pts = np.stack([xx.ravel() + dx, yy.ravel() + dy], axis=1).astype(float)
                X = intersect(cam, pts) - origin
                acc += texture(X @ e1, X @ e2).reshape(xx.shape)
        img = acc / 4 + rng.normal(0, 1.0, xx.shape)
        images.append(np.clip(np.rint(img), 0, 255))
    return cams, images, intersect


def test_rectified_pair_recovers_a_disparity_ramp(rectified, rng):
    pts = np.rint(rng.uniform(25, [215, 175], (800, 2)))
    d_true = ramp(rectified, pts)
    t0 = d_true + rng.uniform(-1, 1, len(pts))
    for method in ("forward", "inverse"):
        res = mpgc(rectified.template, rectified.search, pts, t0, RectifiedPair(),
                   params=LSMParams(method=method))
        assert res.ok.mean() > 0.98
        err = (res.t - d_true)[res.ok]
        assert np.median(np.abs(err)) < 0.02 and np.abs(err).max() < 0.15
        # the positions lie on the rows, and the precision estimate is about right
        assert np.array_equal(res.xy[0][:, 1], pts[:, 1])
        ratio = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(res.sigma_t[res.ok] ** 2))
        assert 0.7 < ratio < 1.4
        assert np.allclose(np.median(res.A[0][res.ok], axis=0), A_RECT, atol=0.01)


def test_row_affine_keeps_rows_and_matches_the_ramp(rectified, rng):
    pts = np.rint(rng.uniform(25, [215, 175], (300, 2)))
    d_true = ramp(rectified, pts)
    res = mpgc(rectified.template, rectified.search, pts, d_true + 0.7, RectifiedPair(),
               params=LSMParams(geometry="row-affine", method="inverse"))
    assert res.ok.mean() > 0.98
    assert np.allclose(res.A[0][res.ok][:, 1], [0.0, 1.0], atol=1e-12)
    assert np.median(np.abs(res.t - d_true)[res.ok]) < 0.02


def test_constrained_triplet_against_the_plane(plane_triplet, rng):
    cams, images, intersect = plane_triplet
    geometry = CameraGeometry(cams, template=1)
    nodes = np.rint(rng.uniform([140, 100], [240, 190], (300, 2)))
    truth = intersect(cams[1], nodes)
    true_xy = np.stack([cams[k].project(truth) for k in (0, 2)], axis=1)       # (n, 2, 2)
    t_true = geometry.parameter(nodes, true_xy)
    start = true_xy + rng.uniform(-0.8, 0.8, true_xy.shape)
    res = mpgc(images[1], [images[0], images[2]], nodes, geometry.parameter(nodes, start),
               geometry, params=LSMParams(patch=11))
    assert res.ok.mean() > 0.95
    err = np.linalg.norm(res.points - truth, axis=1)[res.ok]
    mm_per_px = 2500.0 / cams[1].f
    assert np.median(err) < 0.1 * mm_per_px
    # the positions are the projections of one point: the rays meet
    tri = triangulate(cams, np.stack([res.xy[0], nodes, res.xy[1]]))
    assert np.nanmax(tri.reprojection_error[:, res.ok]) < 2e-3
    # one depth per node, and its precision: the error along the ray is about sigma
    z = np.abs(res.t - t_true)[res.ok] / res.sigma_t[res.ok]
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5
    # matching the two search images independently and intersecting is not better
    indep = [lsm(images[1], images[k], nodes, start[:, j], params=LSMParams(patch=11))
             for j, k in ((0, 0), (1, 2))]
    both = indep[0].ok & indep[1].ok & res.ok
    X = triangulate(cams, np.stack([indep[0].xy, nodes, indep[1].xy])).points
    e_indep = np.linalg.norm(X - truth, axis=1)[both]
    e_joint = np.linalg.norm(res.points - truth, axis=1)[both]
    assert np.median(e_joint) < 1.05 * np.median(e_indep)


def test_joint_growth_over_the_plane(plane_triplet):
    cams, images, intersect = plane_triplet
    seeds_t = np.array([[170.0, 130.0], [210.0, 170.0]])
    truth = intersect(cams[1], seeds_t)
    seeds_s = np.stack([cams[k].project(truth) for k in (0, 2)]) + 0.5
    th = LSMThresholds(max_displacement=4.0, max_sigma_xy=0.2, scale_range=(0.5, 2.0),
                       max_shear=0.5)
    grown = grow_joint(images[1], [images[0], images[2]], seeds_t, seeds_s,
                       CameraGeometry(cams, template=1),
                       params=GrowParams(step=4, patch=9, thresholds=th))
    assert len(grown) == 2 and np.array_equal(grown[0].node_index, grown[1].node_index)
    assert len(grown[0]) > 500 and np.array_equal(grown[0].t, grown[1].t)
    X = CameraGeometry(cams, template=1).points(grown[0].template_xy, grown[0].t)
    err = np.linalg.norm(X - intersect(cams[1], grown[0].template_xy), axis=1)
    assert np.median(err) < 0.5 and np.percentile(err, 99) < 3.0


def test_measure_surface_joint_over_the_plane(plane_triplet):
    """measure_surface with joint=True: grown jointly, filtered with the joint re-match; the rays
    of every tuple meet (positions on the epipolar curves) and the points lie on the plane."""
    cams, images, intersect = plane_triplet
    seeds_t = np.array([[170.0, 130.0], [210.0, 170.0]])
    truth = intersect(cams[1], seeds_t)
    seeds = np.stack([cams[k].project(truth) + (0.5 if k != 1 else 0.0) for k in range(3)])
    th = LSMThresholds(max_displacement=4.0, max_sigma_xy=0.2, scale_range=(0.5, 2.0),
                       max_shear=0.5)
    res = measure_surface(images, cams, seeds, params=MeasureSurfaceParams(
        grow=GrowParams(step=4, patch=9, thresholds=th), joint=True))
    kept = res.neighbourhood_ok & res.intersection.valid
    assert kept.sum() > 500 and kept.mean() > 0.9
    assert np.nanmax(res.intersection.reprojection_error[:, kept]) < 0.01
    err = np.linalg.norm(res.points - intersect(cams[1], res.xy[1, kept]), axis=1)
    assert np.median(err) < 0.5 and np.percentile(err, 99) < 3.0


def test_constrained_growth_and_measure_disparity_on_the_ramp(rectified):
    seeds = find_disparity_seeds(rectified.template, rectified.search, disparity_range=(0, 16),
                                 n_seeds=10)
    assert len(seeds.score) >= 5
    assert np.abs(seeds.disparity - ramp(rectified, seeds.xy[0])).max() < 0.5
    res = grow_matches(rectified.template, rectified.search, seeds.xy[0], seeds.xy[1],
                       constraint=RectifiedPair(), params=GrowParams(patch=9))
    assert len(res) > 1500 and np.all(np.isfinite(res.t))
    assert np.median(np.abs(res.t - ramp(rectified, res.template_xy))) < 0.03
    out = measure_disparity(rectified.template, rectified.search, disparity_range=(0, 16))
    rows, cols = out.disparity.shape
    assert out.density > 0.9                       # patches may reach over the border
    yy, xx = np.mgrid[0:rows, 0:cols] * out.step
    truth = ramp(rectified, np.stack([xx.ravel(), yy.ravel()], 1).astype(float))
    s = stereo.scores(out.disparity, truth.reshape(rows, cols), np.ones((rows, cols), bool))
    assert s["median"] < 0.03 and s["bad1"] == 0.0 and s["density"] == out.density


def test_new_seeds_reach_a_region_the_growth_never_came_to(rectified):
    f, g = rectified.template.copy(), rectified.search.copy()
    f[:, 100:150] = 128.0                 # a flat band the growth cannot cross
    g[:, 100:150] = 128.0
    one = DisparityParams(n_seeds=1, reseed_rounds=0)
    before = measure_disparity(f, g, disparity_range=(0, 16), params=one)
    after = measure_disparity(f, g, disparity_range=(0, 16),
                              params=DisparityParams(n_seeds=1, reseed_rounds=1))
    cols = np.arange(before.disparity.shape[1]) * before.step
    sides = [cols < 90, cols >= 160]
    reached = [np.isfinite(before.disparity[:, s]).mean() for s in sides]
    assert min(reached) < 0.05 < 0.8 < max(reached)        # one seed: one side only
    assert len(after.regrown) == 1
    assert all(np.isfinite(after.disparity[:, s]).mean() > 0.8 for s in sides)
    kept = np.isfinite(before.disparity)
    assert np.array_equal(after.disparity[kept], before.disparity[kept])
    rows, ncols = after.disparity.shape
    yy, xx = np.mgrid[0:rows, 0:ncols] * after.step
    truth = ramp(rectified, np.stack([xx.ravel(), yy.ravel()], 1).astype(float))
    new = np.isfinite(after.disparity) & ~kept
    assert np.median(np.abs(after.disparity - truth.reshape(rows, ncols))[new]) < 0.05
    given = measure_disparity(f, g, disparity_range=(0, 16), seeds=before.seeds,
                              params=DisparityParams(n_seeds=1, reseed_rounds=1))
    assert given.regrown == ()                       # the caller's seeds: no new ones
    left_only = np.zeros(f.shape, bool)
    left_only[:, :90] = True
    masked = measure_disparity(f, g, disparity_range=(0, 16), mask=left_only,
                               params=DisparityParams(n_seeds=1, reseed_rounds=1))
    assert not np.isfinite(masked.disparity[:, cols >= 100]).any()   # never outside the mask
    with pytest.raises(ValueError, match="reseed_rounds"):
        DisparityParams(reseed_rounds=-1)


def test_partial_patches_match_at_the_border(rectified):
    pts = np.array([[6.0, 100.0], [238.0, 60.0], [120.0, 0.0]])
    truth = rectified.true_xy(pts)
    plain = lsm(rectified.template, rectified.search, pts, truth + 0.3)
    assert np.all(plain.status == Status.OUTSIDE)
    part = lsm(rectified.template, rectified.search, pts, truth + 0.3,
               params=LSMParams(partial=True))
    assert part.ok.all() and np.all(part.weight_share < 0.9)
    assert np.abs(part.xy - truth).max() < 0.1


def test_inverse_compositional_near_the_bound(rng):
    from lsmta.evaluation.matching import run_trial

    sigma = 2.0
    pair = warped_pair(rng=rng, A=[[1.04, 0.06], [-0.05, 0.97]], c=(3.0, 2.0), r0=5.0, r1=0.9,
                       noise_sigma=sigma, quantise=False)
    trial = run_trial(pair, rng=rng, n_points=600, start_error=0.5,
                      params=LSMParams(method="inverse"))
    ok = trial.lsm_result.ok
    assert ok.mean() > 0.97
    e = np.linalg.norm(trial.errors["lsm"], axis=1)[ok]
    assert np.median(e) < 1.15 * trial.crb_median(mask=ok, rng=rng)


def test_support_weights_reduce_the_pull_of_another_surface(rng):
    from conftest import occlusion_pair

    template, search = occlusion_pair(rng)
    # background nodes 3 px left of the foreground edge (x = 100): their patch straddles it
    pts = np.stack([np.full(40, 97.0), np.arange(30.0, 70.0)], axis=1)
    start = pts + [3.0, 0.0]
    plain = lsm(template, search, pts, start, params=LSMParams(patch=13))
    weighted = lsm(template, search, pts, start, params=LSMParams(patch=13, support=15.0))
    e_plain = np.abs(plain.xy[:, 0] - pts[:, 0] - 3.0)[plain.ok]
    e_weighted = np.abs(weighted.xy[:, 0] - pts[:, 0] - 3.0)[weighted.ok]
    assert weighted.ok.mean() > plain.ok.mean()
    assert np.median(e_weighted) < 0.7 * np.median(e_plain)
    assert np.all(weighted.weight_share < 0.5)     # the support weights count in the share


@pytest.mark.parametrize("kwargs, match", [
    (dict(constraint="rows"), "constraint"),
    (dict(t0=np.zeros(3)), "t0"),
    (dict(searches=[]), "searches"),
    (dict(support=-1.0), "support"),
    (dict(partial="yes"), "partial"),
    (dict(method="newton"), "method"),
    (dict(geometry="projective"), "geometry"),
    (dict(initial_A=np.eye(3)), "initial_A"),
])
def test_mpgc_bad_input(rectified, kwargs, match):
    args = dict(template=rectified.template, searches=rectified.search,
                template_xy=np.array([[50.0, 50.0], [60.0, 60.0]]), t0=np.array([5.0, 5.0]),
                constraint=RectifiedPair())
    args.update(kwargs)
    settings = {k: args.pop(k) for k in [f.name for f in fields(LSMParams)] if k in args}
    with pytest.raises(ValueError, match=match):
        mpgc(params=LSMParams(**settings), **args)


def test_camera_geometry_and_disparity_bad_input(rectified):
    with pytest.raises(ValueError, match="cameras"):
        CameraGeometry([object(), object()])
    with pytest.raises(ValueError, match="template"):
        CameraGeometry(triplet_rig(), template=3)
    with pytest.raises(ValueError, match="disparity_range"):
        measure_disparity(rectified.template, rectified.search, disparity_range=(10, 5))
    with pytest.raises(ValueError, match="right"):
        measure_disparity(rectified.template, rectified.search[:50], disparity_range=(0, 9))
    with pytest.raises(ValueError, match="constraint"):
        grow_matches(rectified.template, rectified.search, [[50.0, 50.0]], [[45.0, 50.0]],
                     constraint=CameraGeometry(triplet_rig(), template=1))


def test_inputs_not_modified(rectified):
    f, g = rectified.template.copy(), rectified.search.copy()
    pts = np.array([[50.0, 50.0], [100.0, 120.0]])
    t0 = np.array([5.0, 6.0])
    A0 = np.tile(np.eye(2), (2, 1, 1))
    keep = (pts.copy(), t0.copy(), A0.copy())
    mpgc(f, g, pts, t0, RectifiedPair(), initial_A=A0,
         params=LSMParams(method="inverse", partial=True))
    measure_disparity(f, g, disparity_range=(0, 16), params=DisparityParams(n_seeds=5))
    assert np.array_equal(f, rectified.template) and np.array_equal(g, rectified.search)
    assert all(np.array_equal(a, b) for a, b in zip(keep, (pts, t0, A0)))


def test_stereo_scores_and_the_cones_copy():
    truth = np.array([[10.0, 10.25, np.nan], [20.0, 20.0, 20.0]])
    scored = np.isfinite(truth)
    est = np.array([[10.0, 11.5, 3.0], [np.nan, 22.5, 20.1]])
    s = stereo.scores(est, truth, scored)
    assert s["density"] == 4 / 5 and s["n"] == 4
    assert s["bad1"] == 0.5 and s["bad2"] == 0.25 and s["bad1_all"] == 3 / 5
    assert np.isclose(s["median"], (0.1 + 1.25) / 2)
    assert stereo.quantisation_median() == 0.0625
    cones = load_cones()
    assert cones.left.shape == cones.right.shape == (375, 450)
    d = cones.disparity[np.isfinite(cones.disparity)]
    assert np.all(d * 4 == np.rint(d * 4)) and 0.8 < cones.nonoccluded.mean() < 0.9
