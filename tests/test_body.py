"""Body modelling (Plänkers et al. 1999): skeleton, metaballs, fitting, posterior."""

from types import SimpleNamespace

import numpy as np
import pytest

from lsmta.body import (
    FitParams,
    FitStatus,
    Joint,
    ModelState,
    Skeleton,
    angles_from_joints,
    arm_model,
    base_poses,
    ellipsoid_distance,
    field,
    fit_frame,
    fit_sequence,
    iso_surface,
    surface_distance,
    surface_distance_terms,
)
from lsmta.body.fitting import _Layout, _residuals
from lsmta.body.skeleton import as_tuple, rot_x
from lsmta.evaluation import body as eb
from lsmta.synth.body import arm_wave, make_body, surface_samples

RIG = (0.0, -2500.0, 1200.0)


@pytest.fixture(scope="module")
def world():
    body = make_body(rng=np.random.default_rng(3))
    return body, arm_wave(n_frames=50)


def test_fk_hand_computed_single_joint():
    sk = Skeleton((Joint("a", -1, (10.0, 0, 0), as_tuple(np.eye(3))),
                   Joint("b", 0, (100.0, 0, 0), as_tuple(np.eye(3)), limb=0)), ("l",))
    # 90 degrees at the root: the child's offset (100, 0, 0) turns onto +y
    X = sk.forward([np.pi / 2, 0.0], [1.0], [1], [[5.0, 0, 0]])
    np.testing.assert_allclose(X[0, 0], [10.0, 105.0, 0.0], atol=1e-12)
    # scale 2 doubles the bone, the child's own angle turns its point
    X = sk.forward([0.0, np.pi / 2], [2.0], [1], [[5.0, 0, 0]])
    np.testing.assert_allclose(X[0, 0], [210.0, 5.0, 0.0], atol=1e-12)
    # a fixed re-orientation: Rx(90 deg) makes the joint's z the parent's -y
    sk2 = Skeleton((Joint("a", -1, (0, 0, 0), as_tuple(rot_x(np.pi / 2))),), ())
    X = sk2.forward([np.pi / 2], [], [0], [[1.0, 0, 0]])
    np.testing.assert_allclose(X[0, 0], [0.0, 0.0, 1.0], atol=1e-12)


def test_arm_fk_hand_computed():
    m = arm_model()
    W = m.skeleton.transforms(np.zeros(5), [1, 1, 1])
    np.testing.assert_allclose(W[0, 3, :3, 3], [0, 0, -300], atol=1e-9)     # elbow
    np.testing.assert_allclose(W[0, 4, :3, 3], [0, 0, -565], atol=1e-9)     # wrist
    # abduction b = 90 deg swings the arm to -x; flexion a = 90 deg swings it forward (+y)
    W = m.skeleton.transforms([np.pi / 2, 0, 0, 0, 0], [1, 1, 1])
    np.testing.assert_allclose(W[0, 3, :3, 3], [-300, 0, 0], atol=1e-9)
    W = m.skeleton.transforms([0, np.pi / 2, 0, 0, 0], [1, 1, 1])
    np.testing.assert_allclose(W[0, 3, :3, 3], [0, 300, 0], atol=1e-9)
    # elbow at 90 deg, scale 1.1 on the forearm: the wrist 291.5 mm forward of the elbow
    W = m.skeleton.transforms([0, 0, 0, np.pi / 2, 0], [1, 1.1, 1])
    np.testing.assert_allclose(W[0, 4, :3, 3], [0, 291.5, -300], atol=1e-9)


def test_fk_matches_generator(world):
    body, motion = world
    truth = eb.arm_truth(body, motion, [0, 20, 40])
    W = arm_model().skeleton.transforms(truth.angles, [1, 1, 1],
                                        base=base_poses(truth.torso_poses, truth.shoulder_local))
    np.testing.assert_allclose(W[:, 3, :3, 3], truth.joints[:, 1], atol=1e-9)
    np.testing.assert_allclose(W[:, 4, :3, 3], truth.joints[:, 2], atol=1e-9)


