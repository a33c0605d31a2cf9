"""Measuring and tracking the bright targets of a reference bar in image sequences.

Each frame is thresholded at ``background + k * noise`` (median and MAD of the image),
bright connected regions (:func:`scipy.ndimage.label`) give a grey-value
weighted centroid, and the centroid is refined by fitting a 2-D Gaussian blob with a
constant background (five parameters: centre, width, amplitude, background) to the
pixels around it by Gauss-Newton, vectorised over all blobs of the sequence. The fit's own
residuals give each centre's precision, ``s0² (JᵀJ)⁻¹`` (``s0`` the residual RMS: the
image noise around the blob), with no ground truth. Targets are then tracked from frame
to frame: the first frame's targets are labelled left to right (image x), and each later
frame's blobs are assigned to the constant-velocity predictions by the Hungarian method
(:func:`scipy.optimize.linear_sum_assignment`) within a gate. A target that has left the
image and comes back far from where it was lost takes one of the frame's remaining
strongest blobs. Which end of a bar is which may then differ between cameras:
:func:`~lsmta.calibration.labels.consistent_bar_labels` settles that geometrically.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from .._validate import as_int, as_scalar


class TargetStatus(enum.IntEnum):
    """What was measured for a target in a frame."""

    OK = 0             #: a blob, located by the Gaussian fit
    LOST = 1           #: no blob within the gate
    NOT_CONVERGED = 2  #: the Gaussian fit failed; the weighted centroid is kept


@dataclass(frozen=True)
class Blobs:
    """Bright blobs of one frame.

    Attributes
    ----------
    xy : (n, 2) array
        Refined centres, px.
    centroid : (n, 2) array
        Weighted centroids, px.
    sigma, amplitude : (n,) arrays
        Fitted Gaussian width (px) and peak above background (grey levels).
    converged : (n,) bool array
    std : (n,) array
        Standard deviation of a coordinate of the refined centre, px, from the fit:
        ``sqrt((var_x + var_y) / 2)`` of ``s0² (JᵀJ)⁻¹`` (NaN where not converged).
    noise : (n,) array
        The fit's residual RMS ``s0``, grey levels: the image noise around the blob.
    """

    xy: np.ndarray
    centroid: np.ndarray
    sigma: np.ndarray
    amplitude: np.ndarray
    converged: np.ndarray
    std: np.ndarray
    noise: np.ndarray


@dataclass(frozen=True)
class TargetTracks:
    """Targets measured and tracked through a sequence.

    Attributes
    ----------
    xy : (T, M, 2) array
        Image positions of the M targets in each of T frames, px; NaN where lost.
    status : (T, M) int array
        :class:`TargetStatus` codes.
    n_blobs : (T,) int array
        Blobs found in each frame.
    std : (T, M) array
        Standard deviation of a coordinate of each measured position, px (from the
        Gaussian fit, :attr:`Blobs.std`; NaN where lost or not converged).
    """

    xy: np.ndarray
    status: np.ndarray
    n_blobs: np.ndarray
    std: np.ndarray

    @property
    def n_lost(self) -> int:
        return int(np.count_nonzero(self.status == TargetStatus.LOST))


def _gaussian_fit(patches, x0, y0, n_iter: int = 12):
    """Fit ``B + A exp(-((x-x0)^2 + (y-y0)^2) / (2 s^2))`` to patches ``(n, m, m)``
    (coordinates relative to the patch's top-left pixel); returns centres, s, A, ok, the
    centres' standard deviation per coordinate and the residual RMS."""
    n, m, _ = patches.shape
    gy, gx = np.mgrid[0:m, 0:m].astype(float)
    gx, gy = gx.ravel(), gy.ravel()
    g = patches.reshape(n, -1).astype(float)
    B = np.percentile(g, 20, axis=1)
    A = g.max(axis=1) - B
    p = np.stack([x0, y0, np.full(n, 1.5), A, B], axis=1)
    ok = np.ones(n, bool)
    for _ in range(n_iter):
        dx = gx[None] - p[:, 0:1]
        dy = gy[None] - p[:, 1:2]
        s2 = p[:, 2:3] ** 2
        e = np.exp(-(dx**2 + dy**2) / (2 * s2))
        model = p[:, 4:5] + p[:, 3:4] * e
        r = g - model
        Ae = p[:, 3:4] * e
        J = np.stack([Ae * dx / s2, Ae * dy / s2, Ae * (dx**2 + dy**2) / (s2 * p[:, 2:3]), e,
                      np.ones_like(e)], axis=2)
        N = np.einsum("nki,nkj->nij", J, J) + 1e-9 * np.eye(5)
        b = np.einsum("nki,nk->ni", J, r)
        step = np.linalg.solve(N, b[..., None])[..., 0]
        p = p + step
        p[:, 2] = np.abs(p[:, 2])
        if np.all(np.abs(step[:, :2]) < 1e-5):
            break
    ok = (np.isfinite(p).all(axis=1) & (p[:, 2] > 0.3) & (p[:, 2] < m / 2) & (p[:, 3] > 0)
          & (p[:, 0] > 0) & (p[:, 0] < m - 1) & (p[:, 1] > 0) & (p[:, 1] < m - 1))
    # precision at the solution: s0^2 (J^T J)^-1 with s0 from the residuals
    dx, dy = gx[None] - p[:, 0:1], gy[None] - p[:, 1:2]
    s2 = p[:, 2:3] ** 2
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        e = np.exp(-(dx**2 + dy**2) / (2 * s2))
        r = g - (p[:, 4:5] + p[:, 3:4] * e)
        Ae = p[:, 3:4] * e
        J = np.stack([Ae * dx / s2, Ae * dy / s2, Ae * (dx**2 + dy**2) / (s2 * p[:, 2:3]), e,
                      np.ones_like(e)], axis=2)
        s0 = np.sqrt(np.sum(r**2, axis=1) / (m * m - 5))
    std = np.full(n, np.nan)
    if ok.any():
        N = np.einsum("nki,nkj->nij", J[ok], J[ok])
        var = np.linalg.inv(N)[:, [0, 1], [0, 1]] * s0[ok, None] ** 2
        std[ok] = np.sqrt(var.mean(axis=1))
    return p[:, :2], p[:, 2], p[:, 3], ok, std, s0


def detect_blobs(image, *, k: float = 8.0, min_area: int = 3, max_area: int = 400,
                 half: int = 4) -> Blobs:
    """Bright blobs in one grey image ``(H, W)``, located to sub-pixel precision.

    Parameters
    ----------
    image : (H, W) array
    k : float
        Threshold above the background median in units of the noise (1.4826 MAD).
    min_area, max_area : int
        Accepted region sizes, pixels.
    half : int
        Half-size of the patch of the Gaussian fit, px (patch ``2 half + 1`` square).
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D grey image, got shape {img.shape}")
    k = as_scalar(k, "k", positive=True)
    f = img.astype(np.float32)
    med = float(np.median(f[::4, ::4]))
    mad = float(np.median(np.abs(f[::4, ::4] - med))) * 1.4826
    thr = med + k * max(mad, 0.5)
    labels, n = ndimage.label(f > thr, structure=np.ones((3, 3), bool))
    H, W = f.shape
    cents = []
    for lab, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        region = labels[sl] == lab
        area = int(region.sum())
        if not min_area <= area <= max_area:
            continue
        wgt = np.where(region, np.clip(f[sl] - med, 0, None), 0.0)
        yy, xx = np.mgrid[sl]
        s = wgt.sum()
        cents.append((float((wgt * xx).sum() / s), float((wgt * yy).sum() / s)))
    cents = np.array(cents, dtype=float).reshape(-1, 2)
    inside = ((cents[:, 0] >= half) & (cents[:, 0] < W - half - 1)
              & (cents[:, 1] >= half) & (cents[:, 1] < H - half - 1))
    cents = cents[inside]
    if not len(cents):
        e = np.zeros((0, 2))
        return Blobs(xy=e, centroid=e, sigma=np.zeros(0), amplitude=np.zeros(0),
                     converged=np.zeros(0, bool), std=np.zeros(0), noise=np.zeros(0))
    corner = np.round(cents).astype(int) - half
    off = np.arange(2 * half + 1)
    patches = f[corner[:, 1, None, None] + off[None, :, None],
                corner[:, 0, None, None] + off[None, None, :]]
    c, s, a, ok, std, s0 = _gaussian_fit(patches, cents[:, 0] - corner[:, 0],
                                         cents[:, 1] - corner[:, 1])
    xy = np.where(ok[:, None], c + corner, cents)
    return Blobs(xy=xy, centroid=cents, sigma=s, amplitude=a, converged=ok, std=std, noise=s0)


@dataclass(frozen=True)
class TargetParams:
    """Settings of :func:`track_targets`: the gate of the frame-to-frame assignment and
    the blob detection of :func:`detect_blobs` in every frame.

    Attributes
    ----------
    gate : float
        Largest distance (px) between a target's constant-velocity prediction and the blob
        assigned to it. A target with no blob in its gate is lost in that frame (NaN);
        it takes one of the frame's ``n_targets`` strongest blobs that no other target
        claimed (left to right when several targets are lost), so a target that leaves the
        image is found again wherever it comes back.
    k : float
        Detection threshold above the background median in units of the noise (1.4826 MAD).
    min_area, max_area : int
        Accepted region sizes, pixels.
    half : int
        Half-size of the patch of the Gaussian fit, px (patch ``2 half + 1`` square).
    """

    gate: float = 100.0
    k: float = 8.0
    min_area: int = 3
    max_area: int = 400
    half: int = 4

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "gate", as_scalar(self.gate, "gate", positive=True))
        set_(self, "k", as_scalar(self.k, "k", positive=True))
        set_(self, "min_area", as_int(self.min_area, "min_area", minimum=0, unit="pixels"))
        set_(self, "max_area", as_int(self.max_area, "max_area", unit="pixels"))
        set_(self, "half", as_int(self.half, "half", unit="pixels"))


def track_targets(images, *, n_targets: int = 2,
                  params: TargetParams | None = None) -> TargetTracks:
    """Measure ``n_targets`` bright targets in every frame and track them.

    Parameters
    ----------
    images : (T, H, W) array
        One camera's sequence.
    n_targets : int
        Targets to follow; in the first frame they are labelled left to right (image x).
        Labels are per camera: with several cameras, their left-to-right orders usually
        agree (side-by-side cameras facing one way), and
        :func:`~lsmta.calibration.labels.consistent_bar_labels` corrects the frames where
        they do not.
    params : TargetParams, optional
        The assignment's gate and the blob detection (default: ``TargetParams()``).

    Returns
    -------
    TargetTracks
    """
    images = np.asarray(images)
    if images.ndim != 3:
        raise ValueError(f"images: expected (T, H, W), got shape {images.shape}")
    p = TargetParams() if params is None else params
    if not isinstance(p, TargetParams):
        raise TypeError(f"params: expected a TargetParams, got {type(p).__name__}")
    T = len(images)
    M = as_int(n_targets, "n_targets")
    xy = np.full((T, M, 2), np.nan)
    std = np.full((T, M), np.nan)
    status = np.full((T, M), TargetStatus.LOST, dtype=np.int64)
    n_blobs = np.zeros(T, int)
    last = np.full((M, 2), np.nan)
    vel = np.zeros((M, 2))
    for t in range(T):
        b = detect_blobs(images[t], k=p.k, min_area=p.min_area, max_area=p.max_area,
                         half=p.half)
        n_blobs[t] = len(b.xy)
        pick = _assign(b, last, vel, p.gate, M)
        for r, c in enumerate(pick):
            if c < 0:
                vel[r] = 0.0                       # predict from the last position only
                continue
            xy[t, r] = b.xy[c]
            std[t, r] = b.std[c]
            status[t, r] = TargetStatus.OK if b.converged[c] else TargetStatus.NOT_CONVERGED
            vel[r] = b.xy[c] - last[r] if np.isfinite(last[r]).all() else 0.0
            last[r] = b.xy[c]
    return TargetTracks(xy=xy, status=status, n_blobs=n_blobs, std=std)


def _assign(blobs: Blobs, last, vel, gate: float, M: int) -> np.ndarray:
    """Blob index for each of the M targets in one frame (-1: lost).

    Targets seen before take the blob nearest their prediction within the gate (Hungarian
    method); the others take the remaining blobs among the M strongest, left to right.
    """
    pick = np.full(M, -1)
    if not len(blobs.xy):
        return pick
    known = np.flatnonzero(np.isfinite(last).all(axis=1))
    if known.size:
        cost = np.linalg.norm((last + vel)[known, None] - blobs.xy[None], axis=2)
        rows, cols = linear_sum_assignment(cost)
        ok = cost[rows, cols] <= gate
        pick[known[rows[ok]]] = cols[ok]
    lost = np.flatnonzero(pick < 0)
    strongest = np.argsort(-blobs.amplitude)[:M]
    free = strongest[~np.isin(strongest, pick)]
    if lost.size and free.size:
        free = free[np.argsort(blobs.xy[free, 0])]
        if free.size > lost.size:               # keep the strongest of them
            keep = np.sort(np.argsort(-blobs.amplitude[free])[:lost.size])
            free = free[keep]
        pick[lost[:free.size]] = free
    return pick
