"""Wide-area tracking trials (Davis 2002, ch. 3): generated centroids into the tracker
(notebook 10, tests, experiments); the scores are those of
:mod:`lsmta.evaluation.track_scores`.

* :func:`fig35_starvation` — three cameras, one clock 4 ms ahead, the discard-late policy
  against accepting frames within the expected clock discrepancy;
* :func:`offset_sweep` — the eighteen-camera rig with growing clock offsets;
* :func:`queue_policies` — an overloaded estimator choosing which queued frame to use;
* :func:`still_and_stage` — 3-D jitter of a still LED, deviation from a linear stage's line;
* :func:`circle_models` — weak, medium and stiff motion models on a circular path;
* :func:`walking_trial` — eight LEDs on a walking person, scored with our own matching
  and with Stone Soup's metrics, optionally against Stone Soup's tracker;
* :func:`cameras_come_and_go` — the walk with one camera joining while tracking
  (calibrated against the tracked LEDs) and one camera that stops delivering;
* :func:`synchronised_offset_sweep` — Fig. 33: per-instant ray intersection against the
  Kalman integration on the same unsynchronised frames, error against camera time offset.

The trials take their cameras as ``rig`` (default: :func:`trial_rig`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_rng
from ..camera import Camera
from ..synth.calibration import poor_guess
from ..synth.widearea import (
    Clocks,
    LedCentroidParams,
    LedScene,
    ceiling_rig,
    circle_led,
    linear_stage,
    make_clocks,
    observe_leds,
    still_led,
    walking_person,
)
from ..widearea import (
    EstimatorParams,
    Frames,
    JoinParams,
    TrackingResult,
    WideAreaTracker,
    schedule,
    track,
)
from ..widearea.intersection import intersect_instants
from ..widearea.peers import stonesoup_track
from .track_scores import LedTrackScore, longest_track_estimate, score_led_tracks, stonesoup_metrics

RIG_SEED = 7   # seed of the perturbed ceiling rig the trials use unless given cameras


def trial_rig(rig) -> list[Camera]:
    """The cameras of a trial: ``rig`` (a sequence of :class:`~lsmta.camera.Camera`) as
    given, or the 18-camera ceiling rig perturbed with seed :data:`RIG_SEED`."""
    if rig is None:
        return ceiling_rig(rng=RIG_SEED)
    rig = list(rig)
    if not rig or not all(isinstance(c, Camera) for c in rig):
        raise TypeError("rig: expected a non-empty sequence of lsmta.camera.Camera")
    return rig


# ----------------------------------------------------------------------------- starvation
def _used_fraction(result: TrackingResult) -> np.ndarray:
    return result.frames_used / np.maximum(result.frames_received, 1)


@dataclass(frozen=True)
class StarvationTrial:
    """Per camera: fraction of its frames the estimator used, under two late policies.

    Attributes
    ----------
    used_discard, used_tolerant : (K,) arrays
        Fraction of frames used with ``late_tolerance = 0`` and with the tolerance.
    tracks_discard, tracks_tolerant : int
        Targets created under each policy.
    rms_discard, rms_tolerant : float
        RMS 3-D error of the LED's track (mm; NaN if none).
    """

    used_discard: np.ndarray
    used_tolerant: np.ndarray
    tracks_discard: int
    tracks_tolerant: int
    rms_discard: float
    rms_tolerant: float


def _run_policies(scene, cams, obs, params, tolerance, times) -> StarvationTrial:
    out = []
    for tol in (0.0, tolerance):
        res = track(cams, obs.frames, params=replace(params, late_tolerance=tol))
        out.append((_used_fraction(res), len(res.tracks),
                    score_led_tracks(scene, res, times).rms_mm))
    return StarvationTrial(used_discard=out[0][0], used_tolerant=out[1][0],
                           tracks_discard=out[0][1], tracks_tolerant=out[1][1],
                           rms_discard=out[0][2], rms_tolerant=out[1][2])


def fig35_starvation(*, rng: np.random.Generator | int | None = None, rig=None,
                     offset: float = 0.004,
                     tolerance: float = 0.010, duration: float = 2.0) -> StarvationTrial:
    """The thesis's Fig. 35: cameras A, B, C at 60 Hz capture at 2, 3 and 4 ms of every
    frame period; A's clock runs ``offset`` s ahead; equal latencies (5 ms). A still LED
    in view of all three. ``rig``: the cameras, of which 0, 7 and 12 are used (default: the
    unperturbed ceiling rig)."""
    rng = as_rng(rng)
    rig = ceiling_rig() if rig is None else trial_rig(rig)
    cams = [rig[i] for i in (0, 7, 12)]
    clocks = Clocks(rate=np.full(3, 60.0), phase=np.array([0.002, 0.003, 0.004]),
                    offset=np.array([offset, 0.0, 0.0]), latency=np.full(3, 0.005))
    scene = still_led(duration=duration)
    obs = observe_leds(scene, cams, clocks, rng=rng, params=LedCentroidParams(reflections=0.0))
    times = np.arange(0.3, duration, 0.01)
    return _run_policies(scene, cams, obs, EstimatorParams(), tolerance, times)


def offset_sweep(max_offsets, *, rng: np.random.Generator | int | None = None, rig=None,
                 tolerance: float = 0.030, duration: float = 1.5) -> dict:
    """Eighteen cameras (30-60 Hz, latencies 6-10 ms) watching the walking person, with clock
    offsets uniform in ``±max_offset`` for each value of ``max_offsets`` (s).

    Returns
    -------
    dict
        ``max_offset`` (n,), ``min_used_discard`` and ``min_used_tolerant`` (n,): the smallest
        per-camera fraction of frames used; ``starved_discard``/``starved_tolerant`` (n,):
        cameras with fewer than half their frames used; ``rms_discard``/``rms_tolerant``.
    """
    rng = as_rng(rng)
    cams = trial_rig(rig)
    on = np.stack([np.full(8, 0.05), np.full(8, np.inf)], axis=1)
    scene = walking_person(duration=duration + 0.05, on=on)
    times = np.arange(0.4, duration, 0.01)
    rows = []
    for m in max_offsets:
        clocks = make_clocks(len(cams), rng=rng, max_offset=m, latency=(0.006, 0.010))
        obs = observe_leds(scene, cams, clocks, rng=rng, duration=duration)
        trial = _run_policies(scene, cams, obs, EstimatorParams(), tolerance, times)
        rows.append((m, trial.used_discard.min(), trial.used_tolerant.min(),
                     int((trial.used_discard < 0.5).sum()),
                     int((trial.used_tolerant < 0.5).sum()),
                     trial.rms_discard, trial.rms_tolerant))
    keys = ("max_offset", "min_used_discard", "min_used_tolerant", "starved_discard",
            "starved_tolerant", "rms_discard", "rms_tolerant")
    return {k: np.array(v) for k, v in zip(keys, zip(*rows))}


def queue_policies(*, rng: np.random.Generator | int | None = None, service_time: float = 0.0025,
                   duration: float = 4.0, max_offset: float = 0.004, policies=None) -> dict:
    """An overloaded estimator (one frame every ``service_time`` s) fed by 17 cameras at
    60 Hz and one slow camera at 10 Hz (the thesis's example). Only the queues are
    simulated (:func:`lsmta.widearea.schedule`); which frames get processed does not depend
    on what they contain.

    Returns
    -------
    dict
        Per policy: ``share`` (K,) fraction of each camera's frames processed, ``age_ms``
        (K,) mean age of the processed frames when taken up (true capture to start; NaN for
        a camera never served), ``lag_ms`` (K,) mean of how much older each processed frame's
        stamp is than the newest stamp processed before it (what the late tolerance must
        absorb), and ``slow_camera``.
    """
    rng = as_rng(rng)
    K = 18
    rates = np.full(K, 60.0)
    rates[5] = 10.0
    clocks = Clocks(rate=rates, phase=rng.uniform(0, 1, K) / rates,
                    offset=rng.uniform(-max_offset, max_offset, K),
                    latency=rng.uniform(0.004, 0.008, K), jitter=0.0005)
    true_time, camera = [], []
    for k in range(K):
        t = clocks.phase[k] + np.arange(0, duration * rates[k]) / rates[k]
        true_time.append(t[t < duration])
        camera.append(np.full(len(true_time[-1]), k))
    true_time, camera = np.concatenate(true_time), np.concatenate(camera)
    stamp = true_time + clocks.offset[camera]
    arrival = (true_time + clocks.latency[camera]
               + clocks.jitter * np.abs(rng.normal(size=len(true_time))))
    out = {}
    for policy in policies or ("fifo", "newest", "round_robin", "random_recent"):
        sch = schedule(arrival, camera, stamp, policy, service_time, rng=rng)
        cam = camera[sch.order]
        counts = np.bincount(camera, minlength=K)
        done = np.bincount(cam, minlength=K)
        age = sch.started - true_time[sch.order]
        st = stamp[sch.order]
        lag = np.maximum(np.maximum.accumulate(np.r_[-np.inf, st[:-1]]) - st, 0.0)
        per = [cam == k for k in range(K)]
        out[policy] = {
            "share": done / counts,
            "age_ms": np.array([1e3 * age[s].mean() if s.any() else np.nan for s in per]),
            "lag_ms": np.array([1e3 * lag[s].mean() if s.any() else np.nan for s in per]),
            "slow_camera": 5}
    return out


# ----------------------------------------------------------------------------- accuracy
def _line_fit(points):
    """Distance of each point ``(n, 3)`` to its least-squares line (mm)."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c)
    d = points - c
    return np.linalg.norm(d - (d @ vt[0])[:, None] * vt[0], axis=1)


@dataclass(frozen=True)
class StillStage:
    """Figs. 40-41: a still LED and a linear stage seen by the 18-camera rig.

    Attributes
    ----------
    still_times, still_estimate : (T,), (T, 3)
        Estimated position of the still LED at 100 Hz, mm.
    still_truth : (3,)
    still_jitter_mm : (3,) array
        Peak-to-peak of the estimate per axis (x, y, z), mm.
    stage_times, stage_estimate, stage_truth : (S,), (S, 3), (S, 3)
    stage_deviation : (S,) array
        Distance of each estimate from the line fitted to the estimates (moving part), mm.
    stage_error_rms : float
        RMS of estimate minus truth on the stage, mm.
    """

    still_times: np.ndarray
    still_estimate: np.ndarray
    still_truth: np.ndarray
    still_jitter_mm: np.ndarray
    stage_times: np.ndarray
    stage_estimate: np.ndarray
    stage_truth: np.ndarray
    stage_deviation: np.ndarray
    stage_error_rms: float


def still_and_stage(*, rng: np.random.Generator | int | None = None, rig=None,
                    quantize: bool = True,
                    params: EstimatorParams | None = None, duration: float = 4.0,
                    still_duration: float = 2.0) -> StillStage:
    """Track a still LED (``still_duration`` s, scored after the first 0.5 s) and an LED on a
    linear stage (``duration`` s: 0.5 s hold, motion, 0.5 s hold) with the rig; centroids
    rounded to whole pixels by default, as the thesis's detector reported them."""
    rng = as_rng(rng)
    params = EstimatorParams() if params is None else params
    cams = trial_rig(rig)
    clocks = make_clocks(len(cams), rng=rng)
    centroids = LedCentroidParams(quantize=quantize, reflections=0.0)
    still = still_led(duration=still_duration)
    res = track(cams,
                observe_leds(still, cams, clocks, rng=rng, params=centroids).frames,
                params=params)
    ts = np.arange(0.5, still_duration, 0.01)
    est = longest_track_estimate(res, ts)
    stage = linear_stage(duration=duration, hold=0.5)
    res2 = track(cams,
                 observe_leds(stage, cams, clocks, rng=rng, params=centroids).frames,
                 params=params)
    tg = np.arange(0.6, duration - 0.6, 0.01)
    est2 = longest_track_estimate(res2, tg)
    truth2 = stage.positions_at(tg)[:, 0]
    ok = np.isfinite(est2).all(axis=1)
    dev = np.full(len(tg), np.nan)
    dev[ok] = _line_fit(est2[ok])
    return StillStage(
        still_times=ts, still_estimate=est, still_truth=still.positions[0, 0],
        still_jitter_mm=np.nanmax(est, axis=0) - np.nanmin(est, axis=0),
        stage_times=tg, stage_estimate=est2, stage_truth=truth2, stage_deviation=dev,
        stage_error_rms=float(np.sqrt(np.nanmean(np.sum((est2 - truth2) ** 2, axis=1)))))


def circle_models(densities: dict, *, rng: np.random.Generator | int | None = None,
                  rig=None, duration: float = 3.0, camera: int = 0) -> dict:
    """Figs. 42-44: one LED moved in a circle (radius 300 mm, 1 s per turn), tracked with
    motion models of different strength (``densities``: name -> acceleration spectral
    density, mm²/s³). The same observations for every model.

    Returns
    -------
    dict
        Per name: ``tracks`` (targets created), ``coverage`` (fraction of time with a track
        within 60 mm), ``rms_mm``, ``estimate`` (T, 3) of the best track, ``times``,
        ``updates`` (the tracker's update log for ``camera``: predicted and observed
        centroids), plus ``truth`` (T, 3).
    """
    rng = as_rng(rng)
    cams = trial_rig(rig)
    clocks = make_clocks(len(cams), rng=rng)
    scene = circle_led(duration=duration)
    obs = observe_leds(scene, cams, clocks, rng=rng, params=LedCentroidParams(reflections=0.0))
    times = np.arange(0.2, duration, 0.005)
    out = {"truth": scene.positions_at(times)[:, 0], "times": times}
    for name, q in densities.items():
        res = track(cams, obs.frames, params=EstimatorParams(accel_density=q))
        sc = score_led_tracks(scene, res, times)
        sel = res.updates["camera"] == camera
        out[name] = {"tracks": len(res.tracks), "coverage": sc.coverage, "rms_mm": sc.rms_mm,
                     "estimate": res.positions_at(times),
                     "predicted": res.updates["predicted"][sel],
                     "observed": res.updates["observed"][sel],
                     "update_time": res.updates["time"][sel]}
    return out


# ----------------------------------------------------------------------------- walking
@dataclass(frozen=True, eq=False)
class WalkingTrial:
    """The walking person, tracked by our estimator (and optionally by Stone Soup).

    Attributes
    ----------
    cameras : list of Camera
    scene : LedScene
    frames : Frames
        The observations both trackers received.
    ours, stonesoup : TrackingResult (stonesoup None when not run)
    score_ours, score_stonesoup : LedTrackScore
    metrics_ours, metrics_stonesoup : dict (Stone Soup's metrics; see stonesoup_metrics)
    seconds_ours, seconds_stonesoup : float
        Wall-clock time of each tracker.
    """

    cameras: list
    scene: LedScene
    frames: Frames
    ours: TrackingResult
    stonesoup: TrackingResult | None
    score_ours: LedTrackScore
    score_stonesoup: LedTrackScore | None
    metrics_ours: dict
    metrics_stonesoup: dict | None
    seconds_ours: float
    seconds_stonesoup: float


def walking_trial(*, rng: np.random.Generator | int | None = None, rig=None,
                  duration: float = 3.6,
                  cameras=None, params: EstimatorParams | None = None, with_stonesoup: bool = False,
                  on=None, monitors=None, reflections: float = 0.05,
                  max_offset: float = 0.004) -> WalkingTrial:
    """Eight LEDs on a walking person, 18 cameras at 30-60 Hz with clock offsets of
    ``±max_offset`` s; clutter from reflections and (default) a monitor in camera 3.

    ``cameras``: indices into the rig to use (default all 18). The observations reach both
    trackers in arrival order (ours) or time-stamp order (Stone Soup).
    """
    rng = as_rng(rng)
    params = EstimatorParams() if params is None else params
    rig = trial_rig(rig)
    cams = rig if cameras is None else [rig[i] for i in cameras]
    clocks = make_clocks(len(cams), rng=rng, max_offset=max_offset)
    scene = walking_person(duration=duration, on=on)
    if monitors is None:
        monitors = {3: (40.0, 300.0, 140.0, 380.0)} if len(cams) > 3 else {}
    obs = observe_leds(scene, cams, clocks, rng=rng,
                       params=LedCentroidParams(reflections=reflections, monitors=monitors))
    times = np.arange(0.0, duration, 1 / 60)
    t0 = time.perf_counter()
    ours = track(cams, obs.frames, params=params)
    sec = time.perf_counter() - t0
    ss = ss_score = ss_metrics = None
    sec_ss = np.nan
    if with_stonesoup:
        t0 = time.perf_counter()
        ss = stonesoup_track(cams, obs.frames, params=params)
        sec_ss = time.perf_counter() - t0
        ss_score = score_led_tracks(scene, ss, times)
        ss_metrics = stonesoup_metrics(scene, ss, times[::2])
    return WalkingTrial(cameras=cams, scene=scene, frames=obs.frames, ours=ours, stonesoup=ss,
                        score_ours=score_led_tracks(scene, ours, times), score_stonesoup=ss_score,
                        metrics_ours=stonesoup_metrics(scene, ours, times[::2]),
                        metrics_stonesoup=ss_metrics, seconds_ours=sec,
                        seconds_stonesoup=sec_ss)


# ----------------------------------------------------------------------------- come and go
@dataclass(frozen=True, eq=False)
class ComeAndGo:
    """The walk with one camera joining and one leaving (see :func:`cameras_come_and_go`).

    Attributes
    ----------
    scene : LedScene
    joined : int
        Index of the joining camera in the tracker (the last).
    dropped : int
        Index of the camera that stops delivering.
    added_at, stop_at : float
        When the joining camera was added (its first frame fed), when the other camera's
        last frame was stamped, s.
    joined_at, dropped_at : float
        When the tracker calibrated the joining camera and put it to use, and when it
        dropped the silent camera (clock times; NaN if never), s.
    join : CameraJoin or None
        The successful calibration (None if none).
    come_and_go, without : TrackingResult
        The run with both events, and the same run without the joining camera.
    score, score_without : LedTrackScore
    innovation_rms : (K,) array
        Per camera, RMS of (observed - predicted centroid) of its updates after
        ``joined_at``, px (NaN for cameras without updates then).
    calibration_error_px : float
        RMS image distance between the LEDs' projections through the joined camera and
        through the true one (after the fact, truth as input), px.
    rms_after, rms_after_without : float
        3-D RMS error of the matched tracks from ``joined_at`` on, with and without the
        joined camera, mm.
    used_after_drop : (K,) array
        Per camera (of the cameras known when ``drop_camera`` stopped), the fraction of
        the frames it delivered after that which the tracker used (NaN: none delivered).
    """

    scene: LedScene
    joined: int
    dropped: int
    added_at: float
    stop_at: float
    joined_at: float
    dropped_at: float
    join: object
    come_and_go: TrackingResult
    without: TrackingResult
    score: LedTrackScore
    score_without: LedTrackScore
    innovation_rms: np.ndarray
    calibration_error_px: float
    rms_after: float
    rms_after_without: float
    used_after_drop: np.ndarray


def cameras_come_and_go(*, rng: np.random.Generator | int | None = None, rig=None,
                        duration: float = 2.4, join_camera: int = 5, add_at: float = 0.6,
                        drop_camera: int = 11, stop_at: float = 1.4,
                        camera_timeout: float = 0.25, join: JoinParams | None = None,
                        max_offset: float = 0.004) -> ComeAndGo:
    """Eight LEDs on the walking person (on from 0.10-0.45 s to the end), the 18-camera rig
    with clock offsets of ``±max_offset`` s and reflections. The tracker starts with 17
    cameras; camera ``join_camera`` is installed at ``add_at`` s with a tape-measured pose
    (:func:`lsmta.synth.calibration.poor_guess`: 150 mm, 3 degrees, 5 % focal length, no
    distortion) and joins once calibrated against the tracked LEDs
    (:meth:`lsmta.widearea.WideAreaTracker.add_camera`). Camera ``drop_camera`` delivers no
    frame stamped after ``stop_at`` s; the tracker drops it after ``camera_timeout`` s of
    silence. The same frames without the joining camera are the comparison."""
    rng = as_rng(rng)
    rig = trial_rig(rig)
    k = np.arange(8)
    scene = walking_person(duration=duration,
                           on=np.stack([0.1 + 0.05 * k, np.full(8, np.inf)], axis=1))
    clocks = make_clocks(len(rig), rng=rng, max_offset=max_offset)
    obs = observe_leds(scene, rig, clocks, rng=rng)
    guess = poor_guess([rig[join_camera]], rng=rng)[0]
    start = [c for i, c in enumerate(rig) if i != join_camera]
    index = np.array([i - (i > join_camera) for i in range(len(rig))])
    index[join_camera] = len(start)
    fr = obs.frames
    keep = ~((fr.camera == drop_camera) & (fr.stamp > stop_at))
    params = EstimatorParams(camera_timeout=camera_timeout)
    results, snapshot = [], None
    for with_join in (True, False):
        tracker = WideAreaTracker(start, params=params)
        added = False
        for f in np.flatnonzero(keep):
            c = int(fr.camera[f])
            if c == join_camera:
                if not with_join or fr.arrival[f] < add_at:
                    continue
                if not added:
                    added = True
                    tracker.add_camera(guess, calibrated=False, join=join)
            if with_join and snapshot is None and fr.arrival[f] > stop_at:
                snapshot = tracker.result()          # the counters when the camera stops
            tracker.feed(index[c], fr.stamp[f], fr.centroids(f))
        results.append(tracker.result())
    res, res0 = results
    used = res.frames_used[:len(snapshot.frames_used)] - snapshot.frames_used
    got = res.frames_received[:len(snapshot.frames_used)] - snapshot.frames_received
    return _come_and_go(scene, res, res0, rig[join_camera], index, join_camera, drop_camera,
                        add_at, stop_at, duration,
                        np.where(got > 0, used / np.maximum(got, 1), np.nan))


def _event_time(res: TrackingResult, camera: int, what: str) -> float:
    t = [e[0] for e in res.camera_events if e[1] == camera and e[2] == what]
    return float(t[0]) if t else np.nan


def _come_and_go(scene, res, res0, true_camera, index, join_camera, drop_camera, add_at,
                 stop_at, duration, used_after) -> ComeAndGo:
    """Score the two runs of :func:`cameras_come_and_go`."""
    j, d = int(index[join_camera]), int(index[drop_camera])
    joined_at = _event_time(res, j, "joined")
    join = next((r for c, r in res.joins if c == j and r.status == 0), None)
    times = np.arange(0.0, duration, 1 / 60)
    score, score0 = score_led_tracks(scene, res, times), score_led_tracks(scene, res0, times)
    after = times >= joined_at if np.isfinite(joined_at) else np.zeros(len(times), bool)

    def rms(sc):
        e = sc.error[after]
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e**2))) if len(e) else np.nan

    u = res.updates
    late = u["time"] >= joined_at if np.isfinite(joined_at) else np.zeros(len(u["time"]), bool)
    innov = np.linalg.norm(u["observed"] - u["predicted"], axis=1)
    K = len(res.cameras)
    inno = np.array([np.sqrt(np.mean(innov[late & (u["camera"] == c)] ** 2))
                     if (late & (u["camera"] == c)).any() else np.nan for c in range(K)])
    cal = np.nan
    if join is not None:
        X = scene.positions.reshape(-1, 3)[::97]
        a, b = true_camera.project(X, behind="nan"), join.camera.project(X, behind="nan")
        ok = np.isfinite(a).all(axis=1) & true_camera.in_image(a)
        cal = float(np.sqrt(np.mean(np.sum((a[ok] - b[ok]) ** 2, axis=1))))
    return ComeAndGo(
        scene=scene, joined=j, dropped=d, added_at=float(add_at), stop_at=float(stop_at),
        joined_at=joined_at, dropped_at=_event_time(res, d, "dropped"), join=join,
        come_and_go=res, without=res0, score=score, score_without=score0,
        innovation_rms=inno, calibration_error_px=cal, rms_after=rms(score),
        rms_after_without=rms(score0), used_after_drop=used_after)


