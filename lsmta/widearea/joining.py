"""A camera joins a running wide-area system: calibrated from the targets the tracker is
following (a space resection against the tracker's estimates), then used.

Davis builds the wide-area system so that "cameras can be added as necessary to increase
the range of possible recovery" (2002, §3.1); his calibration is the virtual calibration
object of §3.2, made before tracking. Here the tracked LEDs themselves are the calibration
object of a camera that joins later: the tracker's estimates of the live targets at the
time of each of the new camera's frames are the 3-D points, the frame's centroids their
images. Which centroid belongs to which target is not known; the camera's approximate
(tape-measured) pose is:

1. the targets are projected with the approximation; the offsets between projections and
   centroids within ``search_px`` vote for one image shift (the approximation's error is
   mostly a shift of the whole image: a few degrees of attitude); the mode of their 2-D
   histogram is taken;
2. in every frame the shifted projections are paired with the centroids (Hungarian, inside
   a gate) and the camera is resected from all pairs
   (:func:`lsmta.calibration.resect`, exterior orientation and the free interior
   parameters);
3. pairing and resection are repeated with the resected camera and a tight gate.

The camera is accepted when enough pairs remain and their RMS image distance is small.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_int, as_scalar
from ..calibration.virtual_object import resect
from ..camera import Camera


class JoinStatus(IntEnum):
    """Outcome of :func:`calibrate_from_targets`."""

    JOINED = 0
    TOO_FEW_PAIRS = 1
    POOR_FIT = 2


@dataclass(frozen=True)
class JoinParams:
    """Settings of a camera's calibration against the tracked targets.

    Attributes
    ----------
    min_frames : int
        Frames of the joining camera collected before its calibration is tried (and again
        after every further ``min_frames`` frames while it fails).
    min_pairs : int
        Centroid-target pairs needed.
    search_px : float
        Largest image offset between the approximation's projections and the centroids, px.
    first_gate_px, gate_px : float
        Pairing gates after the shift and after the resections, px.
    rounds : int
        Pairing and resection rounds with the resected camera.
    intrinsics : tuple of str
        Interior parameters resected with the exterior orientation (the principal
        distance and the first radial term: the targets of a few seconds cover part of
        the image only, too little for the principal point and a second radial term).
    max_rms_px : float
        Accepted when the final pairs' RMS image distance is below this, px, and the lens
        model can be inverted over the whole image (rays of every pixel).
    """

    min_frames: int = 20
    min_pairs: int = 80
    search_px: float = 80.0
    first_gate_px: float = 8.0
    gate_px: float = 4.0
    rounds: int = 3
    intrinsics: tuple = ("f", "k1")
    max_rms_px: float = 2.0

    def __post_init__(self):
        for key in ("min_frames", "min_pairs", "rounds"):
            as_int(getattr(self, key), key)
        for key in ("search_px", "first_gate_px", "gate_px", "max_rms_px"):
            as_scalar(getattr(self, key), key, positive=True)


@dataclass(frozen=True, eq=False)
class CameraJoin:
    """A joining camera's calibration.

    Attributes
    ----------
    camera : Camera
        The resected camera (the approximation when not joined).
    status : JoinStatus
    rms_px : float
        RMS image distance of the final pairs, px (NaN without pairs).
    pairs : int
        Centroid-target pairs of the final resection.
    frames : int
        Frames used.
    shift_px : (2,) array
        The image shift found between the approximation's projections and the centroids.
    """

    camera: Camera
    status: JoinStatus
    rms_px: float
    pairs: int
    frames: int
    shift_px: np.ndarray


def calibrate_from_targets(guess: Camera, centroids, positions, *,
                           params: JoinParams | None = None) -> CameraJoin:
    """Calibrate a camera from its centroids and the tracked targets (see the module).

    Parameters
    ----------
    guess : Camera
        Approximation (nominal interior orientation, tape-measured pose).
    centroids : sequence of F arrays (n_f, 2)
        The camera's centroids per frame, px.
    positions : sequence of F arrays (m_f, 3)
        The tracked targets' positions at each frame's time, mm.
    params : JoinParams, optional

    Returns
    -------
    CameraJoin
    """
    if not isinstance(guess, Camera):
        raise TypeError("guess: expected an lsmta.camera.Camera")
    p = JoinParams() if params is None else params
    if not isinstance(p, JoinParams):
        raise TypeError("params: expected a JoinParams")
    if len(centroids) != len(positions):
        raise ValueError(f"positions: expected one array per frame ({len(centroids)}), got "
                         f"{len(positions)}")
    cents = [np.asarray(c, float).reshape(-1, 2) for c in centroids]
    pos = [np.asarray(x, float).reshape(-1, 3) for x in positions]
    shift = _image_shift(guess, cents, pos, p.search_px)
    cam, X, xy = guess, np.zeros((0, 3)), np.zeros((0, 2))
    for r in range(p.rounds + 1):
        X, xy = _pairs(cam, cents, pos, shift if r == 0 else np.zeros(2),
                       p.first_gate_px if r == 0 else p.gate_px)
        if len(X) < p.min_pairs:
            return CameraJoin(camera=guess, status=JoinStatus.TOO_FEW_PAIRS, rms_px=np.nan,
                              pairs=len(X), frames=len(cents), shift_px=shift)
        if r < p.rounds:
            cam = resect(cam, X, xy, intrinsics=p.intrinsics)
    rms = float(np.sqrt(np.mean(np.sum((cam.project(X, behind="nan") - xy) ** 2, axis=1))))
    ok = rms <= p.max_rms_px and _invertible(cam)
    return CameraJoin(camera=cam if ok else guess,
                      status=JoinStatus.JOINED if ok else JoinStatus.POOR_FIT, rms_px=rms,
                      pairs=len(X), frames=len(cents), shift_px=shift)


def _invertible(cam: Camera) -> bool:
    """The lens model can be inverted (rays) along the image's border and diagonals."""
    u = np.linspace(0.0, 1.0, 17)
    w, h = cam.width - 1.0, cam.height - 1.0
    pts = np.concatenate([np.stack([u * w, np.zeros_like(u)], 1),
                          np.stack([u * w, np.full_like(u, h)], 1),
                          np.stack([np.zeros_like(u), u * h], 1),
                          np.stack([np.full_like(u, w), u * h], 1),
                          np.stack([u * w, u * h], 1), np.stack([u * w, (1 - u) * h], 1)])
    try:
        cam.rays(pts)
    except ValueError:
        return False
    return True


