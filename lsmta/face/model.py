"""A face model whose method is chosen by evidence: cross-validation on the training
sequence.

Candidates, each fitted per frame together with the rigid alignment (as
:func:`lsmta.face.fill_missing` does):

* ``"extremes"``: the thesis's K extreme faces, weights in [0, 1];
* ``"pca"``: the mean and k principal components, weights free (the thesis's other basis);
* ``"prior"``: the same basis with a Gaussian prior on the weights, the posterior mean of
  probabilistic PCA (Tipping & Bishop 1999): component j has the training variance λ_j, and
  the variance the k components leave out is noise, σ² = Σ_{j>k} λ_j / (3M - k) per
  coordinate. Each frame minimises

      |y_o - (μ + V w)_o|² + Σ_j (σ² / λ_j) w_j²

  over the weights and the rigid motion, so a component the observed markers barely see
  stays near its training mean instead of following their noise;
* ``"box"``: ``"prior"`` with each weight kept within the range it spans over the training
  sequence (bounded-variable least squares): the thesis's idea of interpolating between
  valid faces, applied to the principal components. A new expression is then not
  extrapolated along a component further than the training went.

:func:`learn` hides a share of the markers in held-out sets of the training sequence
(clusters of similar expressions, so that what is held out is unlike what is kept, as in a
new session), fills them with every candidate (method and size) and keeps the one with the
smallest mean error. What ``"auto"`` uses was decided by the same test across two real
captures (:data:`DEFAULT_METHOD`, :data:`DEFAULT_SIZE`): cross-validation inside one
sequence prefers an unbounded prior or basis, which does worse on the other sequence.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.cluster.vq import kmeans2

from .._validate import as_int, as_rng, as_scalar
from .basis import (
    FaceBasis,
    FaceFit,
    _as_sequence,
    _observed,
    align_sequence,
    extreme_basis,
    fit_frames,
    pca_basis,
)

METHODS = ("extremes", "pca", "prior", "box")
#: the method and size ``learn(method="auto")`` uses: the lowest mean error of the hidden
#: markers, averaged over both directions of AnimFace JawMoCap <-> CheeksMoCap (6 of 41
#: hidden per frame, 5 draws pooled: experiments/face_models.py; notebook 18 shows one)
DEFAULT_METHOD, DEFAULT_SIZE = "box", 20


@dataclass(frozen=True)
class FaceParams:
    """How :func:`learn` cross-validates.

    Attributes
    ----------
    sizes : tuple of int
        Basis sizes tried: K extreme faces, or k principal components.
    folds : int
        Contiguous blocks of the training sequence, each held out once (>= 2).
    hidden : float
        Share of the markers hidden in each held-out frame, in (0, 1) (0.15: about the
        thesis's 11 of 76).
    frames_per_fold : int
        Held-out frames scored per block (evenly spaced).
    n_iter : int
        Gauss-Newton passes per frame.
    split : {"clusters", "blocks"}
        Held-out sets: clusters of expressions (what is held out is unlike what is kept,
        as a new session is) or contiguous blocks of frames.
    """

    sizes: tuple = (5, 10, 20, 30)
    folds: int = 4
    hidden: float = 0.15
    frames_per_fold: int = 30
    n_iter: int = 5
    split: str = "clusters"

    def __post_init__(self):
        if not tuple(self.sizes):
            raise ValueError(f"sizes: expected positive integers, got {self.sizes!r}")
        object.__setattr__(self, "sizes", tuple(as_int(k, "sizes") for k in self.sizes))
        for name, least in (("folds", 2), ("frames_per_fold", 1), ("n_iter", 1)):
            object.__setattr__(self, name, as_int(getattr(self, name), name, minimum=least))
        h = as_scalar(self.hidden, "hidden", positive=True)
        if h >= 1:
            raise ValueError(f"hidden: expected a share in (0, 1), got {h}")
        object.__setattr__(self, "hidden", h)
        if self.split not in ("clusters", "blocks"):
            raise ValueError(f"split: expected 'clusters' or 'blocks', got {self.split!r}")


@dataclass(frozen=True)
class FaceModel:
    """A face model learned by :func:`learn`.

    Attributes
    ----------
    method : str
        ``"extremes"``, ``"pca"`` or ``"prior"`` (see the module docstring).
    size : int
        K extreme faces or k principal components.
    basis : FaceBasis
        The basis, in the training sequence's mean head frame.
    prior : tuple or None
        ``(w0, r)``: the prior's mean weights and penalties (``"prior"`` only).
    bounds : tuple or None
        ``(lower, upper)`` of the weights: [0, 1] for the extreme faces, the training
        range of each component's weight for ``"box"``.
    scores : dict
        Cross-validation: ``(method, size)`` -> mean error of the hidden markers, mm.
    n_iter : int
        Gauss-Newton passes per frame.
    """

    method: str
    size: int
    basis: FaceBasis
    prior: tuple | None
    bounds: tuple | None
    scores: dict
    n_iter: int

    def fill(self, frames) -> FaceFit:
        """Fill the missing markers of ``frames`` (T, M, 3), mm, NaN for gaps (not
        modified): each frame aligned rigidly and fitted jointly with the model's weights
        (see :func:`lsmta.face.fill_missing` for the result's fields)."""
        X = _as_sequence(frames, "frames", allow_nan=True)
        M = self.basis.vectors.shape[1]
        if X.shape[1] != M:
            raise ValueError(f"frames: expected {M} markers like the training sequence, got "
                             f"{X.shape[1]}")
        return fit_frames(X, self.basis.vectors, self.basis.reference, n_iter=self.n_iter,
                          bounds=self.bounds, prior=self.prior)


def _build(training, method: str, size: int, n_iter: int) -> FaceModel:
    """One candidate model from a complete training sequence (T, M, 3)."""
    if method == "extremes":
        basis = extreme_basis(training, size)
        return FaceModel(method=method, size=size, basis=basis, prior=None,
                         bounds=(np.zeros(size), np.ones(size)), scores={}, n_iter=n_iter)
    basis = pca_basis(training, size)
    prior = bounds = None
    if method in ("prior", "box"):
        aligned, mean = align_sequence(training)
        D = (aligned - mean).reshape(len(aligned), -1)
        _, sv, Vt = np.linalg.svd(D, full_matrices=False)
        lam = sv ** 2 / len(D)                                      # variance per component
        sigma2 = max(lam[size:].sum() / max(D.shape[1] - size, 1), 1e-12 * lam[0])
        r = np.r_[1e8 * sigma2, sigma2 / np.maximum(lam[:size], 1e-300)]
        prior = (np.r_[1.0, np.zeros(size)], r)
        if method == "box":                  # each weight within its training range
            w = D @ Vt[:size].T
            bounds = (np.r_[-np.inf, w.min(axis=0)], np.r_[np.inf, w.max(axis=0)])
    return FaceModel(method=method, size=size, basis=basis, prior=prior, bounds=bounds,
                     scores={}, n_iter=n_iter)


def _fold_errors(train, test, hide, method, size, n_iter):
    """Mean distance (mm) of the hidden markers of ``test`` filled by one candidate."""
    gappy = np.where(hide[..., None], np.nan, test)
    filled = _build(train, method, size, n_iter).fill(gappy).frames
    return np.linalg.norm(filled - test, axis=2)[hide]


def _folds(X, params: FaceParams, rng) -> list:
    """Held-out sets of frames: contiguous blocks, or clusters of expressions (k-means of
    the aligned shapes' first principal scores), so that what is held out is unlike
    what is kept."""
    T = len(X)
    if params.split == "blocks":
        return np.array_split(np.arange(T), params.folds)
    aligned, mean = align_sequence(X)
    D = (aligned - mean).reshape(T, -1)
    _, _, Vt = np.linalg.svd(D, full_matrices=False)
    scores = D @ Vt[:params.folds].T
    _, label = kmeans2(scores, params.folds, minit="++", seed=rng)
    return [np.flatnonzero(label == c) for c in range(params.folds) if (label == c).sum() >= 2]


def _checked(training, method, params):
    """Params, the complete training frames (T, M, 3) and how many markers to hide."""
    params = FaceParams() if params is None else params
    if not isinstance(params, FaceParams):
        raise TypeError(f"params: expected a FaceParams, got {type(params).__name__}")
    if method not in ("auto", "cv") + METHODS:
        raise ValueError(f"method: expected 'auto', 'cv' or one of {METHODS}, got {method!r}")
    X = _as_sequence(training, "training", allow_nan=True)
    X = X[_observed(X).all(axis=1)]
    T, M, _ = X.shape
    if T < 2 * params.folds:
        raise ValueError(f"training: expected at least {2 * params.folds} complete frames "
                         f"(two per fold), got {T}")
    n_hide = max(1, round(params.hidden * M))
    if M - n_hide < 3:
        raise ValueError(f"training: {M} markers leave fewer than 3 observed after hiding "
                         f"{n_hide}")
    return params, X, n_hide


def _cross_validate(X, methods, params: FaceParams, n_hide: int, rng) -> dict:
    """(method, size) -> mean error (mm) of the markers hidden in the held-out frames."""
    M = X.shape[1]
    folds = _folds(X, params, rng)
    most = len(X) - max(len(f) for f in folds) - 1
    sizes = [k for k in params.sizes if k <= min(most, 3 * M)]
    if not sizes:
        raise ValueError(f"params: no size in {params.sizes} fits {len(X)} training frames")
    errors = {(m, k): [] for m in methods for k in sizes}
    for fold in folds:
        pick = np.linspace(0, len(fold) - 1, min(params.frames_per_fold, len(fold)))
        test = X[fold[pick.round().astype(int)]]
        hide = rng.random((len(test), M)).argsort(axis=1).argsort(axis=1) < n_hide
        train = np.delete(X, fold, axis=0)
        for m, k in errors:
            errors[m, k].append(_fold_errors(train, test, hide, m, k, params.n_iter))
    return {c: float(np.concatenate(e).mean()) for c, e in errors.items()}


def learn(training, *, method: str = "auto", params: FaceParams | None = None,
          rng: np.random.Generator | int | None = None) -> FaceModel:
    """Learn a face model from a training sequence (see the module docstring).

    Parameters
    ----------
    training : (T, M, 3) array
        Training sequence, mm; frames with a gap are left out. Not modified.
    method : {"auto", "cv", "extremes", "pca", "prior", "box"}
        ``"auto"``: :data:`DEFAULT_METHOD` with :data:`DEFAULT_SIZE` components (fewer if
        the training sequence is short), the method and size that won cross-validation
        across real captures (AnimFace, one sequence for training and the other for
        testing, both ways). ``"cv"``: every method and size competes in cross-validation
        on ``training``. A named method: its size is chosen by cross-validation on
        ``training``.
    params : FaceParams, optional
        Sizes tried, the held-out sets and the share of markers hidden.
    rng : numpy.random.Generator, int or None
        The held-out clusters and which markers are hidden.

    Returns
    -------
    FaceModel
        Fitted on the whole training sequence; ``scores`` holds the cross-validation
        (empty for ``"auto"``).
    """
    params, X, n_hide = _checked(training, method, params)
    rng = as_rng(rng)
    if method == "auto":
        size = min(DEFAULT_SIZE, len(X) - 1, 3 * X.shape[1])
        return _build(X, DEFAULT_METHOD, size, params.n_iter)
    scores = _cross_validate(X, METHODS if method == "cv" else (method,), params, n_hide, rng)
    best = min(scores, key=scores.get)
    return replace(_build(X, best[0], best[1], params.n_iter), scores=scores)
