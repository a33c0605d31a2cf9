"""The full-body template: built from anthropometric ratios of a stature, limits, skin."""

import numpy as np
import pytest

from lsmta.body.full_body import LIMBS, full_body_model, limit_violations, limits, template_size
from lsmta.body.skin import merge_patches, model_skin


@pytest.fixture(scope="module")
def model():
    return full_body_model()


def test_template_is_built_from_the_stature_ratios(model):
    """At rest the joints sit at Winter's heights and widths times the stature, relative to
    the hip joints; a taller template is the same shape, larger; the scales stretch it."""
    names, J = model.skeleton.names, model.skeleton.n_joints

    def joints(m, scales=None):
        s = np.ones(len(m.skeleton.limbs)) if scales is None else scales
        return m.skeleton.transforms(np.zeros((1, J)), s)[0, :, :3, 3]

    H = 1750.0
    X = joints(model)
    height = {"shoulder_r_c": 0.818, "elbow_r": 0.818 - 0.186, "wrist_l": 0.818 - 0.186 - 0.146,
              "knee_r": 0.530 - 0.245, "ankle_l": 0.530 - 0.245 - 0.246,
              "neck_c": (0.818 + 0.870) / 2, "hip_l_c": 0.530}
    for joint, h in height.items():
        assert X[names.index(joint), 2] == pytest.approx((h - 0.530) * H, abs=1e-6), joint
    assert X[names.index("shoulder_l_c"), 0] == pytest.approx(-0.259 / 2 * H)
    assert X[names.index("hip_r_c"), 0] == pytest.approx(0.191 / 4 * H)
    assert model.names == [s.name for s in model.segments] and model.n_segments == 15
    tall = full_body_model(stature=1.1 * H)
    np.testing.assert_allclose(joints(tall), 1.1 * X, atol=1e-9)
    scales = np.ones(len(LIMBS))
    scales[LIMBS.index("thigh")] = 1.2
    Y = joints(model, scales)
    knee, hip = names.index("knee_r"), names.index("hip_r_c")
    assert Y[knee, 2] - Y[hip, 2] == pytest.approx(-1.2 * 0.245 * H)
    with pytest.raises(ValueError, match="stature"):
        full_body_model(stature=-1.0)


def test_joint_axes_and_limits(model):
    names = model.skeleton.names
    a0 = np.zeros((1, model.skeleton.n_joints))
    S = np.ones(len(model.skeleton.limbs))

    def moved(joint, segment, angle):
        a = a0.copy()
        a[0, names.index(joint)] = angle
        k = model.names.index(segment)
        tip = np.array([0.0, 0.0, -model.segments[k].length, 1.0])
        return (model.frames(a, S)[0, k] @ tip - model.frames(a0, S)[0, k] @ tip)[:3]

    assert moved("hip_r_a", "thigh_r", 0.3)[1] > 100            # flexion: forward
    assert moved("knee_l", "shank_l", -0.3)[1] < -50            # knee flexion: backward
    assert moved("shoulder_r_b", "upper_arm_r", -0.3)[0] > 50   # right abduction: outwards
    assert moved("shoulder_l_b", "upper_arm_l", 0.3)[0] < -50   # left abduction: outwards
    lim = limits(model)
    assert lim.shape == (model.skeleton.n_joints, 2) and (lim[:, 0] < lim[:, 1]).all()
    assert (limit_violations(model, a0) == 0).all()             # standing is allowed
    bent = a0.copy()
    bent[0, names.index("knee_r")] = 0.5                        # a knee bent forwards
    v = limit_violations(model, bent)
    assert v[0, names.index("knee_r")] == pytest.approx(0.5) and v.sum() == pytest.approx(0.5)
    with pytest.raises(ValueError, match="angles"):
        limit_violations(model, np.zeros((1, 3)))


def test_full_body_skin_is_closed_part_by_part(model):
    pytest.importorskip("pyvista")
    S = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), S)
    patches = model_skin(model, np.zeros((1, model.skeleton.n_joints)), S, radii)
    assert len(patches) == 15
    mesh = merge_patches(patches)
    assert mesh.n_open_edges == 0
    lo, hi = mesh.bounds[4], mesh.bounds[5]
    assert 1500 < hi - lo < 2000                                # a standing adult's height
