"""A synthetic pan-tilt camera and the data of Davis (2002), Sections 4.2 and 4.5.

The true head is a general :class:`~lsmta.pantilt.PanTiltCamera` whose axes miss the
projection centre by centimetres and are tilted by degrees from the image axes, like the
Sony EVI-D30 of the thesis. Observations are world points measured with noise (the thesis
used a coordinate-measuring arm, and says its data were noisy) and image points with
detection noise. Data sets:

* :func:`intrinsic_target` — one view of a precisely known 3-D target at home (the
  thesis's pre-process with Heikkilä's method);
* :func:`calibration_sweeps` — the thesis's calibration settings: pan -50°..50° in 10°
  steps at tilt 0 and tilt -20°..15° in 5° steps at pan 0;
* :func:`evaluation_grid` — 361 points, one per setting of a 19 x 19 grid over the head's
  full range;
* :func:`side_to_side` — a target moved rapidly from side to side (Figs. 50, 53);
* :func:`render_target_frames` — frames of a calibration target's LEDs, lit one at a
  time, as a camera (a head at one setting) films them, for the detector.

World frame as in :mod:`lsmta.synth.rigs`: X right, Y into the volume, Z up, mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from .._validate import as_array, as_int, as_rng, as_scalar, as_vector
from ..camera import Camera
from ..pantilt import PanTiltCamera

# Our assumptions (the thesis gives no optics): the EVI-D30's 1/3" CCD digitised at
# 640 x 480, zoomed to a principal distance of 1000 px (a 35° horizontal field), mild barrel
# distortion.
PANTILT_IMAGE_SIZE = (640, 480)
PANTILT_F_PX = 1000.0
PANTILT_DISTORTION = dict(k1=-0.06, k2=0.04, p1=2e-4, p2=-1e-4)


@dataclass(frozen=True, eq=False)
class PanTiltData:
    """Observations of a pan-tilt camera.

    Attributes
    ----------
    pan, tilt : (N,) arrays
        Setting of each observation, degrees.
    X : (N, 3) array
        Measured world points, mm (with ``world_sigma`` noise).
    xy : (N, 2) array
        Observed image points, pixels (with ``image_sigma`` noise).
    X_true : (N, 3) array
        True world points, mm.
    xy_true : (N, 2) array
        True image points of ``X_true``, pixels.
    """

    pan: np.ndarray
    tilt: np.ndarray
    X: np.ndarray
    xy: np.ndarray
    X_true: np.ndarray
    xy_true: np.ndarray

    def __post_init__(self):
        for key in ("pan", "tilt", "X", "xy", "X_true", "xy_true"):
            a = np.array(getattr(self, key), dtype=float)
            a.flags.writeable = False
            object.__setattr__(self, key, a)

    def __len__(self) -> int:
        return len(self.X)

    def subset(self, mask) -> PanTiltData:
        """The observations selected by a boolean mask or index array."""
        return PanTiltData(*(getattr(self, k)[mask] for k in
                             ("pan", "tilt", "X", "xy", "X_true", "xy_true")))

    def concat(self, other: PanTiltData) -> PanTiltData:
        """These observations followed by ``other``'s."""
        return PanTiltData(*(np.concatenate([getattr(self, k), getattr(other, k)]) for k in
                             ("pan", "tilt", "X", "xy", "X_true", "xy_true")))

    @property
    def home(self) -> np.ndarray:
        """Boolean ``(N,)``: observations at ``pan = tilt = 0``."""
        return (self.pan == 0) & (self.tilt == 0)


def _unit_in_plane(rng, e1, e2):
    a = rng.uniform(0, 2 * np.pi)
    return np.cos(a) * np.asarray(e1, float) + np.sin(a) * np.asarray(e2, float)


