"""Occluded facial markers from a basis-face model (Davis 2002, thesis section 5.4).

A face is a linear combination of basis vectors, ``F = sum_i w_i B_i`` (the thesis's
eq. 5). A frame in which some markers are missing is first carried rigidly onto the
basis's reference shape using its observed markers (:func:`lsmta.rigid.fit_rigid`), the
weights are fitted by least squares on the observed markers only (eq. 6 with the unknown
rows removed), constrained to ``[0, 1]`` so that the model interpolates between valid
faces, and the missing markers are predicted from the full basis and carried back.

Two ways to build the basis from a complete training sequence, both from the thesis:
:func:`extreme_basis` (the training frame with the largest absolute projection on each of
the first principal components: real faces, weights constrained) and :func:`pca_basis`
(mean shape plus the first principal components: not faces, weights free).

The peer method from biomechanics, PCA gap filling, is in :mod:`lsmta.face.peer`; a model
chosen by cross-validation among these and a PCA basis with a prior on its weights, in
:mod:`lsmta.face.model`.

:func:`distance_deviation` is the accuracy measure of the thesis's Fig. 64: how much the
distances between markers that should stay rigid vary about their mean.

Conventions: sequences are ``(T, M, 3)`` arrays in millimetres with NaN for a missing
marker (a marker is missing when any of its coordinates is NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from .._validate import as_array, as_int
from ..rigid import apply_rigid, fit_rigid

__all__ = [
    "FaceBasis", "FaceFit", "fill_missing", "extreme_basis", "pca_basis", "align_sequence",
    "distance_deviation", "min_observed_markers",
]


# ---------------------------------------------------------------- results
@dataclass(frozen=True)
class FaceBasis:
    """A basis-face model.

    Attributes
    ----------
    vectors : (K, M, 3) array
        Basis vectors ``B_i`` in the model's head frame, mm (faces for
        :func:`extreme_basis`; the mean followed by unit principal directions for
        :func:`pca_basis`).
    reference : (M, 3) array
        The shape each frame's observed markers are first aligned to (the training mean).
    kind : str
        ``"extremes"`` or ``"pca"``.
    constrain : bool
        Whether the weights are meant to be constrained to [0, 1] (True for extremes).
    frames : (K,) int array
        Training frames picked as basis faces (extremes); -1 for PCA vectors.
    explained : (k,) array
        Fraction of the training variance along each principal component used.
    """

    vectors: np.ndarray
    reference: np.ndarray
    kind: str
    constrain: bool
    frames: np.ndarray
    explained: np.ndarray


@dataclass(frozen=True)
class FaceFit:
    """Result of :func:`fill_missing`.

    Attributes
    ----------
    frames : (T, M, 3) array
        The input with its missing markers filled from the model, mm; observed markers
        are returned unchanged. Frames that could not be fitted (``fitted`` False) keep
        their NaN.
    model : (T, M, 3) array
        The fitted model face of every marker, in the frame's own coordinates, mm.
    weights : (T, K) array
        Basis weights (NaN where not fitted).
    R : (T, 3, 3) array
        Rotations of the rigid alignment basis -> frame: ``frame ≈ model_head @ R.T + t``.
    t : (T, 3) array
        Translations of that alignment, mm.
    residual : (T,) array
        RMS distance between the observed markers and the fitted model, mm.
    observed : (T, M) bool array
        Which markers were observed.
    fitted : (T,) bool array
        Frames with enough observed markers to fit (see :func:`min_observed_markers`).
    """

    frames: np.ndarray
    model: np.ndarray
    weights: np.ndarray
    R: np.ndarray
    t: np.ndarray
    residual: np.ndarray
    observed: np.ndarray
    fitted: np.ndarray


# ---------------------------------------------------------------- checks
def _as_sequence(value, name: str, *, allow_nan: bool) -> np.ndarray:
    arr = as_array(value, name, shape=(None, None, 3), allow_nan=allow_nan)
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name}: expected at least one frame and one marker, got shape "
                         f"{arr.shape}")
    return arr


def _observed(frames: np.ndarray) -> np.ndarray:
    return np.isfinite(frames).all(axis=2)


def min_observed_markers(n_basis: int) -> int:
    """Fewest observed markers a frame needs for :func:`fill_missing` with ``n_basis``
    vectors: three for the rigid alignment, and at least as many coordinates as unknowns
    (the weights and the six of the rigid motion), so that the least-squares problem is
    (over)determined (the thesis's condition)."""
    return max(3, -(-(int(n_basis) + 6) // 3))


# ---------------------------------------------------------------- the model fit
def _skew_rows(Y: np.ndarray) -> np.ndarray:
    """(m, 3) points -> (3m, 3) stacked matrices [y]_x (so [y]_x d = y x d)."""
    m = len(Y)
    S = np.zeros((m, 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -Y[:, 2], Y[:, 1]
    S[:, 1, 0], S[:, 1, 2] = Y[:, 2], -Y[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -Y[:, 1], Y[:, 0]
    return S.reshape(3 * m, 3)


def _rotvec_to_matrix(d: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(d)
    if th < 1e-300:
        return np.eye(3)
    k = d / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def _gauss_newton_step(Y: np.ndarray, Bo: np.ndarray, bounds=None, prior=None):
    """One linearised joint step for one frame: minimise over a small rotation ``d``, a
    translation ``tau`` and the weights ``w`` the norm of
    ``Y + d x Y + tau - Bo w`` (Y (m, 3) observed markers in the head frame, Bo (3m, K)),
    plus ``sum_k r_k (w_k - w0_k)^2`` for a ``prior`` (w0 (K,), r (K,)), with the weights
    within ``bounds`` (lower (K,), upper (K,)) if given.
    Returns d (3,), tau (3,), w (K,)."""
    m = len(Y)
    A = np.hstack([-_skew_rows(Y), np.tile(np.eye(3), (m, 1)), -Bo])
    rhs = -Y.ravel()
    # normal equations (tiny: K + 6 unknowns); einsum and Cholesky stay fast on a busy
    # machine where threaded LAPACK QR / lstsq of these sizes can stall for 0.5 s a call
    G = np.einsum("ij,ik->jk", A, A)
    g = np.einsum("ij,i->j", A, rhs)
    if prior is not None:
        w0, r = prior
        G[6:, 6:] += np.diag(r)
        g[6:] += r * w0
    try:
        L = np.linalg.cholesky(G)
    except np.linalg.LinAlgError:                  # dependent basis vectors: tiny ridge
        G = G + 1e-10 * np.trace(G) / len(G) * np.eye(len(G))
        L = np.linalg.cholesky(G)
    x = np.linalg.solve(L.T, np.linalg.solve(L, g))
    if bounds is not None and ((x[6:] < bounds[0]).any() or (x[6:] > bounds[1]).any()):
        lb = np.r_[np.full(6, -np.inf), bounds[0]]
        ub = np.r_[np.full(6, np.inf), bounds[1]]
        # min |A x - rhs| == min |L^T x - L^-1 A^T rhs| up to a constant (convex: the free
        # optimum, when inside the bounds, is the bounded one)
        x = lsq_linear(L.T, np.linalg.solve(L, g), bounds=(lb, ub), method="bvls").x
    return x[:3], x[3:6], x[6:]


def fill_missing(frames, basis, *, constrain: bool | None = None, reference=None,
                 n_iter: int = 10) -> FaceFit:
    """Fill the missing markers of a sequence from a basis-face model.

    For each frame: (1) the rigid motion carrying the observed markers onto the same
    markers of the reference shape is found (Kabsch, :func:`lsmta.rigid.fit_rigid`);
    (2) the weights ``w`` are fitted by least squares on the observed markers only,
    within ``[0, 1]`` when ``constrain`` (``scipy.optimize.lsq_linear``, bounded-variable
    least squares), together with a small correction of the rigid motion: each of up to
    ``n_iter`` Gauss-Newton passes solves one linear problem in a small rotation, a
    translation and the weights, so that alignment and weights end up jointly optimal
    (aligning once to the reference would bias the alignment whenever the expression
    differs from it); (3) the model face ``sum_i w_i B_i`` is predicted for every marker
    and carried back into the frame's coordinates.

    Parameters
    ----------
    frames : (T, M, 3) array
        Marker positions, mm; NaN for missing markers (a marker with any NaN coordinate is
        missing). Not modified.
    basis : (K, M, 3) array or FaceBasis
        Basis vectors, mm, finite, with the same M as ``frames``.
    constrain : bool, optional
        Constrain the weights to [0, 1] (the thesis's interpolation constraint). Default:
        True for an array, ``basis.constrain`` for a :class:`FaceBasis`.
    reference : (M, 3) array, optional
        Shape the observed markers are first aligned to. Default: ``basis.reference`` for a
        :class:`FaceBasis`, else the mean of the basis vectors (right for a basis of faces;
        pass the mean shape for a PCA basis).
    n_iter : int
        Most Gauss-Newton passes (>= 1); a frame stops early when the step vanishes.

    Returns
    -------
    FaceFit
        Frames with fewer observed markers than :func:`min_observed_markers` (including
        frames with none) are not fitted: their ``weights``, ``R``, ``t``, ``residual`` and
        ``model`` are NaN and their missing markers stay NaN; ``fitted`` marks them.

    Raises
    ------
    ValueError
        A basis with a different marker count from ``frames``, NaN or infinities in the
        basis or reference, infinities in ``frames``, ``n_iter < 1``.
    """
    if isinstance(basis, FaceBasis):
        if constrain is None:
            constrain = basis.constrain
        if reference is None:
            reference = basis.reference
        basis = basis.vectors
    constrain = True if constrain is None else bool(constrain)
    X = _as_sequence(frames, "frames", allow_nan=True)
    B = _as_sequence(basis, "basis", allow_nan=False)
    M = X.shape[1]
    if B.shape[1] != M:
        raise ValueError(f"basis: expected {M} markers like frames, got {B.shape[1]}")
    ref = B.mean(axis=0) if reference is None else as_array(reference, "reference",
                                                            shape=(M, 3))
    as_int(n_iter, "n_iter")
    K = len(B)
    bounds = (np.zeros(K), np.ones(K)) if constrain else None
    return fit_frames(X, B, ref, bounds=bounds, n_iter=int(n_iter))


def fit_frames(X, B, ref, *, n_iter: int, bounds=None, prior=None) -> FaceFit:
    """The fit of :func:`fill_missing` on checked arrays: frames ``X`` (T, M, 3), basis
    ``B`` (K, M, 3), reference ``ref`` (M, 3); weights within ``bounds`` (lower (K,),
    upper (K,)) if given; ``prior`` (w0 (K,), r (K,)) adds ``sum_k r_k (w_k - w0_k)^2`` to
    each frame's least squares (a Gaussian prior on the weights)."""
    T, M, _ = X.shape
    K = B.shape[0]
    obs = _observed(X)
    need = min_observed_markers(K)
    fitted = obs.sum(axis=1) >= need
    Bflat = B.reshape(K, M * 3).T                      # (3M, K)

    W = np.full((T, K), np.nan)
    Rs = np.full((T, 3, 3), np.nan)
    ts = np.full((T, 3), np.nan)
    resid = np.full(T, np.nan)
    model = np.full((T, M, 3), np.nan)
    for f in np.flatnonzero(fitted):
        o = obs[f]
        P = np.ascontiguousarray(X[f, o])               # observed markers, frame coords
        Bo = Bflat[np.repeat(o, 3)]                     # (3m, K)
        R, t = fit_rigid(P, np.ascontiguousarray(ref[o]))   # frame -> head frame
        for _ in range(n_iter):
            d, tau, w = _gauss_newton_step(P @ R.T + t, Bo, bounds, prior)
            dR = _rotvec_to_matrix(d)
            R, t = dR @ R, dR @ t + tau
            if np.linalg.norm(d) < 1e-12 and np.linalg.norm(tau) < 1e-9:
                break
        face = (Bflat @ w).reshape(M, 3)                # head frame
        # the rigid motion head frame -> frame is the inverse of (R, t)
        W[f], Rs[f], ts[f] = w, R.T, -R.T @ t
        model[f] = (face - t) @ R
        resid[f] = np.sqrt(np.mean(np.sum((model[f, o] - P) ** 2, axis=1)))
    out = X.copy()
    fill = ~obs & fitted[:, None]
    out[fill] = model[fill]
    return FaceFit(frames=out, model=model, weights=W, R=Rs, t=ts, residual=resid,
                   observed=obs, fitted=fitted)


# ---------------------------------------------------------------- building a basis
def align_sequence(frames, *, n_iter: int = 5):
    """Rigidly align every frame of a complete sequence to the sequence's mean shape
    (generalised Procrustes without scaling).

    Parameters
    ----------
    frames : (T, M, 3) array
        Complete marker positions, mm (no NaN). Not modified.
    n_iter : int
        Procrustes passes (mean re-estimated after each).

    Returns
    -------
    aligned : (T, M, 3) array
        Frames in the frame of the first frame's pose, mm.
    mean : (M, 3) array
        Mean of the aligned frames, mm.
    """
    X = _as_sequence(frames, "frames", allow_nan=False)
    if X.shape[1] < 3:
        raise ValueError(f"frames: expected at least 3 markers for a rigid alignment, "
                         f"got {X.shape[1]}")
    mean = X[0]
    aligned = X
    for _ in range(max(1, int(n_iter))):
        R, t = fit_rigid(X, np.broadcast_to(mean, X.shape))
        aligned = apply_rigid(R, t, X)
        mean = aligned.mean(axis=0)
    return aligned, mean


def _principal(aligned: np.ndarray, mean: np.ndarray):
    T, M, _ = aligned.shape
    D = (aligned - mean).reshape(T, M * 3)
    _, s, Vt = np.linalg.svd(D, full_matrices=False)
    var = s ** 2
    explained = var / var.sum() if var.sum() > 0 else np.zeros_like(var)
    return D, Vt, explained


def extreme_basis(training, n_basis: int) -> FaceBasis:
    """Basis faces picked from a training sequence along its principal components.

    The training frames are aligned rigidly to their mean; for each of the first
    ``n_basis`` principal components of the aligned shapes the frame with the largest
    absolute projection on it is taken as a basis face (the thesis's "measure of
    extremeness"). If that frame was already picked for an earlier component, the next
    most extreme frame not yet picked is taken, so the basis has ``n_basis`` distinct
    faces.

    Parameters
    ----------
    training : (T, M, 3) array
        Complete training sequence, mm (no NaN). Not modified.
    n_basis : int
        Number of basis faces K, ``1 <= K <= min(T, 3M)``.

    Returns
    -------
    FaceBasis
        ``kind="extremes"``, ``constrain=True``; vectors are aligned training frames.
    """
    aligned, mean = align_sequence(training)
    T, M, _ = aligned.shape
    K = int(n_basis)
    if K != n_basis or not 1 <= K <= min(T, 3 * M):
        raise ValueError(f"n_basis: expected an integer in [1, {min(T, 3 * M)}], got {n_basis}")
    D, Vt, explained = _principal(aligned, mean)
    proj = np.abs(D @ Vt[:K].T)                         # (T, K)
    picked: list[int] = []
    for k in range(K):
        for idx in np.argsort(-proj[:, k], kind="stable"):
            if idx not in picked:
                picked.append(int(idx))
                break
    idx = np.array(picked)
    return FaceBasis(vectors=aligned[idx].copy(), reference=mean, kind="extremes",
                     constrain=True, frames=idx, explained=explained[:K])


def pca_basis(training, n_components: int) -> FaceBasis:
    """Mean shape plus the first principal components of a training sequence.

    Parameters
    ----------
    training : (T, M, 3) array
        Complete training sequence, mm (no NaN). Not modified.
    n_components : int
        Number of principal components k, ``0 <= k <= min(T - 1, 3M)``.

    Returns
    -------
    FaceBasis
        ``kind="pca"``, ``constrain=False``; ``vectors[0]`` is the mean shape (mm) and
        ``vectors[1:]`` the unit principal directions, K = k + 1. With free weights the
        mean's weight is fitted too (eq. 6 as written); it comes out close to 1.
    """
    aligned, mean = align_sequence(training)
    T, M, _ = aligned.shape
    k = int(n_components)
    if k != n_components or not 0 <= k <= min(T - 1, 3 * M):
        raise ValueError(f"n_components: expected an integer in [0, {min(T - 1, 3 * M)}], "
                         f"got {n_components}")
    _, Vt, explained = _principal(aligned, mean)
    vectors = np.concatenate([mean[None], Vt[:k].reshape(k, M, 3)], axis=0)
    return FaceBasis(vectors=vectors, reference=mean, kind="pca", constrain=False,
                     frames=np.full(k + 1, -1), explained=explained[:k])


# ---------------------------------------------------------------- accuracy measure
def distance_deviation(frames, pairs):
    """Deviation of marker-pair distances from their mean over the sequence (Fig. 64).

    Parameters
    ----------
    frames : (T, M, 3) array
        Marker positions, mm; NaN where missing. Not modified.
    pairs : (P, 2) int array
        Marker index pairs whose separation should stay constant.

    Returns
    -------
    (T, P) array
        ``d_tp - mean_t d_tp``, mm (the mean over the frames where both are observed is
        the "neutral pose"); NaN where either marker is missing.
    """
    X = _as_sequence(frames, "frames", allow_nan=True)
    P = np.asarray(pairs)
    if P.ndim != 2 or P.shape[1] != 2 or not np.issubdtype(P.dtype, np.integer):
        raise ValueError(f"pairs: expected an integer array of shape (P, 2), got "
                         f"{P.shape} {P.dtype}")
    if P.size and (P.min() < 0 or P.max() >= X.shape[1]):
        raise ValueError(f"pairs: indices must lie in [0, {X.shape[1] - 1}]")
    d = np.linalg.norm(X[:, P[:, 0]] - X[:, P[:, 1]], axis=2)
    ok = np.isfinite(d)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, np.where(ok, d, 0.0).sum(axis=0) / n, np.nan)
    return d - mean