def test_skeleton_jacobian_vs_finite_differences():
    rng = np.random.default_rng(0)
    sk = arm_model().skeleton
    th = rng.uniform(-1, 1, (2, 5))
    s = np.array([1.1, 0.9, 1.0])
    joint = np.array([0, 2, 3, 4, 4])
    local = rng.normal(0, 50, (5, 3))
    d_th, d_s = sk.jacobian(th, s, joint, local)
    h = 1e-6
    for j in range(5):
        e = np.zeros(5)
        e[j] = h
        num = (sk.forward(th + e, s, joint, local) - sk.forward(th - e, s, joint, local)) / 2 / h
        np.testing.assert_allclose(d_th[..., j], num, atol=1e-5)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        num = (sk.forward(th, s + e, joint, local) - sk.forward(th, s - e, joint, local)) / 2 / h
        np.testing.assert_allclose(d_s[..., k], num, atol=1e-5)


def test_metaball_field_and_surface():
    radii = np.array([[30.0, 20.0, 50.0]])
    assert field(np.zeros((1, 1, 3)), radii)[0] == pytest.approx(1.0)
    assert ellipsoid_distance([30.0, 20.0, 0.0], radii[0]) == pytest.approx(2.0)
    # one round ball: F = 1/2 at |x| = l sqrt(ln 2 / 2); the residual is the distance
    ball = np.array([[40.0, 40.0, 40.0]])
    rho = 40.0 * np.sqrt(np.log(2) / 2)
    x = np.array([[[0, 0, rho]], [[rho + 7.0, 0, 0]], [[0, rho - 3.0, 0]]])
    assert field(x[:1], ball)[0] == pytest.approx(0.5)
    np.testing.assert_allclose(surface_distance(x, ball), [0.0, 7.0, -3.0], atol=1e-9)
    # the terms of the analytic Jacobian: the same residual, dr/dx = dr/dpsi grad psi
    three = np.array([[20.0, 15.0, 30.0], [25.0, 18.0, 35.0], [20.0, 15.0, 30.0]])
    local = np.array([[[10.0, 5.0, 40.0 - 35.0 * b] for b in range(3)]]) + [[[3.0, 0, 0]]]
    terms = surface_distance_terms(local, three)
    np.testing.assert_array_equal(terms.r, surface_distance(local, three))
    e = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = e
        num = (surface_distance(local + d, three) - surface_distance(local - d, three)) / (2 * e)
        np.testing.assert_allclose(num, terms.dr_dpsi * terms.grad[:, k], rtol=1e-5)
    np.testing.assert_allclose(terms.p.sum(axis=1), 1.0)


def test_iso_surface_lies_on_threshold():
    m = arm_model()
    radii = m.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1])
    v, f = iso_surface(m, np.zeros((1, 5)), [1, 1, 1], radii, spacing=8.0)
    assert len(f) > 100
    F = m.world_field(v, np.zeros((1, 5)), [1, 1, 1], radii)
    assert np.median(np.abs(F - 0.5)) < 0.02


def test_residual_jacobian_vs_finite_differences(world):
    body, motion = world
    rng = np.random.default_rng(1)
    m = arm_model()
    truth = eb.arm_truth(body, motion, [15, 35])
    st, _ = eb.initial_state(truth, rng=rng)
    pts = np.concatenate([surface_samples(body, motion, int(f), rng=rng, n=60)[0]
                          for f in truth.frames])
    frame = np.repeat([0, 1], 60)
    for shape, share in (("simplified", True), ("full", False)):
        lay = _Layout(m, 2, shape, share, (0, 1, 2, 3))
        x = lay.pack(st)
        seg = rng.integers(0, 3, len(pts))
        r, J = _residuals(m, lay, lay.unpack(x, st, m), truth.torso_poses, pts, frame, seg,
                          jac=True)
        num = np.zeros_like(J)
        for i in range(len(x)):
            h = 1e-5 * max(1.0, abs(x[i]))
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            rp = _residuals(m, lay, lay.unpack(xp, st, m), truth.torso_poses, pts, frame, seg,
                            jac=False)[0]
            rm = _residuals(m, lay, lay.unpack(xm, st, m), truth.torso_poses, pts, frame, seg,
                            jac=False)[0]
            num[:, i] = (rp - rm) / (2 * h)
        scale = np.abs(num).max(axis=0) + 1e-9
        assert np.max(np.abs(J - num) / scale) < 1e-4, shape