def pantilt_head(*, rng: np.random.Generator | int | None = None, misalignment: float = 1.0,
                 offset_mm: float = 40.0, axis_tilt_deg: float = 2.0,
                 position=(0.0, -3000.0, 1500.0), look_at=(0.0, 0.0, 1000.0),
                 f: float = PANTILT_F_PX, name: str = "pantilt") -> PanTiltCamera:
    """A true pan-tilt camera whose axes miss the optical centre and the image axes.

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        Draws the directions of the axis offsets and tilts; ``None`` gives a fixed,
        typical head (offsets forward/down, tilts about the camera's z and y axes).
    misalignment : float
        Scales both the offsets and the tilts (0: the ideal head of the simple model).
    offset_mm : float
        Distance of each axis from the projection centre at ``misalignment = 1``, mm.
    axis_tilt_deg : float
        Angle of each axis from the image axis it should follow at ``misalignment = 1``.
    position, look_at : (3,) arrays
        Projection centre at home and the point it looks at, mm.
    f : float
        Principal distance, pixels (image 640 x 480, mild barrel distortion).
    """
    if rng is not None:
        rng = as_rng(rng)
    misalignment = as_scalar(misalignment, "misalignment", nonnegative=True)
    offset = as_scalar(offset_mm, "offset_mm", nonnegative=True) * misalignment
    tilt = np.radians(as_scalar(axis_tilt_deg, "axis_tilt_deg", nonnegative=True)) * misalignment
    cam = Camera.look_at(as_vector(position, "position", 3), as_vector(look_at, "look_at", 3),
                         f=f, width=PANTILT_IMAGE_SIZE[0], height=PANTILT_IMAGE_SIZE[1],
                         name=name).replace(**PANTILT_DISTORTION)
    if rng is None:
        pan_off = np.array([0.3, 0.0, -0.95])   # pan axis behind the lens, a little right
        tilt_off = np.array([0.0, 0.6, -0.8])   # tilt axis behind and below
        pan_tilt_dir = np.array([1.0, 0.0, 0.0])
        tilt_tilt_dir = np.array([0.0, 0.6, 0.8])
    else:
        pan_off = _unit_in_plane(rng, (1, 0, 0), (0, 0, 1))
        tilt_off = _unit_in_plane(rng, (0, 1, 0), (0, 0, 1))
        pan_tilt_dir = _unit_in_plane(rng, (1, 0, 0), (0, 0, 1))
        tilt_tilt_dir = _unit_in_plane(rng, (0, 1, 0), (0, 0, 1))
    pan_off, tilt_off = (v / np.linalg.norm(v) for v in (pan_off, tilt_off))
    pan_tilt_dir, tilt_tilt_dir = (v / np.linalg.norm(v) for v in (pan_tilt_dir, tilt_tilt_dir))
    return PanTiltCamera.from_offsets(
        cam,
        pan_axis_cam=np.cos(tilt) * np.array([0.0, 1.0, 0.0]) + np.sin(tilt) * pan_tilt_dir,
        pan_point_cam=offset * pan_off,
        tilt_axis_cam=np.cos(tilt) * np.array([1.0, 0.0, 0.0]) + np.sin(tilt) * tilt_tilt_dir,
        tilt_point_cam=offset * tilt_off,
    )


def observe_settings(head: PanTiltCamera, pan, tilt, *,
                     rng: np.random.Generator | int | None = None, image_sigma: float = 8.0,
                     world_sigma: float = 25.0, depth=(1500.0, 4500.0),
                     margin: float = 0.05) -> PanTiltData:
    """One observation per setting: a world point seen at a random image position.

    The true image point is uniform over the image (less ``margin`` of its size on each
    side), the world point at a uniform distance in ``depth`` (mm) along its ray; then
    ``world_sigma`` (mm, per axis) and ``image_sigma`` (pixels, per axis) Gaussian noise.
    The defaults (8 px, 25 mm) are our choice: with them the true model's median error on
    the evaluation grid is about 14 px, the size of error the thesis attributes to its noisy
    measurements (its general model's median, 14.2 px).
    """
    rng = as_rng(rng)
    pan, tilt = (np.atleast_1d(a).astype(float) for a in head.check(pan, tilt))
    pan, tilt = np.broadcast_arrays(pan, tilt)
    cam = head.camera
    n = len(pan)
    lo = np.array([margin * cam.width, margin * cam.height]) - 0.5
    hi = np.array([(1 - margin) * cam.width, (1 - margin) * cam.height]) - 0.5
    xy_true = rng.uniform(lo, hi, (n, 2))
    d_cam = np.c_[cam.undistort(cam.pixel_to_normalized(xy_true)), np.ones(n)]
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    R, C = head.poses(pan, tilt)
    d_world = np.einsum("nji,nj->ni", R, d_cam)
    X_true = C + d_world * rng.uniform(depth[0], depth[1], (n, 1))
    X = X_true + rng.normal(0, as_scalar(world_sigma, "world_sigma", nonnegative=True), (n, 3))
    xy = xy_true + rng.normal(0, as_scalar(image_sigma, "image_sigma", nonnegative=True), (n, 2))
    return PanTiltData(pan=pan, tilt=tilt, X=X, xy=xy, X_true=X_true, xy_true=xy_true)


def calibration_sweeps(head: PanTiltCamera, *, rng: np.random.Generator | int | None = None,
                       points_per_setting: int = 20, pans=tuple(range(-50, 51, 10)),
                       tilts=tuple(range(-20, 16, 5)), image_sigma: float = 8.0,
                       world_sigma: float = 25.0, depth=(1500.0, 4500.0),
                       margin: float = 0.05) -> PanTiltData:
    """The thesis's calibration data: ``points_per_setting`` points at each pan of ``pans``
    (tilt 0) and each tilt of ``tilts`` (pan 0); the home setting appears in both sweeps.
    ``image_sigma``, ``world_sigma``, ``depth`` and ``margin`` as in
    :func:`observe_settings`."""
    rng = as_rng(rng)
    pans = np.asarray(pans, dtype=float)
    tilts = np.asarray(tilts, dtype=float)
    k = as_int(points_per_setting, "points_per_setting")
    pan = np.r_[np.repeat(pans, k), np.zeros(len(tilts) * k)]
    tilt = np.r_[np.zeros(len(pans) * k), np.repeat(tilts, k)]
    return observe_settings(head, pan, tilt, rng=rng, image_sigma=image_sigma,
                            world_sigma=world_sigma, depth=depth, margin=margin)


