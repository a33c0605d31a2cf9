"""The building blocks the LSMTA system added to the rooms: image noise from video, bar
labels across cameras, target re-acquisition and precision, rigid groups, functional
joints and the arm's start from trajectories."""

import numpy as np
import pytest

from lsmta.body.joints import functional_joint, segment_axis
from lsmta.body.start import arm_start, torso_frame
from lsmta.calibration import Bar, TargetParams, relative_orientation_start, track_targets
from lsmta.calibration.labels import consistent_bar_labels
from lsmta.calibration.targets import detect_blobs
from lsmta.noise import temporal_noise
from lsmta.synth.calibration import bar_track, project_observations, render_bar_images
from lsmta.synth.rigs import triplet_rig
from lsmta.tracking import Trajectories
from lsmta.tracking.segmentation import rigid_groups


# ------------------------------------------------------------------ image noise
@pytest.mark.parametrize("sigma", [0.7, 2.0, 5.0])
def test_temporal_noise_recovers_sigma_despite_motion(sigma):
    rng = np.random.default_rng(1)
    base = rng.uniform(20, 230, (2, 1, 96, 128))
    v = base + rng.normal(0, sigma, (2, 8, 96, 128))
    # a fifth of the image moves: new texture every frame
    v[:, :, :40, :60] = rng.uniform(20, 230, (2, 8, 40, 60))
    v8 = np.clip(np.rint(v), 0, 255).astype(np.uint8)
    before = v8.copy()
    est = temporal_noise(v8)
    assert np.array_equal(v8, before)
    expected = np.sqrt(sigma**2 + 1 / 12)           # rounding adds 1/12
    assert abs(est.sigma / expected - 1) < 0.06
    assert est.per_camera.shape == (2,)
    # float frames, no rounding: the plain median
    assert abs(temporal_noise(v).sigma / sigma - 1) < 0.06


def test_temporal_noise_leaves_out_clipped_pixels():
    rng = np.random.default_rng(2)
    v = np.clip(np.rint(rng.normal(0, 2.0, (6, 80, 100))), 0, 255).astype(np.uint8)
    v[:, :, 50:] = np.clip(np.rint(100 + rng.normal(0, 2.0, (6, 80, 50))), 0, 255)
    est = temporal_noise(v)             # the black half is clipped: only the grey half counts
    assert abs(est.sigma / np.sqrt(4 + 1 / 12) - 1) < 0.06


def test_temporal_noise_bad_input():
    with pytest.raises(ValueError, match="T >= 2"):
        temporal_noise(np.zeros((1, 10, 10), np.uint8))
    with pytest.raises(TypeError, match="grey values"):
        temporal_noise(np.zeros((2, 10, 10), complex))
    with pytest.raises(ValueError, match="finite"):
        temporal_noise(np.full((2, 10, 10), np.nan))
    with pytest.raises(ValueError, match="too few"):
        temporal_noise(np.zeros((2, 10, 10), np.uint8))      # all clipped
    with pytest.raises(ValueError, match="max_frames"):
        temporal_noise(np.zeros((2, 10, 10)), max_frames=0)


# ------------------------------------------------------------------ bar targets
def _bar(seed, n=60):
    rng = np.random.default_rng(seed)
    cams = triplet_rig(rng=rng)
    track = bar_track(n=n, rng=rng, length=800.0)
    return rng, cams, track


def test_blob_precision_matches_its_scatter():
    rng = np.random.default_rng(3)
    cam = triplet_rig(rng=rng)[1]
    track = bar_track(n=1, rng=rng)
    truth = cam.project(track.points.reshape(-1, 3))
    errs, stds = [], []
    for _ in range(150):
        b = detect_blobs(render_bar_images(cam, track, rng=rng)[0])
        d = np.linalg.norm(b.xy[:, None] - truth[None], axis=2)
        j = d.argmin(axis=0)
        errs.append(b.xy[j] - truth)
        stds.append(b.std[j])
    scatter = np.sqrt(np.mean(np.concatenate(errs) ** 2))
    predicted = np.sqrt(np.mean(np.concatenate(stds) ** 2))
    assert abs(predicted / scatter - 1) < 0.15
    assert np.isfinite(b.noise).all() and abs(np.median(b.noise) / 2.0 - 1) < 0.1


