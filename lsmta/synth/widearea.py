"""The wide-area LED world (Davis 2002, ch. 3): eighteen ceiling cameras over a
3.5 m x 5 m floor, each with its own frame rate, clock offset and latency; LEDs on a
walking, arm-swinging person (the body and walk of :mod:`lsmta.synth.body`), on a linear
translation stage, moved in a circle, or held still; LED brightness falling with distance
and angle, occlusion by the body, clutter (monitors, reflections).

Two ways to observe: :func:`observe_leds` gives per-frame 2-D centroids directly
(projection + noise, no images; :class:`LedCentroidParams`), :func:`render_led_video`
renders small grey images for the detector (:class:`LedVideoParams`).
Ground truth stays here; the library gets cameras and frames only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_rng, as_scalar, as_vector
from ..camera import Camera
from ..widearea.observations import Frames
from .body import make_body, walk
from .rigs import _perturbed

AREA = (3500.0, 5000.0)          # floor area covered, mm (x, y)
CEILING = 2800.0                 # camera height, mm
LED_NAMES = ("head", "shoulder_r", "shoulder_l", "elbow_r", "elbow_l", "wrist_r", "wrist_l",
             "waist")
# (part, local position mm, local outward normal) on the body of lsmta.synth.body
_LED_PLACES = (
    ("head", (0.0, 15.0, 240.0), (0.0, 0.2, 1.0)),
    ("upper_arm_r", (45.0, 0.0, -25.0), (1.0, 0.0, 0.6)),
    ("upper_arm_l", (-45.0, 0.0, -25.0), (-1.0, 0.0, 0.6)),
    ("forearm_r", (38.0, 0.0, -15.0), (1.0, 0.0, 0.3)),
    ("forearm_l", (-38.0, 0.0, -15.0), (-1.0, 0.0, 0.3)),
    ("hand_r", (22.0, 0.0, -10.0), (1.0, 0.0, 0.2)),
    ("hand_l", (-22.0, 0.0, -10.0), (-1.0, 0.0, 0.2)),
    ("pelvis", (0.0, 105.0, 60.0), (0.0, 1.0, 0.3)),
)


def ceiling_rig(*, rng: np.random.Generator | int | None = None, f: float = 480.0, width: int = 640,
                height: int = 480, k1: float = -0.04) -> list[Camera]:
    """Eighteen cameras at the ceiling (2.8 m) around a 3.5 m x 5 m floor, looking inwards
    and down at the volume 0.5-2 m high: five along each long side, four along each short
    side. With ``rng``, poses and lenses are perturbed as in :func:`lsmta.synth.rigs.triplet_rig`.
    """
    if rng is not None:
        rng = as_rng(rng)
    eyes = []
    for x in (-2000.0, 2000.0):
        for y in (-2300.0, -1150.0, 0.0, 1150.0, 2300.0):
            eyes.append((x, y, CEILING))
    for y in (-2800.0, 2800.0):
        for x in (-1200.0, -400.0, 400.0, 1200.0):
            eyes.append((x, y, CEILING))
    cams = []
    for i, eye in enumerate(eyes):
        target = (-0.15 * eye[0], -0.15 * eye[1], 800.0)
        cam = Camera.look_at(eye, target, f=f, width=width, height=height,
                             name=f"cam{i:02d}").replace(k1=k1, k2=0.5 * abs(k1))
        cams.append(_perturbed(cam, rng, pose_mm=10.0, pose_deg=0.5, pp_px=3.0,
                               distortion_rel=0.1))
    return cams


@dataclass(frozen=True)
class Clocks:
    """Timing of K unsynchronised cameras (s).

    Attributes
    ----------
    rate : (K,) array
        Frame rate, Hz.
    phase : (K,) array
        True time of each camera's first frame, s.
    offset : (K,) array
        Camera clock minus true time, s (the stamp error).
    latency : (K,) array
        Mean delay from capture to arrival at the estimator, s.
    jitter : float
        Standard deviation of the latency, s.
    """

    rate: np.ndarray
    phase: np.ndarray
    offset: np.ndarray
    latency: np.ndarray
    jitter: float = 0.0


def make_clocks(n: int, *, rng: np.random.Generator | int | None = None, rate=(30.0, 60.0),
                max_offset=0.004, latency=(0.004, 0.012), jitter=0.001) -> Clocks:
    """Random timing for ``n`` cameras: rates uniform in ``rate`` (Hz), clock offsets
    uniform in ``±max_offset`` (s), latencies uniform in ``latency`` (s)."""
    rng = as_rng(rng)
    rates = rng.uniform(*rate, n)
    return Clocks(rate=rates, phase=rng.uniform(0, 1, n) / rates,
                  offset=rng.uniform(-max_offset, max_offset, n),
                  latency=rng.uniform(*latency, n), jitter=float(jitter))


@dataclass(frozen=True, eq=False)
class LedScene:
    """LEDs moving through the room: positions sampled finely in time (ground truth).

    Attributes
    ----------
    name : str
    times : (S,) array
        Sample times, s (uniform).
    positions : (S, N, 3) array
        LED positions, mm.
    normals : (S, N, 3) array
        Unit directions of the LEDs' strongest emission.
    on : (N, 2) array
        Switch-on and switch-off time of each LED, s.
    hidden : (N, 2) array or None
        An interval ``[start, end)`` per LED during which it is hidden from every camera
        (a hand over it), s; ``(inf, inf)`` or None: never.
    occluders : (S, P, 4, 4) array or None
        Body part poses (part frame -> world) for occlusion.
    ellipsoids : (P, 2, 3) array or None
        Per part: ellipsoid centre and radii in the part frame, mm.
    led_part : (N,) int array or None
        Part each LED sits on.
    """

    name: str
    times: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    on: np.ndarray
    occluders: np.ndarray | None = None
    ellipsoids: np.ndarray | None = None
    led_part: np.ndarray | None = None
    hidden: np.ndarray | None = None

    @property
    def n_leds(self) -> int:
        return self.positions.shape[1]

    def positions_at(self, t, *, only_on: bool = True) -> np.ndarray:
        """LED positions ``(T, N, 3)`` at times ``t`` (linear interpolation); NaN while an
        LED is off or hidden (with ``only_on``)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        dt = self.times[1] - self.times[0]
        u = np.clip((t - self.times[0]) / dt, 0, len(self.times) - 1)
        i = np.clip(np.floor(u).astype(int), 0, len(self.times) - 2)
        w = (u - i)[:, None, None]
        out = (1 - w) * self.positions[i] + w * self.positions[i + 1]
        if only_on:
            off = (t[:, None] < self.on[:, 0]) | (t[:, None] >= self.on[:, 1])
            if self.hidden is not None:
                off |= (t[:, None] >= self.hidden[:, 0]) & (t[:, None] < self.hidden[:, 1])
            out[off] = np.nan
        return out

    def _nearest(self, t) -> np.ndarray:
        dt = self.times[1] - self.times[0]
        return np.clip(np.rint((t - self.times[0]) / dt).astype(int), 0, len(self.times) - 1)


