"""SAPM learned from a labelled clip, the tree search, shared marker pairs, several instances,
and the suggested segments; ground truth from the generator (lsmta.synth.markers)."""

import numpy as np
import pytest

from lsmta.rigid import fit_rigid
from lsmta.sapm import (
    LearnParams,
    MarkerModel,
    SAPMParams,
    identify,
    identify_instances,
    suggest_segments,
)
from lsmta.synth.markers import human_model, marker_clip, random_pose

TREE = SAPMParams(search="tree", beta=0.5, eps=0.05)


def _plates(*, joint_offset=(0.0, 30.0, 0.0)):
    """Three plates of four markers in a chain a - b - c, no marker shared; the joints are
    given away from the closest pairs (``joint_offset``), so that a clip must find them."""
    rng = np.random.default_rng(3)
    pts = {}
    centres = {"a": (0, 0, 0), "b": (0, 0, -300), "c": (0, 0, -600)}
    for name, c in centres.items():
        for i in range(4):
            pts[f"{name}{i}"] = np.array(c, float) + rng.uniform(-50, 50, 3) * (1, 1, 0.6)
    segments = {n: [f"{n}{i}" for i in range(4)] for n in centres}
    parents = {"a": None, "b": "a", "c": "b"}
    joints = {"b": np.array([0, 0, -150.0]) + joint_offset,
              "c": np.array([0, 0, -450.0]) + joint_offset}
    return MarkerModel.from_labelled_frame(pts, segments, parents, joints=joints), segments, \
        parents


def test_learned_tolerances_recover_the_generators_distortion():
    model = human_model()
    loose = LearnParams(margin=1.0, eps_min=1e-4, eps_floor=1e-4)
    learned = {}
    for psi in (0.01, 0.03):
        clip = marker_clip(model, 200, rng=5, amplitude=1.0, distortion=psi)
        learned[psi] = MarkerModel.from_labelled_frames(model.labels, clip.points,
                                                        {s: [model.labels[i] for i in m]
                                                         for s, m in zip(model.segments,
                                                                         model.members)},
                                                        {s: (model.segments[p] if p >= 0 else None)
                                                         for s, p in zip(model.segments,
                                                                         model.parent)},
                                                        params=loose).eps
    # ε_s is the largest ē_s of the clip: about the distortion put in, and three times it
    # for three times the distortion
    for psi, eps in learned.items():
        assert (0.4 * psi < eps).all() and (eps < 2.5 * psi).all(), (psi, eps)
    ratio = learned[0.03] / learned[0.01]
    assert (2.0 < ratio).all() and (ratio < 4.5).all()


def _joint_error(model, joint, s, clip):
    """Distance (T,) of ``joint`` (model coordinates) of segment ``s``, carried by the
    parent's fitted pose, from the generator's true joint."""
    m = model.members[model.parent[s]]
    R, t = fit_rigid(np.broadcast_to(model.points[m], (len(clip.points), len(m), 3)),
                     clip.points[:, m])
    return np.linalg.norm(np.einsum("tij,j->ti", R, joint) + t - clip.joints[:, s], axis=1)


def test_learned_joint_finds_the_centre_of_rotation():
    model, segments, parents = _plates()
    clip = marker_clip(model, 150, rng=6, amplitude=1.0)
    learned = MarkerModel.from_labelled_frames(model.labels, clip.points, segments, parents)
    one = MarkerModel.from_labelled_frames(model.labels, clip.points[:1], segments, parents)
    for s in (1, 2):
        found = _joint_error(learned, learned.joint[s], s, clip)
        guess = _joint_error(learned, one.joint[s] + learned.points[0] - one.points[0], s, clip)
        # the clip moves the joint estimate most of the way from the closest-pair guess to
        # the centre (what is left is the pull of the prior, about joint_prior of it)
        assert found.max() < 0.25 * guess.min(), (found.max(), guess.min())
        assert learned.joint_prior[s] < 0.2 and found.max() < learned.joint_tolerance[s]
    # a still clip cannot find the joint: the one-frame estimate and its tolerance stay
    still = marker_clip(model, 50, rng=6, amplitude=0.0)
    prior = MarkerModel.from_labelled_frames(model.labels, still.points, segments, parents)
    assert (prior.joint_prior[1:] > 0.9).all()
    np.testing.assert_allclose(prior.eps, LearnParams().eps_floor)
    assert (prior.joint_tolerance[1:] > 50).all()