def test_angles_from_joints_inverts_fk(world):
    body, motion = world
    truth = eb.arm_truth(body, motion, [5, 25, 45])
    ang, sh, lengths = angles_from_joints(truth.torso_poses, *truth.joints.transpose(1, 0, 2))
    np.testing.assert_allclose(ang[:, :4], truth.angles[:, :4], atol=1e-9)
    np.testing.assert_allclose(sh, np.tile(truth.shoulder_local, (3, 1)), atol=1e-9)
    np.testing.assert_allclose(lengths, np.tile(truth.lengths, (3, 1)), atol=1e-9)


def _data(world, frames, n, rng, noise=2.0, outliers=0.1):
    body, motion = world
    truth = eb.arm_truth(body, motion, frames)
    pts = [surface_samples(body, motion, int(f), rng=rng, n=n, noise_mm=noise,
                           outlier_share=outliers, view_from=RIG)[0] for f in frames]
    return truth, pts


def test_sequence_recovers_lengths_and_angles(world):
    rng = np.random.default_rng(7)
    truth, pts = _data(world, [8, 20, 32, 44], 400, rng)
    init, _ = eb.initial_state(truth, rng=rng, joint_noise_mm=15.0)
    fit = fit_sequence(arm_model(), pts, truth.torso_poses, init, params=FitParams(sigma_mm=2.0))
    assert fit.ok, fit.message
    score = eb.score_fit(fit, truth)
    # the start is 15 mm of joint noise away: several degrees and centimetres
    start = eb.score_fit(fit_sequence(arm_model(), pts, truth.torso_poses, init,
                                      params=FitParams(max_rounds=1, nfev_per_round=1)), truth)
    assert start["max_angle_err_deg"] > 3.0
    assert score["max_angle_err_deg"] < 3.0
    assert np.all(np.abs(score["length_err_pct"]) < 2.0)
    assert fit.sigma_mm < 5.0
    assert fit.capped_scales == ()         # the hand's points fix where the forearm ends


def test_forearm_without_points_beyond_the_wrist_does_not_lengthen(world):
    # the forearm's points stop at 60 % of its length and the hand has none: nothing fixes
    # where the forearm ends, and a start 30 % too long must not run on to the scale bound
    # (before the cap it ran to 2.4 in the simplified and 3.0 in the full model, the elbow
    # turned by about 180 deg)
    rng = np.random.default_rng(12)
    frames = [8, 20, 32, 44]
    truth = eb.arm_truth(*world, frames)
    pts = []
    for i, f in enumerate(frames):
        p = surface_samples(*world, f, rng=rng, n=400, noise_mm=1.0,
                            parts=("upper_arm_r", "forearm_r"), view_from=RIG)[0]
        elbow, wrist = truth.joints[i, 1], truth.joints[i, 2]
        along = (p - elbow) @ ((wrist - elbow) / np.linalg.norm(wrist - elbow))
        pts.append(p[along < 0.6 * truth.lengths[1]])
    init, _ = eb.initial_state(truth, rng=rng, joint_noise_mm=5.0)
    m = arm_model()
    scales = init.scales * np.array([1.0, 1.3, 1.0])
    init = ModelState(init.angles, init.shoulder, scales,
                      m.simplified_radii(init.radii[:, 1, :2] / m.profile[1], scales))
    simple = fit_sequence(m, pts, truth.torso_poses, init, params=FitParams(sigma_mm=1.0))
    full = fit_sequence(m, pts, truth.torso_poses, simple.state,
                        params=FitParams(sigma_mm=1.0, shape="full"))
    for fit in (simple, full):
        assert fit.state.scales[1] <= scales[1] + 1e-9
    assert eb.score_fit(full, truth)["max_angle_err_deg"] < 3.0
    for fit in (simple, full):
        assert "forearm" in fit.capped_scales and "lengthening" in fit.message
    # the upper arm has points beyond its far joint (the forearm's): not capped
    assert "upper_arm" not in full.capped_scales


