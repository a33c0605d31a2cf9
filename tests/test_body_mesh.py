"""One closed mesh of the body (lsmta.body.mesh): watertight, one piece, the volume of the
field it comes from, exact on a lone metaball; PLY / OBJ read back; the capture's meshes;
bad input."""

from types import SimpleNamespace

import numpy as np
import pytest
import pyvista as pv
from scipy.spatial.transform import Rotation

from lsmta.body import ModelState, arm_model, base_poses, full_body_model, template_size
from lsmta.body._kernels import grid_field
from lsmta.body.mesh import (
    CUTOFF,
    BodyMesh,
    body_balls,
    body_mesh,
    body_volume,
    metaball_mesh,
    metaball_volume,
    write_mesh,
)
from lsmta.systems.capture_files import capture_meshes, mesh_record

ROOT_T = np.sqrt(np.log(2) / 2)    # a lone ball's skin F = 1/2 lies at this share of its radii
STRIDE = {"hip_r_a": 0.35, "knee_r": -0.15, "hip_l_a": -0.3, "knee_l": -0.6, "ankle_l": 0.2,
          "shoulder_r_a": -0.35, "shoulder_l_a": 0.35, "elbow_r": 0.3, "elbow_l": 0.5,
          "shoulder_r_b": -0.1, "shoulder_l_b": 0.1, "trunk_c": -0.1}


@pytest.fixture(scope="module")
def body():
    """The full-body template in a mid-stride pose, away from the origin."""
    model = full_body_model()
    pose = np.zeros(model.skeleton.n_joints)
    for joint, angle in STRIDE.items():
        pose[model.skeleton.names.index(joint)] = angle
    scales = np.ones(len(model.skeleton.limbs))
    radii = model.simplified_radii(template_size(model), scales)
    base = np.eye(4)
    base[:3, :3] = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    base[:3, 3] = [300.0, 2500.0, 900.0]
    return model, pose, scales, radii, base


@pytest.fixture(scope="module")
def posed(body):
    model, pose, scales, radii, base = body
    return body_mesh(model, pose, scales, radii, base=base, voxel_mm=10.0)


def test_posed_body_is_one_closed_mesh(posed, body):
    assert posed.n_faces > 10000
    assert posed.n_open_edges == 0 and posed.n_nonmanifold_edges == 0
    assert posed.n_components == 1
    assert posed.volume > 0                                  # triangles face outwards
    # the vertices lie on the model's skin F = T (linear interpolation between nodes)
    model, pose, scales, radii, base = body
    F = model.world_field(posed.vertices, pose[None], scales, radii, base=base[None])
    assert np.median(np.abs(F - 0.5)) < 0.01 and np.abs(F - 0.5).max() < 0.1


def test_volume_matches_the_fields(posed, body):
    """The triangles' volume against the nodes where F >= T counted on a grid twice as fine
    (an estimate that does not go through the mesh): marching cubes cuts the convex parts'
    corners by a few 0.1 %; a hand left out would be 0.5 %."""
    model, pose, scales, radii, base = body
    counted = body_volume(model, pose, scales, radii, base=base, voxel_mm=5.0)
    assert -0.005 < posed.volume / counted - 1 < 0     # corners cut, never a part lost
    assert abs(posed.field_volume / counted - 1) < 0.005    # the same count on the mesh's grid
    assert 50e6 < counted < 80e6                             # a person of 1.75 m: 50-80 litres


def test_grid_kernel_is_the_models_field(body):
    model, pose, scales, radii, base = body
    P, R = body_balls(model, pose, scales, radii, base=base)
    origin, step, shape = np.array([-200.0, 2300.0, 0.0]), 40.0, np.array([12, 10, 50])
    values = grid_field(origin, step, shape, P, R, CUTOFF)
    ijk = np.stack(np.meshgrid(*map(np.arange, shape), indexing="ij"), -1).reshape(-1, 3)
    ref = model.world_field(origin + step * ijk, pose[None], scales, radii, base=base[None])
    assert values.max() > 1.0                                # the grid reaches inside the body
    assert np.allclose(values.ravel(), ref, rtol=0, atol=1e-9)


