"""The face model chosen by cross-validation (lsmta.face.learn) and the peer's distance
weighting; ground truth from the face generator."""

import numpy as np
import pytest

from lsmta import face
from lsmta.face.model import DEFAULT_METHOD, DEFAULT_SIZE
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
    for method in ("pca", "prior", "box"):
        m = face.learn(train, method=method, params=face.FaceParams(sizes=(2, 6)), rng=1)
        assert (m.method, m.size) == (method, 6), method
        # noise of 0.3 mm per axis in the held-out frames alone is 0.48 mm on average
        assert m.scores[method, 6] < 1.0 < m.scores[method, 2] / 0.48
    every = face.learn(train, method="cv", params=face.FaceParams(sizes=(2, 6)), rng=1)
    assert set(every.scores) == {(m, k) for m in face.model.METHODS for k in (2, 6)}
    assert every.scores[every.method, every.size] == min(every.scores.values())
    assert every.size == 6


def test_learned_model_fills_held_out_gaps_to_the_noise(model):
    rng = np.random.default_rng(31)
    train, test = _faces(model, 150, rng), _faces(model, 40, rng, noise=0.0)
    gappy = test.copy()
    hidden = rng.random(gappy.shape[:2]) < 0.15
    gappy[hidden] = np.nan
    before = gappy.copy()
    m = face.learn(train)
    assert (m.method, m.size) == (DEFAULT_METHOD, DEFAULT_SIZE) and m.scores == {}
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
    with pytest.raises(ValueError, match="training: expected at least 8"):
        face.learn(train[:5])
    with pytest.raises(ValueError, match="training"):
        face.learn(train[:, :, :2])
    with pytest.raises(ValueError, match="hidden"):
        face.FaceParams(hidden=1.0)
    with pytest.raises(ValueError, match="sizes"):
        face.FaceParams(sizes=(0, 3))
    with pytest.raises(ValueError, match="split"):
        face.FaceParams(split="random")
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