def test_target_leaving_the_image_is_found_again_far_away():
    rng, cams, track = _bar(4, 30)
    cam = cams[1]
    images = render_bar_images(cam, track, rng=rng)
    images[10:14] = 25                       # the bar is out of sight for four frames
    tracks = track_targets(images, params=TargetParams(gate=30.0))
    truth = cam.project(track.points.reshape(-1, 3)).reshape(-1, 2, 2)
    assert np.isnan(tracks.xy[10:14]).all()
    assert np.isfinite(tracks.xy[14:]).all()           # re-acquired, wherever it came back
    # which end is which may have swapped, but each frame holds the two true ends
    err = np.minimum(np.linalg.norm(tracks.xy - truth, axis=2).max(axis=1),
                     np.linalg.norm(tracks.xy - truth[:, ::-1], axis=2).max(axis=1))
    assert np.nanmax(err) < 0.1


def test_swapped_bar_ends_are_made_consistent():
    rng, cams, track = _bar(5)
    n = len(track.A)
    xy = project_observations(cams, track.points.reshape(-1, 3), rng=rng, sigma_px=0.05)
    xy = xy.reshape(3, n, 2, 2)
    swap = rng.random((3, n)) < 0.15
    swap[0] = False
    mixed = np.where(swap[..., None, None], xy[:, :, ::-1], xy)
    before = mixed.copy()
    bar = Bar(np.arange(2 * n).reshape(n, 2), 800.0)
    cams0, _ = relative_orientation_start(triplet_rig(), mixed.reshape(3, -1, 2), bar=bar,
                                          pair=(0, 2))
    labels = consistent_bar_labels(cams0, mixed, 800.0)
    assert np.array_equal(mixed, before)
    ok = ~labels.ambiguous
    assert ok.mean() > 0.9
    assert np.allclose(labels.xy[:, ok], xy[:, ok])
    assert labels.n_swapped == swap[:, ok].sum()


def test_bar_labels_bad_input():
    _, cams, _ = _bar(6, 5)
    with pytest.raises(ValueError, match="xy"):
        consistent_bar_labels(cams, np.zeros((2, 5, 2, 2)), 800.0)
    with pytest.raises(ValueError, match="length"):
        consistent_bar_labels(cams, np.zeros((3, 5, 2, 2)), -1.0)
    with pytest.raises(TypeError, match="cameras"):
        consistent_bar_labels([1, 2, 3], np.zeros((3, 5, 2, 2)), 800.0)


# ------------------------------------------------------------------ rigid groups, joints
def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _chain(rng, T=20, n=60, noise=0.3):
    """A static trunk, an upper segment turning about a ball joint at J1 (two axes) and a
    lower segment hinged to it at J2: trajectories (T, 3n, 3), labels, true joints."""
    J1, J2 = np.array([0.0, 0.0, 1000.0]), np.array([0.0, 0.0, 700.0])
    t = np.linspace(0, 1, T)
    R1 = np.stack([_rot([0, 1, 0], 0.8 * s) @ _rot([1, 0, 0], 0.4 * np.sin(3 * s)) for s in t])
    R2 = np.stack([_rot([1, 0, 0], 0.9 * s) for s in t])
    trunk = rng.uniform([-150, -80, 1000], [150, 80, 1500], (n, 3))
    upper = J1 + rng.uniform([-40, -40, -300], [40, 40, 0], (n, 3))
    lower = J2 + rng.uniform([-35, -35, -260], [35, 35, 0], (n, 3))
    X = np.empty((T, 3 * n, 3))
    X[:, :n] = trunk
    X[:, n:2 * n] = J1 + np.einsum("tij,nj->tni", R1, upper - J1)
    j2 = J1 + (R1 @ (J2 - J1))                                   # (T, 3)
    X[:, 2 * n:] = j2[:, None] + np.einsum("tij,nj->tni", R1 @ R2, lower - J2)
    X += rng.normal(0, noise, X.shape)
    labels = np.repeat([0, 1, 2], n)
    return X, labels, np.repeat(J1[None], T, 0), j2