def test_lone_ball_against_the_exact_sphere_and_ellipsoid():
    P = np.eye(4)[None].copy()
    P[0, :3, 3] = [10.0, 20.0, -30.0]
    mesh = metaball_mesh(P, [[100.0] * 3], voxel_mm=4.0)
    R = 100.0 * ROOT_T
    exact = 4 / 3 * np.pi * R ** 3
    assert mesh.n_open_edges == 0 and mesh.n_components == 1
    assert abs(np.linalg.norm(mesh.vertices - P[0, :3, 3], axis=1) - R).max() < 0.05
    assert abs(mesh.volume / exact - 1) < 0.005              # -0.24 % measured (cut corners)
    assert abs(mesh.area / (4 * np.pi * R ** 2) - 1) < 0.005
    P[0, :3, :3] = Rotation.from_rotvec([0.3, 0.5, -0.2]).as_matrix()
    radii = np.array([[40.0, 55.0, 120.0]])
    ell = metaball_mesh(P, radii, voxel_mm=3.0)
    exact = 4 / 3 * np.pi * np.prod(radii * ROOT_T)
    assert ell.n_open_edges == 0 and abs(ell.volume / exact - 1) < 0.01
    assert abs(metaball_volume(P, radii, voxel_mm=3.0) / exact - 1) < 0.01
    assert ell.field_volume == metaball_volume(P, radii, voxel_mm=3.0)


def test_two_apart_balls_are_two_components():
    P = np.tile(np.eye(4), (2, 1, 1))
    P[1, :3, 3] = [300.0, 0.0, 0.0]
    radii = [[100.0] * 3, [80.0] * 3]
    mesh = metaball_mesh(P, radii, voxel_mm=8.0)
    assert mesh.n_components == 2 and mesh.n_open_edges == 0
    label = mesh.component_labels
    assert set(label) == {0, 1}                              # 0: the piece with most vertices
    assert np.all(mesh.vertices[label == 0, 0] < 150) and np.all(mesh.vertices[label == 1, 0] > 150)
    assert abs(mesh.volume / (4 / 3 * np.pi * ROOT_T ** 3 * (100 ** 3 + 80 ** 3)) - 1) < 0.02
    P[1, :3, 3] = [80.0, 0.0, 0.0]                           # blended into one
    assert metaball_mesh(P, [[100.0] * 3] * 2, voxel_mm=8.0).n_components == 1


def test_arm_model_mesh():
    model = arm_model()
    radii = model.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1])
    pose = [0.4, 0.3, 0.2, 1.2, 0.1]
    mesh = body_mesh(model, pose, [1, 1, 1], radii, voxel_mm=6.0)
    assert mesh.n_open_edges == 0 and mesh.n_components == 1
    counted = body_volume(model, pose, [1, 1, 1], radii, voxel_mm=3.0)
    assert abs(mesh.volume / counted - 1) < 0.01


def test_files_read_back(posed, tmp_path):
    for suffix in (".ply", ".obj"):
        path = write_mesh(tmp_path / "sub" / f"body{suffix}", posed)
        back = pv.read(path)
        assert np.array_equal(back.regular_faces, posed.faces)
        assert np.allclose(back.points, posed.vertices, rtol=0, atol=1e-3)   # float32
        assert back.n_open_edges == 0
    assert posed.save(tmp_path / "again.ply").exists()