def evaluation_grid(head: PanTiltCamera, *, rng: np.random.Generator | int | None = None,
                    n_pan: int = 19, n_tilt: int = 19, image_sigma: float = 8.0,
                    world_sigma: float = 25.0, depth=(1500.0, 4500.0),
                    margin: float = 0.05) -> PanTiltData:
    """``n_pan x n_tilt`` settings (19 x 19 = 361, as the thesis's evaluation set) evenly over
    the head's full range, one point each; ``image_sigma``, ``world_sigma``, ``depth`` and
    ``margin`` as in :func:`observe_settings`."""
    rng = as_rng(rng)
    pans = np.linspace(*head.pan_limits, n_pan)
    tilts = np.linspace(*head.tilt_limits, n_tilt)
    pan, tilt = (a.ravel() for a in np.meshgrid(pans, tilts))
    return observe_settings(head, pan, tilt, rng=rng, image_sigma=image_sigma,
                            world_sigma=world_sigma, depth=depth, margin=margin)


def intrinsic_target(head: PanTiltCamera, *, rng: np.random.Generator | int | None = None,
                     n: int = 200, image_sigma: float = 0.3, world_sigma: float = 0.1,
                     depth=(2000.0, 3500.0)) -> PanTiltData:
    """A precisely known 3-D target seen at home, for the intrinsics: ``n`` points spread
    over the image and ``depth`` (mm), measured to ``world_sigma`` mm and detected to
    ``image_sigma`` pixels (a printed target, not the tracked feature)."""
    rng = as_rng(rng)
    return observe_settings(head, np.zeros(n), np.zeros(n), rng=rng, image_sigma=image_sigma,
                            world_sigma=world_sigma, depth=depth, margin=0.02)


def side_to_side(*, duration: float = 30.0, rate: float = 240.0,
                 rng: np.random.Generator | int | None = None, centre=(0.0, 0.0, 1000.0),
                 amplitude: float = 600.0, period: float = 3.0, reversal: float = 0.5,
                 period_jitter: float = 0.0) -> np.ndarray:
    """A target moved by hand from side to side along X: ``(T, 3)`` positions (mm) at ``rate``.

    Each half period the target sweeps ``2 amplitude`` mm, at constant speed
    ``v = 2 amplitude / (period / 2 - reversal / 2)`` except in the reversals, which take
    ``reversal`` seconds at constant deceleration, so the acceleration is zero except in the
    reversals, where it is ``2 v / reversal`` (v the sweep speed) — the motion of Fig. 53,
    whose deviation peaks "correspond to periods of high target acceleration". With ``rng``
    and ``period_jitter`` > 0 each half period varies by that relative standard deviation.

    Returns
    -------
    (T, 3) array, ``T = round(duration * rate)``; starts at ``centre - amplitude`` along X.
    """
    duration = as_scalar(duration, "duration", positive=True)
    rate = as_scalar(rate, "rate", positive=True)
    period = as_scalar(period, "period", positive=True)
    reversal = as_scalar(reversal, "reversal", positive=True)
    amplitude = as_scalar(amplitude, "amplitude", nonnegative=True)
    if not reversal < period / 2:
        raise ValueError(f"reversal: expected less than half the period ({period / 2:g} s), "
                         f"got {reversal:g}")
    n = int(round(duration * rate))
    halves = int(np.ceil(duration / (period / 2))) + 2
    lengths = np.full(halves, period / 2)
    if rng is not None and period_jitter > 0:
        lengths = lengths * np.exp(as_rng(rng).normal(0, period_jitter, halves))
        lengths = np.maximum(lengths, 1.05 * reversal)
    x = np.empty(n)
    t = np.arange(n) / rate
    start = 0.0
    for k, h in enumerate(lengths):
        sel = (t >= start) & (t < start + h)
        u = t[sel] - start
        v = 2 * amplitude / (h - reversal / 2)   # sweep speed: 2A per half period
        sign = 1.0 if k % 2 == 0 else -1.0
        half_r = reversal / 2
        # from the middle of one reversal (speed 0 at x = -A sign) to the middle of the next
        a = v / half_r
        pos = np.where(u < half_r, 0.5 * a * u**2,
                       np.where(u < h - half_r, 0.5 * a * half_r**2 + v * (u - half_r),
                                2 * amplitude - 0.5 * a * (h - u) ** 2))
        x[sel] = sign * (pos - amplitude)
        start += h
        if start >= t[-1]:
            break
    out = np.tile(as_vector(centre, "centre", 3), (n, 1))
    out[:, 0] += x
    return out


