"""The field's framework on the same observations: a Stone Soup tracker.

Stone Soup (https://stonesoup.readthedocs.io) supplies the constant-velocity transition
model, the extended Kalman predictor and updater, a Mahalanobis-distance hypothesiser,
global-nearest-neighbour assignment and an update-time deleter. Two pieces are ours
because Stone Soup has nothing that fits:

* a measurement model for a calibrated camera (``_ProjectionModel``: a
  ``NonLinearGaussianMeasurement`` whose function is :meth:`lsmta.camera.Camera.project`),
  attached to every detection, so that one tracker takes centroids from 18 cameras;
* the two-ray initiator of Davis (2002, §3.6) (``_TwoRayInitiator``, built on
  :func:`lsmta.widearea.management.find_birth`): Stone Soup's initiators start a track
  from one detection whose measurement model can be inverted, and one camera gives only
  a ray.

Stone Soup's predictors step forwards in time from a track's last state, so the frames are
processed in time-stamp order (an offline re-ordering the thesis's real-time estimator could
not do); a late frame needs no special treatment here. The loop is that of Stone Soup's
``MultiTargetTracker`` written out, so that the initiator sees each frame's camera, and
missed tracks get no prediction appended (the deleter is given the frame's time instead).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

import numpy as np
from stonesoup.base import Property
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.time import UpdateTimeDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.initiator.base import Initiator
from stonesoup.measures import Mahalanobis
from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import ExtendedKalmanPredictor
from stonesoup.types.array import StateVector, StateVectors
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.track import Track
from stonesoup.types.update import GaussianStateUpdate
from stonesoup.updater.kalman import ExtendedKalmanUpdater

from ..camera import Camera
from .kalman import projection_jacobian
from .management import RayPool
from .observations import FrameIntake, Frames
from .tracker import EstimatorParams, TrackingResult, WideAreaTrack

EPOCH = datetime.datetime(2002, 1, 1)
POSITION = (0, 2, 4)  # Stone Soup's state order is (x, vx, y, vy, z, vz)


def seconds_to_datetime(t: float) -> datetime.datetime:
    """Stone Soup time stamps are datetimes; ours are seconds from an arbitrary epoch."""
    return EPOCH + datetime.timedelta(seconds=float(t))


class _ProjectionModel(NonLinearGaussianMeasurement):
    """Pixel coordinates of the state's position seen by one :class:`Camera`."""

    camera: Camera = Property(doc="The calibrated camera.")

    @property
    def ndim_meas(self) -> int:
        return 2

    def function(self, state, noise=False, **kwargs):
        sv = np.asarray(state.state_vector, dtype=float)
        X = sv[list(self.mapping), :].T
        xy = self.camera.project(X, behind="nan").T
        if noise is True:
            xy = xy + self.rvs(num_samples=xy.shape[1], **kwargs)
        return StateVectors(xy) if xy.shape[1] > 1 else StateVector(xy[:, 0])

    def jacobian(self, state, **kwargs):
        sv = np.asarray(state.state_vector, dtype=float)[:, 0]
        J = projection_jacobian(self.camera, sv[list(self.mapping)][None])[0]
        H = np.zeros((2, self.ndim_state))
        H[:, list(self.mapping)] = np.nan_to_num(J)
        return H

class _TwoRayInitiator(Initiator):
    """Tracks from two cameras' rays passing within a tolerance (Davis 2002, §3.6)."""

    cameras: list = Property(doc="The K cameras.")
    tolerance: float = Property(default=15.0, doc="mm")
    staleness: float = Property(default=0.070, doc="s")
    sigma: tuple = Property(default=(15.0, 1500.0), doc="initial std of mm, mm/s")
    volume: tuple = Property(default=None, doc="box where births may happen, mm")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._pool = RayPool()

    def initiate(self, detections, timestamp, **kwargs):
        t = (timestamp - EPOCH).total_seconds()
        cam = kwargs["camera"]
        dets = list(detections)
        xy = np.array([np.asarray(d.state_vector, float)[:, 0] for d in dets]).reshape(-1, 2)
        o, d = (self.cameras[cam].rays(xy) if len(xy)
                else (np.zeros((0, 3)), np.zeros((0, 3))))
        pool = self._pool
        pool.refresh(t, cam, self.staleness)
        b = pool.births(o, d, t, cam, tolerance=self.tolerance, staleness=self.staleness,
                        volume=self.volume)
        tracks = set()
        P0 = np.diag([self.sigma[0] ** 2, self.sigma[1] ** 2] * 3)
        for point, i in zip(b.points, b.new):
            sv = np.zeros(6)
            sv[list(POSITION)] = point
            hyp = SingleHypothesis(None, dets[i])
            tracks.add(Track([GaussianStateUpdate(StateVector(sv), P0, hypothesis=hyp,
                                                  timestamp=timestamp)]))
        keep_new = np.ones(len(o), bool)
        keep_new[b.new] = False
        keep_pool = np.ones(len(pool.stamps), bool)
        keep_pool[b.pool] = False
        pool.keep(keep_pool)
        pool.add(o[keep_new], d[keep_new], t, cam)
        return tracks