def test_learning_takes_gaps_and_changes_nothing():
    model, segments, parents = _plates()
    clip = marker_clip(model, 120, rng=7, amplitude=1.0).points
    rng = np.random.default_rng(7)
    gappy = clip.copy()
    gappy[rng.random(gappy.shape[:2]) < 0.15] = np.nan
    before = gappy.copy()
    learned = MarkerModel.from_labelled_frames(model.labels, gappy, segments, parents)
    np.testing.assert_array_equal(gappy, before)
    # the shapes are the generator's up to a rigid motion per segment
    for m in learned.members:
        R, t = fit_rigid(learned.points[m], model.points[m])
        assert np.abs(learned.points[m] @ R.T + t - model.points[m]).max() < 1e-6


def _hinged(model, hand, rng):
    """A pose (M, 3) of ``model``: the whole body turned at random, the ``hand`` segment
    turned about the axis through its two shared markers (the only motion that keeps a
    marker pair rigid with both segments)."""
    from scipy.spatial.transform import Rotation

    P = model.points.copy()
    a, b = P[model.shared[hand]]
    axis = (b - a) / np.linalg.norm(b - a)
    R = Rotation.from_rotvec(axis * rng.uniform(-1.5, 1.5)).as_matrix()
    own = np.setdiff1d(model.members[hand], model.shared[hand])
    P[own] = (P[own] - a) @ R.T + a
    whole = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    return P @ whole.T + rng.uniform(-2000, 2000, 3)


def test_shared_marker_pairs_learned_and_identified():
    model, segments, parents = _plates(joint_offset=(0.0, 0.0, 0.0))
    # the third plate shares two markers with the second: a hinge along them
    segments = {**segments, "c": segments["c"] + ["b0", "b1"]}
    paired = MarkerModel.from_labelled_frame(dict(zip(model.labels, model.points)), segments,
                                             parents)
    rng = np.random.default_rng(8)
    clip = np.stack([_hinged(paired, 2, rng) for _ in range(40)])
    learned = MarkerModel.from_labelled_frames(paired.labels, clip, segments, parents)
    assert sorted(learned.labels[i] for i in learned.shared[2]) == ["b0", "b1"]
    assert learned.joint_tolerance[2] == 0
    for params in (SAPMParams(eps=0.05), TREE):
        for r in range(10):
            rng = np.random.default_rng(r)
            P = _hinged(learned, 2, rng)
            order = rng.permutation(len(P))
            np.testing.assert_array_equal(identify(learned, P[order], params=params).labels,
                                          order, err_msg=params.search)


def test_tree_search_labels_noise_free_poses():
    model = human_model()
    poses = [random_pose(model, rng=r, level=np.pi) for r in range(20)]
    full = [np.array_equal(identify(model, p.observed, params=TREE).labels, p.truth)
            for p in poses]
    assert np.mean(full) >= 0.95


def test_two_instances_in_one_cloud():
    model = human_model()
    a = random_pose(model, rng=11, level=2.0, translation=0.0)
    b = random_pose(model, rng=12, level=2.0, translation=0.0)
    cloud = np.vstack([a.observed, b.observed + [3000.0, 0, 0]])
    truth = np.concatenate([a.truth, b.truth])
    who = np.repeat([0, 1], [len(a.truth), len(b.truth)])
    order = np.random.default_rng(13).permutation(len(cloud))
    res = identify_instances(model, cloud[order], n_instances=2, params=TREE)
    np.testing.assert_array_equal(res.labels, truth[order])
    for i in range(2):                   # each instance is one whole body
        assert len(set(who[order][res.instance == i])) == 1
    assert set(res.instance) == {0, 1}
    free = identify_instances(model, cloud[order], params=TREE)
    assert free.n_instances == 2


def test_suggested_segments_are_the_generators():
    model, segments, parents = _plates()
    clip = marker_clip(model, 150, rng=9, amplitude=1.0, distortion=0.005)
    sug = suggest_segments(model.labels, clip.points)
    assert sorted(sorted(v) for v in sug.segments.values()) == sorted(sorted(v) for v in
                                                                  segments.values())
    # the proposed tree links the same plates (a - b - c), whatever its root
    name = {tuple(sorted(v)): k for k, v in sug.segments.items()}
    of = {k: name[tuple(sorted(v))] for k, v in segments.items()}
    links = {frozenset((c, p)) for c, p in sug.parents.items() if p is not None}
    assert links == {frozenset((of["a"], of["b"])), frozenset((of["b"], of["c"]))}
    # user plates and a loose marker: it joins the plate it is rigid with
    groups = {k: v[:3] for k, v in segments.items()}
    placed = suggest_segments(model.labels, clip.points, groups=groups)
    assert all(sorted(placed.segments[k]) == sorted(v) for k, v in segments.items())
    assert sug.unplaced == [] and np.isnan(placed.max_spread)


