"""Basis-face model, PCA gap filling, the face generator and the AnimFace reader."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lsmta import face
from lsmta.data import load_animface
from lsmta.evaluation import face as ef
from lsmta.io import read_maya_curves
from lsmta.synth import face as sf
from lsmta.triangulation import triangulate_single_pair


@pytest.fixture(scope="module")
def model():
    return sf.face_model()


def _moved(shapes, rng):
    """Each frame of (T, M, 3) under its own random rigid motion."""
    R = Rotation.random(len(shapes), random_state=rng.integers(1 << 31)).as_matrix()
    t = rng.normal(0, 500, (len(shapes), 3))
    return np.einsum("tij,tmj->tmi", R, shapes) + t[:, None]


def test_generator_shape_and_rigid_markers(model):
    assert len(model.labels) == 76 == len(set(model.labels))
    seq = sf.face_sequence(model, 120, rng=np.random.default_rng(0))
    assert seq.world.shape == (120, 76, 3)
    # markers no expression moves keep their head-frame position
    np.testing.assert_allclose(seq.head[:, model.rigid], np.broadcast_to(
        model.neutral[model.rigid], (120, model.rigid.sum(), 3)), atol=1e-12)
    # the lips do move, by centimetres
    lips = model.group("lower_lip")
    assert np.ptp(seq.head[:, lips, 1], axis=0).max() > 10
    assert seq.weights.min() >= 0 and seq.weights.max() <= 1
    # the world points are the head points under the head pose
    np.testing.assert_allclose(ef.to_head(seq.world, seq.R, seq.t), seq.head, atol=1e-9)


def test_geometric_occlusion_hides_half_the_face_when_the_head_turns(model):
    R = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)
    cam = np.array([0.0, -3000.0, 0.0])
    front = sf.visible(model.neutral @ R.T, model.normals @ R.T, cam)
    turn = Rotation.from_euler("y", 70, degrees=True).as_matrix()
    side = sf.visible(model.neutral @ (R @ turn).T, model.normals @ (R @ turn).T, cam)
    assert front.sum() > 60
    assert side.sum() < front.sum() - 20
    left = model.neutral[:, 0] < -20
    right = model.neutral[:, 0] > 20
    # one half of the face loses most of its markers, the other keeps most
    lost = sorted([side[left].mean(), side[right].mean()])
    assert lost[0] < 0.3 and lost[1] > 0.7


def test_occlusion_schedule_counts():
    vis = sf.occlusion_schedule(431, 76, 42, 16, rng=np.random.default_rng(1))
    assert vis.shape == (431, 76)
    assert vis[0].sum() == 42 and vis[-1].sum() == 16
    assert np.all(np.diff(vis.sum(axis=1)) <= 0)
    assert not np.any(vis[1:] & ~vis[:-1])          # once hidden, hidden for good


def test_fill_missing_recovers_a_combination_of_basis_faces(model):
    rng = np.random.default_rng(2)
    basis = model.shapes(np.eye(6))
    w_true = rng.dirichlet(np.ones(6), 30)          # faces between the basis faces
    truth = _moved(np.einsum("tk,kmj->tmj", w_true, basis), rng)
    gappy = truth.copy()
    hidden = rng.random((30, 76)) < 0.3
    gappy[hidden] = np.nan
    before = gappy.copy()
    fit = face.fill_missing(gappy, basis, n_iter=4)
    np.testing.assert_array_equal(gappy, before)           # input untouched
    assert fit.fitted.all()
    np.testing.assert_allclose(fit.frames, truth, atol=1e-5)
    np.testing.assert_allclose(fit.weights, w_true, atol=1e-6)
    assert np.all(fit.residual < 1e-5)
    # observed markers are passed through unchanged
    np.testing.assert_array_equal(fit.frames[~hidden], gappy[~hidden])


def test_constraint_keeps_weights_in_unit_interval(model):
    rng = np.random.default_rng(3)
    basis = model.shapes(np.eye(6))
    w = rng.uniform(-0.5, 1.5, (20, 6))             # outside the box
    frames = np.einsum("tk,kmj->tmj", w, basis) + rng.normal(0, 0.3, (20, 76, 3))
    frames[:, :10] = np.nan
    con = face.fill_missing(frames, basis, constrain=True)
    free = face.fill_missing(frames, basis, constrain=False)
    assert con.weights.min() >= -1e-12 and con.weights.max() <= 1 + 1e-12
    assert free.weights.min() < -0.1 and free.weights.max() > 1.1
    # the unconstrained fit explains the observed markers at least as well
    assert np.all(free.residual <= con.residual + 1e-9)


def test_pca_basis_recovers_a_linear_face_under_head_motion(model):
    # the generator's expressions are linear in six weights; aligning the training frames
    # by Procrustes on all markers couples a little pose into the shapes, so two more
    # components than modes make the fit near exact (not to round-off)
    rng = np.random.default_rng(4)
    train = _moved(sf.face_sequence(model, 150, rng=rng, moving=False).head, rng)
    test = sf.face_sequence(model, 40, rng=rng, moving=True)
    basis = face.pca_basis(train, 8)
    assert basis.vectors.shape == (9, 76, 3) and not basis.constrain
    gappy = test.world.copy()
    hidden = sf.occlusion_schedule(40, 76, 60, 35, rng=rng)
    gappy[~hidden] = np.nan
    fit = face.fill_missing(gappy, basis)
    err = np.linalg.norm(fit.frames - test.world, axis=2)
    assert np.median(err[~hidden]) < 0.05 and err.max() < 0.5


def test_extreme_basis_picks_distinct_training_frames(model):
    rng = np.random.default_rng(5)
    train = sf.face_sequence(model, 200, rng=rng, moving=False).head
    b = face.extreme_basis(train, 12)
    assert len(set(b.frames.tolist())) == 12 and b.constrain
    aligned, _ = face.align_sequence(train)
    np.testing.assert_allclose(b.vectors, aligned[b.frames])
    # the pick for the first component is the frame most extreme along it
    d = (aligned - aligned.mean(axis=0)).reshape(200, -1)
    v = np.linalg.svd(d, full_matrices=False)[2][0]
    assert b.frames[0] == np.argmax(np.abs(d @ v))
    with pytest.raises(ValueError, match="n_basis"):
        face.extreme_basis(train, 0)


def test_fill_missing_beats_the_mean_face_on_generated_data(model):
    rng = np.random.default_rng(6)
    train = sf.face_sequence(model, 200, rng=rng, moving=False).head + rng.normal(0, 0.5,
                                                                               (200, 76, 3))
    test = sf.face_sequence(model, 60, rng=rng, moving=False).head
    gappy = test + rng.normal(0, 0.5, test.shape)
    miss = model.group("lower_lip")
    gappy[:, miss] = np.nan
    obs = np.isfinite(gappy).all(axis=2)
    errs = {}
    for name, filled in ef.fill_all(gappy, train, n_basis=20, n_components=6,
                                    peer_components=6).items():
        errs[name] = np.nanmedian(ef.missing_errors(filled, test, obs))
    mean_face = np.linalg.norm(face.align_sequence(train)[1][miss] - test[:, miss], axis=2)
    for name, e in errs.items():
        assert e < 0.5 * np.median(mean_face), name


def test_pca_gap_fill_exact_on_low_rank_data():
    rng = np.random.default_rng(7)
    comps = rng.normal(size=(3, 20 * 3))
    frames = (rng.normal(size=(80, 3)) @ comps + rng.normal(size=60)).reshape(80, 20, 3)
    gappy = frames.copy()
    gappy[40:, :5] = np.nan
    before = gappy.copy()
    out = face.pca_gap_fill(gappy, n_components=3, weighting="none")
    np.testing.assert_array_equal(gappy, before)
    np.testing.assert_allclose(out.frames, frames, atol=1e-8)
    assert out.fitted.all() and out.n_components == 3
    # the distance-weighted method (two PCAs related by T) is exact only up to the 0.02
    # weight left on the missing columns
    out = face.pca_gap_fill(gappy, n_components=3)
    np.testing.assert_array_equal(gappy, before)
    assert np.abs(out.frames - frames).max() < 1e-2 * np.abs(frames).max()
    # a frame with one observed marker (3 coordinates for 3 scores) and one with none
    sparse = frames.copy()
    sparse[0, 1:] = np.nan
    sparse[1] = np.nan
    out = face.pca_gap_fill(sparse, n_components=3, weighting="none")
    assert np.isfinite(out.frames[0]).all() and np.isnan(out.frames[1]).all()
    np.testing.assert_array_equal(out.fitted[:2], [True, False])
    with pytest.raises(ValueError, match="complete frames"):
        face.pca_gap_fill(np.where(np.arange(20)[None, :, None] < 1, np.nan, frames))


def test_bad_input(model):
    basis = model.shapes(np.eye(6))
    frames = np.repeat(model.neutral[None], 4, axis=0)
    with pytest.raises(ValueError, match="basis: expected 76 markers"):
        face.fill_missing(frames, basis[:, :70])
    bad = basis.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="basis"):
        face.fill_missing(frames, bad)
    inf = frames.copy()
    inf[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="frames"):
        face.fill_missing(inf, basis)
    with pytest.raises(ValueError, match="frames"):
        face.fill_missing(frames[0], basis)
    with pytest.raises(ValueError, match="n_iter"):
        face.fill_missing(frames, basis, n_iter=0)
    # too few observed markers and all-missing frames: NaN results, flagged
    gappy = frames.copy()
    gappy[1, 2:] = np.nan                           # 2 markers left (< 3)
    gappy[2] = np.nan                               # nothing observed
    before = gappy.copy()
    fit = face.fill_missing(gappy, basis)
    np.testing.assert_array_equal(gappy, before)
    np.testing.assert_array_equal(fit.fitted, [True, False, False, True])
    assert np.isnan(fit.frames[1, 2:]).all() and np.isnan(fit.frames[2]).all()
    assert np.isnan(fit.weights[1:3]).all() and np.isnan(fit.residual[1:3]).all()
    np.testing.assert_array_equal(fit.frames[1, :2], gappy[1, :2])
    assert face.min_observed_markers(80) == 29 and face.min_observed_markers(3) == 3


def test_distance_deviation_zero_for_rigid_markers(model):
    seq = sf.face_sequence(model, 300, rng=np.random.default_rng(8))
    ue = model.group("under_eye")
    pairs = np.array(list(itertools.combinations(ue, 2)))
    assert np.abs(face.distance_deviation(seq.world, pairs)).max() < 1e-9
    lips = np.array([[model.group("upper_lip")[0], model.group("lower_lip")[0]]])
    assert np.abs(face.distance_deviation(seq.world, lips)).max() > 5
    with pytest.raises(ValueError, match="pairs"):
        face.distance_deviation(seq.world, np.array([[0, 99]]))


def test_single_pair_triangulation_noise_free(model):
    seq = sf.face_sequence(model, 3, rng=np.random.default_rng(9))
    obs = ef.observe_face(seq, rng=np.random.default_rng(10), pixel_noise=0.0, pose_noise_deg=0.0)
    ok = np.isfinite(obs.points).all(axis=2)
    assert ok.sum(axis=1).min() > 30
    np.testing.assert_allclose(obs.points[ok], seq.world[ok], atol=1e-6)
    cams = sf.face_cameras(seq.t[0])
    xy = np.stack([c.project(seq.world[0]) for c in cams])
    xy[0, :] = np.nan
    r = triangulate_single_pair(cams, xy)
    assert 0 not in r.pair.tolist()


def test_read_maya_curves(tmp_path):
    text = ['currentUnit -l centimeter -a degree -t film;']
    for name, base in (("A", 1.0), ("B", 2.0)):
        for ax, off in zip("XYZ", (0.0, 10.0, 20.0)):
            text.append(f'createNode animCurveTL -n "{name}_translate{ax}";')
            text.append('\tsetAttr -s 3 ".ktv";')
            text.append(f'\tsetAttr ".ktv[0:2]"  0 {base + off} 1 {base + off + 0.5}\n'
                        f'\t\t 2 {base + off + 1};')
    path = tmp_path / "m.ma"
    path.write_text("\n".join(text))
    labels, pts, times = read_maya_curves(path)
    assert labels == ("A", "B")
    np.testing.assert_array_equal(times, [0, 1, 2])
    np.testing.assert_allclose(pts[:, 0, 0], [10, 15, 20])     # cm -> mm
    np.testing.assert_allclose(pts[2, 1], [30, 130, 230])
    with pytest.raises(FileNotFoundError):
        read_maya_curves(tmp_path / "none.ma")


def test_project_copy_of_animface():
    labels, jaw = load_animface("JawMoCap")
    assert len(labels) == 41 and jaw.shape == (1590, 41, 3)
    assert np.isfinite(jaw).all()
    width = np.ptp(jaw[0, :, 0])
    assert 100 < width < 200                                    # a face, in mm


def test_mixing_camera_pairs_distorts_the_face(model):
    seq = sf.face_sequence(model, 40, rng=np.random.default_rng(11))
    ue = model.group("under_eye")
    pairs = np.array(list(itertools.combinations(ue, 2)))
    dev = {}
    for mode in ("single", "per_marker"):
        o = ef.observe_face(seq, rng=np.random.default_rng(12), pairing=mode)
        dev[mode] = np.nanmedian(np.abs(face.distance_deviation(o.points, pairs)))
    assert dev["per_marker"] > 2 * dev["single"]
    with pytest.raises(ValueError, match="pairing"):
        ef.observe_face(seq, rng=np.random.default_rng(12), pairing="any")


def test_fill_missing_needs_enough_observed_markers(model):
    # six basis faces: 6 weights + 6 rigid unknowns need 12 coordinates, i.e. 4 markers
    basis = model.shapes(np.eye(6))
    assert face.min_observed_markers(6) == 4
    rng = np.random.default_rng(13)
    w_true = rng.dirichlet(np.ones(6), 2)
    truth = np.einsum("tk,kmj->tmj", w_true, basis)
    gappy = truth.copy()
    keep = model.group("cheek")[:4]
    mask = np.ones(76, bool)
    mask[keep] = False
    gappy[:, mask] = np.nan
    gappy[0, keep[3]] = np.nan                      # frame 0: 3 markers, one too few
    basis_before = basis.copy()
    fit = face.fill_missing(gappy, basis)
    np.testing.assert_array_equal(fit.fitted, [False, True])
    assert np.isnan(fit.frames[0][mask]).all() and np.isnan(fit.weights[0]).all()
    np.testing.assert_array_equal(fit.frames[0, keep[:3]], gappy[0, keep[:3]])
    assert np.isfinite(fit.frames[1]).all()
    np.testing.assert_array_equal(basis, basis_before)      # basis untouched


def test_fill_missing_rejects_a_bad_face_basis(model):
    rng = np.random.default_rng(14)
    train = sf.face_sequence(model, 60, rng=rng, moving=False).head
    b = face.pca_basis(train, 4)
    frames = train[:3].copy()
    frames[:, :5] = np.nan
    vec = b.vectors.copy()
    vec[2, 7, 1] = np.nan
    with pytest.raises(ValueError, match="basis"):
        face.fill_missing(frames, face.FaceBasis(vec, b.reference, "pca", False,
                                                 b.frames, b.explained))
    ref = b.reference.copy()
    ref[0, 0] = np.nan
    with pytest.raises(ValueError, match="reference"):
        face.fill_missing(frames, b, reference=ref)
    with pytest.raises(ValueError, match="basis: expected 70 markers"):
        face.fill_missing(frames[:, :70], b)
    # a training sequence with a gap cannot build a basis
    bad = train.copy()
    bad[3, 3] = np.nan
    before = bad.copy()
    for build in (face.extreme_basis, face.pca_basis):
        with pytest.raises(ValueError, match="training|frames"):
            build(bad, 3)
    np.testing.assert_array_equal(bad, before)


def test_pca_gap_fill_bad_input(model):
    rng = np.random.default_rng(15)
    seq = sf.face_sequence(model, 30, rng=rng, moving=False).head
    gappy = seq.copy()
    gappy[5:, :4] = np.nan
    gappy[7] = np.nan                                # all-missing frame
    before = gappy.copy()
    out = face.pca_gap_fill(gappy, n_components=4)
    np.testing.assert_array_equal(gappy, before)
    assert not out.fitted[7] and np.isnan(out.frames[7]).all()
    assert out.fitted[np.r_[0:7, 8:30]].all()
    with pytest.raises(ValueError, match="training: expected 76 markers"):
        face.pca_gap_fill(gappy, training=seq[:, :70])
    with pytest.raises(ValueError, match="variance"):
        face.pca_gap_fill(gappy, variance=1.5)
    with pytest.raises(ValueError, match="scale"):
        face.pca_gap_fill(gappy, scale="unit")


def test_extreme_basis_finds_the_planted_extreme_expression(model):
    # ground truth from the generator: mild expressions, one frame with the jaw wide open
    rng = np.random.default_rng(16)
    w = rng.uniform(0, 0.15, (120, 6))
    w[37, 0] = 1.0
    b = face.extreme_basis(model.shapes(w), 6)
    assert b.frames[0] == 37


def test_eleven_of_76_removed_within_the_papers_1_5_mm(model):
    # the target (Figs. 65/66) on generated data: 11 markers removed from every
    # frame, 80 extreme faces from a different noisy sequence, weights in [0, 1]
    rng = np.random.default_rng(17)
    noise = 1.0
    train = sf.face_sequence(model, 200, rng=rng, moving=False).head
    train = train + rng.normal(0, noise, train.shape)
    test = sf.face_sequence(model, 30, rng=rng, moving=False).head
    gappy = test + rng.normal(0, noise, test.shape)
    removed = rng.choice(76, 11, replace=False)
    gappy[:, removed] = np.nan
    fit = face.fill_missing(gappy, face.extreme_basis(train, 80))
    err = np.linalg.norm((fit.frames - test)[:, removed, :2], axis=2)   # frontal plane
    assert np.median(err) < 1.5


def test_head_motion_is_room_scale_and_rigid():
    R, t = sf.head_motion(200, rng=np.random.default_rng(18))
    np.testing.assert_allclose(np.einsum("tij,tkj->tik", R, R),
                               np.broadcast_to(np.eye(3), (200, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert 1900 < np.ptp(t[:, 0]) < 2100


def test_peer_after_alignment_undoes_head_motion(model):
    # ground truth from the generator: a moving head, gaps; aligned peer ~ head-frame peer
    rng = np.random.default_rng(19)
    train = sf.face_sequence(model, 150, rng=rng, moving=False).head
    test = sf.face_sequence(model, 40, rng=rng, moving=True)
    vis = sf.occlusion_schedule(40, 76, 60, 40, rng=rng)
    gappy = np.where(vis[..., None], test.world, np.nan)
    before = gappy.copy()
    out = ef.peer_after_alignment(gappy, train, n_components=8)
    np.testing.assert_array_equal(gappy, before)
    raw = face.pca_gap_fill(gappy, training=train, n_components=8, weighting="none").frames
    moved = face.pca_gap_fill(gappy, training=train, n_components=8).frames
    err = np.linalg.norm(out - test.world, axis=2)[~vis]
    err_raw = np.linalg.norm(raw - test.world, axis=2)[~vis]
    err_moved = np.linalg.norm(moved - test.world, axis=2)[~vis]
    # one Kabsch fit on the observed markers absorbs some expression: millimetres, not 0;
    # without it the core breaks, and the full method's centroid shift removes only the
    # translation of the head, not its turns
    assert np.median(err) < 3.0 and 100 < np.median(err_raw) and 20 < np.median(err_moved)
    np.testing.assert_array_equal(out[vis], gappy[vis])


def test_removal_trials_match_the_experiment_by_hand(model):
    """removal_trials (notebook 13, Figs. 65/66) is the loop it replaced: same draws, same
    errors; and the constrained extreme faces fill the removed markers to a few mm."""
    seed = [5, 65, 0]
    got = ef.removal_trials(model, [seed], n_train=60, n_test=20, n_removed=11, n_basis=12,
                            n_components=5, noise_mm=0.5)
    r = np.random.default_rng(seed)
    tr = sf.face_sequence(model, 60, rng=r, moving=False).head
    tr = tr + r.normal(0, 0.5, tr.shape)
    te = sf.face_sequence(model, 20, rng=r, moving=False).head
    gappy = te + r.normal(0, 0.5, te.shape)
    removed = r.choice(len(model.labels), 11, replace=False)
    np.testing.assert_array_equal(got.removed[0], removed)
    gappy[:, removed] = np.nan
    filled = ef.fill_all(gappy, tr, n_basis=12, n_components=5, peer_components=5)
    for name in ef.METHODS:
        want = (filled[name] - te)[:, np.sort(removed)][..., :2].reshape(-1, 2)
        np.testing.assert_allclose(np.sort(got.errors[name][0]),
                                   np.sort(np.linalg.norm(want, axis=1)), rtol=1e-12)
        assert got.xy[name][0].shape == (20 * 11, 2)
    assert np.median(got.errors[ef.METHODS[2]][0]) < 3.0      # PCA basis: a few mm at most


# --- self-occlusion: markers hidden by the head itself (Davis section 5.3) ------------------

_BASE = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)   # head -> world, facing -Y
_CAM = np.array([[0.0, -3000.0, 0.0]])                             # in front of the face


def _posed(head_points, yaw_deg):
    """Head-frame points (M, 3) under a head at the origin turned by ``yaw_deg``."""
    R = _BASE @ Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    return (head_points @ R.T)[None], R[None], np.zeros((1, 3))


def test_self_occlusion_sphere_far_side_hidden_near_side_seen():
    from lsmta.synth.head_surface import HeadShape, self_occlusion
    sphere = HeadShape(a=100.0, b=100.0, front=100.0, back=100.0, face=False)
    near, far = [0.0, 0.0, 100.0], [0.0, 0.0, -100.0]
    side = [70.0, 0.0, np.sqrt(100.0 ** 2 - 70.0 ** 2)]
    other = [-70.0, 0.0, np.sqrt(100.0 ** 2 - 70.0 ** 2)]
    pts, R, t = _posed(np.array([near, far, side, other]), 0.0)
    seen = self_occlusion(pts, R, t, _CAM, shape=sphere)
    assert seen.shape == (1, 1, 4)
    assert seen[0, 0].tolist() == [True, False, True, True]
    # turning the head by 60 degrees carries the +x side behind the sphere, -x stays in view
    pts, R, t = _posed(np.array([near, far, side, other]), 60.0)
    seen = self_occlusion(pts, R, t, _CAM, shape=sphere)[0, 0]
    assert seen.tolist() == [True, False, False, True]


def test_self_occlusion_sphere_agrees_with_the_tangent_plane():
    # on a sphere, a point is seen exactly when the camera is above its tangent plane
    from lsmta.synth.head_surface import HeadShape, self_occlusion
    rng = np.random.default_rng(3)
    sphere = HeadShape(a=100.0, b=100.0, front=100.0, back=100.0, face=False)
    n = rng.normal(size=(400, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n = n[np.abs(n[:, 0] ** 2 + n[:, 1] ** 2 - 1) > 0.02]   # off the outline's rim
    cams = rng.normal(size=(3, 3))
    cams = 2000 * cams / np.linalg.norm(cams, axis=1, keepdims=True)
    pts = 100.0 * n
    seen = self_occlusion(pts[None], np.eye(3)[None], np.zeros((1, 3)), cams, shape=sphere)[0]
    cosine = np.einsum("cmk,mk->cm", cams[:, None] - pts[None], n) / np.linalg.norm(
        cams[:, None] - pts[None], axis=2)
    clear = np.abs(cosine) > 0.1                         # leave out grazing lines of sight
    assert clear.sum() > 800
    np.testing.assert_array_equal(seen[clear], cosine[clear] > 0)


def test_self_occlusion_the_nose_hides_markers_that_face_the_camera(model):
    from lsmta.synth.head_surface import HeadShape, self_occlusion
    pts, R, t = _posed(model.neutral, 0.0)
    assert self_occlusion(pts, R, t, _CAM).all()          # the whole face seen from the front
    pts, R, t = _posed(model.neutral, 50.0)
    seen = self_occlusion(pts, R, t, _CAM)[0, 0]
    facing = sf.visible(pts[0], model.normals @ R[0].T, _CAM[0], min_cos=0.0)
    behind_nose = np.flatnonzero(facing & ~seen)
    assert {model.labels[i] for i in behind_nose} >= {"under_eye_0", "under_eye_2"}
    # it is the nose that hides them: their lines of sight enter the head at the nose ...
    seen, hit = self_occlusion(pts, R, t, _CAM, return_hit=True)
    assert np.isnan(hit[0, 0][seen[0, 0]]).all()
    hit = hit[0, 0, behind_nose]
    assert (np.abs(hit[:, 0]) < 20).all() and (np.abs(hit[:, 1] + 2) < 30).all()
    # ... and a head without one (a plain half-ellipsoid of the same size, the markers on
    # it) shows them
    plain = HeadShape(a=80.0, b=110.0, front=95.0, face=False)
    on_plain = model.neutral.copy()
    on_plain[:, 2] = plain.sheets(on_plain[:, 0], on_plain[:, 1])[1]
    pts, R, t = _posed(on_plain, 50.0)
    assert self_occlusion(pts, R, t, _CAM, shape=plain)[0, 0, behind_nose].all()
    # turned further, one side of the face is lost and the other kept
    pts, R, t = _posed(model.neutral, 80.0)
    seen = self_occlusion(pts, R, t, _CAM)[0, 0]
    x = model.neutral[:, 0]
    assert seen[x > 20].mean() < 0.2 and seen[x < -20].mean() > 0.95


def test_self_occlusion_expressions_do_not_hide_a_marker_from_the_front(model):
    from lsmta.synth.head_surface import self_occlusion
    w = np.vstack([np.eye(len(model.mode_names)),
                   np.random.default_rng(0).uniform(0, 1, (30, len(model.mode_names)))])
    shapes = model.shapes(w)
    R = np.broadcast_to(_BASE, (len(w), 3, 3))
    seen = self_occlusion(shapes @ _BASE.T, R, np.zeros((len(w), 3)), _CAM,
                          neutral=model.neutral)
    assert seen.all()


def _jaw_normals(model, weight):
    """The neutral normals turned with the jaw (its hinge rotation, 16 degrees at full
    weight, times each marker's share of it): the expressed face's normals, (M, 3)."""
    infl = np.clip((-38 - model.neutral[:, 1]) / 14, 0, 1)
    infl = infl * infl * (3 - 2 * infl)
    rot = Rotation.from_rotvec(np.radians(16.0) * weight * infl[:, None] * [1.0, 0, 0])
    return rot.apply(model.normals)


def test_self_occlusion_the_open_jaw_hides_nothing_that_faces_the_camera(model):
    # the rig's outer cameras (pt0, pt3; Z = 2200 mm) and a head at 1650 mm turning; the
    # jaw opening step by step: a marker that faces a camera strongly (expressed normal,
    # cos > 0.3) and is seen on the neutral face in the same pose (so not behind the nose
    # or another feature that hides it without any expression) stays seen, and no marker
    # is hidden, seen and hidden again as the jaw opens (the occluder used to be the
    # closed-jaw face: chin markers hid and reappeared as the jaw weight rose)
    from lsmta.synth.head_surface import self_occlusion
    cams = np.array([[-1600.0, -3000.0, 2200.0], [1600.0, -3000.0, 2200.0]])
    head_at = np.array([0.0, 0.0, 1650.0])
    yaws, jaw = [-40.0, -20.0, 0.0, 20.0, 40.0], np.linspace(0, 1, 21)
    w = np.zeros((len(jaw), len(model.mode_names)))
    w[:, model.mode_names.index("jaw_open")] = jaw
    shapes = model.shapes(w)                                           # (J, M, 3)
    Rs = np.stack([_BASE @ Rotation.from_euler("y", y, degrees=True).as_matrix() for y in yaws])
    R = np.repeat(Rs, len(jaw), axis=0)                                # (Y * J, 3, 3)
    pts = np.einsum("tij,tmj->tmi", R, np.tile(shapes, (len(yaws), 1, 1))) + head_at
    t = np.broadcast_to(head_at, (len(R), 3))
    seen = self_occlusion(pts, R, t, cams, neutral=model.neutral).reshape(
        len(yaws), len(jaw), 2, -1)
    plain = np.einsum("yij,mj->ymi", Rs, model.neutral) + head_at     # neutral, each yaw
    seen0 = self_occlusion(plain, Rs, np.broadcast_to(head_at, (len(yaws), 3)), cams)
    cos = np.zeros(seen.shape)                                         # (Y, J, C, M)
    for y in range(len(yaws)):
        for j, wj in enumerate(jaw):
            n = _jaw_normals(model, wj) @ Rs[y].T
            v = cams[:, None] - pts[y * len(jaw) + j][None]               # (C, M, 3)
            cos[y, j] = (n[None] * v).sum(axis=2) / np.linalg.norm(v, axis=2)
    facing = cos > 0.3
    must = facing & seen0[:, None]
    assert must.mean() > 0.5
    bad = np.argwhere(must & ~seen)
    assert not len(bad), [(yaws[y], round(jaw[j], 2), c, model.labels[m]) for y, j, c, m in bad]
    # hiding switches at most once along the sweep, for every marker whose line of sight
    # does not graze its surface (|cos| > 0.2 all along; grazing ones hang on fractions of
    # a millimetre of the surface)
    steady = (cos > 0.2).all(axis=1) | (cos < -0.2).all(axis=1)        # (Y, C, M)
    assert steady.mean() > 0.8
    hid = ~seen
    turns_on = (hid[:, 1:] & ~hid[:, :-1]).sum(axis=1) + hid[:, 0]     # (Y, C, M)
    flicker = np.argwhere(steady & (turns_on > 1))
    assert not len(flicker), [(yaws[y], c, model.labels[m]) for y, c, m in flicker]


def test_self_occlusion_bad_input_and_inputs_untouched(model):
    from lsmta.synth.head_surface import HeadShape, self_occlusion
    pts, R, t = _posed(model.neutral, 30.0)
    pts = pts + np.array([0.0, 0.0, 1.0]) * np.linspace(0, 3, len(model.labels))[:, None]
    cams = np.repeat(_CAM[None], 1, axis=0)                               # (T, C, 3) centres
    keep = [a.copy() for a in (pts, R, t, cams, model.neutral)]
    seen = self_occlusion(pts, R, t, cams, neutral=model.neutral)        # deformed surface
    for a, b in zip((pts, R, t, cams, model.neutral), keep):
        np.testing.assert_array_equal(a, b)
    assert seen.shape == (1, 1, len(model.labels))
    with pytest.raises(ValueError, match=r"^points: "):
        self_occlusion(pts[0], R, t, _CAM)
    with pytest.raises(ValueError, match=r"^R: "):
        self_occlusion(pts, 2 * R, t, _CAM)
    with pytest.raises(ValueError, match=r"^neutral: "):
        self_occlusion(pts, R, t, _CAM, neutral=model.neutral[:5])
    with pytest.raises(ValueError, match=r"^grid: "):
        self_occlusion(pts, R, t, _CAM, grid=0)
    with pytest.raises(TypeError, match=r"^return_hit: "):
        self_occlusion(pts, R, t, _CAM, return_hit="yes")
    with pytest.raises(ValueError, match=r"^t: "):
        self_occlusion(pts, R, np.zeros((2, 3)), _CAM)
    with pytest.raises(ValueError, match="camera_centres"):
        self_occlusion(pts, R, t, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="camera_centres"):
        self_occlusion(pts, R, t, np.zeros((1, 3)))             # inside the head
    with pytest.raises(ValueError, match="step"):
        self_occlusion(pts, R, t, _CAM, step=0)
    with pytest.raises(TypeError, match="shape"):
        self_occlusion(pts, R, t, _CAM, shape="sphere")
    with pytest.raises(ValueError, match=r"^face: "):
        HeadShape(a=100.0, face=True)
    with pytest.raises(TypeError, match=r"^face: expected a bool"):
        HeadShape(face="no")


def test_head_turn_and_observation_with_self_occlusion(model):
    R, t = sf.head_turn(41, yaw_deg=70.0)
    turn = np.degrees(np.arccos(np.clip(R[:, :, 2] @ np.array([0.0, -1.0, 0.0]), -1, 1)))
    assert turn[0] == pytest.approx(0, abs=1e-6) and turn.max() == pytest.approx(70, abs=0.5)
    assert R[10, 0, 2] > 0 > R[30, 0, 2]                    # towards +X first, then -X
    seq = sf.face_sequence(model, 41, rng=1, motion=(R, t))
    np.testing.assert_allclose(seq.R, R)
    pos = [(-1600.0, -3000.0, 2200.0), (1600.0, -3000.0, 2200.0)]
    obs = ef.observe_face(seq, rng=2, positions=pos, pose_noise_deg=0.0, occlusion="surface")
    measured = np.isfinite(obs.points).all(axis=2).sum(axis=1)
    assert measured[0] >= 70                                # facing the cameras: nearly all
    assert measured.min() < 0.65 * len(model.labels)
    assert obs.n_visible.min() < 0.65 * len(model.labels)   # turned: a side hidden
    with pytest.raises(ValueError, match="occlusion"):
        ef.observe_face(seq, rng=2, positions=pos, occlusion="rays")
    with pytest.raises(ValueError, match="motion"):
        sf.face_sequence(model, 40, rng=1, motion=(R, t))
    with pytest.raises(ValueError, match=r"^motion: expected a pair"):
        sf.face_sequence(model, 41, rng=1, motion=R)
    with pytest.raises(ValueError, match=r"^moving: ignored when motion is given"):
        sf.face_sequence(model, 41, rng=1, motion=(R, t), moving=False)