@dataclass(frozen=True, eq=False)
class TargetFrames:
    """A camera's frames of a calibration target's LEDs lit one at a time
    (:func:`render_target_frames`).

    Attributes
    ----------
    frames : (N, H, W) uint8 array
        Frame ``i`` shows LED ``i`` alone.
    background : (B, H, W) uint8 array
        Frames of the view with every LED off (for the detector's thresholds).
    true_xy : (N, 2) array
        The LEDs' true image points, px (truth: for scoring only).
    """

    frames: np.ndarray
    background: np.ndarray
    true_xy: np.ndarray


def render_target_frames(camera: Camera, X, *, rng: np.random.Generator | int | None = None,
                         led_peak: float = 230.0, led_sigma: float = 0.9,
                         led_range: float = 4500.0, noise: float = 2.0,
                         n_background: int = 8) -> TargetFrames:
    """Frames of the LEDs at ``X`` lit one at a time, each facing ``camera``.

    The backdrop is the wide-area renderer's smooth grey texture
    (:func:`lsmta.synth.widearea.render_led_video`'s room, without lamp or monitor); each
    LED is a Gaussian spot of ``led_sigma`` px at its (distorted) projection, of peak
    ``led_peak * min((led_range / d)**2, 1.5)`` grey levels at distance ``d`` mm, as that
    renderer's LEDs facing the camera; then Gaussian image noise of ``noise`` grey levels
    (drawn by its quantiles at 2**16 levels),
    rounded to uint8. ``n_background`` frames of the view with the LEDs off (0: none)
    come with it.

    Parameters
    ----------
    camera : Camera
    X : (N, 3) array
        The LEDs, mm.
    rng : numpy.random.Generator, int or None
    led_peak : float
        An LED's peak, grey levels, at ``led_range`` or farther (up to 1.5 times nearer).
    led_sigma : float
        The spot's Gaussian width, px.
    led_range : float
        The distance at which the peak is ``led_peak``, mm.
    noise : float
        The image noise's standard deviation, grey levels.
    n_background : int
        Frames of the view with the LEDs off.

    Returns
    -------
    TargetFrames
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera: expected an lsmta.Camera, got {type(camera).__name__}")
    X = as_array(X, "X", shape=(None, 3))
    for key, v in (("led_peak", led_peak), ("noise", noise)):
        as_scalar(v, key, nonnegative=True)
    for key, v in (("led_sigma", led_sigma), ("led_range", led_range)):
        as_scalar(v, key, positive=True)
    n_background = as_int(n_background, "n_background", minimum=0)
    rng = as_rng(rng)
    H, W = camera.height, camera.width
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    room = 50 + 15 * np.sin(xx / 23.0 + 1.3 * np.sin(yy / 37.0)) + 10 * np.cos(yy / 17.0)
    xy = camera.project(X, behind="nan")
    bright = np.minimum((led_range / np.linalg.norm(X - camera.C, axis=1)) ** 2, 1.5)
    frames = np.repeat(room[None], len(X), axis=0)
    r = int(np.ceil(4 * led_sigma))
    vis = np.isfinite(xy).all(axis=1) & camera.in_image(xy)
    for i in np.flatnonzero(vis):
        x, y = xy[i]
        cs = np.arange(int(round(x)) - r, int(round(x)) + r + 1)
        rs = np.arange(int(round(y)) - r, int(round(y)) + r + 1)
        cs, rs = cs[(cs >= 0) & (cs < W)], rs[(rs >= 0) & (rs < H)]
        g = np.exp(-((cs[None] - x) ** 2 + (rs[:, None] - y) ** 2) / (2 * led_sigma**2))
        frames[i, rs[0]:rs[-1] + 1, cs[0]:cs[-1] + 1] += led_peak * bright[i] * g
    background = np.repeat(room[None], n_background, axis=0)
    # Gaussian noise by its quantiles at 2**16 levels (tails cut at 4.3 sigma): half the
    # time of drawing it, and indistinguishable to a threshold 5 sigma above the maximum
    levels = (noise * ndtri((np.arange(2**16) + 0.5) / 2**16)).astype(np.float32)
    out = []
    for f in (frames, background):
        f += levels[rng.integers(0, 2**16, f.shape, dtype=np.uint16)]
        np.rint(f, out=f)
        np.clip(f, 0, 255, out=f)
        out.append(f.astype(np.uint8))
    return TargetFrames(frames=out[0], background=out[1],
                        true_xy=np.where(vis[:, None], xy, np.nan))
