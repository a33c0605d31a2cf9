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
    pc = (w[:, None, :] @ P)[:, 0] / n_obs
    qc = w @ Q / n_obs
    H = np.swapaxes((P - pc[:, None]) * w[..., None], 1, 2) @ (Q[None] - qc[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    flip = np.linalg.det(V @ np.swapaxes(U, 1, 2)) < 0
    V[flip, :, 2] *= -1
    R = V @ np.swapaxes(U, 1, 2)
    return R, qc - (R @ pc[..., None])[..., 0]


def _rotvecs_to_matrices(d):
    """(n, 3) rotation vectors -> (n, 3, 3) matrices (Rodrigues)."""
    th = np.linalg.norm(d, axis=1)
    k = d / np.where(th > 1e-300, th, 1.0)[:, None]
    Kx = np.zeros((len(d), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx = Kx - np.swapaxes(Kx, 1, 2)
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    return np.eye(3) + s * Kx + c * Kx @ Kx


@dataclass(frozen=True)
class _WeightBlock:
    """The part of the normal equations of a Gauss-Newton pass that does not change between
    passes (it depends on which markers are observed, not on the pose), for n frames:
    ``H = sum B_m^T B_m`` over the observed markers (plus the prior's penalties; a weight a
    frame does not use has H = 1 and nothing else), its inverse, ``G_tw = -sum B_m``, the
    observed count, the prior's right-hand side and which weights each frame fits."""

    H: np.ndarray           # (n, K, K)
    Hinv: np.ndarray        # (n, K, K)
    Gtw: np.ndarray         # (n, 3, K)
    count: np.ndarray       # (n,)
    gw0: np.ndarray         # (n, K)
    keep: np.ndarray        # (n, K) bool


def _weight_block(obs, B2, BB, prior, used) -> _WeightBlock:
    n, M = obs.shape
    K = B2.shape[2]
    o = obs.astype(float)
    H = (o @ BB).reshape(n, K, K)
    gw0 = np.zeros((n, K))
    if prior is not None:
        w0, r = prior
        H += np.diag(r)
        gw0 += r * w0
    keep = np.arange(K) < used[:, None]
    Gtw = -(o @ B2.reshape(M, 3 * K)).reshape(n, 3, K)
    if not keep.all():                                 # the others: w = 0
        H *= keep[:, :, None] & keep[:, None, :]
        H[:, np.arange(K), np.arange(K)] += ~keep
        Gtw *= keep[:, None, :]
        gw0 *= keep
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:                      # one at a time: a tiny ridge if needed
        Hinv = np.empty_like(H)
        for f in range(n):
            try:
                Hinv[f] = np.linalg.inv(H[f])
            except np.linalg.LinAlgError:              # dependent basis vectors
                H[f] += 1e-10 * (np.trace(H[f]) + 2 * o[f].sum()) / (K + 6) * np.eye(K)
                Hinv[f] = np.linalg.inv(H[f])
    return _WeightBlock(H=H, Hinv=Hinv, Gtw=Gtw, count=o.sum(axis=1), gw0=gw0, keep=keep)


def _pose_blocks(Y, obs, B2, keep):
    """The parts of the normal equations that change with the pose, for n frames (``Y``
    (n, M, 3) markers in the head frame, sums over the observed markers, ``[y]_x`` the
    cross-product matrix): ``G_dd = sum(|y|² I - y y^T)``, ``G_dt = [sum y]_x``,
    ``G_dw = sum [y]_x^T B_m`` (column k: ``sum B_mk x y``); right-hand sides
    ``g_t = -sum y``, ``g_w = sum B_m^T y``."""
    n, M, _ = Y.shape
    K = B2.shape[2]
    Yo = Y * obs[..., None]
    Gdd = -np.swapaxes(Yo, 1, 2) @ Y
    Gdd[:, [0, 1, 2], [0, 1, 2]] += (Yo * Y).sum(axis=(1, 2))[:, None]
    sy = Yo.sum(axis=1)
    Gdt = np.zeros((n, 3, 3))
    Gdt[:, 0, 1], Gdt[:, 0, 2], Gdt[:, 1, 2] = -sy[:, 2], sy[:, 1], -sy[:, 0]
    Gdt -= np.swapaxes(Gdt, 1, 2)
    Gdw = np.stack([Yo[..., 2] @ B2[:, 1] - Yo[..., 1] @ B2[:, 2],
                    Yo[..., 0] @ B2[:, 2] - Yo[..., 2] @ B2[:, 0],
                    Yo[..., 1] @ B2[:, 0] - Yo[..., 0] @ B2[:, 1]], axis=1) * keep[:, None]
    gw = (Yo.reshape(n, 3 * M) @ B2.reshape(3 * M, K)) * keep
    return Gdd, Gdt, Gdw, -sy, gw


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
        rhs = np.where(free, g[left] - (Gl @ xf[..., None])[..., 0], xf)
        x[left] = np.linalg.solve(Gf, rhs[..., None])[..., 0]
        grad = (Gl @ x[left][..., None])[..., 0] - g[left]
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


def _steps(Y, obs, B2, wb: _WeightBlock, bounds):
    """One linearised joint step of :func:`fill_missing` for n frames at once: minimise
    over a small rotation ``d``, a translation ``tau`` and the weights ``w`` the norm of
    ``y + d x y + tau - B w`` over each frame's observed markers (plus the prior in ``wb``),
    with the weights within ``bounds`` (lower (K,), upper (K,)) if given. The normal
    equations ``[[A, C], [C^T, H]] (r, w) = (g_r, g_w)``, r = (d, tau), are solved through
    the Schur complement on the six pose unknowns (``H^-1`` is fixed between passes); frames
    whose weights leave the bounds are solved again on the whole system (:func:`_box_qp`,
    or bounded-variable least squares where that does not settle).
    Returns d (n, 3), tau (n, 3), w (n, K)."""
    n = len(Y)
    K = B2.shape[2]
    Gdd, Gdt, Gdw, gt, gw = _pose_blocks(Y, obs, B2, wb.keep)
    A = np.empty((n, 6, 6))
    A[:, :3, :3], A[:, :3, 3:] = Gdd, Gdt
    A[:, 3:, :3] = np.swapaxes(Gdt, 1, 2)
    A[:, 3:, 3:] = wb.count[:, None, None] * np.eye(3)
    C = np.concatenate([Gdw, wb.Gtw], axis=1)                   # (n, 6, K)
    g_r = np.concatenate([np.zeros((n, 3)), gt], axis=1)
    g_w = gw + wb.gw0
    HC = wb.Hinv @ np.swapaxes(C, 1, 2)                         # (n, K, 6)
    Hg = wb.Hinv @ g_w[..., None]                               # (n, K, 1)
    r = np.linalg.solve(A - C @ HC, g_r[..., None] - C @ Hg)    # (n, 6, 1)
    x = np.concatenate([r, Hg - HC @ r], axis=1)[..., 0]
    if bounds is not None:
        lb = np.r_[np.full(6, -np.inf), bounds[0]]
        ub = np.r_[np.full(6, np.inf), bounds[1]]
        out = np.flatnonzero(((x < lb) | (x > ub)).any(axis=1))
        if len(out):
            G = np.empty((len(out), K + 6, K + 6))
            G[:, :6, :6], G[:, :6, 6:] = A[out], C[out]
            G[:, 6:, :6], G[:, 6:, 6:] = np.swapaxes(C[out], 1, 2), wb.H[out]
            g = np.concatenate([g_r[out], g_w[out]], axis=1)
            x[out], done = _box_qp(G, g, lb, ub, x[out])
            for i in np.flatnonzero(~done):
                # min |A x - rhs| == min |L^T x - L^-1 A^T rhs| up to a constant
                L = np.linalg.cholesky(G[i])
                x[out[i]] = lsq_linear(L.T, np.linalg.solve(L, g[i]), bounds=(lb, ub),
                                       method="bvls").x
    return x[:, :3], x[:, 3:6], x[:, 6:]


def _take(wb: _WeightBlock, rows) -> _WeightBlock:
    return _WeightBlock(**{k: v[rows] for k, v in vars(wb).items()})


#: frames fitted together: (frames, K + 6, K + 6) numbers of normal equations in memory
_BATCH_NUMBERS = 4_000_000


def fit_frames(X, B, ref, *, n_iter: int, bounds=None, prior=None, used=None) -> FaceFit:
    """The fit of :func:`fill_missing` on checked arrays: frames ``X`` (T, M, 3), basis
    ``B`` (K, M, 3), reference ``ref`` (M, 3); weights within ``bounds`` (lower (K,),
    upper (K,)) if given; ``prior`` (w0 (K,), r (K,)) adds ``sum_k r_k (w_k - w0_k)^2`` to
    each frame's least squares (a Gaussian prior on the weights). ``used`` (T,) int: frame
    t is fitted with the first ``used[t]`` basis vectors only (nested bases fitted in one
    batch, as cross-validation does; default: all K).

    All frames are fitted at once (batched normal equations, in chunks of frames); frames
    whose weights leave the bounds are solved again by block principal pivoting (by
    bounded-variable least squares, one at a time, where that does not settle); a frame
    stops when its step vanishes."""
    T, M, _ = X.shape
    K = B.shape[0]
    obs = _observed(X)
    used = np.full(T, K) if used is None else np.asarray(used, dtype=int)
    fitted = obs.sum(axis=1) >= np.maximum(3, -(-(used + 6) // 3))   # min_observed_markers
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
        wb = _weight_block(o, B2, BB, prior, used[idx])
        w = np.zeros((len(idx), K))
        active = np.arange(len(idx))
        wb_active = wb
        for _ in range(n_iter):
            Y = P[active] @ np.swapaxes(R[active], 1, 2) + t[active, None]
            d, tau, w[active] = _steps(Y, o[active], B2, wb_active, bounds)
            dR = _rotvecs_to_matrices(d)
            R[active] = dR @ R[active]
            t[active] = (dR @ t[active][..., None])[..., 0] + tau
            moving = (np.linalg.norm(d, axis=1) >= 1e-12) | (np.linalg.norm(tau, axis=1) >= 1e-9)
            if not moving.all():
                active = active[moving]
                wb_active = _take(wb, active)
            if not len(active):
                break
        face = (w @ Bflat.T).reshape(len(idx), M, 3)   # head frame
        # the rigid motion head frame -> frame is the inverse of (R, t)
        W[idx], Rs[idx] = w, np.swapaxes(R, 1, 2)
        ts[idx] = -(np.swapaxes(R, 1, 2) @ t[..., None])[..., 0]
        model[idx] = (face - t[:, None]) @ R
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
    return _extremes_from(aligned, mean, D, Vt, explained, K)


def _extremes_from(aligned, mean, D, Vt, explained, K: int) -> FaceBasis:
    """:func:`extreme_basis` from the aligned training frames, their mean and principal
    decomposition (:func:`_principal`)."""
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
    return _pca_from(mean, Vt, explained, k)


def _pca_from(mean, Vt, explained, k: int) -> FaceBasis:
    """:func:`pca_basis` from the training mean (M, 3) and principal decomposition
    (:func:`_principal`)."""
    M = len(mean)
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
