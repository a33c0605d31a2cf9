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
  and with Stone Soup's metrics, optionally against Stone Soup's tracker.

The trials take their cameras as ``rig`` (default: :func:`trial_rig`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_rng
from ..camera import Camera
from ..synth.widearea import (
    Clocks,
    LedScene,
    ceiling_rig,
    circle_led,
    linear_stage,
    make_clocks,
    observe,
    still_led,
    walking_person,
)
from ..widearea import EstimatorParams, Frames, TrackingResult, schedule, track
from ..widearea.peers import stonesoup_track
from .track_scores import TrackScore, longest_track_estimate, score_tracks, stonesoup_metrics

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
        out.append((_used_fraction(res), len(res.tracks), score_tracks(scene, res, times).rms_mm))
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
    obs = observe(scene, cams, clocks, rng=rng, reflections=0.0)
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
        obs = observe(scene, cams, clocks, rng=rng, duration=duration)
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
    still = still_led(duration=still_duration)
    res = track(cams,
                observe(still, cams, clocks, rng=rng, quantize=quantize,
                              reflections=0.0).frames,
                params=params)
    ts = np.arange(0.5, still_duration, 0.01)
    est = longest_track_estimate(res, ts)
    stage = linear_stage(duration=duration, hold=0.5)
    res2 = track(cams,
                 observe(stage, cams, clocks, rng=rng, quantize=quantize,
                               reflections=0.0).frames,
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
    obs = observe(scene, cams, clocks, rng=rng, reflections=0.0)
    times = np.arange(0.2, duration, 0.005)
    out = {"truth": scene.positions_at(times)[:, 0], "times": times}
    for name, q in densities.items():
        res = track(cams, obs.frames, params=EstimatorParams(accel_density=q))
        sc = score_tracks(scene, res, times)
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
    score_ours, score_stonesoup : TrackScore
    metrics_ours, metrics_stonesoup : dict (Stone Soup's metrics; see stonesoup_metrics)
    seconds_ours, seconds_stonesoup : float
        Wall-clock time of each tracker.
    """

    cameras: list
    scene: LedScene
    frames: Frames
    ours: TrackingResult
    stonesoup: TrackingResult | None
    score_ours: TrackScore
    score_stonesoup: TrackScore | None
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
    obs = observe(scene, cams, clocks, rng=rng, reflections=reflections, monitors=monitors)
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
        ss_score = score_tracks(scene, ss, times)
        ss_metrics = stonesoup_metrics(scene, ss, times[::2])
    return WalkingTrial(cameras=cams, scene=scene, frames=obs.frames, ours=ours, stonesoup=ss,
                        score_ours=score_tracks(scene, ours, times), score_stonesoup=ss_score,
                        metrics_ours=stonesoup_metrics(scene, ours, times[::2]),
                        metrics_stonesoup=ss_metrics, seconds_ours=sec,
                        seconds_stonesoup=sec_ss)
