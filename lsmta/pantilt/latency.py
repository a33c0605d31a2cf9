"""Keeping a moving target in a pan-tilt frame despite latency (Davis 2002, Sections 4.3-4.4).

A simulation of the thesis's control loop, one function, :func:`simulate_tracking`:

1. The wide-area system measures the target (noise ``KalmanCV.measurement_sigma``, about
   10 mm) at ``KalmanCV.rate`` and a constant-velocity Kalman filter
   (:func:`constant_velocity_filter`) estimates its position P and velocity V; the
   estimate reaches the camera controller ``Control.estimate_delay`` seconds later.
2. At ``Control.command_rate`` (15-30 Hz in the thesis) the controller takes the latest
   estimate, predicts ``P + Δt V`` (``Control.lead`` = Δt; 0 switches prediction off),
   smooths it with the damping filter ``S <- S + α (P' - S)`` (``Control.damping`` = α;
   1 = no damping), and aims the camera at S by the local search of
   :func:`lsmta.pantilt.aim` from the previous command (both by
   :class:`lsmta.pantilt.steering.Pointer`, which the mixed-scale system steers with too).
3. The head (:class:`Motor`) starts moving towards a command ``Motor.latency`` seconds after
   it was issued, at a speed proportional to the change still needed (reach it in one
   command period) but at most ``Motor.max_rate``, and its position is quantised to
   ``Motor.quantum`` degrees (a stepper).
4. At ``video_rate`` the true head images the true target; the deviation is the target's
   distance from the principal point in pixels.

Where the thesis is vague (the damping constant, the speed law, the Kalman process noise,
the share of the 300 ms that is the wide-area pipeline's), the defaults are our choice and
are parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_points, as_rng, as_scalar, freeze
from ..widearea.kalman import process_noise
from .model import PanTiltCamera
from .steering import Pointer


@dataclass(frozen=True)
class Motor:
    """The head's response. ``latency`` in s (thesis: at least 250 ms of its 300 ms),
    ``max_rate`` (pan, tilt) in degrees/s (EVI-D30 data sheet: 80 and 50), ``quantum`` the
    position step in degrees (0.1)."""

    latency: float = 0.25
    max_rate: tuple[float, float] = (80.0, 50.0)
    quantum: float = 0.1


@dataclass(frozen=True)
class Control:
    """The controller. ``command_rate`` in Hz, ``lead`` the prediction time Δt in s (0: no
    prediction; thesis: 0.3), ``damping`` α in (0, 1] (1: no damping filter),
    ``estimate_delay`` the age of the wide-area estimate when it arrives, s."""

    command_rate: float = 20.0
    lead: float = 0.3
    damping: float = 1.0
    estimate_delay: float = 0.05


@dataclass(frozen=True)
class KalmanCV:
    """The wide-area estimate: measurement noise ``measurement_sigma`` (mm, per axis) at
    ``rate`` Hz, constant-velocity model with white acceleration of spectral density
    ``accel_density`` (mm² / s³)."""

    measurement_sigma: float = 10.0
    rate: float = 60.0
    accel_density: float = 1.0e6


@dataclass(frozen=True, eq=False)
class TrackingRun:
    """One simulated run.

    Attributes
    ----------
    times : (F,) array
        Video frame times, s.
    xy : (F, 2) array
        Target's image position in each frame, pixels (NaN when behind the camera).
    deviation_px : (F,) array
        Distance from the principal point, pixels (inf when behind the camera).
    in_frame : (F,) bool array
        Target inside the image.
    settings : (F, 2) array
        The head's actual (quantised) pan and tilt at each frame, degrees.
    command_times : (K,) array
        When commands were issued, s.
    commands : (K, 2) array
        Commanded pan and tilt, degrees.
    unreachable : int
        Commands whose aim point the head could not centre (clipped to its range).
    estimate_error_mm : (M,) array
        Distance of each Kalman position estimate from the truth, mm.
    """

    times: np.ndarray
    xy: np.ndarray
    deviation_px: np.ndarray
    in_frame: np.ndarray
    settings: np.ndarray
    command_times: np.ndarray
    commands: np.ndarray
    unreachable: int
    estimate_error_mm: np.ndarray

    def __post_init__(self):
        freeze(self, ("times", "xy", "deviation_px", "in_frame", "settings", "command_times",
                       "commands", "estimate_error_mm"))

    @property
    def command_jitter_deg(self) -> float:
        """RMS second difference of successive commands, degrees: how much the commanded
        motion wobbles (what the damping filter is for)."""
        if len(self.commands) < 3:
            return 0.0
        return float(np.sqrt(np.mean(np.sum(np.diff(self.commands, 2, axis=0) ** 2, axis=1))))

    @property
    def mean_deviation_px(self) -> float:
        """Mean deviation over the frames where the target is in front of the camera."""
        d = self.deviation_px[np.isfinite(self.deviation_px)]
        return float(d.mean()) if d.size else float("inf")


def constant_velocity_filter(times, z, *, sigma: float, accel_density: float):
    """Kalman filter with a constant-velocity model, the three axes independent.

    Parameters
    ----------
    times : (M,) array
        Measurement times, s, increasing.
    z : (M, 3) array
        Measured positions, mm.
    sigma : float
        Measurement noise per axis, mm.
    accel_density : float
        Spectral density of the white acceleration, mm²/s³.

    Returns
    -------
    P, V : (M, 3) arrays
        Filtered position (mm) and velocity (mm/s) after each measurement.
    """
    times = as_array(times, "times", shape=(None,))
    z = as_points(z, "z")
    if len(z) != len(times):
        raise ValueError(f"z: expected {len(times)} measurements like times, got {len(z)}")
    if np.any(np.diff(times) <= 0):
        raise ValueError("times: expected strictly increasing times")
    sigma = as_scalar(sigma, "sigma", positive=True)
    q = as_scalar(accel_density, "accel_density", positive=True)
    x = np.zeros((2, 3))
    x[0] = z[0]
    cov = np.diag([sigma**2, 1e8])
    P = np.empty_like(z)
    V = np.empty_like(z)
    P[0], V[0] = x
    r = sigma**2
    for k in range(1, len(z)):
        dt = times[k] - times[k - 1]
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = process_noise(dt, q)
        x = F @ x
        cov = F @ cov @ F.T + Q
        gain = cov[:, 0] / (cov[0, 0] + r)
        x = x + gain[:, None] * (z[k] - x[0])[None, :]
        cov = cov - np.outer(gain, cov[0])
        P[k], V[k] = x
    return P, V


def simulate_tracking(camera: PanTiltCamera, trajectory, rate: float, *,
                      rng: np.random.Generator | int | None = None,
                      aim_model: PanTiltCamera | None = None, motor: Motor = Motor(),
                      control: Control = Control(), kalman: KalmanCV = KalmanCV(),
                      video_rate: float = 30.0, start=(0.0, 0.0)) -> TrackingRun:
    """Simulate the pan-tilt camera following a target (see the module docstring).

    Parameters
    ----------
    camera : PanTiltCamera
        The true head (it makes the images).
    trajectory : (T, 3) array
        True target positions, mm, sampled at ``rate`` Hz (the simulation step; at least
        four times the video, measurement and command rates is sensible).
    rate : float
        Sampling rate of ``trajectory``, Hz.
    rng : numpy.random.Generator, int or None
        For the measurement noise.
    aim_model : PanTiltCamera, optional
        The calibrated model the controller aims with (default: ``camera``).
    motor, control, kalman : Motor, Control, KalmanCV
        Parameters.
    video_rate : float
        Frame rate of the pan-tilt video, Hz.
    start : (2,) array
        The head's setting (pan, tilt in degrees) when the run starts.

    Returns
    -------
    TrackingRun
    """
    rng = as_rng(rng)
    if not isinstance(camera, PanTiltCamera):
        raise TypeError(f"camera: expected a PanTiltCamera, got {type(camera).__name__}")
    aim_model = camera if aim_model is None else aim_model
    traj = as_points(trajectory, "trajectory")
    rate = as_scalar(rate, "rate", positive=True)
    video_rate = as_scalar(video_rate, "video_rate", positive=True)
    for name, value in (("control.command_rate", control.command_rate),
                        ("kalman.rate", kalman.rate), ("video_rate", video_rate)):
        if not 0 < value <= rate:
            raise ValueError(f"{name}: expected a rate in (0, rate={rate:g}] Hz, got {value}")
    if not 0 < control.damping <= 1:
        raise ValueError(f"control.damping: expected a number in (0, 1], got {control.damping}")
    for name, value in (("motor.latency", motor.latency), ("control.lead", control.lead),
                        ("control.estimate_delay", control.estimate_delay)):
        if value < 0:
            raise ValueError(f"{name}: expected a time >= 0 s, got {value}")
    start = np.array(as_array(start, "start", shape=(2,)))
    camera.check(start[0], start[1])
    dt = 1.0 / rate
    t = np.arange(len(traj)) * dt
    # 1. wide-area estimate
    m_idx = _ticks(t, kalman.rate)
    z = traj[m_idx] + rng.normal(0, kalman.measurement_sigma, (len(m_idx), 3))
    P, V = constant_velocity_filter(t[m_idx], z, sigma=kalman.measurement_sigma,
                                    accel_density=kalman.accel_density)
    # 2. commands, 3. motor, 4. video
    c_idx, commands, unreachable = _commands(aim_model, t, P, V,
                                             t[m_idx] + control.estimate_delay, control, start)
    frames, settings = _drive_and_film(t, dt, t[c_idx] + motor.latency, commands, motor,
                                       1.0 / control.command_rate, _ticks(t, video_rate), start)
    settings = np.clip(settings, [camera.pan_limits[0], camera.tilt_limits[0]],
                       [camera.pan_limits[1], camera.tilt_limits[1]])
    xy = camera.project(traj[frames], settings[:, 0], settings[:, 1], behind="nan")
    dev = np.hypot(xy[:, 0] - camera.camera.cx, xy[:, 1] - camera.camera.cy)
    return TrackingRun(times=t[frames], xy=xy,
                       deviation_px=np.where(np.isfinite(dev), dev, np.inf),
                       in_frame=camera.camera.in_image(xy), settings=settings,
                       command_times=t[c_idx], commands=commands, unreachable=unreachable,
                       estimate_error_mm=np.linalg.norm(P - traj[m_idx], axis=1))


def _ticks(t, r: float) -> np.ndarray:
    """Indices of the simulation steps ``t`` at which a clock of ``r`` Hz ticks."""
    return np.flatnonzero(np.diff(np.floor(t * r + 1e-9), prepend=-1) > 0)


def _commands(aim_model, t, P, V, available, control: Control, start):
    """At the command rate, once an estimate has arrived: predict the latest estimate
    ``P + lead V``, damp it, and aim at it from the previous command. Returns the command
    steps, the commands (pan, tilt degrees) and how many targets were unreachable."""
    c_idx = _ticks(t, control.command_rate)
    c_idx = c_idx[t[c_idx] >= available[0]]
    commands = np.empty((len(c_idx), 2))
    pointer = Pointer([aim_model], [start.copy()], damping=control.damping)
    unreachable = 0
    for k, i in enumerate(c_idx):
        j = np.searchsorted(available, t[i], side="right") - 1
        (a,) = pointer.point(P[j] + control.lead * V[j])
        unreachable += int(not a.reachable[0])
        commands[k] = pointer.current[0]
    return c_idx, commands, unreachable


def _drive_and_film(t, dt: float, active_at, commands, motor: Motor, period: float, video,
                    start):
    """The head moves towards each command from its active time on, at a speed that reaches
    it in one command period but at most the motor's rate; at the video steps its
    (quantised) setting is recorded. Returns the video steps and the settings."""
    max_rate = np.asarray(motor.max_rate, dtype=float)
    pos = start.copy()
    goal = pos.copy()
    speed = np.zeros(2)
    next_cmd = 0
    v_idx = set(video.tolist())
    frames, settings = [], []
    for i in range(len(t)):
        while next_cmd < len(active_at) and active_at[next_cmd] <= t[i] + 1e-12:
            goal = commands[next_cmd]
            speed = np.minimum(np.abs(goal - pos) / period, max_rate)
            next_cmd += 1
        pos = pos + np.clip(goal - pos, -speed * dt, speed * dt)
        if i in v_idx:
            frames.append(i)
            settings.append(np.round(pos / motor.quantum) * motor.quantum)
    return np.array(frames), np.array(settings)
