import numpy as np
import pytest

from conftest import smaller
from lsmta.synth import (
    Renderer,
    Scene,
    arm_wave,
    make_background,
    make_body,
    project_surface_points,
    ring_rig,
    triplet_rig,
    walk,
)
from lsmta.triangulation import triangulate


def _small(cam, factor=4):
    return smaller(cam, factor)


@pytest.fixture(scope="module")
def world():
    rng = np.random.default_rng(7)
    cams = triplet_rig(rng=rng)
    body = make_body(rng=rng)
    scene = Scene(body, walk(n_frames=30), make_background(rng=rng))
    return cams, scene


@pytest.fixture(scope="module")
def centre_frame(world):
    cams, scene = world
    return Renderer(scene, [cams[1]], supersample=3).render(12)


def test_rigs_are_seeded_and_named():
    a = triplet_rig(rng=np.random.default_rng(3))
    b = triplet_rig(rng=np.random.default_rng(3))
    c = triplet_rig(rng=np.random.default_rng(4))
    assert [x.name for x in a] == ["left", "centre", "right"]
    assert all(np.array_equal(x.R, y.R) and x.k1 == y.k1 for x, y in zip(a, b))
    assert not np.array_equal(a[0].C, c[0].C)
    assert a[0].image_size == (768, 576)
    ring = ring_rig(n=6, rng=np.random.default_rng(0))
    assert len(ring) == 6
    # every ring camera sees the volume centre near its image centre
    for cam in ring:
        xy = cam.project([[0.0, 0.0, 1000.0]])[0]
        assert np.hypot(xy[0] - cam.cx, xy[1] - cam.cy) < 60


@pytest.mark.slow
def test_ground_truth_world_point_projects_to_pixel_centre(world, centre_frame):
    cams, _ = world
    f = centre_frame
    hit = np.isfinite(f.world_xyz[0, ..., 0])
    assert hit.mean() > 0.99  # wall and floor fill the view
    ii, jj = np.nonzero(hit)
    xy = cams[1].project(f.world_xyz[0][ii, jj])
    assert np.abs(xy - np.stack([jj, ii], axis=1)).max() < 0.05
    on_body = f.part_id[0] >= 0
    assert 0.01 < on_body.mean() < 0.2
    assert np.isnan(f.local_xyz[0][~on_body]).all()
    assert np.isfinite(f.local_xyz[0][on_body]).all()
    # depth is the camera z of the world point
    z = cams[1].to_camera(f.world_xyz[0][ii, jj])[:, 2]
    assert np.allclose(z, f.depth[0][ii, jj])


@pytest.mark.slow
def test_local_points_lie_on_their_ellipsoids(world, centre_frame):
    _, scene = world
    f = centre_frame
    on = f.part_id[0] >= 0
    parts = f.part_id[0][on]
    local = f.local_xyz[0][on]
    c = np.array([scene.body.parts[p].centre for p in parts])
    r = np.array([scene.body.parts[p].radii for p in parts], float)
    assert np.allclose(np.sum(((local - c) / r) ** 2, axis=1), 1.0, atol=1e-9)


@pytest.mark.slow
def test_same_seed_same_images(world):
    cams, scene = world
    small = [_small(c) for c in cams]
    a = Renderer(scene, small, noise_sigma=2.0).render(5, rng=np.random.default_rng(1))
    b = Renderer(scene, small, noise_sigma=2.0).render(5, rng=np.random.default_rng(1))
    c = Renderer(scene, small, noise_sigma=2.0).render(5, rng=np.random.default_rng(2))
    assert a.images.dtype == np.uint8 and a.images.shape == (3, 144, 192)
    assert np.array_equal(a.images, b.images)
    assert not np.array_equal(a.images, c.images)


@pytest.mark.slow
def test_noise_level_and_texture_move_with_the_body(world):
    cams, scene = world
    small = [_small(cams[1], 2)]
    clean = Renderer(scene, small, dtype=np.float64).render(3)
    noisy = Renderer(scene, small, dtype=np.float64, noise_sigma=4.0).render(
        3, rng=np.random.default_rng(0))
    assert np.std(noisy.images - clean.images) == pytest.approx(4.0, rel=0.02)
    # a body-local point has the same grey value whatever the pose (ambient-only light)
    flat = Scene(scene.body, scene.motion, None, ambient=1.0)
    r = Renderer(flat, small, dtype=np.float64, supersample=1)
    f0, f1 = r.render(0), r.render(20)
    part = scene.body.index("torso")
    m0 = f0.part_id[0] == part
    local = f0.local_xyz[0][m0]
    expected = 255 * np.clip(scene.body.parts[part].albedo
                             * scene.body.texture.value(np.full(len(local), part), local), 0, 1)
    assert np.allclose(f0.images[0][m0], expected)
    assert (f1.part_id[0] == part).any()


def test_surface_points_triangulate_exactly(world):
    cams, scene = world
    part, local = scene.body.sample_surface(n_per_part=60, rng=np.random.default_rng(0))
    proj = project_surface_points(scene, cams, part, local, frames=[0, 10, 20])
    both = proj.visible[:, 0] & proj.visible[:, 2]
    assert both.sum() > 100
    for t in range(3):
        sel = both[t]
        xy = proj.xy[t][:, sel].copy()
        xy[1] = np.nan  # left and right cameras only
        res = triangulate(cams, xy)
        assert np.abs(res.points - proj.world[t, sel]).max() < 1e-6


