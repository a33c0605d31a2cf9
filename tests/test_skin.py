"""B-spline skin from ray-cast cross-sections of the implicit surface (issue 25, Fig. 6)."""

import numpy as np
import pytest

from lsmta.body import arm_model
from lsmta.body.skin import SkinParams, merge_patches, model_skin, skin_patch
from lsmta.synth.surface import distance_to_ellipsoid

pv = pytest.importorskip("pyvista")

R = np.array([40.0, 55.0, 120.0])                    # one metaball's radii (mm)
E = R * np.sqrt(np.log(2) / 2)                       # its skin F = 1/2: an exact ellipsoid


def _level(x):
    return np.exp(-2 * np.sum((x / R) ** 2, axis=1)) - 0.5


def _mesh(patch):
    faces = np.hstack([np.full((len(patch.faces), 1), 3), patch.faces]).ravel()
    return pv.PolyData(np.asarray(patch.vertices), faces).clean()


def test_skin_of_one_ellipsoid_against_its_exact_surface():
    axis = np.array([0.0, 0.0, 0.8 * E[2]])
    patch = skin_patch(_level, -axis, axis, reach=200.0)
    # the ray-cast samples lie on the surface (bisection), the spline between them close by
    assert np.abs(distance_to_ellipsoid(patch.samples.reshape(-1, 3), E)).max() < 1e-6
    d_skin = np.abs(distance_to_ellipsoid(patch.vertices, E))
    assert np.median(d_skin) < 0.02 and d_skin.max() < 0.5
    rng = np.random.default_rng(0)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    mesh = _mesh(patch)
    d_true = np.abs(pv.PolyData(u * E).compute_implicit_distance(mesh)["implicit_distance"])
    assert np.median(d_true) < 0.1 and d_true.max() < 0.5
    assert mesh.n_open_edges == 0 and mesh.is_manifold
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * np.prod(E), rel=0.01)


def test_finer_sections_bring_the_spline_closer():
    axis = np.array([0.0, 0.0, 0.8 * E[2]])
    med = [np.median(np.abs(distance_to_ellipsoid(
        skin_patch(_level, -axis, axis, reach=200.0,
                   params=SkinParams(n_sections=n)).vertices, E))) for n in (6, 12, 24)]
    assert med[0] > med[1] > med[2]


def test_arm_skin_is_closed_part_by_part():
    m = arm_model()
    radii = m.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1])
    angles = np.array([[0.3, 0.2, 0.0, 1.0, 0.0]])
    patches = model_skin(m, angles, [1, 1, 1], radii)
    assert len(patches) == 3
    for patch in patches:
        assert _mesh(patch).n_open_edges == 0
    merged = merge_patches(patches)
    assert merged.n_open_edges == 0 and merged.n_cells == sum(len(p.faces) for p in patches)
    # every vertex lies on its own segment's level set F = T (up to the spline's error)
    for k, patch in enumerate(patches):
        d = m.distance(patch.vertices, np.full(len(patch.vertices), k), angles, [1, 1, 1], radii)
        assert np.median(np.abs(d)) < 0.1 and np.abs(d).max() < 2.0


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="inside"):
        skin_patch(_level, [0, 0, 500.0], [0, 0, 600.0], reach=800.0)
    with pytest.raises(ValueError, match="reach"):
        skin_patch(_level, [0, 0, -10.0], [0, 0, 10.0], reach=5.0)
    with pytest.raises(ValueError, match="axis_end"):
        skin_patch(_level, [0, 0, 1.0], [0, 0, 1.0], reach=200.0)
    with pytest.raises(ValueError, match="n_around"):
        SkinParams(n_around=3)
    with pytest.raises(ValueError, match="radii"):
        distance_to_ellipsoid(np.zeros((1, 3)), [1.0, 0.0, 1.0])


def test_distance_to_the_true_body():
    from lsmta.synth import make_body, walk
    from lsmta.synth.body import surface_samples
    from lsmta.synth.surface import distance_to_body

    body, motion = make_body(rng=0), walk(n_frames=2)
    poses = body.part_poses(motion, frames=0)[0]
    on, _, _ = surface_samples(body, motion, 0, rng=1, parts=("torso", "thigh_r", "head"), n=200)
    assert np.abs(distance_to_body(body, poses, on)).max() < 1e-6
    head = poses[body.index("head")]
    top = head[:3, :3] @ (np.array(body.parts[body.index("head")].centre)
                          + [0, 0, body.parts[body.index("head")].radii[2]]) + head[:3, 3]
    above = top + 100.0 * head[:3, 2]
    assert distance_to_body(body, poses, above[None])[0] == pytest.approx(100.0, abs=1e-6)
