"""The full-body fit: stature and start from the data, a fit of the template's own pose,
bad input (issue 25)."""

from dataclasses import replace

import numpy as np
import pytest

from lsmta.body.full_body import full_body_model, template_size
from lsmta.body.full_fit import (
    BodyShape,
    FullBodyFitParams,
    body_start,
    fit_full_body,
    measure_stature,
)
from lsmta.body.skin import SkinParams, model_skin


def test_stature_ignores_lone_points_above_the_head():
    rng = np.random.default_rng(0)
    body = rng.uniform([-200, -100, 0], [200, 100, 1700], (3000, 3))
    stray = np.array([[0.0, 0.0, 1900.0], [50.0, 0.0, 2100.0]])
    h = measure_stature(np.vstack([body, stray]), floor=0.0)
    assert 1650 < h <= 1700
    assert measure_stature(body + [0, 0, 100], floor=100.0) == pytest.approx(h, abs=30)


def test_start_faces_the_direction_of_motion():
    model = full_body_model()
    pts = [np.random.default_rng(1).normal(0, 100, (200, 3)) + [x, 0, 900] for x in (0, 300)]
    angles, base = body_start(model, pts, stature=1750.0)
    names = model.skeleton.names
    assert angles[0, names.index("pelvis_c")] == pytest.approx(-np.pi / 2)   # faces +x
    assert base[1, 0, 3] - base[0, 0, 3] == pytest.approx(300, abs=30)
    assert 850 < base[0, 2, 3] < 1000                                        # hip height
    with pytest.raises(ValueError, match="heading"):
        body_start(model, pts[:1], stature=1750.0)


@pytest.mark.slow
def test_fit_recovers_a_pose_of_the_model_itself():
    """Points on the template's own skin in a stride: the fit, started from the data,
    comes back to the pose."""
    model = full_body_model(stature=1750.0)
    names = model.skeleton.names
    truth = np.zeros((1, model.skeleton.n_joints))
    for joint, a in {"pelvis_c": -np.pi / 2, "hip_r_a": 0.3, "knee_r": -0.3, "hip_l_a": -0.2,
                     "knee_l": -0.5, "shoulder_r_a": -0.3, "shoulder_l_a": 0.3,
                     "elbow_r": 0.4, "elbow_l": 0.3}.items():
        truth[0, names.index(joint)] = a
    base = np.eye(4)[None].copy()
    base[0, :3, 3] = (100.0, 50.0, 920.0)
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    patches = model_skin(model, truth, S, radii, base=base, params=SkinParams(n_u=30, n_v=20))
    rng = np.random.default_rng(2)
    pts = np.vstack([p.vertices for p in patches])
    pts = pts[rng.choice(len(pts), 2500, replace=False)] + rng.normal(0, 1.0, (2500, 3))
    fit = fit_full_body([pts], heading=0.0, params=FullBodyFitParams(n_rounds=2))
    for joint in ("hip_r_a", "knee_r", "hip_l_a", "knee_l", "elbow_r", "elbow_l"):
        k = names.index(joint)
        assert abs(fit.angles[0, k] - truth[0, k]) < np.radians(4), joint
    assert np.abs(fit.scales - 1).max() < 0.08
    assert np.median(np.abs(fit.point_residuals[0])) < 2.0


def test_bad_input():
    pts = [np.zeros((10, 3))]
    with pytest.raises(ValueError, match="points"):
        fit_full_body([])
    with pytest.raises(ValueError, match=r"points\[0\]"):
        fit_full_body([np.zeros((10, 2))])
    with pytest.raises(ValueError, match="rays"):
        fit_full_body(pts, rays=[], camera_centre=np.zeros(3))
    with pytest.raises(ValueError, match="camera_centre"):
        fit_full_body(pts, rays=[(np.zeros((2, 3)), np.ones((2, 3)))])
    with pytest.raises(TypeError, match="params"):
        fit_full_body(pts, params={})
    with pytest.raises(ValueError, match="scale_bounds"):
        FullBodyFitParams(scale_bounds=(1.1, 1.2))
    with pytest.raises(ValueError, match="loss"):
        FullBodyFitParams(loss="l2")
    with pytest.raises(ValueError, match="free_loss"):
        FullBodyFitParams(free_loss="l2")
    with pytest.raises(ValueError, match="free_rounds"):
        FullBodyFitParams(free_rounds=-1)
    with pytest.raises(ValueError, match="offset_prior"):
        FullBodyFitParams(offset_prior=0.0)
    with pytest.raises(ValueError, match="temporal_sigma"):
        FullBodyFitParams(temporal_sigma=0.0)
    with pytest.raises(ValueError, match="temporal_sigma"):
        FullBodyFitParams(temporal_sigma=-0.1)
    with pytest.raises(TypeError, match="warm_start"):
        FullBodyFitParams(warm_start=1)
    assert FullBodyFitParams().temporal_sigma is None and not FullBodyFitParams().warm_start