def test_bad_input_gets_clear_errors():
    model, segments, parents = _plates()
    clip = marker_clip(model, 30, rng=10, amplitude=0.5).points
    labels = list(model.labels)
    with pytest.raises(ValueError, match="labels: expected 12 names"):
        MarkerModel.from_labelled_frames(labels[:-1], clip, segments, parents)
    with pytest.raises(ValueError, match="labels: names occur more than once"):
        MarkerModel.from_labelled_frames(labels[:-1] + ["a0"], clip, segments, parents)
    with pytest.raises(ValueError, match="every marker is missing"):
        MarkerModel.from_labelled_frames(labels, np.full_like(clip, np.nan), segments, parents)
    gone = clip.copy()
    gone[:, 5] = np.nan
    with pytest.raises(ValueError, match=r"markers \['b1'\] are missing"):
        MarkerModel.from_labelled_frames(labels, gone, segments, parents)
    with pytest.raises(ValueError, match="at least 3"):
        MarkerModel.from_labelled_frames(labels, clip, {**segments, "c": ["c0", "c1"],
                                                        "d": ["c2", "c3", "c1"]},
                                         {**parents, "d": "c"})
    with pytest.raises(ValueError, match="not in labels"):
        MarkerModel.from_labelled_frames(labels, clip, {**segments, "c": ["c0", "c1", "zz"]},
                                         parents)
    with pytest.raises(ValueError, match="points: expected an array of shape"):
        MarkerModel.from_labelled_frames(labels, clip[..., :2], segments, parents)
    with pytest.raises(TypeError, match="params"):
        MarkerModel.from_labelled_frames(labels, clip, segments, parents, params={"margin": 2})
    with pytest.raises(ValueError, match="margin"):
        LearnParams(margin=0.5)
    with pytest.raises(ValueError, match="search"):
        SAPMParams(search="breadth_first")
    with pytest.raises(ValueError, match="groups: labels"):
        suggest_segments(labels, clip, groups={"x": ["a0", "a1", "a2"], "y": ["a2", "b0", "b1"]})
    with pytest.raises(ValueError, match="n_instances"):
        identify_instances(model, clip[0], n_instances=0)


def test_real_recording_protocol_and_scores():
    from lsmta.data import load_recording
    from lsmta.real import marker_captures as mr

    rec = load_recording("racing", step=50)
    assert rec.n_train == 70 and rec.frames[0] == 70 and np.all(np.diff(rec.frames) == 50)
    assert not any(k.startswith("Probe") for k in rec.labels)      # absent from every frame
    model, segments = mr.learned_model(rec)
    assert "Sternum" not in model.labels                           # too rare in the clip
    before = rec.points.copy()
    trials = mr.recording_trials(model, rec, params=TREE, rng=1)
    np.testing.assert_array_equal(rec.points, before)
    present = np.isfinite(rec.points[rec.frames]).all(axis=2)
    np.testing.assert_array_equal(trials.points, present.sum(axis=1))
    assert (trials.correct <= trials.markers).all() and (trials.given[~present] == -2).all()
    s = trials.summary()
    assert s["correct"] > 0.9 and s["wrong"] < 0.02
    with pytest.raises(ValueError, match="name"):
        load_recording("golf")


# ---------------------------------------------------------------------- beyond the clip
def _definition(model):
    seg = {n: [model.labels[i] for i in m] for n, m in zip(model.segments, model.members)}
    par = {n: (model.segments[p] if p >= 0 else None)
           for n, p in zip(model.segments, model.parent)}
    return seg, par


def _scores(model, frames, params, rng):
    c = w = n = 0
    for X in frames:
        perm = rng.permutation(len(X))
        r = identify(model, X[perm], params=params)
        c += int((r.labels == perm).sum())
        w += int(((r.labels >= 0) & (r.labels != perm)).sum())
        n += len(perm)
    return c / n, w / n