@pytest.mark.slow
def test_frame_fit_and_full_refinement(world):
    rng = np.random.default_rng(8)
    truth, pts = _data(world, [30], 500, rng)
    init, _ = eb.initial_state(truth, rng=rng)
    fit = fit_frame(arm_model(), pts[0], truth.torso_poses[0], init, params=FitParams(sigma_mm=2.0))
    assert fit.ok, fit.message
    full = fit_frame(arm_model(), pts[0], truth.torso_poses[0], fit.state,
                     params=FitParams(shape="full", sigma_mm=2.0))
    assert full.status == FitStatus.OK, full.message
    s_fit, s_full = eb.score_fit(fit, truth), eb.score_fit(full, truth)
    assert s_full["max_angle_err_deg"] < 3.0      # (one frame: lengths follow the shoulder)
    assert full.sigma_mm <= fit.sigma_mm * 1.01          # free ball sizes fit at least as well
    assert s_full["max_angle_err_deg"] < s_fit["max_angle_err_deg"] + 1.0
    # skin scored both ways, where there were points: the fit is near the true skin, and
    # much nearer than its start
    body, motion = world
    back = eb.true_skin_to_fit(full, truth, body, motion, pts, n=6000)
    start = eb.true_skin_to_fit(SimpleNamespace(state=init), truth, body, motion, pts, n=6000)
    fwd = eb.skin_errors(full, truth, body, motion, points=pts)
    assert len(back) > 100 and np.median(back) < 4.0 and np.median(fwd) < 4.0
    assert np.median(start) > 2 * np.median(back)


def test_bad_input(world):
    rng = np.random.default_rng(9)
    truth, pts = _data(world, [30], 400, rng, outliers=0.0)
    init, _ = eb.initial_state(truth, rng=rng)
    m = arm_model()
    P = truth.torso_poses[0]
    # NaN points: dropped and reported
    p = pts[0].copy()
    p[:7] = np.nan
    fit = fit_frame(m, p, P, init, params=FitParams(sigma_mm=2.0))
    assert fit.n_nan[0] == 7 and "7 NaN" in fit.message
    assert np.all(fit.segment[0][:7] == -1) and np.all(np.isnan(fit.residuals[0][:7]))
    # too few points on the hand: its shape and length held and named
    hand = fit.segment[0] == 2
    keep = ~hand | (np.cumsum(hand) <= 1)
    fit2 = fit_frame(m, p[keep], P, init, params=FitParams(sigma_mm=2.0))
    assert "hand" in fit2.fixed_segments
    np.testing.assert_allclose(fit2.state.radii[2], init.radii[2])
    assert fit2.state.scales[2] == init.scales[2]
    # a segment without points in a frame is named, and the message says so
    upper = surface_samples(*world, 30, rng=rng, parts=("upper_arm_r",), n=300, noise_mm=1.0)[0]
    upper = upper[np.linalg.norm(upper - truth.joints[0, 1], axis=1) > 120]
    fit3 = fit_frame(m, upper, P, init, params=FitParams(sigma_mm=2.0))
    assert (0, "forearm") in fit3.unobserved and "forearm in frame 0" in fit3.message
    assert "forearm" in fit3.fixed_segments
    # a far initial posture: a clear failure, not a silent wrong fit
    far = ModelState(init.angles + np.array([[2.0, 1.0, 0.0, 1.2, 0.0]]), init.shoulder,
                     init.scales, init.radii)
    bad = fit_frame(m, p, P, far, params=FitParams(sigma_mm=2.0))
    assert not bad.ok and bad.status in (FitStatus.INIT_FAR, FitStatus.POOR_FIT)
    # argument errors
    with pytest.raises(ValueError, match="shape"):
        FitParams(shape="round")
    with pytest.raises(ValueError, match="points"):
        fit_frame(m, p[:, :2], P, init)
    with pytest.raises(ValueError, match="torso_pose"):
        fit_frame(m, p, np.eye(3), init)
    with pytest.raises(ValueError, match="loss"):
        FitParams(loss="l7")
    with pytest.raises(ValueError, match="sigma_mm"):
        FitParams(sigma_mm=0.0)
    with pytest.raises(TypeError, match="params"):
        fit_frame(m, p, P, init, params={"sigma_mm": 2.0})
    with pytest.raises(TypeError, match="init"):
        fit_frame(m, p, P, {"angles": 0})
    with pytest.raises(ValueError, match="scales"):
        fit_frame(m, p, P, ModelState(init.angles, init.shoulder, -init.scales, init.radii))
    with pytest.raises(ValueError, match="outlier_share"):
        surface_samples(*world, 0, rng=rng, outlier_share=1.0)


