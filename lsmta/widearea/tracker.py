"""The central estimator of the wide-area system (Davis 2002, §§3.4-3.6).

One loop over the frames in the order the estimator takes them up (see
:mod:`lsmta.widearea.scheduler` for the queue policies). The estimator keeps a single
clock, ``now``: the newest time stamp it has used. For each frame:

1. reject bad input, counting it (unknown camera, time stamp not after that camera's
   previous one, non-finite stamp, NaN centroids; empty frames are counted and only
   advance the clock);
2. a frame older than ``now`` by more than ``late_tolerance`` is dropped (the naive
   "discard late" policy is ``late_tolerance = 0``); a newer one predicts every target to
   its stamp (:func:`lsmta.widearea.kalman.predict`);
3. targets seen by fewer than two cameras within ``timeout`` die
   (:func:`lsmta.widearea.management.starved`);
4. targets are projected into the camera, retrodicted by the frame's lag, and paired with
   centroids (:func:`lsmta.widearea.association.associate`); each pair is one extended
   Kalman update (:func:`lsmta.widearea.kalman.ekf_update`);
5. centroids no target took become rays; a ray that meets a fresh ray of another camera
   within ``birth_tolerance`` starts a target (:func:`lsmta.widearea.management.find_birth`).

Target identities are integers that are never reused.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array, as_scalar
from ..camera import Camera
from .association import associate, innovation_gate
from .kalman import innovation_covariance, kalman_update, measurement, predict
from .management import RayPool, starved
from .observations import FrameIntake, Frames


@dataclass(frozen=True)
class EstimatorParams:
    """Settings of the estimator (units: px, mm, s, mm²/s³).

    Attributes
    ----------
    sigma_px : float
        Standard deviation of a centroid per image axis, pixels.
    accel_density : float
        Acceleration spectral density ``q`` of the constant-velocity model, mm²/s³: the
        strength of the motion model (small: stiff; large: weak).
    gate_px : float
        Largest association gate, pixels.
    gate_sigma : float
        The gate of a target is ``gate_sigma`` standard deviations of its predicted
        centroid (larger axis of the innovation covariance), between ``min_gate_px`` and
        ``gate_px``.
    min_gate_px : float
        Smallest association gate, pixels.
    late_tolerance : float
        Frames older than the estimator's clock by up to this are used (the expected clock
        discrepancy); older ones are dropped. 0 is the naive discard-late policy.
    birth_tolerance : float
        Rays closer than this may start a target, mm (thesis: 15).
    staleness : float
        Unassociated rays older than this do not take part in births, s (thesis: 0.070).
    timeout : float
        A target seen by fewer than two cameras for this long dies, s (thesis: 0.1-0.3).
    birth_sigma : (float, float)
        Initial standard deviation of a new target's position (mm) and velocity (mm/s).
    min_separation : float
        No birth closer than this to an existing target, mm.
    volume : ((3,), (3,)) or None
        Box (lower, upper corner, mm) where births may happen.
    """

    sigma_px: float = 0.5
    accel_density: float = 4e6
    gate_px: float = 15.0
    gate_sigma: float = 4.0
    min_gate_px: float = 2.0
    late_tolerance: float = 0.030
    birth_tolerance: float = 15.0
    staleness: float = 0.070
    timeout: float = 0.150
    birth_sigma: tuple = (15.0, 1500.0)
    min_separation: float = 40.0
    volume: tuple | None = ((-2500.0, -3000.0, 0.0), (2500.0, 3000.0, 2500.0))

    def __post_init__(self):
        for key in ("sigma_px", "gate_px", "gate_sigma", "min_gate_px", "birth_tolerance",
                    "timeout"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("accel_density", "late_tolerance", "staleness", "min_separation"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_array(self.birth_sigma, "birth_sigma", shape=(2,))
        if self.volume is not None:
            as_array(self.volume, "volume", shape=(2, 3))


@dataclass(frozen=True)
class WideAreaTrack:
    """One target's life.

    Attributes
    ----------
    id : int
    times : (n,) array
        Times of the recorded states (birth and every update), s.
    states : (n, 6) array
        Filtered states at those times (mm, mm/s).
    birth_time, death_time : float
        s; ``death_time`` is NaN for a target alive at the end.
    """

    id: int
    times: np.ndarray
    states: np.ndarray
    birth_time: float
    death_time: float

    def positions_at(self, t) -> np.ndarray:
        """Real-time estimate ``(T, 3)`` at times ``t``: the last recorded state carried
        forward at constant velocity; NaN before birth and from death on."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        k = np.searchsorted(self.times, t, side="right") - 1
        alive = (k >= 0) & ~(t >= self.death_time)
        kk = np.clip(k, 0, None)
        dt = (t - self.times[kk])[:, None]
        out = self.states[kk, :3] + dt * self.states[kk, 3:]
        out[~alive] = np.nan
        return out


