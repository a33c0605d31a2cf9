"""The face model chosen by cross-validation over blocks of time (lsmta.face.learn), the
batched fit, and the peer's distance weighting; ground truth from the face generator."""

import numpy as np
import pytest

from lsmta import face
from lsmta.synth import face as sf


@pytest.fixture(scope="module")
def model():
    return sf.face_model()


def _faces(model, n, rng, *, noise=0.3, top=0.5):
    """Head-frame faces of the generator's six expression modes, weights uniform in
    [0, top], with Gaussian noise (mm)."""
    shapes = model.shapes(rng.uniform(0, top, (n, 6)))
    return shapes + rng.normal(0, noise, shapes.shape)


def test_cross_validation_finds_the_six_modes(model):
    # the generator mixes six expression modes: two components cannot represent them,
    # six can, whatever the method
    rng = np.random.default_rng(30)
    train = _faces(model, 120, rng)
    params = face.FaceParams(sizes=(2, 6), pca_sizes=(2, 6))
    for method in ("pca", "prior", "box"):
        m = face.learn(train, method=method, params=params, rng=1)
        assert (m.method, m.size) == (method, 6), method
        # noise of 0.3 mm per axis in the held-out frames alone is 0.48 mm on average
        assert m.scores[method, 6] < 1.0 < m.scores[method, 2] / 0.48
        assert m.choice.rule == "lowest"
    every = face.learn(train, method="cv", params=params, rng=1)
    assert set(every.scores) == {(m, k) for m in face.model.METHODS for k in (2, 6)}
    assert every.scores[every.method, every.size] == min(every.scores.values())
    assert every.size == 6


def test_default_picks_pca_where_pca_is_the_right_model(model):
    # a generated sequence whose faces are linear in six expression modes (moving head,
    # 0.3 mm noise): plain PCA with about six components is the right model, and the
    # default's cross-validation over blocks of time picks it
    rng = np.random.default_rng(35)
    seq = sf.face_sequence(model, 200, rng=rng, moving=True)
    train = seq.world + rng.normal(0, 0.3, seq.world.shape)
    m = face.learn(train)
    c = m.choice
    assert (m.method, c.rule) == ("pca", "one standard error") and 6 <= m.size <= 8
    assert c.chosen == c.best_pca == c.lowest and m.scores == c.scores
    assert c.errors.shape == (len(c.candidates), 5) and c.fold_frames.sum() == 200
    assert c.row(("pca", m.size))[0] < min(c.row(("box", k))[0] for k in (5, 10, 20, 30))
    # fewer components than modes: clearly worse; the chosen size fills to about the noise
    # of the held-out frames themselves (0.3 mm per axis: 0.48 mm on average)
    score, se = c.row(("pca", m.size))
    assert c.row(("pca", 5))[0] > score + 3 * se and score < 0.6
    assert "| pca |" in c.table() and "**chosen**" in c.table()
    assert face.learn(train).choice.chosen == c.chosen            # seeded: the same choice
    # the PCA-only choice runs the same blocks and hidden markers: the same best size
    assert face.learn(train, method="pca").size == c.best_pca[1]


def test_one_standard_error_rule_prefers_pca():
    from lsmta.face.model import _one_standard_error
    cands = [("pca", 3), ("pca", 6), ("box", 10), ("box", 20)]
    se = np.array([0.05, 0.05, 0.04, 0.04])
    # the learnt model lower, but within its standard error: plain PCA at its best size
    chosen, why = _one_standard_error(cands, np.array([1.2, 1.03, 1.05, 1.00]), se)
    assert chosen == ("pca", 6) and "within one standard error" in why
    # lower by more than its standard error: the learnt model
    chosen, why = _one_standard_error(cands, np.array([1.2, 1.10, 1.05, 1.00]), se)
    assert chosen == ("box", 20) and "more than one standard error" in why
    # plain PCA lowest
    chosen, _ = _one_standard_error(cands, np.array([0.9, 1.10, 1.05, 1.00]), se)
    assert chosen == ("pca", 3)


def test_choice_hides_markers_as_given(model):
    # the visibility the model will meet: one fixed pattern (the lower lip hidden) in
    # every held-out frame; too few observed markers for 30 components are not tried
    rng = np.random.default_rng(36)
    train = _faces(model, 100, rng)
    seen = np.ones(76, bool)
    seen[model.group("lower_lip")] = False
    c = face.choose_face_model(train, observed=seen, params=face.FaceParams(folds=4))
    assert c.hidden.startswith("1 given visibility pattern")
    sparse = np.zeros((3, 76), bool)
    sparse[:, :12] = True                                       # 12 markers seen
    c = face.choose_face_model(train, observed=sparse, params=face.FaceParams(folds=4))
    largest = max(k + 1 for m, k in c.candidates)
    assert face.min_observed_markers(largest) <= 12 < face.min_observed_markers(31)
    with pytest.raises(ValueError, match="observed: expected a bool"):
        face.choose_face_model(train, observed=seen.astype(int))
    with pytest.raises(ValueError, match=r"observed: expected shape \(S, 76\)"):
        face.choose_face_model(train, observed=seen[:70])
    with pytest.raises(ValueError, match="observed: expected patterns"):
        face.choose_face_model(train, observed=np.ones(76, bool))


