"""The silhouette term of the body fit: residual and gradient check (issue 25)."""

import numpy as np
import pytest

from lsmta.body import arm_model
from lsmta.body.silhouette import silhouette_terms

SCALES = [1.0, 1.0, 1.0]


@pytest.fixture(scope="module")
def arm():
    m = arm_model()
    radii = m.simplified_radii([[80, 80], [65, 65], [35, 70]], SCALES)
    angles = np.array([[0.4, 0.3, 0.2, 1.0, 0.1]])
    on_bones = m.skeleton.forward(angles, SCALES, np.array([2, 2, 3, 3, 4]),
                                  np.array([[0, 0, -100.0], [0, 0, -250], [0, 0, 0],
                                            [0, -150, 0], [0, -60, 0]]))[0]
    rng = np.random.default_rng(1)
    origin = np.array([0.0, -3000.0, 200.0])
    target = on_bones[rng.integers(0, 5, 40)] + rng.normal(0, 50, (40, 3))
    d = target - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return m, radii, angles, np.broadcast_to(origin, d.shape).copy(), d, on_bones


def _r(m, radii, angles, o, d):
    return silhouette_terms(m, o, d, angles, SCALES, radii, near=2000.0, far=4000.0)


def test_gradient_check_by_the_joint_angles(arm):
    m, radii, angles, o, d, _ = arm
    t = _r(m, radii, angles, o, d)
    assert (t.r > 5).any() and (t.r < -5).any()       # lines that miss and that pass through
    eps = 1e-6
    numeric = np.zeros_like(t.d_angles)
    for j in range(angles.shape[1]):
        step = np.zeros_like(angles)
        step[0, j] = eps
        numeric[:, j] = (_r(m, radii, angles + step, o, d).r
                         - _r(m, radii, angles - step, o, d).r) / (2 * eps)
    scale = np.abs(numeric).max()
    assert scale > 10
    assert np.abs(t.d_angles - numeric).max() < 1e-5 * scale


def test_residual_is_the_closest_approach(arm):
    m, radii, angles, o, _, on_bones = arm
    # a line through the upper arm's bone passes through the model; one 400 mm off misses
    d_in = on_bones[1] - o[0]
    d_out = on_bones[1] + np.array([400.0, 0, 0]) - o[0]
    d = np.stack([d_in, d_out])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = _r(m, radii, angles, o[:2], d)
    assert t.r[0] < -20 and t.r[1] > 100
    # the closest point is where the line meets the skin's distance minimum
    assert np.allclose(m.distance(t.closest, t.segment, angles, SCALES, radii), t.r)


def test_bad_input_is_named(arm):
    m, radii, angles, o, d, _ = arm
    with pytest.raises(ValueError, match="directions"):
        silhouette_terms(m, o, d[:3], angles, SCALES, radii, near=0.0, far=10.0)
    with pytest.raises(ValueError, match="far"):
        silhouette_terms(m, o, d, angles, SCALES, radii, near=10.0, far=5.0)
    with pytest.raises(ValueError, match="angles"):
        silhouette_terms(m, o, d, angles[:, :3], SCALES, radii, near=0.0, far=10.0)


@pytest.mark.slow
def test_points_and_silhouettes_beat_points_alone_from_a_perturbed_start():
    """Points on the upper arm and the forearm's first third only (the rest unseen), and
    the arm's outline in two views: the outline pins the forearm, the points alone leave
    it free to take the mirrored pose."""
    from lsmta.body import model_skin
    from lsmta.body.silhouette import PoseFitParams, fit_pose
    from lsmta.evaluation.silhouettes import outline_rays

    m = arm_model()
    radii = m.simplified_radii([[80, 80], [65, 65], [35, 70]], SCALES)
    truth = np.array([[0.4, 0.3, 0.2, 1.2, 0.0]])
    patches = model_skin(m, truth, SCALES, radii)
    rng = np.random.default_rng(0)
    upper = patches[0].vertices[rng.choice(len(patches[0].vertices), 300, replace=False)]
    fore = patches[1].vertices
    F = m.frames(truth, SCALES)[0, 1]
    fore = fore[(fore - F[:3, 3]) @ F[:3, 2] > -0.35 * 265]         # the first third
    fore = fore[rng.choice(len(fore), 100, replace=False)]
    points = np.vstack([upper, fore]) + rng.normal(0, 1.0, (400, 3))
    centre = np.vstack([p.vertices for p in patches]).mean(axis=0)
    rays = outline_rays(m, truth, SCALES, radii, centre + np.array([[0, -2500.0, 0],
                                                                    [2500.0, 0, 0]]),
                        look_at=centre)
    free = np.array([True, True, True, True, False])
    # six gating rounds: with the default three, the far start's outlier set has not
    # settled and the elbow ends 3.7 degrees off on some processors (0.015 with six; measured)
    params = PoseFitParams(near=1500.0, far=3500.0, n_rounds=6)
    worst = {}
    starts = {"near": [0.1, -0.1, 0.1, -0.15, 0], "far": [0.15, -0.15, 0.15, -0.2, 0]}
    for name, start in starts.items():
        a0 = truth + np.array([start])
        alone = fit_pose(m, a0, SCALES, radii, points=points, free=free, params=params)
        both = fit_pose(m, a0, SCALES, radii, points=points, rays=rays, free=free, params=params)
        worst[name] = (np.degrees(np.abs(alone.angles - truth).max()),
                       np.degrees(np.abs(both.angles - truth).max()))
        assert both.used.sum() > 100 and both.n_point_outliers < 40
    assert worst["near"][1] < 0.2 < worst["near"][0]          # both converge, silhouettes closer
    assert worst["far"][1] < 0.5 and worst["far"][0] > 90     # points alone: the mirrored pose
    with pytest.raises(ValueError, match="points, rays"):
        fit_pose(m, truth, SCALES, radii)