def _grid(duration: float, rate: float = 1000.0) -> np.ndarray:
    return np.arange(int(round(duration * rate)) + 1) / rate


def still_led(*, duration: float = 2.0, position=(300.0, 200.0, 1000.0)) -> LedScene:
    """One LED held still, pointing up."""
    t = _grid(duration)
    pos = np.broadcast_to(as_array(position, "position", shape=(3,)), (len(t), 1, 3)).copy()
    nrm = np.zeros_like(pos)
    nrm[..., 2] = 1
    return LedScene(name="still", times=t, positions=pos, normals=nrm, on=np.array([[0.0, np.inf]]))


def linear_stage(*, duration: float = 6.0, start=(-600.0, -400.0, 900.0),
                 end=(600.0, 600.0, 1100.0), hold: float = 1.0) -> LedScene:
    """An LED on a linear translation stage: still for ``hold`` s, then moving at constant
    speed from ``start`` to ``end`` (mm), then still again for ``hold`` s."""
    t = _grid(duration)
    a, b = as_array(start, "start", shape=(3,)), as_array(end, "end", shape=(3,))
    hold = as_scalar(hold, "hold", nonnegative=True)
    if 2 * hold >= duration:
        raise ValueError("hold: expected less than half the duration")
    s = np.clip((t - hold) / (duration - 2 * hold), 0, 1)
    pos = (a + s[:, None] * (b - a))[:, None, :]
    nrm = np.zeros_like(pos)
    nrm[..., 2] = 1
    return LedScene(name="linear stage", times=t, positions=pos, normals=nrm,
                    on=np.array([[0.0, np.inf]]))


