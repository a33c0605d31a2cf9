"""The central estimator's running state and its stages (Davis 2002, §§3.4-3.6), used one
frame at a time by :class:`lsmta.widearea.WideAreaTracker`.

For each frame the estimator takes up:

1. :func:`advance` — a frame older than the clock by more than the late tolerance is
   dropped; a newer one predicts every target to its stamp
   (:func:`lsmta.widearea.kalman.predict`) and moves the clock;
2. :func:`drop_silent` — cameras that delivered nothing for ``camera_timeout`` are dropped;
3. :func:`end_starved` — targets seen by fewer than two cameras within ``timeout`` die
   (:func:`lsmta.widearea.management.starved`);
4. :func:`gate_and_update` — targets are projected into the camera, retrodicted by the
   frame's lag (:func:`frame_measurement`), paired with centroids
   (:func:`lsmta.widearea.association.associate`); each pair is one extended Kalman
   update (:func:`update_pairs`);
5. :func:`births` — centroids no target took become rays; a ray that meets a fresh ray of
   another camera within ``birth_tolerance`` starts a target
   (:func:`lsmta.widearea.management.find_birth`), or resumes one that has just died near
   there (``rejoin``).

A joining camera's frames go to :func:`collect_join` instead: they are kept with the live
targets' positions at their stamps until the camera can be calibrated
(:func:`lsmta.widearea.joining.calibrate_from_targets`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from ..camera import Camera
from .association import associate, innovation_gate
from .joining import CameraJoin, JoinParams, JoinStatus, calibrate_from_targets
from .kalman import innovation_covariance, kalman_update, measurement, predict
from .management import RayPool, starved
from .observations import FrameIntake


class CameraStatus(IntEnum):
    """What the tracker does with a camera's frames."""

    ACTIVE = 0      # used
    JOINING = 1     # collected for its calibration against the tracked targets
    SILENT = 2      # dropped after delivering nothing for camera_timeout; back on its next frame
    REMOVED = 3     # removed by the caller; its frames are refused


@dataclass
class _Joining:
    """A joining camera's collected frames."""

    guess: Camera
    params: JoinParams
    centroids: list = field(default_factory=list)
    positions: list = field(default_factory=list)
    attempts: int = 0


@dataclass
class EstimatorState:
    """Everything a tracker changes as frames come in (one per tracker; mutable)."""

    cameras: list                   # (K,) Camera
    status: np.ndarray              # (K,) CameraStatus codes
    intake: FrameIntake
    P0: np.ndarray                  # (6, 6) covariance of a new target
    now: float = -np.inf            # the estimator's clock, s
    X: np.ndarray = None            # (M, 6) live targets' states
    P: np.ndarray = None            # (M, 6, 6)
    ids: np.ndarray = None          # (M,) target identities
    last_seen: np.ndarray = None    # (M, K) when each camera last updated each target
    heard: np.ndarray = None        # (K,) when each camera's last frame was stamped (or added)
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
    not_active: np.ndarray = None   # (K,) frames of removed cameras
    joining: dict = field(default_factory=dict)   # camera -> _Joining
    joins: list = field(default_factory=list)     # CameraJoin results, in order
    events: list = field(default_factory=list)    # (time, camera, what)
    log: dict = field(default_factory=lambda: {k: [] for k in (
        "target", "camera", "time", "predicted", "observed")})

    @classmethod
    def initial(cls, cameras, birth_sigma) -> EstimatorState:
        K = len(cameras)
        s0, v0 = birth_sigma
        zeros = np.zeros(K, np.int64)
        return cls(cameras=list(cameras), status=np.zeros(K, np.int64),
                   intake=FrameIntake.initial(K),
                   P0=np.diag([s0**2] * 3 + [v0**2] * 3), X=np.zeros((0, 6)),
                   P=np.zeros((0, 6, 6)), ids=np.zeros(0, np.int64),
                   last_seen=np.zeros((0, K)), heard=np.full(K, np.nan), pool=RayPool(),
                   used=zeros, dropped=zeros.copy(), late_used=zeros.copy(),
                   observations=zeros.copy(), not_active=zeros.copy())

    def add_camera(self, camera: Camera, status: CameraStatus) -> int:
        """Append a camera (all per-camera arrays grow by one); its index."""
        self.cameras.append(camera)
        self.status = np.append(self.status, int(status))
        self.intake.add_camera()
        self.last_seen = np.hstack([self.last_seen, np.full((len(self.X), 1), -np.inf)])
        self.heard = np.append(self.heard, self.now if np.isfinite(self.now) else np.nan)
        for key in ("used", "dropped", "late_used", "observations", "not_active"):
            setattr(self, key, np.append(getattr(self, key), 0))
        return len(self.cameras) - 1


def advance(state: EstimatorState, c: int, t: float, p) -> float | None:
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


def drop_silent(state: EstimatorState, p) -> None:
    """Active cameras that have delivered nothing for ``p.camera_timeout`` s of the clock
    are dropped: their pooled rays are forgotten and they no longer count as seeing a
    target."""
    if p.camera_timeout is None:
        return
    silent = ((state.status == CameraStatus.ACTIVE) & np.isfinite(state.heard)
              & (state.heard < state.now - p.camera_timeout))
    for k in np.flatnonzero(silent).tolist():
        state.status[k] = CameraStatus.SILENT
        state.last_seen[:, k] = -np.inf
        state.pool.keep(state.pool.cameras != k)
        state.events.append((state.now, k, "dropped"))