@dataclass(frozen=True)
class TrackingResult:
    """Tracks and the bookkeeping of one run.

    Attributes
    ----------
    tracks : tuple of WideAreaTrack
    frames_received, frames_used, late_dropped, late_used, observations_used : (K,) arrays
        Per camera: valid frames seen; frames used (not dropped as late); frames dropped as
        too late; frames used although older than the clock; centroids that updated a target.
    unknown_camera, backwards_time, nonfinite_stamp, empty_frames, nan_centroids : int
        Rejected or empty input, counted.
    updates : dict of arrays
        One row per Kalman update: ``target`` id, ``camera``, ``time`` (s), ``predicted``
        and ``observed`` centroids (px) — for plots like the thesis's Fig. 44.
    """

    tracks: tuple
    frames_received: np.ndarray
    frames_used: np.ndarray
    late_dropped: np.ndarray
    late_used: np.ndarray
    observations_used: np.ndarray
    unknown_camera: int
    backwards_time: int
    nonfinite_stamp: int
    empty_frames: int
    nan_centroids: int
    updates: dict = field(default_factory=dict)

    @property
    def rejected(self) -> dict:
        """The counters of rejected input, by name."""
        return {"unknown_camera": self.unknown_camera, "backwards_time": self.backwards_time,
                "nonfinite_stamp": self.nonfinite_stamp, "empty_frames": self.empty_frames,
                "nan_centroids": self.nan_centroids,
                "late_dropped": int(self.late_dropped.sum())}

    def positions_at(self, t) -> np.ndarray:
        """Positions ``(T, n_tracks, 3)`` of every track at times ``t`` (NaN when not alive)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not self.tracks:
            return np.zeros((len(t), 0, 3))
        return np.stack([tr.positions_at(t) for tr in self.tracks], axis=1)


def track(cameras, frames: Frames, *, params: EstimatorParams | None = None) -> TrackingResult:
    """Run the estimator over ``frames`` in the given order.

    Parameters
    ----------
    cameras : sequence of K Camera
        Calibrated cameras; ``frames.camera`` indexes them.
    frames : Frames
        Frames in processing order (reorder them with :meth:`Frames.reordered` and a
        :class:`~lsmta.widearea.scheduler.Schedule`).
    params : EstimatorParams, optional

    Returns
    -------
    TrackingResult
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    if not isinstance(frames, Frames):
        raise TypeError("frames: expected lsmta.widearea.Frames")
    p = EstimatorParams() if params is None else params
    if not isinstance(p, EstimatorParams):
        raise TypeError("params: expected lsmta.widearea.EstimatorParams")
    state = _State.initial(len(cameras), p)
    for f in range(frames.n_frames):
        xy = state.intake.take(frames, f)
        if xy is None:
            continue
        c, t = int(frames.camera[f]), float(frames.stamp[f])
        lag = _advance(state, c, t, p)
        if lag is None:                                      # too late: dropped
            continue
        _end_starved(state, p)
        if len(xy) == 0:
            continue
        free = _gate_and_update(state, cameras[c], c, t, xy, lag, p)
        _births(state, cameras[c], c, t, xy[free], p)
    return _result(state)


@dataclass
class _State:
    """Everything one run of :func:`track` changes."""

    intake: FrameIntake
    P0: np.ndarray                  # (6, 6) covariance of a new target
    now: float = -np.inf            # the estimator's clock, s
    X: np.ndarray = None            # (M, 6) live targets' states
    P: np.ndarray = None            # (M, 6, 6)
    ids: np.ndarray = None          # (M,) target identities
    last_seen: np.ndarray = None    # (M, K) when each camera last updated each target
    pool: RayPool = None
    next_id: int = 0
    times: dict = field(default_factory=dict)     # id -> recorded times
    states: dict = field(default_factory=dict)    # id -> recorded states
    born: dict = field(default_factory=dict)
    died: dict = field(default_factory=dict)
    used: np.ndarray = None         # (K,) frame counters
    dropped: np.ndarray = None
    late_used: np.ndarray = None
    observations: np.ndarray = None
    log: dict = field(default_factory=lambda: {k: [] for k in (
        "target", "camera", "time", "predicted", "observed")})

    @classmethod
    def initial(cls, K: int, p: EstimatorParams) -> _State:
        s0, v0 = p.birth_sigma
        return cls(intake=FrameIntake.initial(K), P0=np.diag([s0**2] * 3 + [v0**2] * 3),
                   X=np.zeros((0, 6)), P=np.zeros((0, 6, 6)), ids=np.zeros(0, np.int64),
                   last_seen=np.zeros((0, K)), pool=RayPool(),
                   used=np.zeros(K, np.int64), dropped=np.zeros(K, np.int64),
                   late_used=np.zeros(K, np.int64), observations=np.zeros(K, np.int64))