def circle_led(*, duration: float = 4.0, centre=(0.0, 0.0, 1000.0), radius: float = 300.0,
               period: float = 1.0) -> LedScene:
    """An LED moved in a horizontal circle of ``radius`` mm once every ``period`` s."""
    t = _grid(duration)
    c = as_array(centre, "centre", shape=(3,))
    radius = as_scalar(radius, "radius", positive=True)
    w = 2 * np.pi / as_scalar(period, "period", positive=True)
    pos = np.stack([c[0] + radius * np.cos(w * t), c[1] + radius * np.sin(w * t),
                    np.full_like(t, c[2])], axis=1)[:, None, :]
    nrm = np.zeros_like(pos)
    nrm[..., 2] = 1
    return LedScene(name="circle", times=t, positions=pos, normals=nrm,
                    on=np.array([[0.0, np.inf]]))


def walking_person(*, duration: float = 3.6, rng: np.random.Generator | int | None = None,
                   start=(0.0, -2000.0), heading_deg: float = 90.0, speed: float = 1200.0,
                   on=None) -> LedScene:
    """Eight LEDs (:data:`LED_NAMES`: head, shoulders, elbows, wrists, waist) on the walking,
    arm-swinging body of :mod:`lsmta.synth.body`, crossing the floor.

    Parameters
    ----------
    duration : float
        s.
    start : (float, float)
        Start of the pelvis on the floor, mm.
    heading_deg : float
        Walking direction, degrees anticlockwise from +X.
    speed : float
        mm/s.
    on : (8, 2) array, optional
        Switch-on and switch-off times (s); default: on at 0.1-0.45 s, off at 2.8-3.15 s,
        staggered, so that births and deaths can be timed.
    """
    rate = 1000.0
    n = int(round(duration * rate)) + 1
    body = make_body(rng=np.random.default_rng(0) if rng is None else rng)
    motion = walk(n_frames=n, fps=rate, start=start, heading_deg=heading_deg, speed=speed)
    poses = body.part_poses(motion)                                   # (S, P, 4, 4)
    parts = np.array([body.index(p) for p, _, _ in _LED_PLACES])
    local = np.array([q for _, q, _ in _LED_PLACES])
    nrm_local = np.array([v for _, _, v in _LED_PLACES])
    nrm_local /= np.linalg.norm(nrm_local, axis=1, keepdims=True)
    sel = poses[:, parts]
    R = sel[..., :3, :3]
    pos = np.einsum("snij,nj->sni", R, local) + sel[..., :3, 3]
    nrm = np.einsum("snij,nj->sni", R, nrm_local)
    if on is None:
        k = np.arange(len(LED_NAMES))
        on = np.stack([0.1 + 0.05 * k, 2.8 + 0.05 * k], axis=1)
    on = as_array(on, "on", shape=(len(LED_NAMES), 2), finite=False)
    if np.isnan(on).any():
        raise ValueError("on: expected switch-on and switch-off times (inf: never off), got NaN")
    ell = np.array([[p.centre, p.radii] for p in body.parts], dtype=float)
    return LedScene(name="walking person", times=motion.times, positions=pos, normals=nrm, on=on,
                    occluders=poses, ellipsoids=ell, led_part=parts)


@dataclass(frozen=True)
class WideAreaObservations:
    """Generated frames and their ground truth.

    Attributes
    ----------
    frames : Frames
        What the estimator receives (in arrival order): camera, stamp, centroids, arrival.
    true_time : (F,) array
        When each frame was really captured, s.
    truth : (M,) int array
        LED index behind each centroid; -1 for clutter.
    visible : (F, N) bool array
        Which LEDs each frame saw.
    """

    frames: Frames
    true_time: np.ndarray
    truth: np.ndarray
    visible: np.ndarray