def test_rigid_groups_split_an_articulated_chain():
    rng = np.random.default_rng(7)
    X, labels, _, _ = _chain(rng)
    X[5:9, 10:20] = np.nan                     # gaps
    X[:, -1] = X[:, 0] + np.cumsum(rng.normal(0, 20, (len(X), 3)), axis=0)   # a wanderer
    before = X.copy()
    traj = Trajectories(X, 25.0)
    g = rigid_groups(traj, tolerance=3.0, rng=0)
    assert np.array_equal(np.isnan(X), np.isnan(before))
    assert g.n_groups == 3
    for true in range(3):
        got = g.label[:-1][labels[:-1] == true]
        assert len(set(got.tolist())) == 1 and got[0] >= 0
    assert g.label[-1] == -1
    assert np.all(g.deviation[g.label >= 0] < 3.0)
    # each group's motion carries its frame onto the trajectories
    for k in range(3):
        m = g.label == k
        pred = np.einsum("tij,nj->tni", g.rotation[k], g.local[m]) + g.translation[k][:, None]
        assert np.nanmax(np.linalg.norm(pred - X[:, m], axis=2)) < 3.0


def test_rigid_groups_bad_input():
    traj = Trajectories(np.zeros((5, 4, 3)), 25.0)
    with pytest.raises(TypeError, match="trajectories"):
        rigid_groups(np.zeros((5, 4, 3)))
    with pytest.raises(ValueError, match="tolerance"):
        rigid_groups(traj, tolerance=0.0)
    with pytest.raises(ValueError, match="min_size"):
        rigid_groups(traj, min_size=1)
    assert rigid_groups(traj).n_groups == 0          # nothing long enough


def test_functional_joint_of_a_ball_joint_and_a_hinge():
    rng = np.random.default_rng(8)
    X, labels, J1, J2 = _chain(rng, noise=0.2)
    g = rigid_groups(Trajectories(X, 25.0), tolerance=3.0, rng=0)
    trunk, upper, lower = (int(np.bincount(g.label[labels == k]).argmax()) for k in range(3))
    ball = functional_joint(g.rotation[trunk], g.translation[trunk], g.rotation[upper],
                            g.translation[upper])
    assert np.abs(ball.world - J1).max() < 2.0 and ball.rms < 1.0
    # a hinge: the centre slides along its axis unless a segment axis holds it
    axis = segment_axis(g.local[g.label == lower])
    hinge = functional_joint(g.rotation[upper], g.translation[upper], g.rotation[lower],
                             g.translation[lower], child_line=axis)
    assert hinge.condition < ball.condition
    assert np.abs(hinge.world - J2).max() < 8.0


def test_segment_axis_of_a_half_seen_limb():
    rng = np.random.default_rng(9)
    z = rng.uniform(-150, 150, 400)
    a = rng.uniform(-np.pi / 2, np.pi / 2, 400)           # only the front half is seen
    r = 45 * np.sqrt(1 - (z / 170) ** 2)                  # tapering to the ends
    P = np.stack([r * np.sin(a), -r * np.cos(a), z], axis=1) + rng.normal(0, 0.3, (400, 3))
    ax = segment_axis(P)
    assert abs(abs(ax.direction[2]) - 1) < 1e-3
    assert np.linalg.norm(ax.point[:2]) < 3.0 and abs(ax.radius - 45) < 4.0
    with pytest.raises(ValueError, match="at least 5"):
        segment_axis(P[:6])


def test_functional_joint_bad_input():
    R = np.tile(np.eye(3), (4, 1, 1))
    t = np.zeros((4, 3))
    with pytest.raises(ValueError, match="at least 3"):
        functional_joint(R, np.full((4, 3), np.nan), R, t)
    with pytest.raises(ValueError, match="child_rotation"):
        functional_joint(R, t, R[:3], t)


