"""The central estimator of the wide-area system (Davis 2002, §§3.4-3.6), frame by frame.

:class:`WideAreaTracker` takes frames as they arrive (:meth:`~WideAreaTracker.feed`: a
camera index, its time stamp, its centroids) and can be read at any time: the current
estimate of every live target (:meth:`~WideAreaTracker.estimate`), its prediction to any
time (:meth:`~WideAreaTracker.predict`) and into any camera's image, with the image-plane
velocity (:meth:`~WideAreaTracker.predict_image`, which steers the detector's windows).
Cameras come and go while it runs: :meth:`~WideAreaTracker.add_camera` (a camera calibrated
already, or one to be calibrated against the tracked targets first, see
:mod:`lsmta.widearea.joining`), :meth:`~WideAreaTracker.remove_camera`, and cameras that
stop delivering frames are dropped after ``camera_timeout``. :meth:`~WideAreaTracker.result`
returns a frozen snapshot. The batch :func:`track` is a loop of ``feed`` over
:class:`~lsmta.widearea.Frames` in the order the estimator takes them up (see
:mod:`lsmta.widearea.scheduler` for the queue policies).

The estimator keeps a single clock, ``now``: the newest time stamp it has used. The stages
of one frame are those of :mod:`lsmta.widearea.stages`: reject bad input (counted:
unknown camera, time stamp not after that camera's previous one, non-finite stamp, NaN
centroids; empty frames only advance the clock), drop a frame older than ``now`` by more
than ``late_tolerance`` (the naive "discard late" policy is ``late_tolerance = 0``) or
predict every target to its stamp, drop silent cameras, end starved targets, gate and
update, births. Target identities are integers that are never reused (a target that comes
back soon after its death, ``EstimatorParams.rejoin``, keeps its own).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import IntEnum

import numpy as np

from .._validate import as_array, as_scalar
from ..camera import Camera
from .association import innovation_gate
from .joining import JoinParams
from .kalman import _measurement, _predict, innovation_covariance
from .observations import Frames, screen_values
from .stages import (
    CameraStatus,
    EstimatorState,
    _Joining,
    advance,
    births,
    collect_join,
    drop_silent,
    end_starved,
    frame_measurement,
    gate_and_update,
    update_pairs,
)


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
    camera_timeout : float or None
        An active camera whose newest frame is this much older than the clock is dropped
        (s); None: cameras are never dropped for silence.
    rejoin : float
        A birth within ``rejoin_mm`` of where a target that died less than this long ago
        would be now (its last state carried on at constant velocity) resumes that target,
        identity and velocity, instead of starting a new one, s (0, the thesis: never; an
        LED seen by one camera for a moment, at the rig's edge or dim in a far camera,
        would otherwise come back under a new identity).
    rejoin_mm : float
        See ``rejoin``, mm.
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
    camera_timeout: float | None = None
    rejoin: float = 0.0
    rejoin_mm: float = 100.0

    def __post_init__(self):
        for key in ("sigma_px", "gate_px", "gate_sigma", "min_gate_px", "birth_tolerance",
                    "timeout"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("accel_density", "late_tolerance", "staleness", "min_separation",
                    "rejoin", "rejoin_mm"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_array(self.birth_sigma, "birth_sigma", shape=(2,))
        if self.volume is not None:
            as_array(self.volume, "volume", shape=(2, 3))
        if self.camera_timeout is not None:
            as_scalar(self.camera_timeout, "camera_timeout", positive=True)


@dataclass(frozen=True)
class WideAreaTrack:
    """One target's life.

    Attributes
    ----------
    id : int
    times : (n,) array
        Times of the recorded states (birth and every update), s.
    states : (n, 6) array
        Filtered states at those times (mm, mm/s); a row of NaN at a death the target
        came back from (``EstimatorParams.rejoin``): not alive until its next row.
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
    cameras : tuple of Camera
        The cameras at the end (a joined camera as calibrated).
    camera_status : (K,) int array
        :class:`CameraStatus` codes at the end.
    camera_events : tuple of (float, int, str)
        (clock time, camera, what): ``"added"``, ``"joined"``, ``"join failed"``,
        ``"dropped"`` (silent), ``"back"`` (a dropped camera delivered again),
        ``"removed"``.
    joins : tuple of (int, CameraJoin)
        Every calibration attempt of a joining camera.
    not_active : (K,) int array
        Frames refused because their camera had been removed.
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
    cameras: tuple = ()
    camera_status: np.ndarray | None = None
    camera_events: tuple = ()
    joins: tuple = ()
    not_active: np.ndarray | None = None

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