@pytest.mark.slow
def test_visibility_agrees_with_rendering(world, centre_frame):
    cams, scene = world
    cam = cams[1]
    part, local = scene.body.sample_surface(n_per_part=200, rng=np.random.default_rng(1))
    proj = project_surface_points(scene, [cam], part, local, frames=12)
    xy = proj.xy[0, 0]
    px = np.rint(xy).astype(int)
    inside = (cam.in_image(xy) & (px[:, 0] >= 1) & (px[:, 0] < cam.width - 1)
              & (px[:, 1] >= 1) & (px[:, 1] < cam.height - 1))
    px, z = px[inside], cam.to_camera(proj.world[0][inside])[:, 2]
    vis = proj.visible[0, 0][inside]
    ids = centre_frame.part_id[0]
    depth = centre_frame.depth[0][px[:, 1], px[:, 0]]
    # away from silhouettes: the 3x3 pixel neighbourhood shows one surface only
    neighbourhood = np.stack([ids[px[:, 1] + di, px[:, 0] + dj]
                              for di in (-1, 0, 1) for dj in (-1, 0, 1)])
    interior = (neighbourhood == neighbourhood[4]).all(axis=0)
    assert 0.2 < vis.mean() < 0.8 and interior.mean() > 0.5
    v, h = vis & interior, ~vis & interior
    # a visible point is the surface rendered at its pixel, on its own part...
    assert np.all(ids[px[v, 1], px[v, 0]] == part[inside][v])
    assert np.abs(depth[v] - z[v]).max() < 30  # within the slope of one pixel footprint
    # ...and a hidden point lies behind the rendered surface
    assert np.all(depth[h] < z[h] - 1)


def test_skeleton_keeps_bone_lengths():
    body = make_body(rng=np.random.default_rng(0))
    for motion in (walk(n_frames=40), arm_wave(n_frames=40)):
        poses = body.part_poses(motion)
        for i, spec in enumerate(body.parts):
            if spec.parent < 0:
                continue
            joint = poses[:, i, :3, 3]
            parent = poses[:, spec.parent, :3, 3]
            length = np.linalg.norm(joint - parent, axis=1)
            assert np.allclose(length, np.linalg.norm(spec.joint))
        R = poses[..., :3, :3]
        assert np.allclose(np.einsum("tpij,tpkj->tpik", R, R), np.eye(3), atol=1e-12)


def test_walk_moves_across_and_feet_stay_near_floor():
    body = make_body(rng=np.random.default_rng(0))
    m = walk(n_frames=50, speed=1300.0)
    assert m.root_position[-1, 0] - m.root_position[0, 0] == pytest.approx(1300 * 49 / 25)
    part, local = body.sample_surface(n_per_part=400, rng=np.random.default_rng(0),
                                      parts=["foot_l", "foot_r"])
    z = body.to_world(m, part, local)[..., 2]
    lowest = z.min(axis=1)
    assert np.all(lowest > -60) and np.all(lowest < 80)


@pytest.mark.parametrize("call, match", [
    (lambda s, c: Renderer(s, c, supersample=2), "supersample: expected an odd"),
    (lambda s, c: Renderer(s, c, dtype=np.int32), "dtype"),
    (lambda s, c: Renderer(s, c, noise_sigma=1.0).render(0), "rng"),
    (lambda s, c: Renderer(s, c).render(999), "frames"),
    (lambda s, c: Renderer(s, ["cam"]), "cameras"),
    (lambda s, c: project_surface_points(s, c, "elbow", np.zeros((2, 3))), "unknown part"),
    (lambda s, c: project_surface_points(s, c, 0, np.zeros((2, 2))), "local_points"),
    (lambda s, c: make_body(rng=np.random.default_rng(0), contrast={"tail": 0.1}), "tail"),
    (lambda s, c: make_body(rng="0"), "numpy.random.Generator"),
])
def test_bad_input(world, call, match):
    cams, scene = world
    with pytest.raises((ValueError, TypeError), match=match):
        call(scene, [_small(cams[1], 8)])


def test_motion_ground_truth_is_read_only_and_frames_one_at_a_time(world):
    cams, scene = world
    with pytest.raises(ValueError):
        scene.motion.angle("thigh_r")[0, 0] = 1.0
    with pytest.raises(ValueError, match="one frame"):
        Renderer(scene, [_small(cams[1], 8)]).render([3, 7])


def test_with_scene_shares_the_rays_and_renders_like_a_new_renderer(world):
    cams, scene = world
    cam = [_small(cams[1])]
    first = Renderer(scene, cam, dtype=np.float64)
    first.render(12)
    other_scene = Scene(make_body(rng=np.random.default_rng(5), contrast=0.05), scene.motion,
                        scene.background)
    shared = first.with_scene(other_scene)
    assert shared._cache[0]["dirs"] is first._cache[0]["dirs"]
    fresh = Renderer(other_scene, cam, dtype=np.float64)
    assert np.array_equal(shared.render(12).images, fresh.render(12).images)
    no_background = first.with_scene(Scene(other_scene.body, scene.motion, None))
    assert np.array_equal(no_background.render(12).images,
                          Renderer(Scene(other_scene.body, scene.motion, None), cam,
                                   dtype=np.float64).render(12).images)