def test_generalising_search_labels_frames_beyond_the_training_range():
    truth = human_model(hands=True)
    seg, par = _definition(truth)
    clip = marker_clip(truth, 60, rng=1, amplitude=0.3, distortion=0.01)   # arms kept low
    model = MarkerModel.from_labelled_frames(truth.labels, clip.points, seg, par)
    # test frames: every joint turns five times as far, and the upper arms' markers slide
    # (skin over the shoulder) far beyond what the clip showed
    psi = np.array([0.25 if "upper_arm" in n else 0.04 for n in truth.segments])
    test = marker_clip(truth, 40, rng=2, amplitude=1.5, distortion=psi)
    def raised(X):                               # the highest wrist over its shoulder, mm
        return max((X[:, truth.label_index(f"{S}wrist"), 2]
                    - X[:, truth.label_index(f"{S}sho"), 2]).max() for S in "LR")

    assert raised(clip.points) < -400 and raised(test.points) > 100     # hands overhead
    plain = _scores(model, test.points, SAPMParams(search="tree", beta=0.5),
                    np.random.default_rng(3))
    ours = _scores(model, test.points, SAPMParams.generalising(), np.random.default_rng(3))
    assert ours[0] >= 0.97 and ours[1] <= 0.01, ours
    assert ours[0] > plain[0] + 0.01, (plain, ours)


def test_abstains_where_two_labellings_are_equally_good():
    # a root plate and a child whose three markers form an equilateral triangle with the
    # joint on its axis: its three rotations fit and join equally well
    root = {"a0": (0, 0, 0), "a1": (80, 0, 0), "a2": (0, 50, 0), "a3": (30, 20, 40)}
    ang = np.radians([90, 210, 330])
    child = {f"b{i}": (60 * np.cos(t), 60 * np.sin(t), -300.0) for i, t in enumerate(ang)}
    pts = {k: np.array(v, float) for k, v in {**root, **child}.items()}
    segments = {"a": list(root), "b": list(child)}
    model = MarkerModel.from_labelled_frame(pts, segments, {"a": None, "b": "a"},
                                            joints={"b": np.array([0.0, 0.0, -150.0])})
    X = np.stack([pts[k] for k in model.labels])
    perm = np.random.default_rng(4).permutation(len(X))
    careful = identify(model, X[perm], params=SAPMParams.generalising())
    is_b = np.isin(perm, [model.label_index(k) for k in child])
    assert (careful.labels[is_b] == -1).all() and careful.abstained[is_b].all()
    np.testing.assert_array_equal(careful.labels[~is_b], perm[~is_b])     # the plate kept
    assert (careful.confidence[~is_b] > 0.1).all()
    bold = identify(model, X[perm], params=SAPMParams.generalising(abstain=0.0))
    assert (bold.labels[is_b] >= 0).all() and not bold.abstained.any()


def test_labels_carried_through_a_recording_with_a_gap():
    from lsmta.sapm.tracking import TrackParams, label_recording

    truth = human_model(hands=True)
    seg, par = _definition(truth)
    clip = marker_clip(truth, 40, rng=5, amplitude=0.6, distortion=0.01)
    model = MarkerModel.from_labelled_frames(truth.labels, clip.points, seg, par)
    rec = marker_clip(truth, 400, rng=6, amplitude=0.6, distortion=0.01, speed=2.0).points
    rec[50:55, 7] = np.nan                                   # a marker hidden for 5 frames
    rng = np.random.default_rng(7)
    perms = np.array([rng.permutation(truth.n_points) for _ in rec])
    X = np.take_along_axis(rec, perms[..., None], axis=1)
    before = X.copy()
    out = label_recording(model, X, params=SAPMParams.generalising(), track=TrackParams())
    np.testing.assert_array_equal(X, before)
    present = np.isfinite(X).all(axis=2)
    correct = ((out.labels == perms) & present).sum() / present.sum()
    wrong = ((out.labels >= 0) & (out.labels != perms)).sum() / present.sum()
    assert correct >= 0.995 and wrong <= 0.002
    assert out.sapm_frames[0] == 0 and 55 in out.sapm_frames     # back from the gap
    assert len(out.sapm_frames) <= 0.1 * len(rec) and out.carried[1:].mean() > 0.95
    with pytest.raises(TypeError, match="track"):
        label_recording(model, X, track=3)
    with pytest.raises(ValueError, match="relax"):
        SAPMParams(relax=(0.5,))