@pytest.mark.slow
def test_temporal_prior_keeps_an_unseen_forearm_near_its_neighbours():
    """Three frames of the template's own skin, the left elbow bent ~60 deg; in the middle
    frame the left forearm and hand have no point. Frame by frame, that elbow goes where the
    points of the trunk beside it pull it; with the temporal prior and the warm start it
    stays near its neighbours' angle, and the seen frames barely move."""
    model = full_body_model(stature=1750.0)
    names = model.skeleton.names
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    rng = np.random.default_rng(8)
    unseen = [k for k, s in enumerate(model.segments) if s.name in ("forearm_l", "hand_l")]
    pts, truth = [], []
    for t in range(3):
        a = np.zeros((1, model.skeleton.n_joints))
        a[0, names.index("pelvis_c")] = -np.pi / 2
        a[0, names.index("elbow_l")] = 1.0 + 0.05 * t
        a[0, names.index("elbow_r")] = 0.3
        b = np.eye(4)[None].copy()
        b[0, :3, 3] = (50.0 * t, 0.0, 930.0)
        patches = model_skin(model, a, S, radii, base=b, params=SkinParams(n_u=16, n_v=12))
        seg = np.concatenate([np.full(len(p.vertices), k) for k, p in enumerate(patches)])
        x = np.vstack([p.vertices for p in patches])
        if t == 1:
            x = x[~np.isin(seg, unseen)]
        pts.append(x[rng.choice(len(x), 800, replace=False)] + rng.normal(0, 1.0, (800, 3)))
        truth.append(a[0, names.index("elbow_l")])
    k = names.index("elbow_l")
    alone = fit_full_body(pts, params=FullBodyFitParams(n_rounds=2)).angles[:, k]
    seq = fit_full_body(pts, params=FullBodyFitParams(n_rounds=2, temporal_sigma=0.3,
                                                      warm_start=True)).angles[:, k]
    # measured: alone 20.7 deg in the middle frame (truth 60.2), with the prior 51.7
    assert abs(alone[1] - truth[1]) > np.radians(25)
    assert abs(seq[1] - truth[1]) < np.radians(12)
    assert np.abs(seq[[0, 2]] - alone[[0, 2]]).max() < np.radians(2)


def test_grouped_differences_match_dense_differences():
    """One residual call per group of columns that share no row gives the dense Jacobian."""
    from lsmta.body.full_fit import _grouped_jacobian

    A = np.random.default_rng(5).normal(size=(6, 4))
    A[:3, 2] = A[3:, 3] = 0.0                        # columns 2 and 3 share no row
    calls = []

    def residual(x):
        calls.append(1)
        return A @ x + 0.1 * (A @ x) ** 2

    x = np.array([0.3, -0.2, 0.5, 1.0])
    J = _grouped_jacobian(residual, x, [np.array([0]), np.array([1]), np.array([2, 3])],
                          A != 0, np.full(4, np.inf))
    np.testing.assert_allclose(J, A * (1 + 0.2 * (A @ x))[:, None], atol=1e-5)
    assert len(calls) == 4                            # the base point and three groups
    step_back = _grouped_jacobian(residual, x, [np.array([0]), np.array([1]), np.array([2, 3])],
                                  A != 0, x.copy())  # every x at its upper bound: steps back
    np.testing.assert_allclose(step_back, A * (1 + 0.2 * (A @ x))[:, None], atol=1e-5)