def _occluded(scene: LedScene, cam_C, t, positions, normals) -> np.ndarray:
    """(T, N) bool: the segment LED -> camera centre crosses a body ellipsoid."""
    if scene.occluders is None:
        return np.zeros(positions.shape[:2], bool)
    poses = scene.occluders[scene._nearest(t)]                          # (T, P, 4, 4)
    start = positions + 20.0 * normals                                   # off the skin
    seg = cam_C[None, None, :] - start                                   # (T, N, 3)
    R = poses[:, :, :3, :3]
    # start and direction in each part's frame, scaled to the unit sphere
    rel = start[:, :, None, :] - poses[:, None, :, :3, 3]               # (T, N, P, 3)
    o = np.einsum("tpji,tnpj->tnpi", R, rel) - scene.ellipsoids[None, None, :, 0]
    d = np.einsum("tpji,tnj->tnpi", R, seg)
    radii = scene.ellipsoids[None, None, :, 1] * 0.95
    o, d = o / radii, d / radii
    a = (d * d).sum(-1)
    b = 2 * (o * d).sum(-1)
    c = (o * o).sum(-1) - 1
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(np.where(disc > 0, disc, np.nan))
        t1 = (-b - sq) / (2 * a)
        t2 = (-b + sq) / (2 * a)
    hit = (disc > 0) & (t2 > 0) & (t1 < 1)
    return hit.any(axis=2)


@dataclass(frozen=True)
class LedCentroidParams:
    """Settings of :func:`observe_leds` (the centroids a detector would report).

    Attributes
    ----------
    noise_px : float
        Centroid noise (px, per axis) of an LED at unit brightness; it grows as
        ``1 / sqrt(brightness)``, up to three times.
    quantize : bool
        Round centroids to whole pixels (the thesis's detector had no sub-pixel estimate).
    led_range : float
        Distance (mm) at which an on-axis LED has unit brightness; brightness falls as
        ``(led_range / distance)² * cos(angle)^led_exponent``.
    led_exponent : float
    min_brightness : float
        LEDs dimmer than this are not detected.
    reflections : float
        Mean number of spurious centroids per frame anywhere in the image.
    monitors : dict, optional
        ``{camera index: (x0, y0, x1, y1)}`` pixel rectangles of bright monitors, each
        giving Poisson(``monitor_rate``) false centroids per frame.
    monitor_rate : float
    """

    noise_px: float = 0.3
    quantize: bool = False
    led_range: float = 4500.0
    led_exponent: float = 1.5
    min_brightness: float = 0.1
    reflections: float = 0.05
    monitors: dict | None = None
    monitor_rate: float = 1.0

    def __post_init__(self):
        for key in ("noise_px", "min_brightness", "reflections", "monitor_rate"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_scalar(self.led_range, "led_range", positive=True)
        as_scalar(self.led_exponent, "led_exponent")


def observe_leds(scene: LedScene, cameras, clocks: Clocks, *,
                 rng: np.random.Generator | int | None = None, duration: float | None = None,
                 params: LedCentroidParams | None = None) -> WideAreaObservations:
    """Per-frame LED centroids from every camera (projection + noise, no images).

    Parameters
    ----------
    scene : LedScene
    cameras : sequence of K Camera
    clocks : Clocks
    rng : numpy.random.Generator, int or None
    duration : float, optional
        Seconds to observe (default: the scene's length).
    params : LedCentroidParams, optional
        Noise, brightness, clutter (default: ``LedCentroidParams()``).
    """
    p = LedCentroidParams() if params is None else params
    noise_px, quantize, led_range, led_exponent = (p.noise_px, p.quantize, p.led_range,
                                                   p.led_exponent)
    min_brightness, reflections, monitors, monitor_rate = (p.min_brightness, p.reflections,
                                                           p.monitors, p.monitor_rate)
    rng = as_rng(rng)
    cameras = list(cameras)
    duration = float(scene.times[-1] if duration is None else duration)
    monitors = {} if monitors is None else dict(monitors)
    rows = []  # (true_time, camera, stamp, arrival, xy (n,2), truth (n,), visible (N,))
    for k, cam in enumerate(cameras):
        tt = clocks.phase[k] + np.arange(0, duration * clocks.rate[k]) / clocks.rate[k]
        tt = tt[tt < duration]
        pos = scene.positions_at(tt)                                       # (T, N, 3)
        idx = scene._nearest(tt)
        nrm = scene.normals[idx]
        T, N = pos.shape[:2]
        on = np.isfinite(pos).all(axis=2)
        safe = np.where(on[..., None], pos, 0.0)
        xy = cam.project(safe.reshape(-1, 3), behind="nan").reshape(T, N, 2)
        to_cam = cam.C - safe
        dist = np.linalg.norm(to_cam, axis=2)
        cos = np.einsum("tnc,tnc->tn", nrm, to_cam) / dist
        bright = (led_range / dist) ** 2 * np.clip(cos, 0, None) ** led_exponent
        vis = (on & cam.in_image(xy.reshape(-1, 2)).reshape(T, N) & (bright >= min_brightness)
               & ~_occluded(scene, cam.C, tt, safe, nrm))
        sigma = noise_px * np.minimum(1 / np.sqrt(np.maximum(bright, 1e-9)), 3.0)
        noisy = xy + rng.normal(size=xy.shape) * sigma[..., None]
        if quantize:
            noisy = np.rint(noisy)
        lat = clocks.latency[k] + clocks.jitter * np.abs(rng.normal(size=T))
        for i in range(T):
            pts = [noisy[i, vis[i]]]
            who = [np.flatnonzero(vis[i])]
            n_ref = rng.poisson(reflections)
            if n_ref:
                pts.append(rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n_ref, 2)))
                who.append(np.full(n_ref, -1))
            if k in monitors:
                x0, y0, x1, y1 = monitors[k]
                n_mon = rng.poisson(monitor_rate)
                pts.append(rng.uniform([x0, y0], [x1, y1], (n_mon, 2)))
                who.append(np.full(n_mon, -1))
            p = np.concatenate(pts)
            order = rng.permutation(len(p))
            rows.append((tt[i], k, tt[i] + clocks.offset[k], tt[i] + lat[i], p[order],
                         np.concatenate(who)[order], vis[i]))
    rows.sort(key=lambda r: r[3])
    frames = Frames.from_lists([r[1] for r in rows], [r[2] for r in rows],
                               [r[4] for r in rows], arrival=np.array([r[3] for r in rows]))
    return WideAreaObservations(
        frames=frames, true_time=np.array([r[0] for r in rows]),
        truth=np.concatenate([r[5] for r in rows]).astype(np.int64),
        visible=np.array([r[6] for r in rows], dtype=bool).reshape(len(rows), -1))