def test_capture_meshes_from_a_fitted_arm(tmp_path):
    """The capture's mesh stage on a stand-in arm fit (the fitted state's fields only)."""
    model = arm_model()
    radii = model.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1])
    angles = np.array([[0.4, 0.3, 0.2, 1.2, 0.1], [0.2, 0.1, 0.0, 0.8, 0.0]])
    torso = np.tile(np.eye(4), (5, 1, 1))
    torso[:, 0, 3] = np.arange(5) * 100.0
    state = ModelState(angles=angles, shoulder=np.array([[180.0, 0, 400], [180.0, 0, 400]]),
                       scales=np.ones(3), radii=radii)
    arm = SimpleNamespace(frames=np.array([1, 3]), full=SimpleNamespace(state=state),
                          start=SimpleNamespace(torso_poses=torso))
    meshes = capture_meshes(SimpleNamespace(arm=arm), voxel_mm=8.0)
    assert [t for t, _ in meshes] == [1, 3]
    assert all(m.n_open_edges == 0 and m.n_components == 1 for _, m in meshes)
    # fitted frame i is processed frame frames[i]: its torso pose, the fit's own shoulder
    again = body_mesh(model, angles[1], np.ones(3), radii,
                      base=base_poses(torso[3:4], state.shoulder[1]), voxel_mm=8.0)
    assert np.array_equal(meshes[1][1].vertices, again.vertices)
    shifted = body_mesh(model, angles[1], np.ones(3), radii,
                        base=base_poses(torso[1:2], state.shoulder[1]), voxel_mm=8.0)
    assert np.allclose(again.vertices.mean(0) - shifted.vertices.mean(0), [200.0, 0, 0], atol=1.0)
    record = mesh_record([(20 + t, m) for t, m in meshes])
    assert record["written"] and [f["frame"] for f in record["frames"]] == [21, 23]
    assert record["frames"][0]["open_edges"] == 0
    assert capture_meshes(SimpleNamespace(arm=None)) == []
    assert mesh_record([])["written"] is False


def test_mesh_is_read_only_and_inputs_untouched(body):
    model, pose, scales, radii, base = body
    copies = [a.copy() for a in (pose, scales, radii, base)]
    mesh = body_mesh(model, pose, scales, radii, base=base, voxel_mm=20.0)
    assert all(np.array_equal(a, b) for a, b in zip((pose, scales, radii, base), copies))
    with pytest.raises(ValueError):
        mesh.vertices[0, 0] = 1.0
    assert isinstance(mesh, BodyMesh) and mesh.voxel_mm == 20.0 and mesh.level == 0.5


def test_bad_input(body, posed, tmp_path):
    model, pose, scales, radii, base = body
    for voxel in (0.0, -5.0, np.nan):
        with pytest.raises(ValueError, match="voxel_mm"):
            body_mesh(model, pose, scales, radii, voxel_mm=voxel)
    with pytest.raises(ValueError, match="voxel_mm.*too big"):
        body_mesh(model, pose, scales, radii, voxel_mm=0.5)
    with pytest.raises(ValueError, match="voxel_mm.*below the level"):
        metaball_mesh(np.eye(4)[None], [[10.0] * 3], voxel_mm=40.0)
    for level in (0.0, 1.0, 2.0):
        with pytest.raises(ValueError, match="level"):
            body_mesh(model, pose, scales, radii, level=level)
    with pytest.raises(ValueError, match="angles: expected one frame"):
        body_mesh(model, np.zeros((2, len(pose))), scales, radii)
    with pytest.raises(ValueError, match="angles: expected one frame"):
        body_mesh(model, pose[:-1], scales, radii)
    with pytest.raises(ValueError, match="scales"):
        body_mesh(model, pose, scales[:-1], radii)
    with pytest.raises(ValueError, match="radii"):
        body_mesh(model, pose, scales, radii[:-1])
    with pytest.raises(ValueError, match="radii"):
        body_mesh(model, pose, scales, -radii)
    with pytest.raises(ValueError, match="base: expected one frame"):
        body_mesh(model, pose, scales, radii, base=np.eye(3))
    with pytest.raises(ValueError, match="poses: expected an array"):
        metaball_mesh(np.eye(4), [[10.0] * 3])
    with pytest.raises(ValueError, match="poses: expected rigid"):
        metaball_mesh(2 * np.eye(4)[None], [[10.0] * 3])
    with pytest.raises(ValueError, match="radii"):
        metaball_volume(np.eye(4)[None], [[10.0] * 2])
    for name in ("body.stl", "body.PLY"):
        with pytest.raises(ValueError, match="path: expected"):
            write_mesh(tmp_path / name, posed)
    with pytest.raises(TypeError, match="mesh: expected a BodyMesh"):
        write_mesh(tmp_path / "body.ply", pv.Sphere())
