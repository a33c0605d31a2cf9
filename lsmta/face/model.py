"""A face model chosen by held-out evidence within the training sequence: cross-validation
over contiguous time blocks, with plain PCA as the default whenever the evidence is not
clear.

Candidates, each fitted per frame together with the rigid alignment (as
:func:`lsmta.face.fill_missing` does):

* ``"extremes"``: the thesis's K extreme faces, weights in [0, 1];
* ``"pca"``: the mean and k principal components, weights free (the thesis's other basis;
  "plain PCA" below);
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

**How** :func:`learn` **chooses** (``method="auto"``, :func:`choose_face_model`). The
complete training frames are cut into ``FaceParams.folds`` contiguous blocks of time; each
block is held out once, every candidate is built from the other blocks, and in (up to
``frames_per_fold`` evenly spaced) held-out frames markers are hidden the way the model will
be used: ``FaceParams.hidden`` of them at random in every frame, or the visibility patterns
passed as ``observed`` (a row drawn at random per frame). A candidate's score is the mean
over the blocks of the mean distance (mm) between its filled and the true hidden markers;
its standard error is the spread of the block means over √folds. The candidates are plain
PCA with every k of ``FaceParams.pca_sizes`` and the learnt ``FaceParams.families``
(default ``"box"``) at every size of ``FaceParams.sizes``. The rule:

1. the best PCA size is the k with the lowest score;
2. a learnt candidate is chosen only if its score is lower than the best PCA's by more than
   its own standard error; otherwise (a tie, or within one standard error) plain PCA with
   the best k is chosen, the simpler model.

So the default is plain PCA with its size chosen on the training data, unless the training
data itself shows clearly that the learnt model generalises better to frames it was not
built from. Blocks of time, not random frames, are held out, because neighbouring frames
are nearly the same face: a random split would reward a model for remembering them.

**The evidence** (notebook 13, ``experiments/face_models.py``): each AnimFace sequence is
split in time; the choice is made on the first half only (the training half), and the
model is scored on the second half, which the choice never saw (6 of 41 markers hidden at
random per frame), against plain PCA with its size chosen on the same training half. The
fixed default used before (``"box"`` with 20 components, :data:`DEFAULT_METHOD`,
:data:`DEFAULT_SIZE`) was chosen by testing across the two AnimFace captures, and lost to
plain PCA with 10 components on two other facial sequences it had not seen.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.cluster.vq import kmeans2

from .._validate import as_int, as_rng, as_scalar
from .basis import (
    FaceFit,
    _as_sequence,
    _extremes_from,
    _observed,
    _pca_from,
    _principal,
    align_sequence,
    fit_frames,
    min_observed_markers,
)

METHODS = ("extremes", "pca", "prior", "box")
#: the learnt family and size that did best across the two AnimFace captures (train on one,
#: fill the other; experiments/face_models.py): the fixed default of ``learn`` before the
#: choice by cross-validation; ``"auto"`` now offers this family to the cross-validation
#: beside plain PCA
DEFAULT_METHOD, DEFAULT_SIZE = "box", 20


@dataclass(frozen=True)
class FaceParams:
    """How :func:`learn` and :func:`choose_face_model` cross-validate.

    Attributes
    ----------
    pca_sizes : tuple of int
        Numbers of principal components tried for plain PCA (``"pca"``): every k up to 8,
        then sparser (the error changes slowly with k there).
    sizes : tuple of int
        Sizes tried for the other families: K extreme faces, or k principal components
        with a prior or box.
    families : tuple of str
        The learnt families ``"auto"`` weighs against plain PCA (from ``"extremes"``,
        ``"prior"``, ``"box"``; may be empty: PCA's size alone is chosen).
    folds : int
        Held-out sets of the training frames, each held out once (>= 2).
    hidden : float
        Share of the markers hidden at random in each held-out frame, in (0, 1) (0.15:
        about the thesis's 11 of 76), when no ``observed`` patterns are given.
    frames_per_fold : int
        Most held-out frames scored per set (evenly spaced).
    n_iter : int
        Gauss-Newton passes per frame.
    split : {"blocks", "clusters"}
        Held-out sets: contiguous blocks of time (default), or clusters of expressions
        (k-means of the aligned shapes' first principal scores: what is held out is unlike
        what is kept).
    """

    pca_sizes: tuple = (1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 25, 30)
    sizes: tuple = (5, 10, 20, 30)
    families: tuple = (DEFAULT_METHOD,)
    folds: int = 5
    hidden: float = 0.15
    frames_per_fold: int = 60
    n_iter: int = 5
    split: str = "blocks"

    def __post_init__(self):
        for name in ("pca_sizes", "sizes"):
            v = tuple(getattr(self, name))
            if not v:
                raise ValueError(f"{name}: expected positive integers, got {v!r}")
            object.__setattr__(self, name, tuple(as_int(k, name) for k in v))
        fam = tuple(self.families)
        if any(f not in METHODS or f == "pca" for f in fam):
            raise ValueError(f"families: expected names from {METHODS[:1] + METHODS[2:]}, "
                             f"got {fam!r}")
        object.__setattr__(self, "families", fam)
        for name, least in (("folds", 2), ("frames_per_fold", 1), ("n_iter", 1)):
            object.__setattr__(self, name, as_int(getattr(self, name), name, minimum=least))
        h = as_scalar(self.hidden, "hidden", positive=True)
        if h >= 1:
            raise ValueError(f"hidden: expected a share in (0, 1), got {h}")
        object.__setattr__(self, "hidden", h)
        if self.split not in ("clusters", "blocks"):
            raise ValueError(f"split: expected 'blocks' or 'clusters', got {self.split!r}")


@dataclass(frozen=True)
class FaceChoice:
    """What the cross-validation of :func:`choose_face_model` measured and chose.

    Attributes
    ----------
    candidates : tuple of (str, int)
        ``(method, size)`` of every candidate, in the rows' order.
    errors : (C, F) array
        Mean distance between the filled and the true hidden markers of each held-out set
        (mm), per candidate.
    score : (C,) array
        Mean of ``errors`` over the sets, mm.
    se : (C,) array
        Standard error of ``score``: the spread of the set means over √F, mm.
    lowest : (str, int)
        The candidate with the lowest score.
    best_pca : (str, int) or None
        Plain PCA at the size with the lowest score (None if PCA was not a candidate).
    chosen : (str, int)
        What the rule chose (see the module docstring).
    reason : str
        The rule's decision, in words.
    rule : str
        ``"one standard error"`` (``"auto"``: PCA unless a learnt candidate is clearly
        better) or ``"lowest"`` (``"cv"`` or a named method).
    fold_frames : (F,) int array
        Training frames held out in each set.
    scored_frames : int
        Held-out frames scored, all sets together.
    hidden : str
        How the markers were hidden, in words.
    """

    candidates: tuple
    errors: np.ndarray
    score: np.ndarray
    se: np.ndarray
    lowest: tuple
    best_pca: tuple | None
    chosen: tuple
    reason: str
    rule: str
    fold_frames: np.ndarray
    scored_frames: int
    hidden: str

    @property
    def method(self) -> str:
        return self.chosen[0]

    @property
    def size(self) -> int:
        return self.chosen[1]

    @property
    def scores(self) -> dict:
        """``(method, size)`` -> score (mm)."""
        return {c: float(s) for c, s in zip(self.candidates, self.score)}

    def row(self, candidate) -> tuple:
        """``(score, se)`` of one ``(method, size)``, mm."""
        i = self.candidates.index(tuple(candidate))
        return float(self.score[i]), float(self.se[i])

    def table(self, *, every: bool = False) -> str:
        """The cross-validation as a Markdown table: every learnt candidate and the PCA
        sizes near the best (all of them with ``every``), lowest score marked."""
        rows = ["| candidate | size | CV error [mm] | standard error [mm] | |",
                "|---|---|---|---|---|"]
        keep = range(len(self.candidates))
        if not every and self.best_pca is not None:
            k = self.best_pca[1]
            pca = sorted(s for m, s in self.candidates if m == "pca")
            near = set(pca[max(pca.index(k) - 2, 0):pca.index(k) + 3]) | {pca[0], pca[-1]}
            keep = [i for i, (m, s) in enumerate(self.candidates) if m != "pca" or s in near]
        for i in keep:
            c = self.candidates[i]
            mark = ", ".join(n for n, v in (("lowest", self.lowest), ("best PCA", self.best_pca),
                                            ("**chosen**", self.chosen)) if v == c)
            rows.append(f"| {c[0]} | {c[1]} | {self.score[i]:.3f} | {self.se[i]:.3f} | {mark} |")
        return "\n".join(rows)


@dataclass(frozen=True)
class FaceModel:
    """A face model learned by :func:`learn`.

    Attributes
    ----------
    method : str
        ``"extremes"``, ``"pca"``, ``"prior"`` or ``"box"`` (see the module docstring).
    size : int
        K extreme faces or k principal components.
    basis : FaceBasis
        The basis, in the training sequence's mean head frame.
    prior : tuple or None
        ``(w0, r)``: the prior's mean weights and penalties (``"prior"`` and ``"box"``).
    bounds : tuple or None
        ``(lower, upper)`` of the weights: [0, 1] for the extreme faces, the training
        range of each component's weight for ``"box"``.
    scores : dict
        Cross-validation: ``(method, size)`` -> mean error of the hidden markers, mm
        (empty when the model was built without a choice).
    n_iter : int
        Gauss-Newton passes per frame.
    choice : FaceChoice or None
        The cross-validation behind the model, with its table and the rule's reason.
    """

    method: str
    size: int
    basis: object
    prior: tuple | None
    bounds: tuple | None
    scores: dict
    n_iter: int
    choice: FaceChoice | None = field(default=None, repr=False)

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


# ---------------------------------------------------------------- building candidates
@dataclass(frozen=True)
class _Decomposition:
    """A complete training sequence aligned to its mean, and its principal components."""

    aligned: np.ndarray
    mean: np.ndarray
    D: np.ndarray          # (T, 3M) aligned shapes minus the mean
    sv: np.ndarray         # singular values of D
    Vt: np.ndarray         # principal directions (rows)
    explained: np.ndarray


def _decompose(training) -> _Decomposition:
    aligned, mean = align_sequence(training)
    D, Vt, explained = _principal(aligned, mean)
    return _Decomposition(aligned=aligned, mean=mean, D=D,
                          sv=np.sqrt(np.maximum(explained, 0) * (D ** 2).sum()), Vt=Vt,
                          explained=explained)


def _largest(method: str, T: int, M: int) -> int:
    """Largest size a training sequence of T frames of M markers allows."""
    return min(T, 3 * M) if method == "extremes" else min(T - 1, 3 * M)


def _model(dec: _Decomposition, method: str, size: int, n_iter: int) -> FaceModel:
    """One candidate from a decomposed training sequence."""
    T = len(dec.D)
    if not 1 <= size <= _largest(method, T, len(dec.mean)) and not (method == "pca"
                                                                      and size == 0):
        raise ValueError(f"size: {method} with {size} does not fit {T} training frames")
    if method == "extremes":
        basis = _extremes_from(dec.aligned, dec.mean, dec.D, dec.Vt, dec.explained, size)
        return FaceModel(method=method, size=size, basis=basis, prior=None,
                         bounds=(np.zeros(size), np.ones(size)), scores={}, n_iter=n_iter)
    basis = _pca_from(dec.mean, dec.Vt, dec.explained, size)
    prior = bounds = None
    if method in ("prior", "box"):
        lam = dec.sv ** 2 / T                                      # variance per component
        sigma2 = max(lam[size:].sum() / max(dec.D.shape[1] - size, 1), 1e-12 * lam[0])
        r = np.r_[1e8 * sigma2, sigma2 / np.maximum(lam[:size], 1e-300)]
        prior = (np.r_[1.0, np.zeros(size)], r)
        if method == "box":                  # each weight within its training range
            w = dec.D @ dec.Vt[:size].T
            bounds = (np.r_[-np.inf, w.min(axis=0)], np.r_[np.inf, w.max(axis=0)])
    return FaceModel(method=method, size=size, basis=basis, prior=prior, bounds=bounds,
                     scores={}, n_iter=n_iter)


def build_face_model(training, *, method: str, size: int, n_iter: int = 5) -> FaceModel:
    """One face model of a given method and size, without a choice.

    Parameters
    ----------
    training : (T, M, 3) array
        Training sequence, mm; frames with a gap are left out. Not modified.
    method : {"extremes", "pca", "prior", "box"}
    size : int
        K extreme faces (``1 <= K <= min(T, 3M)``) or k principal components
        (``1 <= k <= min(T - 1, 3M)``; 0 for plain PCA: the mean alone).
    n_iter : int
        Gauss-Newton passes per frame when filling.

    Returns
    -------
    FaceModel
        ``scores`` empty and ``choice`` None.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    X = _as_sequence(training, "training", allow_nan=True)
    X = X[_observed(X).all(axis=1)]
    if len(X) < 2:
        raise ValueError(f"training: expected at least 2 complete frames, got {len(X)}")
    return _model(_decompose(X), method, as_int(size, "size", minimum=0),
                  as_int(n_iter, "n_iter", minimum=1))


def _build(training, method: str, size: int, n_iter: int) -> FaceModel:
    """:func:`build_face_model` positionally (notebook 18 and the experiments use it)."""
    return build_face_model(training, method=method, size=size, n_iter=n_iter)


# ---------------------------------------------------------------- cross-validation
def _folds(X, params: FaceParams, rng) -> list:
    """Held-out sets of frames: contiguous blocks of time, or clusters of expressions
    (k-means of the aligned shapes' first principal scores)."""
    T = len(X)
    if params.split == "blocks":
        return np.array_split(np.arange(T), params.folds)
    aligned, mean = align_sequence(X)
    D = (aligned - mean).reshape(T, -1)
    _, _, Vt = np.linalg.svd(D, full_matrices=False)
    scores = D @ Vt[:params.folds].T
    _, label = kmeans2(scores, params.folds, minit="++", seed=rng)
    return [np.flatnonzero(label == c) for c in range(params.folds) if (label == c).sum() >= 2]


def _hide(n_frames: int, M: int, params: FaceParams, patterns, rng) -> np.ndarray:
    """(n, M) bool: the markers hidden in n held-out frames."""
    if patterns is None:
        n_hide = max(1, round(params.hidden * M))
        return rng.random((n_frames, M)).argsort(axis=1).argsort(axis=1) < n_hide
    return ~patterns[rng.integers(len(patterns), size=n_frames)]


def _fold_errors(dec, test, hide, candidates, n_iter) -> list:
    """Mean distance (mm) between the filled and the true hidden markers of ``test``
    (n, M, 3), for every candidate; plain PCA at every size in one batch (nested bases)."""
    gappy = np.where(hide[..., None], np.nan, test)
    out = {}
    pca = sorted(k for m, k in candidates if m == "pca")
    if pca:
        top = _model(dec, "pca", pca[-1], n_iter).basis
        n = len(test)
        fit = fit_frames(np.tile(gappy, (len(pca), 1, 1)), top.vectors, top.reference,
                         n_iter=n_iter, used=np.repeat(np.array(pca) + 1, n))
        e = np.linalg.norm(fit.frames - np.tile(test, (len(pca), 1, 1)), axis=2)
        e = e.reshape(len(pca), n, -1)[:, hide]
        out.update({("pca", k): float(v.mean()) for k, v in zip(pca, e)})
    for m, k in candidates:
        if m != "pca":
            filled = _model(dec, m, k, n_iter).fill(gappy).frames
            out[m, k] = float(np.linalg.norm(filled - test, axis=2)[hide].mean())
    return [out[c] for c in candidates]


def _candidates(method: str, params: FaceParams, T: int, M: int, least_seen: int) -> list:
    """(method, size) pairs tried: those the held-out training sets and the fewest markers
    seen in a held-out frame allow."""
    if method == "auto":
        pairs = [("pca", k) for k in params.pca_sizes]
        pairs += [(m, k) for m in params.families for k in params.sizes]
    else:
        methods = METHODS if method == "cv" else (method,)
        pairs = [(m, k) for m in methods
                 for k in (params.pca_sizes if m == "pca" else params.sizes)]
    out = []
    for m, k in pairs:
        vectors = k if m == "extremes" else k + 1
        if k <= _largest(m, T, M) and min_observed_markers(vectors) <= least_seen \
                and (m, k) not in out:
            out.append((m, k))
    return out


def _checked(training, method, params, observed):
    """Params, the complete training frames (T, M, 3) and the visibility patterns (or
    None)."""
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
    if M < 3:
        raise ValueError(f"training: expected at least 3 markers, got {M}")
    patterns = None
    if observed is not None:
        patterns = np.atleast_2d(np.asarray(observed))
        if patterns.dtype != bool:
            raise ValueError(f"observed: expected a bool array, got dtype {patterns.dtype}")
        if patterns.ndim != 2 or patterns.shape[1] != M:
            raise ValueError(f"observed: expected shape (S, {M}) or ({M},) like the training "
                             f"markers, got {np.shape(observed)}")
        patterns = patterns[(patterns.sum(axis=1) >= 3) & ~patterns.all(axis=1)]
        if not len(patterns):
            raise ValueError("observed: expected patterns that hide at least one marker and "
                             "keep at least 3")
    elif M - max(1, round(params.hidden * M)) < 3:
        raise ValueError(f"training: {M} markers leave fewer than 3 observed after hiding "
                         f"{max(1, round(params.hidden * M))}")
    return params, X, patterns


def _one_standard_error(cands, score, se):
    """``"auto"``'s rule: the (method, size) chosen among ``cands`` with cross-validation
    ``score`` and standard error ``se`` (mm), and the reason in words. Plain PCA at its
    lowest-scoring size, unless the lowest candidate is a learnt one whose score is lower
    than that PCA's by more than the learnt candidate's standard error."""
    lo = int(np.argmin(score))
    lowest = cands[lo]
    pca = [i for i, c in enumerate(cands) if c[0] == "pca"]
    if lowest[0] == "pca":
        return lowest, f"pca {lowest[1]}: plain PCA has the lowest cross-validation error"
    if not pca:
        return lowest, f"{lowest[0]} {lowest[1]}: the lowest cross-validation error (no PCA)"
    i = min(pca, key=lambda j: score[j])
    gap = score[i] - score[lo]
    if gap <= se[lo]:
        return cands[i], (f"pca {cands[i][1]}: within one standard error ({se[lo]:.3f} mm) "
                          f"of the lowest, {lowest[0]} {lowest[1]} ({gap:+.3f} mm): the "
                          f"simpler model")
    return lowest, (f"{lowest[0]} {lowest[1]}: lower than the best plain PCA (pca "
                    f"{cands[i][1]}) by {gap:.3f} mm, more than one standard error "
                    f"({se[lo]:.3f} mm)")


def _choose(X, method: str, params: FaceParams, patterns, rng) -> FaceChoice:
    T, M, _ = X.shape
    folds = _folds(X, params, rng)
    least_train = T - max(len(f) for f in folds)
    least_seen = M - max(1, round(params.hidden * M)) if patterns is None \
        else int(patterns.sum(axis=1).min())
    cands = _candidates(method, params, least_train, M, least_seen)
    if not cands:
        raise ValueError(f"params: no candidate size fits {least_train} training frames per "
                         f"fold and {least_seen} observed markers")
    errors = np.empty((len(cands), len(folds)))
    scored = 0
    for j, fold in enumerate(folds):
        pick = np.linspace(0, len(fold) - 1, min(params.frames_per_fold, len(fold)))
        test = X[fold[np.unique(pick.round().astype(int))]]
        scored += len(test)
        hide = _hide(len(test), M, params, patterns, rng)
        dec = _decompose(np.delete(X, fold, axis=0))
        errors[:, j] = _fold_errors(dec, test, hide, cands, params.n_iter)
    score = errors.mean(axis=1)
    se = errors.std(axis=1, ddof=1) / np.sqrt(errors.shape[1])
    lo = int(np.argmin(score))
    lowest = cands[lo]
    pca = [i for i, c in enumerate(cands) if c[0] == "pca"]
    best_pca = cands[min(pca, key=lambda i: score[i])] if pca else None
    if method != "auto":
        rule, chosen = "lowest", lowest
        reason = f"{lowest[0]} {lowest[1]}: the lowest cross-validation error"
    else:
        rule = "one standard error"
        chosen, reason = _one_standard_error(cands, score, se)
    how = (f"{max(1, round(params.hidden * M))} of {M} markers hidden at random per frame"
           if patterns is None else f"{len(patterns)} given visibility pattern"
           + ("s" if len(patterns) > 1 else "") + ", one drawn per held-out frame")
    return FaceChoice(candidates=tuple(cands), errors=errors, score=score, se=se, lowest=lowest,
                      best_pca=best_pca, chosen=chosen, reason=reason, rule=rule,
                      fold_frames=np.array([len(f) for f in folds]), scored_frames=scored,
                      hidden=how)


def choose_face_model(training, *, method: str = "auto", params: FaceParams | None = None,
                      observed=None, rng: np.random.Generator | int | None = None
                      ) -> FaceChoice:
    """Choose a face model's method and size by cross-validation on the training sequence
    (the protocol and the rule: the module docstring).

    Parameters
    ----------
    training : (T, M, 3) array
        Training sequence, mm; frames with a gap are left out. Not modified.
    method : {"auto", "cv", "extremes", "pca", "prior", "box"}
        ``"auto"``: plain PCA at every size of ``params.pca_sizes`` against the learnt
        ``params.families``; PCA unless a learnt candidate is lower by more than one
        standard error. ``"cv"``: every method, the lowest score. A named method: its size
        with the lowest score.
    params : FaceParams, optional
        Sizes, families, the held-out sets and how many markers are hidden.
    observed : (S, M) or (M,) bool array, optional
        The visibility the model will meet (True: seen): each held-out frame hides the
        markers of a row drawn at random (rows that hide nothing or keep fewer than 3 are
        left out). Default: ``params.hidden`` of the markers hidden at random per frame.
    rng : numpy.random.Generator, int or None
        The hidden markers (and the clusters of ``split="clusters"``). None: seeded with 0,
        so that one training sequence always gives the same choice.

    Returns
    -------
    FaceChoice
    """
    params, X, patterns = _checked(training, method, params, observed)
    rng = as_rng(0 if rng is None else rng)
    return _choose(X, method, params, patterns, rng)


def learn(training, *, method: str = "auto", params: FaceParams | None = None,
          observed=None, rng: np.random.Generator | int | None = None) -> FaceModel:
    """Learn a face model from a training sequence: the method and size chosen by
    :func:`choose_face_model`, then built from every complete training frame.

    Parameters
    ----------
    training : (T, M, 3) array
        Training sequence, mm; frames with a gap are left out. Not modified.
    method : {"auto", "cv", "extremes", "pca", "prior", "box"}
        ``"auto"`` (default): plain PCA with the size cross-validation prefers, unless a
        learnt family (``params.families``, default ``"box"``) is better by more than one
        standard error of its cross-validation error. ``"cv"``: every method and size
        competes, the lowest wins. A named method: its size is chosen.
    params : FaceParams, optional
        Sizes tried, the held-out sets and the share of markers hidden.
    observed : (S, M) or (M,) bool array, optional
        The visibility the model will meet (see :func:`choose_face_model`).
    rng : numpy.random.Generator, int or None
        The hidden markers; None: seeded with 0 (the same training, the same model).

    Returns
    -------
    FaceModel
        ``choice`` holds the cross-validation table and the rule's reason; ``scores`` its
        scores.
    """
    choice = choose_face_model(training, method=method, params=params, observed=observed,
                               rng=rng)
    params, X, _ = _checked(training, method, params, observed)
    m, k = choice.chosen
    return replace(_model(_decompose(X), m, k, params.n_iter), scores=choice.scores,
                   choice=choice)