def test_model_offsets_shift_the_skin():
    model = full_body_model()
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    angles = np.zeros((1, model.skeleton.n_joints))
    shift = np.zeros((model.n_segments, 3, 2))
    shift[..., 1] = 25.0
    moved = model.with_offsets(shift)
    F = model.frames(angles, S)[0]
    x = np.random.default_rng(6).normal(0, 60, (50, 3)) + F[4, :3, 3]   # around the upper arm
    seg = np.full(len(x), 4)
    along = F[4, :3, 1] * 25.0                                          # its bone frame's y, mm
    np.testing.assert_allclose(moved.distance(x + along, seg, angles, S, radii),
                               model.distance(x, seg, angles, S, radii), atol=1e-9)
    with pytest.raises(ValueError, match="offsets"):
        model.with_offsets(np.zeros((model.n_segments, 3, 3)))


@pytest.mark.slow
def test_free_shape_takes_balls_the_tied_shape_cannot():
    """Points all round the template's skin with its middle balls 25 % wider: the free shape
    (each ball its own size) comes closer to them than the tied one (one profile)."""
    model = full_body_model(stature=1750.0)
    names = model.skeleton.names
    truth = np.zeros((1, model.skeleton.n_joints))
    truth[0, names.index("pelvis_c")] = -np.pi / 2
    for joint, a in {"knee_r": -0.2, "knee_l": -0.2, "elbow_r": 0.3, "elbow_l": 0.3}.items():
        truth[0, names.index(joint)] = a
    base = np.eye(4)[None].copy()
    base[0, :3, 3] = (0.0, 0.0, 930.0)
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    radii[:, 1, :2] *= 1.25
    patches = model_skin(model, truth, S, radii, base=base, params=SkinParams(n_u=30, n_v=20))
    rng = np.random.default_rng(7)
    pts = np.vstack([p.vertices for p in patches])
    pts = pts[rng.choice(len(pts), 3000, replace=False)] + rng.normal(0, 0.5, (3000, 3))
    rms = {}
    for rounds in (0, 1):
        fit = fit_full_body([pts], heading=0.0,
                            params=FullBodyFitParams(n_rounds=2, free_rounds=rounds))
        rms[rounds] = np.sqrt(np.mean(fit.point_residuals[0] ** 2))
    assert rms[1] < 0.7 * rms[0], rms


def test_translation_derivative_matches_differences():
    from lsmta.body.silhouette import point_derivatives

    model = full_body_model()
    J = model.skeleton.n_joints
    angles = np.random.default_rng(3).uniform(-0.2, 0.2, (1, J))
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    x = np.random.default_rng(4).normal(0, 200, (30, 3)) + [0, 0, 300]
    seg = np.argmin(model.all_distances(x, angles, S, radii), axis=1)
    _, d_t = point_derivatives(model, x, seg, angles, S, radii)
    eps, numeric = 1e-3, []
    for k in range(3):
        b = np.eye(4)[None].repeat(2, 0)
        b[0, k, 3], b[1, k, 3] = eps, -eps
        up, down = (model.distance(x, seg, angles, S, radii, base=b[[i]]) for i in (0, 1))
        numeric.append((up - down) / (2 * eps))
    np.testing.assert_allclose(d_t, np.stack(numeric, axis=1), atol=1e-5)


def test_a_given_build_is_kept_or_started_from():
    """``shape`` sets the stature and the start of the build; ``fit_shape=False`` keeps it,
    and the fit hands its build back (:meth:`FullBodyFit.body_shape`)."""
    rng = np.random.default_rng(3)
    pts = rng.uniform([-150, -80, 0], [150, 80, 1700], (600, 3))
    given = BodyShape.template(1650.0)
    given = BodyShape(stature=1650.0, scales=given.scales * 1.05, limb_shape=given.limb_shape)
    p = FullBodyFitParams(n_rounds=1, max_nfev=3, n_inner=1)
    kept = fit_full_body([pts], heading=0.0, shape=given, params=replace(p, fit_shape=False))
    assert kept.stature == 1650.0 and np.allclose(kept.scales, given.scales)
    back = kept.body_shape()
    assert np.allclose(back.limb_shape, given.limb_shape) and back.stature == 1650.0
    solved = fit_full_body([pts], heading=0.0, shape=given, params=p)
    assert solved.stature == 1650.0 and not np.allclose(solved.scales, given.scales)
    with pytest.raises(TypeError, match="shape"):
        fit_full_body([pts], heading=0.0, shape=(1650.0,), params=p)
    with pytest.raises(ValueError, match="limb_shape"):
        replace(kept, limb_shape=None).body_shape()