class FrameStatus(IntEnum):
    """What :meth:`WideAreaTracker.feed` did with a frame."""

    USED = 0            # in time (or the newest): targets predicted to it, updated, births
    USED_LATE = 1       # older than the clock by less than the late tolerance: used as it is
    DROPPED_LATE = 2    # older than the clock by more than the late tolerance
    REFUSED = 3         # bad input (unknown camera, stamp not after the last, non-finite)
    NOT_ACTIVE = 4      # its camera was removed
    COLLECTED = 5       # its camera is joining: kept for its calibration


@dataclass(frozen=True)
class TargetEstimate:
    """The live targets at one time.

    Attributes
    ----------
    time : float
        s (the tracker's clock, or the time predicted to).
    ids : (M,) int array
    states : (M, 6) array
        Position (mm) and velocity (mm/s).
    covariances : (M, 6, 6) array
    """

    time: float
    ids: np.ndarray
    states: np.ndarray
    covariances: np.ndarray

    @property
    def positions(self) -> np.ndarray:
        """``(M, 3)`` positions, mm."""
        return self.states[:, :3]


@dataclass(frozen=True)
class ImagePrediction:
    """The live targets predicted into one camera's image at one time.

    Attributes
    ----------
    camera : int
    time : float
        s.
    ids : (M,) int array
    xy : (M, 2) array
        Predicted centroids, px (NaN behind the camera).
    velocity : (M, 2) array
        Image-plane velocity, px/s (the projection's Jacobian times the target's velocity).
    gate_px : (M,) array
        The association gate the tracker will use for each target in this frame:
        ``gate_sigma`` times the larger semi-axis of the predicted centroid's innovation
        ellipse, within ``[min_gate_px, gate_px]``.
    waiting : (P, 2) array
        This camera's centroids, px, that no target explained and that still wait (fresh)
        for a partner from another camera to start a target (the birth pool): LEDs not yet
        tracked, where a window keeps finding them until they are (empty from
        :meth:`WideAreaTracker.predict_image`).
    partners : (Q, 2) array
        Points, px, at most ``gate_px`` (the parameter) apart along the images in this
        camera of the *other* cameras' fresh rays in the birth pool, within the birth
        volume and the image: where the partner that would start a target must be (its
        depth along the ray is unknown, so it is anywhere on that line). Windows around
        them (half-size ``gate_px``, or the lean rule's 10.5 px:
        :func:`lsmta.evaluation.widearea_images.guided_search_windows`) search a band
        about the line, so that an LED
        seen by one camera is found by the others in their next frames instead of only
        when their grids happen to hit it (empty from :meth:`WideAreaTracker.predict_image`
        and without ``volume``).
    observed : (M,) bool array or None
        Whether this camera has observed each target (updated it, or started it) since the
        target was born and since the camera was last removed or dropped as silent. A
        target it has not observed is
        projected here from the other cameras' measurements only, unchecked in this image:
        an error of its birth's triangulation shows here beyond the gate, which measures
        the filter's own uncertainty (None: unknown, treated as observed).
    """

    camera: int
    time: float
    ids: np.ndarray
    xy: np.ndarray
    velocity: np.ndarray
    gate_px: np.ndarray
    waiting: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    partners: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    observed: np.ndarray | None = None

    def windows(self, *, margin_px: float = 3.0, unobserved_px: float | None = None):
        """Search windows for :func:`lsmta.widearea.search_frame` around the predicted
        centroids: the gate plus a spot's radius; wider where the prediction is unchecked.

        Parameters
        ----------
        margin_px : float
            Added to each target's ``gate_px``, px (a spot's radius; >= 0).
        unobserved_px : float or None
            The least half-size, px (> 0), of the window around a target this camera has
            not observed (:attr:`observed`): its prediction here comes from the other
            cameras only. For example 20, the thesis's window size (Davis 2002: 40 x 40),
            our rule as a minimum for unobserved targets. None: no least.

        Returns
        -------
        xy : (M, 2) array
            The predicted centroids, px (:attr:`xy`; NaN rows: no window).
        half : (M,) array
            Half the side of each window, px.
        """
        margin = as_scalar(margin_px, "margin_px", nonnegative=True)
        half = self.gate_px + margin
        if unobserved_px is not None and self.observed is not None:
            if np.shape(self.observed) != (len(self.xy),):
                raise ValueError(f"observed: expected one flag per target ({len(self.xy)}), "
                                 f"got shape {np.shape(self.observed)}")
            least = as_scalar(unobserved_px, "unobserved_px", positive=True)
            half = np.where(self.observed, half, np.maximum(half, least))
        return self.xy, half


