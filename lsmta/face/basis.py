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
def fill_missing(frames, basis, *, constrain: bool | None = None, reference=None,
                 n_iter: int = 10) -> FaceFit:
    """Fill the missing markers of a sequence from a basis-face model.

    For each frame: (1) the rigid motion carrying the observed markers onto the same
    markers of the reference shape is found (Kabsch, :func:`lsmta.rigid.fit_rigid`);
    (2) the weights ``w`` are fitted by least squares on the observed markers only,
    within ``[0, 1]`` when ``constrain`` (bounded least squares: block principal pivoting
    on the normal equations, ``scipy.optimize.lsq_linear`` for a frame where that does not
    settle), together with a small correction of the rigid motion: each of up to
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


def _masked_kabsch(P, Q, w):
    """Rigid motions carrying ``P`` (n, M, 3) onto ``Q`` (M, 3) on the markers with weight
    ``w`` (n, M) 1 (0: left out), all frames at once: R (n, 3, 3), t (n, 3) with
    ``Q ≈ P @ R.T + t`` (the fit of :func:`lsmta.rigid.fit_rigid` on each frame's markers)."""
    n_obs = w.sum(axis=1)[:, None]
    pc = np.einsum("nm,nmi->ni", w, P) / n_obs
    qc = w @ Q / n_obs
    H = np.einsum("nm,nmi,nmj->nij", w, P - pc[:, None], Q[None] - qc[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    flip = np.linalg.det(V @ np.swapaxes(U, 1, 2)) < 0
    V[flip, :, 2] *= -1
    R = V @ np.swapaxes(U, 1, 2)
    return R, qc - np.einsum("nij,nj->ni", R, pc)


def _rotvecs_to_matrices(d):
    """(n, 3) rotation vectors -> (n, 3, 3) matrices (Rodrigues)."""
    th = np.linalg.norm(d, axis=1)
    k = d / np.where(th > 1e-300, th, 1.0)[:, None]
    Kx = np.zeros((len(d), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx = Kx - np.swapaxes(Kx, 1, 2)
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    return np.eye(3) + s * Kx + c * Kx @ Kx


def _normal_equations(Y, obs, B2, BB):
    """The normal equations ``G x = g`` of one linearised joint step (a Gauss-Newton pass of
    :func:`fill_missing`) for n frames at once, ``x = (d, tau, w)``: minimise over a
    small rotation ``d``, a translation ``tau`` and the weights ``w`` the norm of
    ``y + d x y + tau - B w`` over each frame's observed markers. ``Y`` (n, M, 3) markers in
    the head frame, ``obs`` (n, M) which are observed, ``B2`` (M, 3, K) the basis per marker,
    ``BB`` (M, K * K) each marker's ``B_m^T B_m``. Returns G (n, K + 6, K + 6), g (n, K + 6).

    Block by block (``[y]_x`` the cross-product matrix of y, sums over observed markers):
    ``G_dd = sum(|y|² I - y y^T)``, ``G_dt = [sum y]_x``, ``G_dw = sum [y]_x^T B_m``
    (column k: ``sum B_mk x y``), ``G_tt = m I``, ``G_tw = -sum B_m``,
    ``G_ww = sum B_m^T B_m``; ``g = (0, -sum y, sum B_m^T y)``."""
    n, M, _ = Y.shape
    K = B2.shape[2]
    o = obs.astype(float)
    Yo = Y * o[..., None]
    G = np.empty((n, K + 6, K + 6))
    G[:, :3, :3] = np.einsum("nm,nmi,nmj->nij", -o, Y, Y)
    G[:, [0, 1, 2], [0, 1, 2]] += np.einsum("nmi,nmi->n", Yo, Y)[:, None]
    s = Yo.sum(axis=1)
    Sx = np.zeros((n, 3, 3))
    Sx[:, 0, 1], Sx[:, 0, 2], Sx[:, 1, 2] = -s[:, 2], s[:, 1], -s[:, 0]
    Sx -= np.swapaxes(Sx, 1, 2)
    G[:, :3, 3:6] = Sx
    G[:, :3, 6:] = np.stack([Yo[..., 2] @ B2[:, 1] - Yo[..., 1] @ B2[:, 2],
                             Yo[..., 0] @ B2[:, 2] - Yo[..., 2] @ B2[:, 0],
                             Yo[..., 1] @ B2[:, 0] - Yo[..., 0] @ B2[:, 1]], axis=1)
    G[:, 3:6, 3:6] = o.sum(axis=1)[:, None, None] * np.eye(3)
    G[:, 3:6, 6:] = -(o @ B2.reshape(M, 3 * K)).reshape(n, 3, K)
    G[:, 6:, 6:] = (o @ BB).reshape(n, K, K)
    G[:, 3:, :3] = np.swapaxes(G[:, :3, 3:], 1, 2)
    G[:, 6:, 3:6] = np.swapaxes(G[:, 3:6, 6:], 1, 2)
    g = np.zeros((n, K + 6))
    g[:, 3:6] = -s
    g[:, 6:] = Yo.reshape(n, 3 * M) @ B2.reshape(3 * M, K)
    return G, g


def _box_qp(G, g, lb, ub, x, *, max_iter: int = 30):
    """``min 0.5 x^T G x - g^T x`` within ``lb <= x <= ub`` for n frames at once (G (n, p, p)
    positive definite, g (n, p), lb and ub (p,), ``x`` (n, p) the unbounded minima), by
    block principal pivoting: the variables out of their bounds are fixed there and the rest
    solved again; a fixed variable whose gradient points inside is released. Returns the
    minima (n, p) and which frames met the optimality conditions (n,) bool (the others are
    left to a one-frame solver)."""
    x = x.copy()
    at_lo, at_hi = x < lb, x > ub
    done = np.zeros(len(g), bool)
    left = np.arange(len(g))                       # frames not yet optimal
    eye = np.eye(g.shape[1])
    tol = 1e-10 * (np.abs(g).max(axis=1) + 1.0)
    for _ in range(max_iter):
        lo, hi = at_lo[left], at_hi[left]
        free = ~(lo | hi)
        xf = np.where(lo, lb, np.where(hi, ub, 0.0))
        Gl = G[left]
        Gf = Gl * (free[:, :, None] & free[:, None, :]) + eye * ~free[:, :, None]
        rhs = np.where(free, g[left] - np.einsum("nij,nj->ni", Gl, xf), xf)
        x[left] = np.linalg.solve(Gf, rhs[..., None])[..., 0]
        grad = np.einsum("nij,nj->ni", Gl, x[left]) - g[left]
        low, high = free & (x[left] < lb), free & (x[left] > ub)
        t = tol[left, None]
        release = (lo & (grad < -t)) | (hi & (grad > t))
        ok = ~(low | high | release).any(axis=1)
        done[left[ok]] = True
        at_lo[left] = (lo & ~release) | low
        at_hi[left] = (hi & ~release) | high
        left = left[~ok]
        if not len(left):
            break
    return np.clip(x, lb, ub), done


def _steps(Y, obs, B2, BB, bounds, prior):
    """One linearised joint step (see :func:`_normal_equations`) for each of n frames at
    once, with the ``prior`` (w0 (K,), r (K,)) and the ``bounds`` (lower (K,), upper (K,))
    of the weights if given. Returns d (n, 3), tau (n, 3), w (n, K)."""
    G, g = _normal_equations(Y, obs, B2, BB)
    if prior is not None:
        w0, r = prior
        G[:, 6:, 6:] += np.diag(r)
        g[:, 6:] += r * w0
    try:
        x = np.linalg.solve(G, g[..., None])[..., 0]
    except np.linalg.LinAlgError:                  # one at a time: a tiny ridge where needed
        x = np.empty_like(g)
        for f in range(len(G)):
            try:
                x[f] = np.linalg.solve(G[f], g[f])
            except np.linalg.LinAlgError:          # dependent basis vectors
                G[f] += 1e-10 * np.trace(G[f]) / len(G[f]) * np.eye(len(G[f]))
                x[f] = np.linalg.solve(G[f], g[f])
    if bounds is not None:
        lb = np.r_[np.full(6, -np.inf), bounds[0]]
        ub = np.r_[np.full(6, np.inf), bounds[1]]
        out = ((x < lb) | (x > ub)).any(axis=1)
        if out.any():
            x[out], done = _box_qp(G[out], g[out], lb, ub, x[out])
            for f in np.flatnonzero(out)[~done]:
                # min |A x - rhs| == min |L^T x - L^-1 A^T rhs| up to a constant
                L = np.linalg.cholesky(G[f])
                x[f] = lsq_linear(L.T, np.linalg.solve(L, g[f]), bounds=(lb, ub),
                                  method="bvls").x
    return x[:, :3], x[:, 3:6], x[:, 6:]


#: frames fitted together: (frames, K + 6, K + 6) numbers of normal equations in memory
_BATCH_NUMBERS = 4_000_000


def fit_frames(X, B, ref, *, n_iter: int, bounds=None, prior=None) -> FaceFit:
    """The fit of :func:`fill_missing` on checked arrays: frames ``X`` (T, M, 3), basis
    ``B`` (K, M, 3), reference ``ref`` (M, 3); weights within ``bounds`` (lower (K,),
    upper (K,)) if given; ``prior`` (w0 (K,), r (K,)) adds ``sum_k r_k (w_k - w0_k)^2`` to
    each frame's least squares (a Gaussian prior on the weights).

    All frames are fitted at once (batched normal equations, in chunks of frames); a frame
    whose weights leave the bounds is solved on its own by bounded-variable least squares;
    a frame stops when its step vanishes."""
    T, M, _ = X.shape
    K = B.shape[0]
    obs = _observed(X)
    need = min_observed_markers(K)
    fitted = obs.sum(axis=1) >= need
    Bflat = B.reshape(K, M * 3).T                      # (3M, K)
    B2 = np.ascontiguousarray(np.moveaxis(B, 0, -1))   # (M, 3, K)
    BB = np.einsum("mik,mil->mkl", B2, B2).reshape(M, K * K)

    W = np.full((T, K), np.nan)
    Rs = np.full((T, 3, 3), np.nan)
    ts = np.full((T, 3), np.nan)
    resid = np.full(T, np.nan)
    model = np.full((T, M, 3), np.nan)
    todo = np.flatnonzero(fitted)
    chunk = max(1, _BATCH_NUMBERS // (K + 6) ** 2)
    for c in range(0, len(todo), chunk):
        idx = todo[c:c + chunk]
        o = obs[idx]
        P = np.where(o[..., None], X[idx], 0.0)        # observed markers, frame coords
        R, t = _masked_kabsch(P, ref, o.astype(float))  # frame -> head frame
        w = np.zeros((len(idx), K))
        active = np.arange(len(idx))
        for _ in range(n_iter):
            Y = np.einsum("nij,nmj->nmi", R[active], P[active]) + t[active, None]
            d, tau, w[active] = _steps(Y, o[active], B2, BB, bounds, prior)
            dR = _rotvecs_to_matrices(d)
            R[active] = dR @ R[active]
            t[active] = np.einsum("nij,nj->ni", dR, t[active]) + tau
            moving = (np.linalg.norm(d, axis=1) >= 1e-12) | (np.linalg.norm(tau, axis=1) >= 1e-9)
            active = active[moving]
            if not len(active):
                break
        face = (w @ Bflat.T).reshape(len(idx), M, 3)   # head frame
        # the rigid motion head frame -> frame is the inverse of (R, t)
        W[idx], Rs[idx] = w, np.swapaxes(R, 1, 2)
        ts[idx] = -np.einsum("nji,nj->ni", R, t)
        model[idx] = np.einsum("nmj,nji->nmi", face - t[:, None], R)
        sq = np.where(o, np.sum((model[idx] - X[idx]) ** 2, axis=2), 0.0)
        resid[idx] = np.sqrt(sq.sum(axis=1) / o.sum(axis=1))
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