def _own_skin(model, pose, *, rng, n=700, x=0.0):
    """``n`` noisy points of the template's own skin in ``pose`` (joint -> radians)."""
    names = model.skeleton.names
    a = np.zeros((1, model.skeleton.n_joints))
    a[0, names.index("pelvis_c")] = -np.pi / 2
    for joint, v in pose.items():
        a[0, names.index(joint)] = v
    b = np.eye(4)[None].copy()
    b[0, :3, 3] = (x, 0.0, 930.0)
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    patches = model_skin(model, a, S, radii, base=b, params=SkinParams(n_u=16, n_v=12))
    pts = np.vstack([p.vertices for p in patches])
    return pts[rng.choice(len(pts), n, replace=False)] + rng.normal(0, 1.0, (n, 3)), a, b


def test_a_badly_fitted_frame_is_left_out_of_the_shape_solve():
    """Four frames of the template's own skin; in the third a cloud of 80 stray points (a fifth)
    beside the body (no pose fits them, as a flipped limb's points): its cost (90th
    percentile |skin distance|) is far above the others', so ``drop_k`` leaves it out of
    the shape solve; without ``drop_k`` every frame is in. No truth goes in."""
    model = full_body_model(stature=1750.0)
    rng = np.random.default_rng(11)
    pts = [_own_skin(model, {"elbow_r": 0.3, "elbow_l": 0.2 + 0.05 * t}, rng=rng, n=400,
                     x=40.0 * t)[0] for t in range(4)]
    pts[2] = np.vstack([pts[2][:320], rng.uniform([300, -600, 800], [700, -300, 1400],
                                                  (80, 3))])
    p = FullBodyFitParams(n_rounds=1, n_inner=1, max_nfev=15, drop_k=2.0)
    fit = fit_full_body(pts, params=p)
    assert fit.shape_frames.tolist() == [True, True, False, True]
    cost = [np.percentile(np.abs(r), 90) for r in fit.point_residuals]
    assert cost[2] > 2.0 * np.median(cost)                    # the rule, from the residuals
    every = fit_full_body(pts, params=replace(p, drop_k=None, max_nfev=2))
    assert every.shape_frames.all()
    with pytest.raises(ValueError, match="drop_k"):
        FullBodyFitParams(drop_k=1.0)
    with pytest.raises(TypeError, match="rest_start"):
        FullBodyFitParams(rest_start=1)


def test_a_further_start_keeps_the_lower_cost():
    """One frame with the left arm raised sideways 1.4 rad: from the rest pose alone the
    solve does not reach it in a few steps; given a further start at another fit's pose
    near it (here the generator's, as a stand-in), the frame keeps the lower cost, and a
    start far off is not taken."""
    model = full_body_model(stature=1750.0)
    rng = np.random.default_rng(12)
    pose = {"shoulder_l_a": 1.4, "elbow_l": 0.3}
    pts, a, b = _own_skin(model, pose, rng=rng)
    shape = BodyShape.template(1750.0)
    p = FullBodyFitParams(n_rounds=1, n_inner=1, max_nfev=10, fit_shape=False)
    rest = fit_full_body([pts], heading=0.0, shape=shape, params=p)
    near = fit_full_body([pts], heading=0.0, shape=shape, starts=[(a, b)], params=p)
    both = fit_full_body([pts], heading=0.0, shape=shape, starts=[(rest.angles, rest.base),
                                                                    (a, b)], params=p)

    def cost(f):
        return np.percentile(np.abs(f.point_residuals[0]), 90)

    assert cost(near) < cost(rest) - 1.0
    assert cost(both) <= cost(near) + 1e-9
    with pytest.raises(ValueError, match=r"starts\[0\]"):
        fit_full_body([pts], heading=0.0, starts=[(a[:, :3], b)], params=p)