class WideAreaTracker:
    """The wide-area tracker, frame by frame (see the module).

    Parameters
    ----------
    cameras : sequence of K Camera
        Calibrated cameras; a frame's camera index refers to them (cameras added later get
        the next indices).
    params : EstimatorParams, optional
    """

    def __init__(self, cameras, *, params: EstimatorParams | None = None):
        cameras = list(cameras)
        if not cameras or not all(isinstance(c, Camera) for c in cameras):
            raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
        p = EstimatorParams() if params is None else params
        if not isinstance(p, EstimatorParams):
            raise TypeError("params: expected lsmta.widearea.EstimatorParams")
        self._p = p
        self._s = EstimatorState.initial(cameras, p.birth_sigma)

    @property
    def params(self) -> EstimatorParams:
        return self._p

    @property
    def now(self) -> float:
        """The estimator's clock: the newest time stamp used, s (-inf before any)."""
        return self._s.now

    @property
    def cameras(self) -> tuple:
        """The cameras as the tracker uses them (a joined camera as calibrated)."""
        return tuple(self._s.cameras)

    @property
    def camera_status(self) -> np.ndarray:
        """``(K,)`` :class:`CameraStatus` codes."""
        return self._s.status.copy()

    def feed(self, camera, stamp, xy) -> FrameStatus:
        """Take up one frame: camera index, capture time stamp by its clock (s), and its
        centroids ``(n, 2)`` px (NaN rows are counted and left out). Nothing passed in is
        changed."""
        s = self._s
        xy = s.intake.take_values(camera, stamp, xy)
        if xy is None:
            return FrameStatus.REFUSED
        c, t = int(camera), float(stamp)
        status = self._camera_gate(c, t, xy)
        if status is not None:
            return status
        lag = self._advance(c, t)
        if lag is None:
            return FrameStatus.DROPPED_LATE
        if len(xy):
            free = gate_and_update(s, c, t, xy, lag, self._p)
            births(s, c, t, xy[free], self._p)
        return FrameStatus.USED_LATE if lag > 0 else FrameStatus.USED

    def feed_detect(self, camera, stamp, detect) -> FrameStatus:
        """Take up one frame whose centroids are still to be found, the detection steered by
        the prediction (Davis §3.3): ``detect(prediction)`` gets the
        :class:`ImagePrediction` of the live targets for this frame (centroids at its time,
        image-plane velocities, and the gates the association then uses: computed once, for
        both) and returns the frame's centroids ``(n, 2)``. The same as :meth:`feed` of the
        centroids found, except that a frame that is refused, dropped as late or of a
        removed camera is not searched (and not counted as empty); a joining camera's frame
        is searched without windows."""
        s, p = self._s, self._p
        if screen_values(camera, stamp, np.zeros((0, 2)), len(s.cameras),
                         s.intake.last_stamp).refused is not None:
            s.intake.take_values(camera, stamp, np.zeros((0, 2)))      # counted there
            return FrameStatus.REFUSED
        c, t = int(camera), float(stamp)
        if s.status[c] == CameraStatus.JOINING:
            return self.feed(c, t, detect(self._no_prediction(c, t)))
        if s.status[c] == CameraStatus.REMOVED or s.now - t > p.late_tolerance:
            s.intake.take_unsearched(c, t)
            return self._camera_gate(c, t, None) or (
                FrameStatus.DROPPED_LATE if self._advance(c, t) is None else FrameStatus.USED)
        self._camera_gate(c, t, None)
        lag = self._advance(c, t)
        fm = frame_measurement(s, c, lag, p)
        v = np.einsum("aij,aj->ai", fm.H[:, :, :3], s.X[:, 3:])
        v[~np.isfinite(fm.predicted).all(axis=1)] = np.nan
        xy = s.intake.take_values(c, t, detect(ImagePrediction(
            camera=c, time=t, ids=s.ids.copy(), xy=fm.predicted, velocity=v,
            gate_px=fm.gate, waiting=_waiting(s, c, t, p.staleness),
            partners=_partners(s, c, t, p), observed=s.last_seen[:, c] > -np.inf)))
        if len(xy):
            free = update_pairs(s, c, t, xy, fm, p)
            births(s, c, t, xy[free], p)
        return FrameStatus.USED_LATE if lag > 0 else FrameStatus.USED

    def _no_prediction(self, c: int, t: float) -> ImagePrediction:
        z = np.zeros((0, 2))
        return ImagePrediction(camera=c, time=t, ids=np.zeros(0, np.int64), xy=z,
                               velocity=z.copy(), gate_px=np.zeros(0),
                               observed=np.zeros(0, bool))

    def _camera_gate(self, c: int, t: float, xy) -> FrameStatus | None:
        """Frames of removed and joining cameras; a silent camera is back."""
        s = self._s
        if s.status[c] == CameraStatus.REMOVED:
            s.not_active[c] += 1
            return FrameStatus.NOT_ACTIVE
        if s.status[c] == CameraStatus.JOINING:
            collect_join(s, c, t, xy)
            return FrameStatus.COLLECTED
        if s.status[c] == CameraStatus.SILENT:
            s.status[c] = CameraStatus.ACTIVE
            s.events.append((s.now, c, "back"))
        return None

    def _advance(self, c: int, t: float) -> float | None:
        """The clock's stages of a frame: advance, silent cameras, starved targets."""
        s, p = self._s, self._p
        s.heard[c] = t
        lag = advance(s, c, t, p)
        if lag is None:
            return None
        s.heard[np.isnan(s.heard)] = s.now          # the silence of a camera counts from here
        drop_silent(s, p)
        end_starved(s, p)
        return lag

    def estimate(self) -> TargetEstimate:
        """The live targets at the clock ``now`` (copies)."""
        s = self._s
        return TargetEstimate(time=s.now, ids=s.ids.copy(), states=s.X.copy(),
                              covariances=s.P.copy())

    def predict(self, t) -> TargetEstimate:
        """The live targets predicted to time ``t`` (s) by the constant-velocity model (the
        covariances grow by the process noise; for ``t`` before the clock the states are
        carried back along their velocity, covariances unchanged)."""
        s = self._s
        t = as_scalar(t, "t")
        if not len(s.X) or not np.isfinite(s.now):
            return replace(self.estimate(), time=t)
        dt = t - s.now
        if dt >= 0:
            X, P = _predict(s.X, s.P, np.full(len(s.X), dt), self._p.accel_density)
        else:
            X, P = s.X.copy(), s.P.copy()
            X[:, :3] += dt * X[:, 3:]
        return TargetEstimate(time=t, ids=s.ids.copy(), states=X, covariances=P)

    def predict_image(self, camera: int, t) -> ImagePrediction:
        """The live targets predicted into camera ``camera`` at time ``t`` (s, that camera's
        clock): centroids, image-plane velocities and the gates the association will use
        (for the windows of the guided search, :func:`lsmta.widearea.search_frame`)."""
        s, p = self._s, self._p
        if int(camera) != camera or not 0 <= camera < len(s.cameras):
            raise ValueError(f"camera: expected an index in [0, {len(s.cameras) - 1}], "
                             f"got {camera}")
        e = self.predict(t)
        if not len(e.ids):
            return self._no_prediction(int(camera), e.time)
        h, H = _measurement(s.cameras[camera], e.states, 0.0)
        gate = innovation_gate(innovation_covariance(e.covariances, H, p.sigma_px),
                               n_sigma=p.gate_sigma, lower=p.min_gate_px, upper=p.gate_px)
        v = np.einsum("aij,aj->ai", H[:, :, :3], e.states[:, 3:])
        v[~np.isfinite(h).all(axis=1)] = np.nan
        return ImagePrediction(camera=int(camera), time=e.time, ids=e.ids, xy=h, velocity=v,
                               gate_px=gate, observed=s.last_seen[:, camera] > -np.inf)

    def add_camera(self, camera: Camera, *, calibrated: bool = True,
                   join: JoinParams | None = None) -> int:
        """Add a camera while tracking; its index (the next one).

        ``calibrated``: use it at once. Otherwise ``camera`` is an approximation (nominal
        interior orientation, tape-measured pose): its frames are collected with the live
        targets' positions until it can be calibrated against them
        (:func:`lsmta.widearea.joining.calibrate_from_targets` with ``join``), and it is
        used from then on.
        """
        if not isinstance(camera, Camera):
            raise TypeError("camera: expected an lsmta.camera.Camera")
        j = JoinParams() if join is None else join
        if not isinstance(j, JoinParams):
            raise TypeError("join: expected a JoinParams")
        s = self._s
        k = s.add_camera(camera, CameraStatus.ACTIVE if calibrated else CameraStatus.JOINING)
        if not calibrated:
            s.joining[k] = _Joining(guess=camera, params=j)
        s.events.append((s.now, k, "added"))
        return k

    def remove_camera(self, camera: int) -> None:
        """Stop using a camera (its later frames are refused and counted)."""
        s = self._s
        if int(camera) != camera or not 0 <= camera < len(s.cameras):
            raise ValueError(f"camera: expected an index in [0, {len(s.cameras) - 1}], "
                             f"got {camera}")
        c = int(camera)
        s.status[c] = CameraStatus.REMOVED
        s.joining.pop(c, None)
        s.last_seen[:, c] = -np.inf
        s.pool.keep(s.pool.cameras != c)
        s.events.append((s.now, c, "removed"))

    def result(self) -> TrackingResult:
        """A frozen snapshot of the tracks and the bookkeeping so far."""
        return _result(self._s)


