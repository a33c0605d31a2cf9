"""SAPM: rigid fits, the marker model, the pose generator, identification and its baseline,
the C3D reader. Ground truth comes from the generator (or the labelled file)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lsmta.evaluation.sapm import cell_seeds, frame_trials, pose_trials
from lsmta.io import read_c3d
from lsmta.real.marker_captures import clouthier_model
from lsmta.rigid import apply_rigid, fit_rigid
from lsmta.sapm import MarkerModel, SAPMParams, global_assignment, identify
from lsmta.synth.markers import human_model, random_pose

C3D = Path(__file__).resolve().parents[1] / "data" / "clouthier2021" / "KneeltoProne01.c3d"


@pytest.fixture(scope="module")
def model():
    return human_model()


# ---------------------------------------------------------------------- rigid fit
def test_fit_rigid_recovers_a_batch_of_motions(rng):
    R_true = Rotation.random(5, random_state=rng).as_matrix()
    t_true = rng.normal(0, 500, (5, 3))
    P = rng.normal(0, 100, (5, 7, 3))
    Q = apply_rigid(R_true, t_true, P)
    R, t = fit_rigid(P, Q)
    np.testing.assert_allclose(R, R_true, atol=1e-10)
    np.testing.assert_allclose(t, t_true, atol=1e-8)


def test_fit_rigid_returns_a_rotation_for_mirrored_points(rng):
    P = rng.normal(0, 100, (6, 3))
    R, _ = fit_rigid(P, P * [-1, 1, 1])
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_fit_rigid_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="source, target"):
        fit_rigid(np.zeros((4, 3)), np.zeros((5, 3)))


# ---------------------------------------------------------------------- model
def test_human_models_have_the_papers_sizes():
    m13, m15 = human_model(), human_model(hands=True)
    assert (m13.n_segments, m13.n_points) == (13, 44)
    assert (m15.n_segments, m15.n_points) == (15, 49)
    assert max(len(m) for m in m13.members) == 6
    assert m13.segments[m13.search_root] == "torso"
    # every link of the code-built model has a shared joint marker
    assert (m13.joint_label[m13.parent >= 0] >= 0).all()


def _tiny(**change):
    pts = {"a": [0, 0, 0], "b": [100, 0, 0], "c": [0, 80, 0], "d": [0, 0, 120],
           "e": [200, 0, 0], "f": [150, 60, 0]}
    segs = {"s1": ["a", "b", "c", "d"], "s2": ["b", "e", "f"]}
    parents = {"s1": None, "s2": "s1"}
    kw = {"points_by_label": pts, "segments": segs, "parents": parents}
    kw.update(change)
    return kw


def test_model_from_a_labelled_frame_finds_joints_and_estimates_missing_ones():
    m = MarkerModel.from_labelled_frame(**_tiny())
    assert m.labels[m.joint_label[1]] == "b" and m.joint_tolerance[1] == 0
    segs = {"s1": ["a", "b", "c", "d"], "s2": ["e", "f", "g"]}
    pts = dict(_tiny()["points_by_label"], g=[180, 50, 30])
    m2 = MarkerModel.from_labelled_frame(pts, segs, {"s1": None, "s2": "s1"})
    assert m2.joint_label[1] == -1
    # the closest pair across the link is b (100, 0, 0) and f (150, 60, 0)
    np.testing.assert_allclose(m2.joint[1], [125, 30, 0])
    assert m2.joint_tolerance[1] == pytest.approx(np.hypot(50, 60))


@pytest.mark.parametrize("change, message", [
    ({"segments": {"s1": ["a", "b", "c", "c"], "s2": ["b", "e", "f"]}}, "lists a label twice"),
    ({"segments": {"s1": ["a", "b", "c", "d"], "s2": ["b", "e"]}}, "at least 3"),
    ({"segments": {"s1": ["a", "b", "c", "d"], "s2": ["b", "e", "x"]}}, "not in points_by_label"),
    ({"segments": {"s1": ["a", "b", "c"], "s2": ["b", "e", "f"]}}, "labels in no segment"),
    ({"parents": {"s1": None, "s2": None}}, "exactly one root"),
    ({"parents": {"s1": "s2", "s2": "s1"}}, "exactly one root"),
    ({"parents": {"s1": None, "s2": "s2"}}, "its own parent"),
    ({"parents": {"s1": None, "s2": "zz"}}, "unknown parent"),
    ({"parents": {"s1": None}}, "one entry per segment"),
])
def test_model_rejects_bad_definitions(change, message):
    with pytest.raises(ValueError, match=message):
        MarkerModel.from_labelled_frame(**_tiny(**change))


def test_model_rejects_a_cycle_beside_the_root():
    pts = dict(_tiny()["points_by_label"], g=[0, 50, 50], h=[30, 30, 30], i=[10, 90, 40])
    segs = {"s1": ["a", "b", "c", "d"], "s2": ["e", "f", "g"], "s3": ["g", "h", "i"]}
    with pytest.raises(ValueError, match="cycle"):
        MarkerModel.from_labelled_frame(pts, segs, {"s1": None, "s2": "s3", "s3": "s2"})


def test_model_takes_two_joint_markers_on_one_link():
    segs = {"s1": ["a", "b", "c", "d"], "s2": ["b", "c", "e", "f"]}
    m = MarkerModel.from_labelled_frame(_tiny()["points_by_label"], segs,
                                        {"s1": None, "s2": "s1"})
    assert [m.labels[i] for i in m.shared[1]] == ["b", "c"] and m.joint_tolerance[1] == 0
    np.testing.assert_allclose(m.joint[1], [50, 40, 0])       # the pair's centroid


def test_model_rejects_a_label_shared_by_unlinked_segments():
    pts = dict(_tiny()["points_by_label"], g=[0, 50, 50], h=[30, 30, 30])
    segs = {"s1": ["a", "b", "c", "d"], "s2": ["b", "e", "f"], "s3": ["e", "g", "h"]}
    with pytest.raises(ValueError, match="shared label"):
        MarkerModel.from_labelled_frame(pts, segs, {"s1": None, "s2": "s1", "s3": "s1"})


# ---------------------------------------------------------------------- generator
def test_random_pose_keeps_every_segment_rigid_and_shuffles(model, rng):
    pose = random_pose(model, rng=rng, level=4.0)
    order = np.argsort(pose.truth)
    assert not np.array_equal(pose.truth, np.sort(pose.truth))
    pts = pose.observed[order]
    for m in model.members:
        d_model = np.linalg.norm(model.points[m][:, None] - model.points[m][None], axis=-1)
        d_pose = np.linalg.norm(pts[m][:, None] - pts[m][None], axis=-1)
        np.testing.assert_allclose(d_pose, d_model, atol=1e-9)


def test_random_pose_at_level_zero_is_a_translation(model, rng):
    pose = random_pose(model, rng=rng, level=0.0)
    shift = pose.observed - model.points[pose.truth]
    np.testing.assert_allclose(shift, shift[0] + 0 * shift, atol=1e-9)


def test_random_pose_distortion_has_the_papers_spread(model, rng):
    psi, resid, scale = 0.05, [], []
    for _ in range(100):
        pose = random_pose(model, rng=rng, level=0.0, distortion=psi)
        resid.append(pose.observed - pose.points[pose.truth])
        scale.append(np.repeat(model.mean_length[model.point_segment[pose.truth]], 3))
    z = np.concatenate([r.ravel() for r in resid]) / np.concatenate(scale)
    # per coordinate N(0, ψ l̄_s / √6): 13,200 samples, so the sd is known to about 1 %
    assert np.std(z) == pytest.approx(psi / np.sqrt(6), rel=0.04)
    assert abs(np.mean(z)) < 0.01 * psi


def test_random_pose_missing_and_extra_points(model, rng):
    pose = random_pose(model, rng=rng, n_missing=3, n_extra=4, distortion=0.05)
    assert len(pose.observed) == model.n_points - 3 + 4
    assert (pose.truth == -1).sum() == 4
    assert len(np.unique(pose.truth[pose.truth >= 0])) == model.n_points - 3


# ---------------------------------------------------------------------- identification
def test_identify_labels_noise_free_arbitrary_poses(model, rng):
    for _ in range(20):
        pose = random_pose(model, rng=rng, level=np.pi)
        result = identify(model, pose.observed, params=SAPMParams(eps=0.05))
        np.testing.assert_array_equal(result.labels, pose.truth)
        assert result.found.all()
        np.testing.assert_allclose(result.mean_error, 0, atol=1e-9)


def test_identify_transforms_carry_the_model_onto_the_pose(model, rng):
    pose = random_pose(model, rng=rng, level=2.0)
    r = identify(model, pose.observed, params=SAPMParams(eps=0.05))
    for s, m in enumerate(model.members):
        pred = apply_rigid(r.rotation[s], r.translation[s], model.points[m])
        np.testing.assert_allclose(pred, pose.points[m], atol=1e-6)


def test_identify_leaves_extra_points_unlabelled_and_survives_missing(model, rng):
    n_ok, n_total = 0, 0
    for _ in range(10):
        pose = random_pose(model, rng=rng, level=2.0, n_missing=1, n_extra=4)
        r = identify(model, pose.observed, params=SAPMParams(eps=0.05, beta=0.7))
        labelled = r.labels >= 0
        assert (r.labels[labelled] == pose.truth[labelled]).all(), "a point got a wrong label"
        n_ok += (r.labels == pose.truth).sum()
        n_total += len(pose.truth)
    assert n_ok / n_total > 0.9


def _without(pose, model, names):
    drop = np.isin(pose.truth, [model.label_index(n) for n in names])
    return pose.observed[~drop], pose.truth[~drop]


def test_virtual_joint_carries_a_child_past_a_missing_joint_marker(model, rng):
    lower = model.segment_index("Lforearm")
    for _ in range(5):
        obs, truth = _without(random_pose(model, rng=rng, level=2.0), model, ["Lelbow"])
        r = identify(model, obs, params=SAPMParams(eps=0.05, beta=0.7))
        assert r.found[lower] and r.found[model.segment_index("Lupper_arm")]
        np.testing.assert_array_equal(r.labels, truth)


def test_broken_chain_is_searched_from_scratch(model, rng):
    # the left upper arm keeps two markers and cannot be found; its forearm still is
    obs, truth = _without(random_pose(model, rng=rng, level=2.0), model, ["Luarm_lat", "Luarm_ant"])
    r = identify(model, obs, params=SAPMParams(eps=0.05))
    assert not r.found[model.segment_index("Lupper_arm")]
    assert r.found[model.segment_index("Lforearm")]
    lab = r.labels >= 0
    np.testing.assert_array_equal(r.labels[lab], truth[lab])
    forearm = model.members[model.segment_index("Lforearm")]
    assert set(forearm) - {model.label_index("Lelbow")} <= set(r.labels[lab])


def test_effort_is_counted_and_ranking_the_root_still_labels(model, rng):
    pose = random_pose(model, rng=rng, level=np.pi)
    for rank in (False, True):
        r = identify(model, pose.observed, params=SAPMParams(eps=0.05, rank_root=rank))
        np.testing.assert_array_equal(r.labels, pose.truth)
        assert r.tables >= model.n_segments and r.fits >= model.n_segments
        assert r.backtracks >= 0 and r.seconds > 0


def test_identify_drops_nan_rows_and_leaves_the_input_alone(model, rng):
    pose = random_pose(model, rng=rng, level=1.0)
    obs = pose.observed.copy()
    obs[[3, 7]] = np.nan
    before = obs.copy()
    r = identify(model, obs, params=SAPMParams(eps=0.05))
    np.testing.assert_array_equal(obs, before)
    np.testing.assert_array_equal(r.dropped, [3, 7])
    assert (r.labels[[3, 7]] == -1).all()
    ok = np.ones(len(obs), bool)
    ok[[3, 7]] = False
    assert (r.labels[ok] == pose.truth[ok]).mean() > 0.9


@pytest.mark.parametrize("kw, error, message", [
    ({"observed": np.zeros((2, 3))}, ValueError, "at least 3"),
    ({"observed": np.zeros((5, 2))}, ValueError, r"shape \(N, 3\)"),
    ({"observed": np.full((6, 3), np.nan)}, ValueError, "at least 3"),
    ({"rng": "3"}, TypeError, "Generator"),
    ({"params": {"eps": 0.1}}, TypeError, "SAPMParams"),
])
def test_identify_rejects_bad_arguments(model, rng, kw, error, message):
    args = {"observed": random_pose(model, rng=rng).observed}
    args.update(kw)
    with pytest.raises(error, match=message):
        identify(model, **args)


@pytest.mark.parametrize("kw, error, message", [
    ({"eps": 1.5}, ValueError, "eps"),
    ({"eps": 0.0}, ValueError, "eps"),
    ({"beta": 1.0}, ValueError, "beta"),
    ({"beta": -0.1}, ValueError, "beta"),
    ({"max_tables": 0}, ValueError, "max_tables"),
    ({"max_alternatives": 1.5}, ValueError, "max_alternatives"),
    ({"max_tabels": 3}, TypeError, "max_tabels"),
])
def test_sapm_params_are_checked(kw, error, message):
    with pytest.raises(error, match=message):
        SAPMParams(**kw)


def test_identify_rejects_a_non_model(rng):
    with pytest.raises(TypeError, match="model"):
        identify({"a": 1}, np.zeros((5, 3)))


def test_baseline_works_for_rigid_poses_only(model, rng):
    rigid = random_pose(model, rng=rng, level=0.0)
    np.testing.assert_array_equal(global_assignment(model, rigid.observed).labels, rigid.truth)
    trials = pose_trials(model, 10, rng=rng, level=2.0, methods=("sapm", "baseline"),
                         params=SAPMParams(eps=0.05))
    assert trials["sapm"].accuracy.mean() > trials["baseline"].accuracy.mean() + 0.3


def test_cell_seeds_are_reproducible_and_distinct():
    a, b = cell_seeds(7, (3, 4)), cell_seeds(7, (3, 4))
    np.testing.assert_array_equal(a, b)
    assert len(np.unique(a)) == 12


# ---------------------------------------------------------------------- real data
def test_read_c3d_of_the_bundled_recording():
    labels, points, rate = read_c3d(C3D)
    assert len(labels) == 62 and points.shape == (1745, 62, 3) and rate == 240.0
    assert np.isnan(points[:, labels.index("RAC")]).any(axis=1).sum() == 153
    # mm: the back markers are centimetres apart, not metres or micrometres
    d = np.linalg.norm(points[0, labels.index("LBUL")] - points[0, labels.index("LBLL")])
    assert 20 < d < 500


def test_read_c3d_converts_units_and_keeps_gaps(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [100]
    c["parameters"]["POINT"]["LABELS"]["value"] = ("A", "B")
    c["parameters"]["POINT"]["UNITS"]["value"] = ["m"]
    pts = np.ones((4, 2, 3))
    pts[:3] *= 0.5
    pts[0, 1, 2] = np.nan
    c["data"]["points"] = pts
    c.write(str(tmp_path / "x.c3d"))
    data = read_c3d(tmp_path / "x.c3d")
    assert data.labels == ("A", "B") and data.rate == 100
    np.testing.assert_allclose(data.points[0, 0], [500, 500, 500])
    assert np.isnan(data.points[2, 1]).all() and not np.isnan(data.points[1, 1]).any()


def test_read_c3d_names_a_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="path"):
        read_c3d(tmp_path / "nothing.c3d")


def test_real_frames_are_mostly_identified():
    model, points = clouthier_model(C3D)
    assert (model.n_segments, model.n_points) == (15, 62)
    ft = frame_trials(model, points, [150, 700, 1100, 1600], rng=np.random.default_rng(1),
                      params=SAPMParams(eps=0.1))
    assert ft.trials["sapm"].accuracy.mean() > 0.9


# ---------------------------------------------------------------------- cached scores
def test_candidate_scores_are_read_only(model, rng):
    from lsmta.sapm.candidates import segment_candidates

    pose = random_pose(model, rng=rng, level=0.5)
    Q = pose.observed
    D = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
    c = segment_candidates(model, 0, Q, D, eps=0.05, beta=0.5, limit=10)
    assert len(c) > 0
    s = c.scores
    assert not s.flags.writeable and c.scores is s            # computed once
    with pytest.raises(ValueError):
        s[0] = 0.0


# ---------------------------------------------------------------------- label carrying
def _carry_loop(pred, speed, Q, free, params):
    """The loop version of ``tracking._carry`` (commit f161c69), the reference."""
    from scipy.optimize import linear_sum_assignment

    rows = np.flatnonzero(np.isfinite(pred).all(axis=1))
    cols = np.flatnonzero(free)
    if not len(rows) or not len(cols):
        return {}
    d = np.linalg.norm(pred[rows][:, None] - Q[cols][None], axis=-1)
    gate = params.gate + params.speed_gate * speed[rows]
    big = 1e9
    r, c = linear_sum_assignment(np.where(d < gate[:, None], d, big))
    out = {}
    for i, j in zip(r, c):
        if d[i, j] >= gate[i]:
            continue
        zone = max(2 * d[i, j], d[i, j] + params.gate)
        others_pt = np.delete(d[i], j)
        others_pr = np.delete(d[:, j], i)
        if (others_pt < zone).any() or (others_pr < zone).any():
            continue
        out[int(cols[j])] = int(rows[i])
    return out


def test_vectorised_carry_matches_the_loop():
    """Random frames on a coarse grid (ties and zero distances), NaN predictions (rows left
    out), no free points, a single row or column: the same {point: label} as the loop."""
    from lsmta.sapm.tracking import TrackParams, _carry

    gen = np.random.default_rng(11)
    params = TrackParams()
    cases = 0
    for trial in range(400):
        n_pred, n_pts = gen.integers(0, 9), gen.integers(0, 9)
        scale = [5.0, 10.0, 40.0][trial % 3]
        pred = gen.integers(0, 6, (n_pred, 3)) * scale        # grid: ties, zero distances
        Q = np.concatenate([pred[: gen.integers(0, n_pred + 1)],
                            gen.integers(0, 6, (n_pts, 3)) * scale])
        Q = Q + (gen.random(Q.shape) < 0.3) * gen.normal(0, 3, Q.shape)
        pred[gen.random(n_pred) < 0.2] = np.nan              # unknown predictions
        speed = gen.integers(0, 3, n_pred) * 10.0
        free = gen.random(len(Q)) < 0.8
        if trial % 50 == 0:
            free[:] = False                                  # nothing free
        got, want = _carry(pred, speed, Q, free, params), _carry_loop(pred, speed, Q, free, params)
        assert got == want, (trial, got, want)
        cases += bool(want)
    assert cases > 100                                       # most cases carry something
