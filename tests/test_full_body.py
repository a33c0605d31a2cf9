"""The full-body skeleton: layout against the generator's body, limits, skin (issue 25)."""

import numpy as np
import pytest

from lsmta.body.full_body import full_body_model, limit_violations, limits, template_size
from lsmta.body.skin import merge_patches, model_skin
from lsmta.synth import make_body
from lsmta.synth.body import Motion


@pytest.fixture(scope="module")
def model():
    return full_body_model()


def test_rest_pose_joints_match_the_generators_body(model):
    body = make_body(rng=0)
    P = len(body.parts)
    rest = Motion(name="rest", fps=25.0, root_position=np.zeros((1, 3)),
                  joint_angles=np.zeros((1, P, 3)), part_names=tuple(body.names))
    true = body.part_poses(rest)[0, :, :3, 3]                      # each part's joint
    ours = model.skeleton.transforms(np.zeros((1, model.skeleton.n_joints)),
                                     np.ones(len(model.skeleton.limbs)))[0, :, :3, 3]
    names = model.skeleton.names
    pairs = {"shoulder_r_c": "upper_arm_r", "elbow_l": "forearm_l", "wrist_r": "hand_r",
             "hip_l_c": "thigh_l", "knee_r": "shank_r", "ankle_l": "foot_l", "neck_c": "head"}
    for joint, part in pairs.items():
        np.testing.assert_allclose(ours[names.index(joint)], true[body.index(part)], atol=1e-9)


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