def track(cameras, frames: Frames, *, params: EstimatorParams | None = None) -> TrackingResult:
    """Run the estimator over ``frames`` in the given order: :meth:`WideAreaTracker.feed`
    for every frame.

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
    tracker = WideAreaTracker(cameras, params=params)
    if not isinstance(frames, Frames):
        raise TypeError("frames: expected lsmta.widearea.Frames")
    for f in range(frames.n_frames):
        tracker.feed(frames.camera[f], frames.stamp[f], frames.centroids(f))
    return tracker.result()


def _result(state: EstimatorState) -> TrackingResult:
    tracks = tuple(
        WideAreaTrack(id=i, times=np.asarray(state.times[i]), states=np.asarray(state.states[i]),
                      birth_time=state.born[i], death_time=state.died.get(i, np.nan))
        for i in sorted(state.born))
    updates = {k: np.asarray(v) for k, v in state.log.items()}
    if len(updates["predicted"]) == 0:
        updates["predicted"] = np.zeros((0, 2))
        updates["observed"] = np.zeros((0, 2))
    return TrackingResult(tracks=tracks, frames_received=state.intake.received.copy(),
                          frames_used=state.used.copy(), late_dropped=state.dropped.copy(),
                          late_used=state.late_used.copy(),
                          observations_used=state.observations.copy(), updates=updates,
                          cameras=tuple(state.cameras), camera_status=state.status.copy(),
                          camera_events=tuple(state.events), joins=tuple(state.joins),
                          not_active=state.not_active.copy(), **state.intake.rejected)


def _partners(s, c: int, t: float, p) -> np.ndarray:
    """Points ``(Q, 2)``, px, at most ``p.gate_px`` apart along the images in camera ``c``
    of the other cameras' rays in the birth pool stamped within ``p.staleness`` s of ``t``,
    each ray clipped to ``p.volume``, in the image only, each point once. Sampled in 3-D,
    so lens distortion bends the line as it should: 64 equal steps in depth, then every
    step whose pixel segment meets the image in ``ceil(1.1 * length / gate_px)`` equal
    sub-steps (1.1: equal steps in depth are not quite equal in pixels). A sub-step that
    crosses an image corner with both ends outside gives the middle of its part in the
    image."""
    pool, cam = s.pool, s.cameras[c]
    m = (pool.cameras != c) & (pool.stamps >= t - p.staleness)
    if p.volume is None or not m.any():
        return np.zeros((0, 2))
    o, d = pool.origins[m], pool.directions[m]
    lo, hi = np.asarray(p.volume, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - o) / d, (hi - o) / d           # the slabs of the box along each ray
        near = np.maximum(np.nanmax(np.minimum(a, b), axis=1), 0.0)
        far = np.nanmin(np.maximum(a, b), axis=1)
    r = np.flatnonzero(far > near)
    if len(r) == 0:
        return np.zeros((0, 2))
    lam = near[r, None] + (far - near)[r, None] * np.linspace(0.0, 1.0, 65)   # (R, 65)
    coarse = cam.project((o[r, None] + lam[..., None] * d[r, None]).reshape(-1, 3),
                         behind="nan").reshape(len(r), 65, 2)
    gap = np.linalg.norm(np.diff(coarse, axis=1), axis=2)                    # (R, 64)
    box = np.array([-0.5, -0.5]), np.array([cam.width - 0.5, cam.height - 0.5])
    keep = _meets_box(coarse[:, :-1], coarse[:, 1:], *box)[0] & np.isfinite(gap)
    ray, j = np.nonzero(keep)
    n = np.ceil(1.1 * gap[ray, j] / p.gate_px).astype(int).clip(1)
    k = np.repeat(np.arange(len(n)), n + 1)          # the sub-steps' ends, of step k
    frac = np.arange(len(k)) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
    u = lam[ray, j][k] + (lam[ray, j + 1] - lam[ray, j])[k] * frac / n[k]
    i = r[ray[k]]
    xy = cam.project(o[i] + u[:, None] * d[i], behind="nan")      # one call for all rays
    inside = cam.in_image(xy)
    # a step's far end is the next step's near end: once
    then = np.concatenate([keep[:, 1:], np.zeros((len(r), 1), bool)], axis=1)[ray, j]
    once = (frac < n[k]) | ~then[k]
    s0 = np.flatnonzero(frac < n[k])                 # sub-steps from s0 to s0 + 1
    meets, mid = _meets_box(xy[s0], xy[s0 + 1], *box)
    corner = s0[meets & ~inside[s0] & ~inside[s0 + 1]]
    mid = mid[meets & ~inside[s0] & ~inside[s0 + 1]]
    extra = np.clip(xy[corner] + mid[:, None] * (xy[corner + 1] - xy[corner]), *box)
    return np.concatenate([xy[inside & once], extra])


def _meets_box(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Whether the segments from ``a`` to ``b`` (``(..., 2)``, px) meet the rectangle
    ``lo <= xy <= hi`` (boolean ``(...)``; a NaN end: False), and the fraction of the way
    from ``a`` to ``b`` of the middle of their part in it (Liang-Barsky clipping)."""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo, t_hi = (lo - a) / d, (hi - a) / d
        enter = np.maximum(np.where(d != 0, np.minimum(t_lo, t_hi), -np.inf).max(axis=-1), 0.0)
        leave = np.minimum(np.where(d != 0, np.maximum(t_lo, t_hi), np.inf).min(axis=-1), 1.0)
        level = ((d != 0) | ((a >= lo) & (a <= hi))).all(axis=-1)  # no motion: a inside
        return level & (enter <= leave), (enter + leave) / 2


def _waiting(s, c: int, t: float, staleness: float) -> np.ndarray:
    """Camera ``c``'s rays in the birth pool stamped within ``staleness`` s of ``t``, as
    pixels ``(P, 2)`` (a point 1 m along each ray, projected)."""
    pool = s.pool
    m = (pool.cameras == c) & (pool.stamps >= t - staleness)
    if not m.any():
        return np.zeros((0, 2))
    return s.cameras[c].project(pool.origins[m] + 1000.0 * pool.directions[m], behind="nan")
