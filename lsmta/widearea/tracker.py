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
from .association import associate
from .kalman import _kalman_update, _measurement, _predict, innovation_covariance
from .management import find_birth
from .observations import Frames, screen_frame


@dataclass(frozen=True)
class TrackerParams:
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


def track(cameras, frames: Frames, *, params: TrackerParams = TrackerParams()) -> TrackingResult:
    """Run the estimator over ``frames`` in the given order.

    Parameters
    ----------
    cameras : sequence of K Camera
        Calibrated cameras; ``frames.camera`` indexes them.
    frames : Frames
        Frames in processing order (reorder them with :meth:`Frames.reordered` and a
        :class:`~lsmta.widearea.scheduler.Schedule`).
    params : TrackerParams

    Returns
    -------
    TrackingResult
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    if not isinstance(frames, Frames):
        raise TypeError("frames: expected lsmta.widearea.Frames")
    if not isinstance(params, TrackerParams):
        raise TypeError("params: expected lsmta.widearea.TrackerParams")
    p = params
    K = len(cameras)
    P0 = np.diag([p.birth_sigma[0] ** 2] * 3 + [p.birth_sigma[1] ** 2] * 3)
    now = -np.inf
    X = np.zeros((0, 6))
    P = np.zeros((0, 6, 6))
    ids: list[int] = []
    last_seen = np.zeros((0, K))
    hist_t: dict[int, list] = {}
    hist_x: dict[int, list] = {}
    born: dict[int, float] = {}
    died: dict[int, float] = {}
    next_id = 0
    pool_o, pool_d = np.zeros((0, 3)), np.zeros((0, 3))
    pool_t, pool_c = np.zeros(0), np.zeros(0, np.int64)
    last_stamp = np.full(K, -np.inf)
    received, used, dropped, late_used, obs_used = (np.zeros(K, np.int64) for _ in range(5))
    bad = {"unknown_camera": 0, "backwards_time": 0, "nonfinite_stamp": 0,
           "empty_frames": 0, "nan_centroids": 0}
    log = {"target": [], "camera": [], "time": [], "predicted": [], "observed": []}

    for f in range(frames.n_frames):
        xy = screen_frame(frames, f, K, last_stamp, received, bad)
        if xy is None:
            continue
        c, t = int(frames.camera[f]), float(frames.stamp[f])
        lag = now - t
        if lag > p.late_tolerance:
            dropped[c] += 1
            continue
        used[c] += 1
        if lag > 0:
            late_used[c] += 1
        else:
            if len(X) and np.isfinite(now):
                X, P = _predict(X, P, np.full(len(X), t - now), p.accel_density)
            now = t
            lag = 0.0
        # deaths
        if len(X):
            dead = (last_seen > now - p.timeout).sum(axis=1) < 2   # management.starved
            for m in np.flatnonzero(dead):
                died[ids[m]] = now
            keep = ~dead
            X, P, last_seen = X[keep], P[keep], last_seen[keep]
            ids = [i for i, k in zip(ids, keep) if k]
        if len(xy) == 0:
            continue
        cam = cameras[c]
        free = np.ones(len(xy), bool)
        if len(X):
            pred, H = _measurement(cam, X, lag)
            S = innovation_covariance(P, H, p.sigma_px)
            # per-target gate: n_sigma times the larger axis of the innovation ellipse
            tr, det = S[:, 0, 0] + S[:, 1, 1], np.linalg.det(S)
            big_axis = np.sqrt(0.5 * tr + np.sqrt(np.maximum(0.25 * tr**2 - det, 0.0)))
            gate = np.clip(p.gate_sigma * big_axis, p.min_gate_px, p.gate_px)
            a = associate(pred, xy, gate)
            if len(a.target):
                m_, j_ = a.target, a.centroid
                x_new, P_new, _ = _kalman_update(X[m_], P[m_], H[m_], pred[m_], xy[j_],
                                                 p.sigma_px)
                X[m_], P[m_] = x_new, P_new
                last_seen[m_, c] = np.maximum(last_seen[m_, c], t)
                obs_used[c] += len(m_)
                for m, j, xn in zip(m_, j_, x_new):
                    hist_t[ids[m]].append(now)
                    hist_x[ids[m]].append(xn)
                    log["target"].append(ids[m])
                    log["camera"].append(c)
                    log["time"].append(t)
                    log["predicted"].append(pred[m])
                    log["observed"].append(xy[j])
            free = a.unassociated
        # births from the unassociated centroids
        o, d = cam.rays(xy[free]) if free.any() else (np.zeros((0, 3)), np.zeros((0, 3)))
        stale = (pool_t < t - p.staleness) | (pool_c == c)
        pool_o, pool_d, pool_t, pool_c = (pool_o[~stale], pool_d[~stale], pool_t[~stale],
                                          pool_c[~stale])
        b = find_birth(o, d, t, c, pool_o, pool_d, pool_t, pool_c,
                       tolerance=p.birth_tolerance, staleness=p.staleness, volume=p.volume)
        taken_new = np.zeros(len(o), bool)
        taken_pool = np.zeros(len(pool_t), bool)
        for point, i, j in zip(b.points, b.new, b.pool):
            if len(X) and np.min(np.linalg.norm(X[:, :3] - point, axis=1)) < p.min_separation:
                continue
            taken_new[i] = taken_pool[j] = True
            x0 = np.concatenate([point, np.zeros(3)])
            X = np.vstack([X, x0])
            P = np.concatenate([P, P0[None]])
            row = np.full(K, -np.inf)
            row[c] = t
            row[pool_c[j]] = pool_t[j]
            last_seen = np.vstack([last_seen, row])
            ids.append(next_id)
            born[next_id] = now
            hist_t[next_id] = [now]
            hist_x[next_id] = [x0]
            next_id += 1
        pool_o = np.concatenate([pool_o[~taken_pool], o[~taken_new]])
        pool_d = np.concatenate([pool_d[~taken_pool], d[~taken_new]])
        pool_t = np.concatenate([pool_t[~taken_pool], np.full((~taken_new).sum(), t)])
        pool_c = np.concatenate([pool_c[~taken_pool],
                                 np.full((~taken_new).sum(), c, dtype=np.int64)])

    tracks = tuple(
        WideAreaTrack(id=i, times=np.asarray(hist_t[i]), states=np.asarray(hist_x[i]),
                      birth_time=born[i], death_time=died.get(i, np.nan))
        for i in sorted(born))
    updates = {k: np.asarray(v) for k, v in log.items()}
    if len(updates["predicted"]) == 0:
        updates["predicted"] = np.zeros((0, 2))
        updates["observed"] = np.zeros((0, 2))
    return TrackingResult(tracks=tracks, frames_received=received, frames_used=used,
                          late_dropped=dropped, late_used=late_used,
                          observations_used=obs_used, updates=updates, **bad)