# ----------------------------------------------------------------------------- images
@dataclass(frozen=True, eq=False)
class LedVideo:
    """Rendered grey frames of one camera and their ground truth.

    Attributes
    ----------
    camera : Camera
    times : (T,) array
        Capture times, s.
    frames : (T, H, W) uint8 array
    background : (B, H, W) uint8 array
        Frames of the empty room (no LEDs), for learning thresholds.
    true_xy : (T, N, 2) array
        Projected LED positions, px (NaN where not visible).
    monitor : (4,) array
        The monitor's rectangle (x0, y0, x1, y1), px.
    lighting_change : int or None
        First frame after the room lights were turned up.
    """

    camera: Camera
    times: np.ndarray
    frames: np.ndarray
    background: np.ndarray
    true_xy: np.ndarray
    monitor: np.ndarray
    lighting_change: int | None


def small_camera(camera: Camera, *, scale: float = 0.5) -> Camera:
    """The same camera with its image scaled by ``scale`` (fewer, larger pixels)."""
    w, h = int(round(camera.width * scale)), int(round(camera.height * scale))
    return camera.replace(f=camera.f * scale, width=w, height=h,
                          cx=(camera.cx + 0.5) * scale - 0.5, cy=(camera.cy + 0.5) * scale - 0.5)


