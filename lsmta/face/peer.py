"""The peer from biomechanics: missing markers from marker intercorrelations (PCA gap
filling; Federolf 2013, Gløersen & Federolf 2016).

All marker coordinates of a frame form one vector; the principal components of complete
frames describe how the coordinates co-vary, and a frame's missing coordinates are read
off the components fitted to its observed ones. Two versions:

* ``weighting="none"``: the reconstruction core (Federolf 2013): columns centred and scaled
  to unit standard deviation, the component scores fitted to a frame's observed coordinates
  by least squares;
* ``weighting="distance"``: the full method of Gløersen & Federolf (2016), as their
  published code ``PredictMissingMarkers`` does it (strategy R1, applied to each pattern of
  missing markers): each frame is first moved by the centroid of its observed markers (a
  coordinate system that moves with the subject); every marker's columns are weighted by
  ``exp(-d² / (2 σ²))``, d its mean distance from the nearest missing marker (σ = 200 mm),
  and the missing markers' own columns by 0.02; a PCA of the complete frames and a PCA of
  the same frames with the missing columns zeroed are related by ``T = V_full^T V_zero``,
  and the gap frame (missing columns zeroed) is reconstructed as
  ``x V_zero T V_full^T``, then un-weighted and un-normalised. Components are kept until
  their singular values sum to ``variance`` of the total, as in the authors' code.

Neither version aligns a frame rigidly; :func:`lsmta.evaluation.face.peer_after_alignment`
gives the peer the same per-frame rigid alignment as the basis-face fits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_int, as_scalar
from .basis import _as_sequence, _observed


@dataclass(frozen=True)
class GapFill:
    """Result of :func:`pca_gap_fill`.

    Attributes
    ----------
    frames : (T, M, 3) array
        The input with its missing markers filled, mm (observed markers unchanged;
        frames that could not be filled keep their NaN).
    n_components : int
        Principal components used (for ``weighting="distance"``, the most used for any
        pattern of missing markers).
    observed : (T, M) bool array
    fitted : (T,) bool array
        Frames that were filled (or needed no filling).
    """

    frames: np.ndarray
    n_components: int
    observed: np.ndarray
    fitted: np.ndarray


def _complete_frames(X, training):
    """Complete frames of ``X`` and ``training`` (S, M, 3), checked."""
    M = X.shape[1]
    pool = [X]
    if training is not None:
        Y = _as_sequence(training, "training", allow_nan=True)
        if Y.shape[1] != M:
            raise ValueError(f"training: expected {M} markers like frames, got {Y.shape[1]}")
        pool.append(Y)
    allf = np.concatenate(pool, axis=0)
    complete = allf[_observed(allf).all(axis=1)]
    if len(complete) < 2:
        raise ValueError("frames, training: need at least two complete frames to learn the "
                         "marker intercorrelations from")
    return complete


def _n_kept(values, share: float) -> int:
    """Fewest leading ``values`` whose sum reaches ``share`` of their total."""
    total = max(values.sum(), 1e-300)
    return int(np.searchsorted(np.cumsum(values) / total, share - 1e-12) + 1)


def pca_gap_fill(frames, *, training=None, n_components: int | None = None,
                 variance: float = 0.99, scale: str = "std", weighting: str = "distance",
                 sigma: float = 200.0, missing_weight: float = 0.02) -> GapFill:
    """Fill missing markers from marker intercorrelations (see the module docstring).

    Parameters
    ----------
    frames : (T, M, 3) array
        Marker positions with NaN gaps, mm. Not modified.
    training : (S, M, 3) array, optional
        Further frames to learn the intercorrelations from, mm; only its complete frames
        (and those of ``frames``) are used.
    n_components : int, optional
        Components to use; default: the fewest reaching ``variance``. Capped per frame at
        the number of observed coordinates.
    variance : float
        In (0, 1]: the share of the variance (``weighting="none"``) or of the sum of
        singular values (``"distance"``, as the authors' code) the kept components reach.
    scale : {"std", "none"}
        ``weighting="none"`` only: divide each centred column by its standard deviation
        (as the cited papers do) or leave it in mm.
    weighting : {"distance", "none"}
        The full method of Gløersen & Federolf (2016), or the 2013 reconstruction core.
    sigma : float
        Width of the distance weighting, mm (authors' default 200).
    missing_weight : float
        Weight of the missing markers' own columns (authors' default 0.02).

    Returns
    -------
    GapFill

    Raises
    ------
    ValueError
        No complete frame to learn from, wrong shapes, infinities, bad settings.
    """
    X = _as_sequence(frames, "frames", allow_nan=True)
    complete = _complete_frames(X, training)
    if not 0 < variance <= 1:
        raise ValueError(f"variance: expected a number in (0, 1], got {variance}")
    as_int(n_components, "n_components", allow_none=True)
    if scale not in ("std", "none"):
        raise ValueError(f"scale: expected 'std' or 'none', got {scale!r}")
    if weighting == "none":
        return _core(X, complete, n_components, variance, scale)
    if weighting != "distance":
        raise ValueError(f"weighting: expected 'distance' or 'none', got {weighting!r}")
    sigma = as_scalar(sigma, "sigma", positive=True)
    missing_weight = as_scalar(missing_weight, "missing_weight", positive=True)
    return _weighted(X, complete, n_components, variance, sigma, missing_weight)


def _core(X, complete, n_components, variance, scale) -> GapFill:
    """Federolf's reconstruction core: scores fitted to the observed coordinates."""
    T, M, _ = X.shape
    C = complete.reshape(len(complete), 3 * M)
    mu = C.mean(axis=0)
    sd = C.std(axis=0) if scale == "std" else np.ones(3 * M)
    sd[sd < 1e-9] = 1.0
    _, s, Vt = np.linalg.svd((C - mu) / sd, full_matrices=False)
    k = _n_kept(s ** 2, variance) if n_components is None else int(n_components)
    k = min(k, Vt.shape[0])
    V = Vt[:k].T                                        # (3M, k)
    obs = _observed(X)
    out = X.copy()
    fitted = obs.all(axis=1).copy()
    flat = X.reshape(T, 3 * M)
    for f in np.flatnonzero(~obs.all(axis=1) & obs.any(axis=1)):
        cols = np.repeat(obs[f], 3)
        kk = min(k, int(cols.sum()))
        z = (flat[f, cols] - mu[cols]) / sd[cols]
        Vo = V[cols, :kk]
        try:
            c = np.linalg.solve(np.einsum("ij,ik->jk", Vo, Vo), np.einsum("ij,i->j", Vo, z))
        except np.linalg.LinAlgError:              # observed rows do not span kk scores
            c = np.linalg.lstsq(Vo, z, rcond=None)[0]
        full = (V[:, :kk] @ c) * sd + mu
        out[f, ~obs[f]] = full.reshape(M, 3)[~obs[f]]
        fitted[f] = True
    return GapFill(frames=out, n_components=k, observed=obs, fitted=fitted)


def _top(cov, k=None):
    """Eigenvectors (columns) and square-rooted eigenvalues of a symmetric matrix, largest
    first (the right singular vectors and singular values of the data behind it)."""
    ev, V = np.linalg.eigh(cov)
    return V[:, ::-1], np.sqrt(np.maximum(ev[::-1], 0.0))


def _weighted(X, complete, n_components, variance, sigma, missing_weight) -> GapFill:
    """Gløersen & Federolf (2016), strategy R1 per pattern of missing markers. The two PCAs
    come from one covariance of the complete frames, carried to each pattern's moving
    coordinates, normalisation and weights (the same components as an SVD of the
    normalised frames, at the cost of a 3M x 3M eigendecomposition)."""
    T, M, _ = X.shape
    obs = _observed(X)
    out = X.copy()
    fitted = obs.all(axis=1).copy()
    dist = np.linalg.norm(complete[:, :, None] - complete[:, None], axis=-1).mean(axis=0)
    C = complete.reshape(len(complete), 3 * M)
    mu_x = C.mean(axis=0)
    cov_x = (C - mu_x).T @ (C - mu_x) / len(C)
    todo = ~obs.all(axis=1) & (obs.sum(axis=1) >= 1)
    patterns, which = np.unique(obs[todo], axis=0, return_inverse=True)
    frames_todo = np.flatnonzero(todo)
    most = 0
    for p, seen in enumerate(patterns):
        rows = frames_todo[which.ravel() == p]
        miss = ~seen
        cols = np.repeat(miss, 3)
        # a coordinate system moving with the subject: minus the observed markers' centroid
        A = np.eye(3 * M) - np.kron(np.outer(np.ones(M), seen / seen.sum()), np.eye(3))
        mu = A @ mu_x
        cov = A @ cov_x @ A.T
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        sd[sd < 1e-9] = 1.0
        w = np.exp(-dist[miss].min(axis=0) ** 2 / (2 * sigma ** 2))
        w[miss] = missing_weight
        w3 = np.repeat(w, 3)
        d = w3 / sd
        cov_z = cov * np.outer(d, d)                       # the weighted, normalised frames
        cov_zz = np.where(cols[:, None] | cols[None], 0.0, cov_z)   # ... missing columns zeroed
        mz = np.where(cols, 0.0, mu)
        G = X[rows] - X[rows][:, seen].mean(axis=1, keepdims=True)
        Gz = (np.where(cols, 0.0, G.reshape(len(rows), 3 * M)) - mz) * d
        V_full, s_full = _top(cov_z)
        V_zero, s_zero = _top(cov_zz)
        k = max(_n_kept(s_full, variance), _n_kept(s_zero, variance)) \
            if n_components is None else int(n_components)
        k = min(k, len(C), 3 * M, 3 * int(seen.sum()))
        most = max(most, k)
        Vf, Vz = V_full[:, :k], V_zero[:, :k]
        R = Gz @ Vz @ (Vf.T @ Vz) @ Vf.T
        filled = (mu + R / d).reshape(len(rows), M, 3)
        filled += X[rows][:, seen].mean(axis=1, keepdims=True)
        out[np.ix_(rows, np.flatnonzero(miss))] = filled[:, miss]
        fitted[rows] = True
    return GapFill(frames=out, n_components=most, observed=obs, fitted=fitted)
