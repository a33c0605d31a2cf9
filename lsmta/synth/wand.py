"""A wand recording as users of easyWand, Argus and aniposelib make one.

Four action-style cameras (1280 x 720 px, wide lenses with barrel distortion) at the
corners of a room look at a volume of about 2 x 2 x 1.5 m. A wand - two balls a known
distance apart - is waved through the volume; in each frame only some cameras see it (the
person waving it hides it from the others, or it leaves their view): by default every
frame is seen by two or three of the four cameras. The ball centres are measured with
Gaussian noise; optionally some cameras label the two ends the other way round in some
frames (an automatic tracker that loses track), and background points of unknown position
serve as tie points.

The truth (cameras, wand positions) reaches the library only through
:mod:`lsmta.evaluation.wand`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_rng, as_scalar
from ..camera import Camera

WAND_IMAGE_SIZE = (1280, 720)


def wand_rig(*, rng: np.random.Generator | int | None = None, n_cameras: int = 4,
             distance: float = 3200.0,
             height: float = 1900.0, target=(0.0, 0.0, 900.0), image_size=WAND_IMAGE_SIZE,
             focal_px: float = 840.0, k1: float = -0.12, k2: float = 0.03) -> list[Camera]:
    """Cameras in the corners of a room, aimed at ``target`` (mm).

    Camera k stands at azimuth ``45 + 360 k / n`` degrees, ``distance`` mm from the target
    horizontally and ``height`` mm above the floor (alternately 300 mm higher and lower),
    with images of ``image_size`` px, a focal length of ``focal_px`` (by default 840 px:
    75 degrees across 1280 px) and barrel distortion ``k1``, ``k2`` (by default -0.12,
    0.03); with ``rng`` each camera's focal length (7 % of it), principal point (0.5 % of
    the image width), lens (10 % of k1, k2, decentring of 3e-4) and aim (150 mm) vary as
    in a real rig. :data:`WIDE_RIG` is a wide-angle variant.
    """
    rng = None if rng is None else as_rng(rng)
    W, H = (int(v) for v in image_size)
    focal_px = as_scalar(focal_px, "focal_px", positive=True)
    target = np.asarray(target, float)

    def vary(scale, n=None):
        return np.zeros(n) if rng is None and n else (
            0.0 if rng is None else rng.normal(0, scale, n))

    cams = []
    for k in range(int(n_cameras)):
        a = np.radians(45.0 + 360.0 * k / n_cameras)
        eye = target + [distance * np.cos(a), distance * np.sin(a),
                        height - target[2] + (300.0 if k % 2 else -300.0)]
        cam = Camera.look_at(
            eye, target + vary(150.0, 3), f=focal_px * (1 + vary(60.0 / 840.0)), width=W,
            height=H, cx=(W - 1) / 2 + vary(6.0 / 1280 * W),
            cy=(H - 1) / 2 + vary(6.0 / 1280 * W), name=f"cam{k + 1}")
        cams.append(cam.replace(k1=k1 * (1 + vary(0.1)), k2=k2 * (1 + vary(0.1)),
                                p1=vary(3e-4), p2=vary(3e-4)))
    return cams


#: a wide-angle rig of the real one's image size (2560 x 1600 px): 100 degrees across the
#: width, strong barrel distortion (a point at the image corner is pulled in by 28 %),
#: cameras 2 m (horizontally) from the volume's centre (keywords of :func:`wand_rig`)
WIDE_RIG = dict(image_size=(2560, 1600), focal_px=1070.0, k1=-0.22, k2=0.05,
                distance=2000.0)
#: the wand volume for :data:`WIDE_RIG` (``half_size`` of :func:`wand_recording`, mm): the
#: wand reaches 60-75 % of the way from the image centre to the corners
WIDE_VOLUME = (1500.0, 1500.0, 800.0)


@dataclass(frozen=True, eq=False)
class WandRecording:
    """A generated wand recording and its truth.

    Attributes
    ----------
    cameras : list of K Camera
        The true cameras.
    ends : (T, 2, 3) array
        True positions of the wand's two ends per frame, mm.
    length : float
        The wand's length, mm.
    xy : (K, T, 2, 2) array
        Measured image positions of the two ends, px; NaN where a camera does not see the
        wand; the ends exchanged where ``swapped``.
    xy_true : (K, T, 2, 2) array
        Their true projections (NaN where not seen), labels not exchanged.
    swapped : (K, T) bool array
        Where a camera's labels of the two ends are exchanged.
    tie_points : (N, 3) array
        True background points, mm.
    tie_xy : (K, N, 2) array
        Their measured image positions (NaN where not seen).
    sigma_px : float
        Standard deviation of the measurement noise per coordinate, px.
    """

    cameras: list
    ends: np.ndarray
    length: float
    xy: np.ndarray
    xy_true: np.ndarray
    swapped: np.ndarray
    tie_points: np.ndarray
    tie_xy: np.ndarray
    sigma_px: float

    @property
    def n_cameras_seeing(self) -> np.ndarray:
        """``(T,)`` how many cameras see the wand (both ends) in each frame."""
        return np.isfinite(self.xy).all(axis=(2, 3)).sum(axis=0)


def _project(cameras, X):
    """``(K, N, 2)`` projections, NaN outside the image or behind the camera."""
    out = np.empty((len(cameras), len(X), 2))
    for k, cam in enumerate(cameras):
        p = cam.project(X, behind="nan")
        p[~cam.in_image(p)] = np.nan
        out[k] = p
    return out


def wand_recording(*, cameras=None, rng: np.random.Generator | int | None = None,
                   n_frames: int = 25, length: float = 600.0,
                   sigma_px: float = 0.3, seen_by=(2, 3), swap_fraction: float = 0.0,
                   n_tie: int = 0, center=(0.0, 0.0, 900.0),
                   half_size=(900.0, 900.0, 600.0), margin_px: float = 20.0) -> WandRecording:
    """A wand waved through the volume, seen by some of the cameras in each frame.

    Parameters
    ----------
    rng : numpy.random.Generator or int
    cameras : list of Camera, optional
        Default :func:`wand_rig` of ``rng``.
    n_frames : int
        Frames T.
    length : float
        Distance between the wand's ends, mm.
    sigma_px : float
        Measurement noise per coordinate, px (0.3: centroids of bright balls; a person
        clicking in DLTdv is nearer 1 px).
    seen_by : (int, int)
        Each frame is seen by a number of cameras drawn uniformly from this range
        (inclusive), among those that have both ends inside the image (at least
        ``margin_px`` from the border); positions where fewer cameras could see the wand
        are drawn again.
    swap_fraction : float
        Fraction of (camera, frame) observations whose two ends carry each other's labels.
    n_tie : int
        Background points (on the floor and walls around the volume), each seen by every
        camera that has it in view (at least two).
    """
    rng = as_rng(rng)
    cameras = wand_rig(rng=rng) if cameras is None else list(cameras)
    K = len(cameras)
    length = as_scalar(length, "length", positive=True)
    lo, hi = (int(v) for v in seen_by)
    if not 1 <= lo <= hi <= K:
        raise ValueError(f"seen_by: expected 1 <= low <= high <= {K}, got {seen_by!r}")
    if not 0 <= swap_fraction <= 1:
        raise ValueError(f"swap_fraction: expected a fraction in [0, 1], got {swap_fraction}")
    center, half = np.asarray(center, float), np.asarray(half_size, float)
    ends = np.empty((n_frames, 2, 3))
    xy_true = np.full((K, n_frames, 2, 2), np.nan)
    for t in range(n_frames):
        for _ in range(1000):
            mid = center + rng.uniform(-1, 1, 3) * half
            d = rng.normal(0, 1, 3)
            d /= np.linalg.norm(d)
            pair = np.stack([mid - 0.5 * length * d, mid + 0.5 * length * d])
            p = _project(cameras, pair)
            inside = np.isfinite(p).all(axis=(1, 2)) & np.all(
                (p[..., 0] > margin_px) & (p[..., 0] < cameras[0].width - margin_px)
                & (p[..., 1] > margin_px) & (p[..., 1] < cameras[0].height - margin_px),
                axis=1)
            n_want = int(rng.integers(lo, hi + 1))
            if inside.sum() >= n_want:
                break
        else:  # pragma: no cover - the default volume is in view of every camera
            raise ValueError("half_size: the wand is rarely in view of enough cameras")
        chosen = rng.choice(np.flatnonzero(inside), n_want, replace=False)
        ends[t] = pair
        xy_true[chosen, t] = p[chosen]
    xy = xy_true + rng.normal(0, sigma_px, xy_true.shape)
    seen = np.isfinite(xy).all(axis=(2, 3))
    swapped = seen & (rng.uniform(size=seen.shape) < swap_fraction)
    xy[swapped] = xy[swapped][:, ::-1]
    # tie points: on the floor and low on the walls around the volume
    tie = np.column_stack([rng.uniform(-1, 1, n_tie) * 1.6 * half[0] + center[0],
                           rng.uniform(-1, 1, n_tie) * 1.6 * half[1] + center[1],
                           rng.uniform(0, 300, n_tie)])
    tie_xy = _project(cameras, tie) + rng.normal(0, sigma_px, (K, n_tie, 2))
    keep = np.isfinite(tie_xy).all(axis=2).sum(axis=0) >= 2
    return WandRecording(cameras=cameras, ends=ends, length=length, xy=xy, xy_true=xy_true,
                         swapped=swapped, tie_points=tie[keep], tie_xy=tie_xy[:, keep],
                         sigma_px=float(sigma_px))