# two builds to try (limb, factor of the template's limb scale); any pair either way does
LONG_TRUNK = (("trunk", 1.15), ("head", 0.8), ("shoulders", 0.9), ("upper_arm", 0.9))
SHORT_TRUNK = (("trunk", 0.85), ("head", 1.2), ("shoulders", 1.1), ("upper_arm", 1.1))


def _skin_points(build, n=900, seed=6):
    """``(n, 3)`` points of the template's own skin (stature 1750 mm) with ``build``."""
    from lsmta.body.full_body import LIMBS

    model = full_body_model(stature=1750.0)
    factors = np.ones(len(LIMBS))
    for name, f in build:
        factors[LIMBS.index(name)] = f
    a = np.zeros((1, model.skeleton.n_joints))
    a[0, model.skeleton.names.index("pelvis_c")] = -np.pi / 2
    b = np.eye(4)[None].copy()
    b[0, :3, 3] = (0.0, 0.0, 930.0)
    radii = model.simplified_radii(template_size(model), factors)
    patches = model_skin(model, a, factors, radii, base=b, params=SkinParams(n_u=16, n_v=12))
    pts = np.vstack([p.vertices for p in patches])
    return pts[np.random.default_rng(seed).choice(len(pts), n, replace=False)]


def test_a_build_start_is_kept_when_it_fits_better():
    """Points of the template's own skin with a longer trunk, shorter head, narrower
    shoulders and shorter upper arms: started from the template alone and from builds too
    (``build_starts``), the first round keeps the build of the lowest cost whatever its
    place (two solver steps, so that the template alone cannot walk there); on the
    template's own build the template wins."""
    from lsmta.body.full_body import LIMBS

    pts = _skin_points(LONG_TRUNK)
    p = FullBodyFitParams(n_rounds=1, n_inner=1, max_nfev=2)
    shape = BodyShape.template(1750.0)
    alone = fit_full_body([pts], heading=0.0, shape=shape, params=p)
    last = fit_full_body([pts], heading=0.0, shape=shape,
                         params=replace(p, build_starts=(SHORT_TRUNK, LONG_TRUNK)))
    first = fit_full_body([pts], heading=0.0, shape=shape,
                          params=replace(p, build_starts=(LONG_TRUNK, SHORT_TRUNK)))
    trunk = LIMBS.index("trunk")
    assert alone.build == 0 and last.build == 2 and first.build == 1
    for both in (last, first):
        assert both.scales[trunk] > 1.1 > alone.scales[trunk]
        assert (np.median(np.abs(both.point_residuals[0]))
                < np.median(np.abs(alone.point_residuals[0])))
    own = fit_full_body([_skin_points(())], heading=0.0, shape=shape, params=replace(
        p, build_starts=(LONG_TRUNK, (("trunk", 1.3), ("upper_arm", 0.75)))))
    assert own.build == 0 and abs(own.scales[trunk] - 1.0) < 0.05


@pytest.mark.parametrize("bad", [
    (("trunk", 1.1),), ((("tail", 1.0),),), [(("trunk", 1.1),)], ((("trunk", -1.0),),),
    ((("trunk", float("nan")),),), ((("trunk", float("inf")),),), ((("trunk", True),),),
    ((),), ((("trunk", 1.5),),), ((("trunk", 0.5),),), ((("trunk", "1.1"),),)])
def test_bad_build_starts_are_refused(bad):
    with pytest.raises(ValueError, match="build_starts"):
        FullBodyFitParams(build_starts=bad)


def test_build_starts_take_numpy_floats_and_need_the_shape_fit():
    p = FullBodyFitParams(build_starts=((("trunk", np.float32(1.1)), ("head", np.float64(0.9))),))
    assert p.build_starts[0][0][1] == np.float32(1.1)
    with pytest.raises(ValueError, match="build_starts.*fit_shape"):
        FullBodyFitParams(build_starts=(LONG_TRUNK,), fit_shape=False)
    assert FullBodyFitParams(fit_shape=False).build_starts == ()