# ------------------------------------------------------------------ the arm's start
def _arm_trajectories(seed=10, T=20):
    """Surface samples of the generator's seated arm wave, carried by their parts."""
    from lsmta.evaluation import body as eb
    from lsmta.synth import arm_wave, make_body

    rng = np.random.default_rng(seed)
    body = make_body(rng=rng)
    motion = arm_wave(n_frames=14 + T, position=(450.0, 0.0))
    frames = np.arange(14, 14 + T)
    names = ("torso", "upper_arm_r", "forearm_r")
    part, local = body.sample_surface(n_per_part=150, parts=names, rng=rng)
    X = body.to_world(motion, part, local, frames=frames)
    X = X + rng.normal(0, 0.5, X.shape)
    return Trajectories(X, 25.0), eb.arm_truth(body, motion, frames), part, body


def test_arm_start_finds_the_arm_and_its_joints():
    traj, truth, part, body = _arm_trajectories()
    start = arm_start(traj, forward=(0.0, -1.0, 0.0), rng=0)
    for g, name in ((start.torso, "torso"), (start.upper_arm, "upper_arm_r"),
                    (start.forearm, "forearm_r")):
        assert np.all(part[start.groups.label == g] == body.index(name))
    err = np.linalg.norm(start.joints - truth.joints, axis=2)
    assert np.median(err[:, 0]) < 10 and np.median(err[:, 1]) < 10
    assert np.median(err[:, 2]) < 30                     # the wrist is a guess
    # the torso frame: the true one (facing -Y, upright) up to the arbitrary origin
    assert np.allclose(start.torso_poses[:, :3, :3], truth.torso_poses[:, :3, :3], atol=0.02)
    d = np.degrees(np.abs(np.angle(np.exp(1j * (start.state.angles[:, :4]
                                                - truth.angles[:, :4])))))
    assert np.median(d) < 5
    assert len(start.points) == len(truth.frames)


def test_arm_start_says_when_there_is_no_arm():
    traj, _, part, _ = _arm_trajectories(T=12)
    still = Trajectories(np.where((part == part[0])[None, :, None], traj.xyz, np.nan), 25.0)
    with pytest.raises(ValueError, match="rigidly moving group"):
        arm_start(still, forward=(0.0, -1.0, 0.0))
    with pytest.raises(ValueError, match="forward"):
        torso_frame((0, 0, 1), (0, 0, 2))
    with pytest.raises(TypeError, match="trajectories"):
        arm_start(np.zeros((3, 3, 3)), forward=(0, -1, 0))



def test_forearm_length_ends_where_the_forearm_points_end():
    from lsmta.body.start import forearm_length

    rng = np.random.default_rng(11)
    forearm = rng.uniform(15, 262, 150)
    hand = rng.uniform(295, 400, 15)                     # beyond the unmatched wrist
    assert abs(forearm_length(np.r_[forearm, hand]) - forearm.max()) < 1e-9
    assert forearm_length(forearm) == forearm.max()     # no hand: the distal end
    stray = np.r_[forearm, 300.0, 310.0]                 # two stray points are no hand
    assert forearm_length(stray) == 310.0
    stray3 = np.r_[forearm, 290.0, 300.0, 310.0]         # nor three near a tapering tip
    assert forearm_length(stray3) == 310.0
    # a hand tracked at only a handful of points (under 5 % of the forearm's), far beyond
    # the last forearm point: still a hand
    few = np.r_[forearm, 352.0, 359.0, 373.0, 398.0]
    assert abs(forearm_length(few) - forearm.max()) < 1e-9
    assert forearm_length(forearm[:10]) is None


def test_observed_frames_need_every_segment():
    from lsmta.systems import observed_frames

    counts = np.array([[30, 12], [30, 9], [25, 40], [11, 10], [40, 40]])
    assert observed_frames(counts, min_points=10).tolist() == [0, 2, 3, 4]
    with pytest.raises(ValueError, match="only 1 of 5 frames"):
        observed_frames(counts, min_points=35)