@dataclass(frozen=True)
class LedVideoParams:
    """Settings of :func:`render_led_video` (grey levels, pixels, millimetres).

    Attributes
    ----------
    led_peak : float
        Peak grey level of an LED spot at unit brightness.
    led_sigma : float
        Spot radius (Gaussian sigma), px.
    led_range, led_exponent : float
        Brightness falling with distance and angle, as in :class:`LedCentroidParams`.
    noise : float
        Image noise, grey levels.
    monitor : (4,) tuple
        The monitor's rectangle as fractions of the image, (x0, y0, x1, y1).
    monitor_flicker : float
        Fraction of frames in which the monitor shows a bright white window.
    reflections : float
        Mean number of bright specks per frame anywhere in the image.
    n_background : int
        Frames of the empty room rendered for learning thresholds.
    """

    led_peak: float = 230.0
    led_sigma: float = 0.9
    led_range: float = 4500.0
    led_exponent: float = 1.5
    noise: float = 2.0
    monitor: tuple = (0.08, 0.55, 0.3, 0.8)
    monitor_flicker: float = 0.3
    reflections: float = 0.03
    n_background: int = 20

    def __post_init__(self):
        for key in ("led_sigma", "led_range"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("led_peak", "noise", "monitor_flicker", "reflections"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_scalar(self.led_exponent, "led_exponent")
        as_vector(self.monitor, "monitor", 4)
        as_int(self.n_background, "n_background")


def render_led_video(scene: LedScene, camera: Camera, times, *,
                     rng: np.random.Generator | int | None = None,
                     lighting_change: int | None = None,
                     params: LedVideoParams | None = None) -> LedVideo:
    """Render small grey frames of LEDs for the detector.

    The room is a smooth grey texture with a lamp; a monitor (rectangle given as fractions
    of the image, x0, y0, x1, y1) shows a changing picture and, in a fraction
    ``monitor_flicker`` of the frames, a bright white window that exceeds anything it
    showed while the thresholds were learnt. LEDs are Gaussian spots (``led_sigma`` px) whose
    peak falls with distance and angle as in :func:`observe_leds`, occluded by the body;
    ``reflections`` bright specks per frame appear anywhere. From frame
    ``lighting_change`` on, the room is 35 % brighter. Grey levels are rounded to uint8.
    The settings are ``params`` (default: ``LedVideoParams()``).
    """
    p = LedVideoParams() if params is None else params
    noise, monitor, monitor_flicker, reflections, n_background = (
        p.noise, p.monitor, p.monitor_flicker, p.reflections, p.n_background)
    rng = as_rng(rng)
    times = np.asarray(times, dtype=float)
    H, W = camera.height, camera.width
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    room = 50 + 15 * np.sin(xx / 23.0 + 1.3 * np.sin(yy / 37.0)) + 10 * np.cos(yy / 17.0)
    room += 120 * np.exp(-((xx - 0.8 * W) ** 2 + (yy - 0.15 * H) ** 2) / (2 * (0.03 * W) ** 2))
    mx0, my0, mx1, my1 = (np.array(monitor) * [W, H, W, H]).round().astype(int)
    in_mon = (xx >= mx0) & (xx < mx1) & (yy >= my0) & (yy < my1)
    mon_pattern = 30 * np.sin(xx[in_mon] / 5.0)[None]

    def base(pic, lit):
        out = np.repeat(room[None], len(pic), axis=0)
        out[:, in_mon] = pic + mon_pattern
        out *= lit[:, None, None]
        return out

    T = len(times)
    lit = np.ones(T)
    if lighting_change is not None:
        lit[lighting_change:] = 1.35
    # the random numbers in the order of a whole-video rendering (the monitor's pictures, its
    # white windows, the reflections, then the image noise frame after frame), so that
    # rendering blocks of frames (far less memory traffic) gives the same frames
    pic = 120 + 40 * rng.random((T, 1))
    windows = [(t, rng.integers(mx0, max(mx0 + 1, mx1 - 8)),
                rng.integers(my0, max(my0 + 1, my1 - 6)))
               for t in np.flatnonzero(rng.random(T) < monitor_flicker)]
    xy, vis, peak = _led_spots(scene, camera, times, p)
    specks = [(t, rng.uniform(0, W - 1), rng.uniform(0, H - 1))
              for t in range(T) for _ in range(rng.poisson(reflections))]
    frames = np.empty((T, H, W), np.uint8)
    z = np.empty((min(T, _BLOCK), H, W))
    for a in range(0, T, _BLOCK):
        b = min(a + _BLOCK, T)
        block = base(pic[a:b], lit[a:b])
        for t, w0, h0 in windows:
            if a <= t < b:
                block[t - a, h0:h0 + 6, w0:w0 + 8] = 250
        _add_spots(block, xy[a:b], vis[a:b], peak[a:b], p.led_sigma)
        for t, x, y in specks:
            if a <= t < b:
                block[t - a] += 180 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.7**2))
        block += _normal(rng, noise, z[:b - a])
        frames[a:b] = _grey8(block)
    background = base(120 + 40 * rng.random((n_background, 1)), np.ones(n_background))
    background += _normal(rng, noise, np.empty((n_background, H, W)))
    return LedVideo(camera=camera, times=times, frames=frames,
                    background=_grey8(background),
                    true_xy=np.where(vis[..., None], xy, np.nan),
                    monitor=np.array([mx0, my0, mx1, my1], float),
                    lighting_change=lighting_change)