# ----------------------------------------------------------------------------- Fig. 33
def synchronised_offset_sweep(offsets, *, rng: np.random.Generator | int | None = None,
                              rig=None, duration: float = 1.6, rate: float = 60.0,
                              tolerance: float = 15.0, match_mm: float = 100.0) -> dict:
    """Fig. 33: the walking person's eight LEDs seen by the 18 cameras, all at ``rate`` Hz
    with correct time stamps, but capturing at different moments: camera k's frames are
    taken ``phase_k`` after the frame grid, ``phase_k`` uniform in ``[0, offset]`` for each
    value of ``offsets`` (s). The same frames go to the Kalman integration (the tracker, in
    arrival order) and to the synchronised method, which intersects at each instant of the
    grid the rays of every camera's frame nearest to it
    (:func:`lsmta.widearea.intersection.intersect_instants`, ``tolerance`` mm). At every
    instant both sets of points are matched to the true LEDs (Hungarian, within
    ``match_mm``).

    Returns
    -------
    dict
        ``offset`` (n,) s; per method (``"kalman"``, ``"synchronised"``): ``rms_mm`` (n,)
        RMS 3-D error of the matched points, ``completeness`` (n,) the share of (LED,
        instant) pairs with a point within ``match_mm``, ``extra`` (n,) points per instant
        matched to no LED.
    """
    rng = as_rng(rng)
    cams = trial_rig(rig)
    K = len(cams)
    scene = walking_person(duration=duration + 0.1,
                           on=np.stack([np.zeros(8), np.full(8, np.inf)], axis=1))
    times = np.arange(0.3, duration - 0.05, 1 / rate)
    truth = scene.positions_at(times)
    out = {"offset": np.asarray(offsets, float)}
    for name in ("kalman", "synchronised"):
        out[name] = {key: [] for key in ("rms_mm", "completeness", "extra")}
    for off in offsets:
        clocks = Clocks(rate=np.full(K, rate), phase=rng.uniform(0.0, off, K) if off > 0
                        else np.zeros(K), offset=np.zeros(K),
                        latency=rng.uniform(0.004, 0.008, K), jitter=0.0005)
        obs = observe_leds(scene, cams, clocks, rng=rng, duration=duration,
                           params=LedCentroidParams(reflections=0.0))
        res = track(cams, obs.frames)
        pts = intersect_instants(cams, obs.frames, times, window=1 / rate,
                                 tolerance=tolerance)
        est = res.positions_at(times)
        for name, per in (("kalman", [e[np.isfinite(e).all(axis=1)] for e in est]),
                          ("synchronised", [pts.at(t) for t in range(len(times))])):
            err, extra = _match_points(truth, per, match_mm)
            ok = np.isfinite(err)
            out[name]["rms_mm"].append(float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any()
                                       else np.nan)
            out[name]["completeness"].append(float(ok.mean()))
            out[name]["extra"].append(float(np.mean(extra)))
    for name in ("kalman", "synchronised"):
        out[name] = {k: np.array(v) for k, v in out[name].items()}
    return out


def _match_points(truth, points, match_mm: float):
    """Errors (T, N) of the points matched to the true LEDs per instant (NaN: none within
    ``match_mm``) and the unmatched points per instant (T,)."""
    T, N = truth.shape[:2]
    err = np.full((T, N), np.nan)
    extra = np.zeros(T)
    for t in range(T):
        P = points[t]
        if not len(P):
            continue
        dist = np.linalg.norm(truth[t][:, None] - P[None], axis=2)
        r, c = linear_sum_assignment(np.where(dist <= match_mm, dist, 1e9))
        ok = dist[r, c] <= match_mm
        err[t, r[ok]] = dist[r[ok], c[ok]]
        extra[t] = len(P) - ok.sum()
    return err, extra