def test_learned_model_fills_held_out_gaps_to_the_noise(model):
    rng = np.random.default_rng(31)
    train, test = _faces(model, 150, rng), _faces(model, 40, rng, noise=0.0)
    gappy = test.copy()
    hidden = rng.random(gappy.shape[:2]) < 0.15
    gappy[hidden] = np.nan
    before = gappy.copy()
    m = face.learn(train)
    assert m.method == "pca" and m.scores
    fit = m.fill(gappy)
    np.testing.assert_array_equal(gappy, before)
    np.testing.assert_array_equal(fit.frames[~hidden], test[~hidden])
    err = np.linalg.norm(fit.frames - test, axis=2)[hidden]
    assert np.median(err) < 1.0                       # noise 0.3 mm per axis in training


def test_box_keeps_weights_within_the_training_range(model):
    rng = np.random.default_rng(32)
    train = _faces(model, 120, rng)
    m = face.learn(train, method="box", params=face.FaceParams(sizes=(6,)))
    lower, upper = m.bounds
    fit = m.fill(_faces(model, 10, rng, top=1.0))     # expressions beyond the training's
    w = fit.weights[:, 1:]
    assert (w >= lower[1:] - 1e-9).all() and (w <= upper[1:] + 1e-9).all()


def test_learn_rejects_bad_input(model):
    rng = np.random.default_rng(33)
    train = _faces(model, 40, rng)
    with pytest.raises(ValueError, match="method"):
        face.learn(train, method="nearest")
    with pytest.raises(TypeError, match="params"):
        face.learn(train, params={"folds": 2})
    with pytest.raises(ValueError, match="training: expected at least 10"):
        face.learn(train[:5])
    with pytest.raises(ValueError, match="training"):
        face.learn(train[:, :, :2])
    with pytest.raises(ValueError, match="hidden"):
        face.FaceParams(hidden=1.0)
    with pytest.raises(ValueError, match="sizes"):
        face.FaceParams(sizes=(0, 3))
    with pytest.raises(ValueError, match="split"):
        face.FaceParams(split="random")
    with pytest.raises(ValueError, match="families"):
        face.FaceParams(families=("pca",))
    with pytest.raises(ValueError, match="pca_sizes"):
        face.FaceParams(pca_sizes=())
    with pytest.raises(ValueError, match="method"):
        face.build_face_model(train, method="auto", size=3)
    with pytest.raises(ValueError, match="size"):
        face.build_face_model(train, method="pca", size=40)
    m = face.learn(train)
    with pytest.raises(ValueError, match="frames: expected 76 markers"):
        m.fill(train[:, :70])


def test_distance_weighting_follows_the_published_method():
    # the missing marker's neighbours carry it: a marker that is rigidly attached to a
    # near marker is recovered from it; far markers moving independently do not disturb it
    rng = np.random.default_rng(34)
    T = 200
    near = rng.normal(0, 20, (T, 3))
    frames = np.zeros((T, 6, 3))
    frames[:, 0] = near
    frames[:, 1] = near + [30.0, 0, 0]              # the marker that will go missing
    frames[:, 2] = near + [0, 30.0, 0]
    frames[:, 3:] = rng.normal(0, 20, (T, 3, 3)) + [[2000.0, 0, 0]]   # far and independent
    gappy = frames.copy()
    gappy[150:, 1] = np.nan
    weighted = face.pca_gap_fill(gappy, sigma=200.0).frames
    err = np.linalg.norm(weighted[150:, 1] - frames[150:, 1], axis=1)
    assert np.median(err) < 2.0
    with pytest.raises(ValueError, match="weighting"):
        face.pca_gap_fill(gappy, weighting="gaussian")
    with pytest.raises(ValueError, match="sigma"):
        face.pca_gap_fill(gappy, sigma=0)


def test_batched_fit_matches_one_frame_solutions(model):
    # nested bases fitted in one batch (``used``) give the separate fits; weights kept
    # within bounds by block pivoting are the bounded least-squares optimum (scipy's BVLS)
    from scipy.optimize import lsq_linear

    from lsmta.face.basis import _box_qp, fit_frames
    rng = np.random.default_rng(37)
    train = _faces(model, 120, rng)
    test = _faces(model, 12, rng, top=1.0)
    gappy = np.where(rng.random(test.shape[:2])[..., None] < 0.2, np.nan, test)
    b = face.pca_basis(train, 8)
    both = fit_frames(np.concatenate([gappy, gappy]), b.vectors, b.reference, n_iter=5,
                      used=np.r_[np.full(12, 4), np.full(12, 9)])
    for half, k in ((slice(0, 12), 3), (slice(12, 24), 8)):
        one = face.fill_missing(gappy, face.pca_basis(train, k), n_iter=5)
        np.testing.assert_allclose(both.frames[half], one.frames, atol=1e-8)
    p = 12
    A = rng.normal(size=(40, p, p + 3))
    G = A @ np.swapaxes(A, 1, 2)
    g = rng.normal(size=(40, p)) * 3
    lb, ub = np.r_[np.full(2, -np.inf), -np.ones(p - 2)], np.r_[np.full(2, np.inf), np.ones(p - 2)]
    x, done = _box_qp(G, g, lb, ub, np.linalg.solve(G, g[..., None])[..., 0])
    assert done.mean() > 0.9
    for i in np.flatnonzero(done):
        L = np.linalg.cholesky(G[i])
        ref = lsq_linear(L.T, np.linalg.solve(L, g[i]), bounds=(lb, ub), method="bvls").x
        np.testing.assert_allclose(x[i], ref, atol=1e-7)