_BLOCK = 16     # frames rendered at a time by render_led_video


def _normal(rng: np.random.Generator, sigma: float, out: np.ndarray) -> np.ndarray:
    """``rng.normal(0, sigma, out.shape)`` written into ``out`` (and returned): the same
    numbers, three times faster (no per-element loc and scale)."""
    rng.standard_normal(out=out)
    out *= sigma
    return out


def _grey8(x) -> np.ndarray:
    """Float grey levels ``x`` (any shape, e.g. (T, H, W) frames or an (H, W) background)
    rounded and clipped to uint8 (same shape), in place in ``x`` (a scratch array, changed;
    ``np.clip`` into a new array took ten times as long on a walk's frames)."""
    np.rint(x, out=x)
    np.clip(x, 0, 255, out=x)
    return x.astype(np.uint8)


def _led_spots(scene: LedScene, camera: Camera, times, p: LedVideoParams):
    """The LEDs' image positions ``(T, N, 2)`` px, visibility ``(T, N)`` bool and spot peaks
    ``(T, N)`` grey levels (``led_peak`` times the brightness, at most 1.5) at ``times``."""
    led_range, led_exponent = p.led_range, p.led_exponent
    T = len(times)
    pos = scene.positions_at(times)
    nrm = scene.normals[scene._nearest(times)]
    N = pos.shape[1]
    on = np.isfinite(pos).all(axis=2)
    safe = np.where(on[..., None], pos, 0.0)
    xy = camera.project(safe.reshape(-1, 3), behind="nan").reshape(T, N, 2)
    to_cam = camera.C - safe
    dist = np.linalg.norm(to_cam, axis=2)
    cos = np.einsum("tnc,tnc->tn", nrm, to_cam) / dist
    bright = (led_range / dist) ** 2 * np.clip(cos, 0, None) ** led_exponent
    vis = on & camera.in_image(xy.reshape(-1, 2)).reshape(T, N) & ~_occluded(
        scene, camera.C, times, safe, nrm) & (bright > 0.05)
    return xy, vis, p.led_peak * np.minimum(bright, 1.5)


def _add_spots(frames, xy, vis, peak, led_sigma: float) -> None:
    """Add Gaussian spots (sigma ``led_sigma`` px, peaks ``peak`` ``(T, N)`` grey levels) at
    the visible (``vis`` ``(T, N)``) image positions ``xy`` ``(T, N, 2)`` px to ``frames``
    ``(T, H, W)`` float, in place."""
    T, H, W = frames.shape
    r = int(np.ceil(4 * led_sigma))
    for t, n in zip(*np.nonzero(vis)):
        x, y = xy[t, n]
        c0, r0 = int(round(x)) - r, int(round(y)) - r
        cs, rs = np.arange(c0, c0 + 2 * r + 1), np.arange(r0, r0 + 2 * r + 1)
        ok_c, ok_r = (cs >= 0) & (cs < W), (rs >= 0) & (rs < H)
        g = np.exp(-((cs[None, ok_c] - x) ** 2 + (rs[ok_r, None] - y) ** 2)
                   / (2 * led_sigma**2))
        frames[t, rs[ok_r][:, None], cs[ok_c][None, :]] += peak[t, n] * g