def _advance(state: _State, c: int, t: float, p: EstimatorParams) -> float | None:
    """Drop a frame older than the clock by more than the late tolerance (None); use an
    older one as it is (its lag, s); for a newer one predict every target to its stamp and
    move the clock (lag 0)."""
    lag = state.now - t
    if lag > p.late_tolerance:
        state.dropped[c] += 1
        return None
    state.used[c] += 1
    if lag > 0:
        state.late_used[c] += 1
        return lag
    if len(state.X) and np.isfinite(state.now):
        state.X, state.P = predict(state.X, state.P, np.full(len(state.X), t - state.now),
                                   p.accel_density)
    state.now = t
    return 0.0


def _end_starved(state: _State, p: EstimatorParams) -> None:
    """Targets seen by fewer than two cameras within the timeout die."""
    if not len(state.X):
        return
    dead = starved(state.now, state.last_seen, p.timeout)
    for i in state.ids[dead]:
        state.died[int(i)] = state.now
    keep = ~dead
    state.X, state.P = state.X[keep], state.P[keep]
    state.ids, state.last_seen = state.ids[keep], state.last_seen[keep]


def _gate_and_update(state: _State, cam: Camera, c: int, t: float, xy, lag: float,
                     p: EstimatorParams) -> np.ndarray:
    """Pair the targets' projections with the centroids inside each target's gate and
    update each pair (one extended Kalman update); the centroids no target took."""
    if not len(state.X):
        return np.ones(len(xy), bool)
    pred, H = measurement(cam, state.X, lag=lag)
    gate = innovation_gate(innovation_covariance(state.P, H, p.sigma_px),
                           n_sigma=p.gate_sigma, lower=p.min_gate_px, upper=p.gate_px)
    a = associate(pred, xy, gate)
    m, j = a.target, a.centroid
    if len(m):
        x_new, P_new, _ = kalman_update(state.X[m], state.P[m], H[m], pred[m], xy[j],
                                        sigma_px=p.sigma_px)
        state.X[m], state.P[m] = x_new, P_new
        state.last_seen[m, c] = np.maximum(state.last_seen[m, c], t)
        state.observations[c] += len(m)
        for k, i in enumerate(state.ids[m].tolist()):
            state.times[i].append(state.now)
            state.states[i].append(x_new[k])
        log = state.log
        log["target"] += state.ids[m].tolist()
        log["camera"] += [c] * len(m)
        log["time"] += [t] * len(m)
        log["predicted"] += list(pred[m])
        log["observed"] += list(xy[j])
    return a.unassociated


def _births(state: _State, cam: Camera, c: int, t: float, xy, p: EstimatorParams) -> None:
    """The frame's free centroids become rays; a ray that meets a fresh ray of another
    camera (and is not near a live target) starts a target; the rest wait in the pool."""
    o, d = cam.rays(xy) if len(xy) else (np.zeros((0, 3)), np.zeros((0, 3)))
    pool = state.pool
    pool.refresh(t, c, p.staleness)
    b = pool.births(o, d, t, c, tolerance=p.birth_tolerance, staleness=p.staleness,
                    volume=p.volume)
    taken_new = np.zeros(len(o), bool)
    taken_pool = np.zeros(len(pool.stamps), bool)
    for point, i, j in zip(b.points, b.new, b.pool):
        if len(state.X) and np.min(np.linalg.norm(state.X[:, :3] - point, axis=1)) \
                < p.min_separation:
            continue
        taken_new[i] = taken_pool[j] = True
        seen = np.full(state.last_seen.shape[1], -np.inf)
        seen[c], seen[pool.cameras[j]] = t, pool.stamps[j]
        _start_target(state, np.concatenate([point, np.zeros(3)]), seen)
    pool.keep(~taken_pool)
    pool.add(o[~taken_new], d[~taken_new], t, c)


def _start_target(state: _State, x0, seen) -> None:
    i = state.next_id
    state.next_id += 1
    state.X = np.vstack([state.X, x0])
    state.P = np.concatenate([state.P, state.P0[None]])
    state.ids = np.append(state.ids, i)
    state.last_seen = np.vstack([state.last_seen, seen])
    state.born[i] = state.now
    state.times[i] = [state.now]
    state.states[i] = [x0]


def _result(state: _State) -> TrackingResult:
    tracks = tuple(
        WideAreaTrack(id=i, times=np.asarray(state.times[i]), states=np.asarray(state.states[i]),
                      birth_time=state.born[i], death_time=state.died.get(i, np.nan))
        for i in sorted(state.born))
    updates = {k: np.asarray(v) for k, v in state.log.items()}
    if len(updates["predicted"]) == 0:
        updates["predicted"] = np.zeros((0, 2))
        updates["observed"] = np.zeros((0, 2))
    return TrackingResult(tracks=tracks, frames_received=state.intake.received,
                          frames_used=state.used, late_dropped=state.dropped,
                          late_used=state.late_used, observations_used=state.observations,
                          updates=updates, **state.intake.rejected)