def end_starved(state: EstimatorState, p) -> None:
    """Targets seen by fewer than two cameras within the timeout die."""
    if not len(state.X):
        return
    dead = starved(state.now, state.last_seen, p.timeout)
    for i in state.ids[dead]:
        state.died[int(i)] = state.now
    keep = ~dead
    state.X, state.P = state.X[keep], state.P[keep]
    state.ids, state.last_seen = state.ids[keep], state.last_seen[keep]


def gate_and_update(state: EstimatorState, c: int, t: float, xy, lag: float,
                    p) -> np.ndarray:
    """Pair the targets' projections with the centroids inside each target's gate and
    update each pair (one extended Kalman update); the centroids no target took."""
    return update_pairs(state, c, t, xy, frame_measurement(state, c, lag, p), p)


@dataclass(frozen=True)
class FrameMeasurement:
    """The live targets as one frame of camera ``c`` sees them (see :func:`frame_measurement`).

    Attributes
    ----------
    predicted : (M, 2) array
        Projected positions at the frame's time, px (NaN behind the camera).
    H : (M, 2, 6) array
        Measurement Jacobians.
    gate : (M,) array
        Association gates, px.
    """

    predicted: np.ndarray
    H: np.ndarray
    gate: np.ndarray


def frame_measurement(state: EstimatorState, c: int, lag: float, p) -> FrameMeasurement:
    """Project the live targets into camera ``c`` at the frame's time (``lag`` s before the
    clock), with their Jacobians and association gates."""
    pred, H = measurement(state.cameras[c], state.X, lag=lag)
    gate = innovation_gate(innovation_covariance(state.P, H, p.sigma_px),
                           n_sigma=p.gate_sigma, lower=p.min_gate_px, upper=p.gate_px)
    return FrameMeasurement(predicted=pred, H=H, gate=gate)


def update_pairs(state: EstimatorState, c: int, t: float, xy, fm: FrameMeasurement,
                 p) -> np.ndarray:
    """The association and update of :func:`gate_and_update` from a frame measurement."""
    if not len(state.X):
        return np.ones(len(xy), bool)
    pred, H = fm.predicted, fm.H
    a = associate(pred, xy, fm.gate)
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


def births(state: EstimatorState, c: int, t: float, xy, p) -> None:
    """The frame's free centroids become rays; a ray that meets a fresh ray of another
    camera (and is not near a live target) starts a target; the rest wait in the pool."""
    cam = state.cameras[c]
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
        back = _rejoining(state, point, p)
        if back is None:
            _start_target(state, np.concatenate([point, np.zeros(3)]), seen)
        else:
            _resume_target(state, back, point, seen)
    pool.keep(~taken_pool)
    pool.add(o[~taken_new], d[~taken_new], t, c)


def _start_target(state: EstimatorState, x0, seen) -> None:
    i = state.next_id
    state.next_id += 1
    state.born[i] = state.now
    state.times[i], state.states[i] = [], []
    _add_live(state, i, x0, seen)


def _add_live(state: EstimatorState, i: int, x0, seen) -> None:
    """Target ``i`` joins the live targets with state ``x0`` (recorded) and a new target's
    covariance."""
    state.X = np.vstack([state.X, x0])
    state.P = np.concatenate([state.P, state.P0[None]])
    state.ids = np.append(state.ids, i)
    state.last_seen = np.vstack([state.last_seen, seen])
    state.times[i].append(state.now)
    state.states[i].append(x0)


def _rejoining(state: EstimatorState, point, p) -> int | None:
    """The target that died less than ``p.rejoin`` s ago nearest to ``point`` where its last
    state, carried on at constant velocity, would be now, if within ``p.rejoin_mm``."""
    if p.rejoin <= 0:
        return None
    best, best_d = None, p.rejoin_mm
    for i, died in state.died.items():
        if state.now - died > p.rejoin:
            continue
        x = state.states[i][-1]
        d = float(np.linalg.norm(x[:3] + (state.now - state.times[i][-1]) * x[3:] - point))
        if d <= best_d:
            best, best_d = i, d
    return best


def _resume_target(state: EstimatorState, i: int, point, seen) -> None:
    """Target ``i`` lives again at ``point`` with its last velocity (a NaN row at its death
    marks the gap in its record)."""
    state.times[i].append(state.died.pop(i))
    state.states[i].append(np.full(6, np.nan))
    _add_live(state, i, np.concatenate([point, state.states[i][-2][3:]]), seen)


def collect_join(state: EstimatorState, c: int, t: float, xy) -> CameraJoin | None:
    """Keep a joining camera's frame with the live targets' positions at its stamp; once
    enough frames are in, calibrate it (on success it becomes active)."""
    j = state.joining[c]
    if len(state.X) and np.isfinite(state.now):
        j.centroids.append(xy)
        j.positions.append(state.X[:, :3] + (t - state.now) * state.X[:, 3:])
    if len(j.centroids) < (j.attempts + 1) * j.params.min_frames:
        return None
    j.attempts += 1
    res = calibrate_from_targets(j.guess, j.centroids, j.positions, params=j.params)
    state.joins.append((c, res))
    if res.status == JoinStatus.JOINED:
        state.cameras[c] = res.camera
        state.status[c] = CameraStatus.ACTIVE
        state.heard[c] = t
        del state.joining[c]
        state.events.append((state.now, c, "joined"))
    else:
        state.events.append((state.now, c, "join failed"))
    return res