def stonesoup_track(cameras, frames: Frames, *, params: EstimatorParams | None = None,
                    gate_sigma: float | None = None) -> TrackingResult:
    """Track ``frames`` with Stone Soup components (see the module docstring).

    Parameters
    ----------
    cameras : sequence of K Camera
    frames : Frames
        Processed in time-stamp order; bad input is counted as by
        :func:`lsmta.widearea.tracker.track`.
    params : EstimatorParams, optional
        The same settings as our tracker: ``sigma_px``, ``accel_density`` (Stone Soup's
        ``ConstantVelocity`` noise_diff_coeff), ``timeout`` (``UpdateTimeDeleter``),
        ``birth_tolerance``, ``staleness``, ``birth_sigma``, ``volume``.
    gate_sigma : float, optional
        Mahalanobis gate of the hypothesiser (default ``params.gate_sigma``).

    Returns
    -------
    TrackingResult
        Tracks in our units and state order; counters as for our tracker (``late_*`` zero).
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    if not isinstance(frames, Frames):
        raise TypeError("frames: expected lsmta.widearea.Frames")
    p = EstimatorParams() if params is None else params
    parts = _components(cameras, p, p.gate_sigma if gate_sigma is None else gate_sigma)
    K = len(cameras)
    intake = FrameIntake.initial(K)
    obs_used = np.zeros(K, np.int64)
    live: set = set()
    born: list = []
    death: dict = {}
    order = np.argsort(np.where(np.isfinite(frames.stamp), frames.stamp, np.inf),
                       kind="stable")
    for f in order:
        xy = intake.take(frames, f)
        if xy is None:
            continue
        c, t = int(frames.camera[f]), float(frames.stamp[f])
        when = seconds_to_datetime(t)
        detections = {Detection(z[:, None], timestamp=when, measurement_model=parts.models[c])
                      for z in xy}
        with np.errstate(invalid="ignore"):   # Stone Soup's Mahalanobis sqrt of a NaN
            hyps = parts.associator.associate(live, detections, when)
        used = set()
        for trk, hyp in hyps.items():
            if hyp:
                trk.append(parts.updater.update(hyp))
                used.add(hyp.measurement)
                obs_used[c] += 1
        # MultiTargetTracker appends a prediction to every missed track so that the deleter
        # sees time pass; giving the deleter the frame's time stamp does the same, faster
        for trk in parts.deleter.delete_tracks(live, timestamp=when):
            death[id(trk)] = t
            live.discard(trk)
        new = parts.initiator.initiate(detections - used, when, camera=c)
        live |= new
        born.extend(new)
    zeros = np.zeros(K, np.int64)
    return TrackingResult(tracks=_our_tracks(born, death), frames_received=intake.received,
                          frames_used=intake.received.copy(), late_dropped=zeros,
                          late_used=zeros.copy(), observations_used=obs_used,
                          **intake.rejected)


@dataclass(frozen=True)
class _Components:
    models: list
    updater: object
    associator: object
    deleter: object
    initiator: object


def _components(cameras, p: EstimatorParams, gate_sigma: float) -> _Components:
    """Stone Soup's pieces with our settings, and our camera model and initiator."""
    R = p.sigma_px**2 * np.eye(2)
    models = [_ProjectionModel(ndim_state=6, mapping=POSITION, noise_covar=R, camera=c)
              for c in cameras]
    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(p.accel_density)] * 3)
    predictor = ExtendedKalmanPredictor(transition)
    updater = ExtendedKalmanUpdater(measurement_model=None)
    hypothesiser = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(),
                                        missed_distance=gate_sigma)
    return _Components(
        models=models, updater=updater, associator=GNNWith2DAssignment(hypothesiser),
        deleter=UpdateTimeDeleter(datetime.timedelta(seconds=p.timeout)),
        initiator=_TwoRayInitiator(cameras=cameras, tolerance=p.birth_tolerance,
                                  staleness=p.staleness, sigma=tuple(p.birth_sigma),
                                  volume=p.volume))


def _our_tracks(born, death) -> tuple:
    """Stone Soup tracks as :class:`WideAreaTrack` (our state order, seconds)."""
    out = []
    for i, trk in enumerate(born):
        states = [s for s in trk.states if hasattr(s, "hypothesis")]
        times = np.array([(s.timestamp - EPOCH).total_seconds() for s in states])
        sv = np.array([np.asarray(s.state_vector, float)[:, 0] for s in states])
        x = np.concatenate([sv[:, [0, 2, 4]], sv[:, [1, 3, 5]]], axis=1)
        out.append(WideAreaTrack(id=i, times=times, states=x, birth_time=times[0],
                                 death_time=death.get(id(trk), np.nan)))
    return tuple(out)