def test_posterior_agrees_with_least_squares(world):
    from lsmta.body.posterior import sample_limb_posterior

    rng = np.random.default_rng(10)
    truth, pts = _data(world, [30], 300, rng)
    init, _ = eb.initial_state(truth, rng=rng)
    m = arm_model()
    fit = fit_frame(m, pts[0], truth.torso_poses[0], init, params=FitParams(sigma_mm=2.0))
    post = sample_limb_posterior(m, fit, pts[0], truth.torso_poses[0], rng=rng, n_walkers=20,
                                 n_steps=120, burn=60)
    assert 0.1 < post.acceptance < 0.9
    assert np.all(np.abs(post.mean - post.ls_mean) < 3 * post.ls_std)
    assert np.all((post.std > 0.4 * post.ls_std) & (post.std < 2.5 * post.ls_std))


def test_metaball_argument_errors():
    m = arm_model()
    radii = m.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1])
    ball = np.array([[40.0, 40.0, 40.0]])
    x = np.zeros((2, 1, 3))
    with pytest.raises(ValueError, match="radii.*positive"):
        ellipsoid_distance([1.0, 2.0, 3.0], [30.0, 0.0, 10.0])
    with pytest.raises(ValueError, match="radii.*finite"):
        field(x, [[30.0, np.inf, 10.0]])
    with pytest.raises(ValueError, match="radii.*shape"):
        field(x, np.ones((2, 3)))          # two balls' radii for one ball
    with pytest.raises(ValueError, match="local.*shape"):
        field(np.zeros((2, 3)), ball)
    with pytest.raises(ValueError, match="radii.*positive"):
        surface_distance(x, -ball)
    with pytest.raises(ValueError, match="threshold"):
        surface_distance(x, ball, threshold=1.5)
    with pytest.raises(ValueError, match="radii.*positive"):
        m.distance(np.zeros((2, 3)), np.zeros(2, int), np.zeros((1, 5)), [1, 1, 1], -radii)
    with pytest.raises(ValueError, match="segment.*indices"):
        m.distance(np.zeros((2, 3)), np.array([0, 3]), np.zeros((1, 5)), [1, 1, 1], radii)
    with pytest.raises(ValueError, match="frame.*indices"):
        m.distance(np.zeros((2, 3)), np.zeros(2, int), np.zeros((1, 5)), [1, 1, 1], radii,
                   frame=np.array([0, 1]))
    with pytest.raises(ValueError, match="points.*shape"):
        m.world_field(np.zeros((4, 2)), np.zeros((1, 5)), [1, 1, 1], radii)
    with pytest.raises(ValueError, match="radii.*shape"):
        iso_surface(m, np.zeros((1, 5)), [1, 1, 1], radii[:2])
    with pytest.raises(ValueError, match="angles.*shape"):
        iso_surface(m, np.zeros((2, 5)), [1, 1, 1], radii)
    with pytest.raises(ValueError, match="spacing"):
        iso_surface(m, np.zeros((1, 5)), [1, 1, 1], radii, spacing=0.0)


def test_angles_from_joints_coincident_joints(world):
    body, motion = world
    truth = eb.arm_truth(body, motion, [5, 25])
    s, e, w = (j.copy() for j in truth.joints.transpose(1, 0, 2))
    w[1] = e[1]
    with pytest.raises(ValueError, match=r"wrist: coincides with elbow in frame\(s\) \[1\]"):
        angles_from_joints(truth.torso_poses, s, e, w)
    e[0] = s[0]
    with pytest.raises(ValueError, match="elbow: coincides with shoulder"):
        angles_from_joints(truth.torso_poses, s, e, truth.joints[:, 2])