def _image_shift(cam: Camera, cents, pos, search_px: float) -> np.ndarray:
    """The mode (2-px bins, 3x3 smoothing, then the mean within 2 px of it) of the offsets
    centroid - projection within ``search_px``, px."""
    d = []
    for c, x in zip(cents, pos):
        if len(c) and len(x):
            q = cam.project(x, behind="nan")
            q = q[np.isfinite(q).all(axis=1)]
            off = (c[None, :, :] - q[:, None, :]).reshape(-1, 2)
            d.append(off[np.abs(off).max(axis=1) <= search_px])
    d = np.concatenate(d) if d else np.zeros((0, 2))
    if not len(d):
        return np.zeros(2)
    edges = np.arange(-search_px, search_px + 2.0, 2.0)
    h, _, _ = np.histogram2d(d[:, 0], d[:, 1], bins=(edges, edges))
    h = sum(np.roll(np.roll(h, i, 0), j, 1) for i in (-1, 0, 1) for j in (-1, 0, 1))
    i, j = np.unravel_index(np.argmax(h), h.shape)
    peak = np.array([edges[i] + 1.0, edges[j] + 1.0])
    near = np.linalg.norm(d - peak, axis=1) <= 2.0
    return d[near].mean(axis=0) if near.any() else peak


def _pairs(cam: Camera, cents, pos, shift, gate: float):
    """Per frame, the one-to-one pairs of projected (and shifted) targets and centroids
    inside ``gate`` px: stacked points (P, 3) and centroids (P, 2)."""
    X, xy = [], []
    for c, x in zip(cents, pos):
        if not (len(c) and len(x)):
            continue
        q = cam.project(x, behind="nan") + shift
        d = np.linalg.norm(q[:, None, :] - c[None, :, :], axis=2)
        d = np.where(np.isfinite(d), d, np.inf)
        cost = np.where(d <= gate, d, 1e9)
        r, k = linear_sum_assignment(cost)
        ok = cost[r, k] < 1e9
        X.append(x[r[ok]])
        xy.append(c[k[ok]])
    if not X:
        return np.zeros((0, 3)), np.zeros((0, 2))
    return np.concatenate(X), np.concatenate(xy)
