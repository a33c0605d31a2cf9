"""Wide-area tracking trials (Davis 2002, ch. 3): generator and tracker side by side
(notebook 10, tests, experiments).

* :func:`fig35_starvation` — three cameras, one clock 4 ms ahead, the discard-late policy
  against accepting frames within the expected clock discrepancy;
* :func:`offset_sweep` — the eighteen-camera rig with growing clock offsets;
* :func:`queue_policies` — an overloaded estimator choosing which queued frame to use;
* :func:`still_and_stage` — 3-D jitter of a still LED, deviation from a linear stage's line;
* :func:`circle_models` — weak, medium and stiff motion models on a circular path;
* :func:`walking_trial` — eight LEDs on a walking person, scored with our own matching
  (identity changes, birth and death delays, RMS error) and with Stone Soup's metrics
  (OSPA, SIAP completeness and spuriousness);
* :func:`rendered_tracking_trial` — the end-to-end path: an LED on the linear stage rendered
  in a few cameras, detected (full or sub-sampled search), tracked, and scored in 3-D.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_rng
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
from ..widearea import Frames, TrackerParams, TrackingResult, schedule, track

MATCH_MM = 60.0   # a track within this distance of an LED may be that LED's track


# ----------------------------------------------------------------------------- matching
@dataclass(frozen=True)
class TrackScore:
    """A tracking run scored against the LEDs' ground truth.

    Attributes
    ----------
    times : (T,) array
        Evaluation times, s.
    assigned : (T, N) int array
        Track id assigned to each LED at each time (-1: none within ``MATCH_MM``; -2: LED off).
    error : (T, N) array
        Distance of the assigned track from the LED, mm (NaN when none).
    rms_mm : float
        Root mean square of ``error`` over assigned (LED, time) pairs only; read it with
        ``coverage`` (an LED without a track within ``MATCH_MM`` adds nothing to it).
    identity_changes : int
        Times an LED's assigned track id changed to another id (gaps not counted).
    birth_delay, death_delay : (N,) arrays
        Birth of the first track an LED got minus the LED's switch-on time; death of its
        last track minus the switch-off time (NaN when never born / still alive), s.
    coverage : float
        Fraction of (LED on, time) pairs with an assigned track.
    spurious_tracks : int
        Tracks never assigned to any LED.
    never_born : int
        LEDs on at some scoring time that were never assigned a track (a failed birth;
        their ``birth_delay`` is NaN).
    never_deleted : int
        LEDs switched off before the last scoring time whose last track was still alive
        at the end of the run (a failed death; their ``death_delay`` is NaN). An LED that
        was never born is not counted here.
    """

    times: np.ndarray
    assigned: np.ndarray
    error: np.ndarray
    rms_mm: float
    identity_changes: int
    birth_delay: np.ndarray
    death_delay: np.ndarray
    coverage: float
    spurious_tracks: int
    never_born: int = 0
    never_deleted: int = 0


def score_tracks(scene: LedScene, result: TrackingResult, times) -> TrackScore:
    """Match tracks to LEDs at ``times`` (Hungarian on distances, gated at ``MATCH_MM``)."""
    times = np.asarray(times, dtype=float)
    truth = scene.positions_at(times)                                  # (T, N, 3)
    est = result.positions_at(times)                                   # (T, M, 3)
    T, N = truth.shape[:2]
    ids = np.array([tr.id for tr in result.tracks], dtype=int)
    assigned = np.full((T, N), -1)
    error = np.full((T, N), np.nan)
    on = np.isfinite(truth).all(axis=2)
    assigned[~on] = -2
    for k in range(T):
        if est.shape[1] == 0:
            break
        d = np.linalg.norm(truth[k][:, None] - est[k][None], axis=2)
        d = np.where(np.isfinite(d), d, 1e9)
        r, c = linear_sum_assignment(d)
        ok = d[r, c] <= MATCH_MM
        assigned[k, r[ok]] = ids[c[ok]]
        error[k, r[ok]] = d[r[ok], c[ok]]
    changes = 0
    birth = np.full(N, np.nan)
    death = np.full(N, np.nan)
    by_id = {tr.id: tr for tr in result.tracks}
    never_born = never_deleted = 0
    for n in range(N):
        seq = assigned[:, n][assigned[:, n] >= 0]
        if len(seq):
            changes += int(np.count_nonzero(np.diff(seq)))
            birth[n] = by_id[seq[0]].birth_time - scene.on[n, 0]
            if np.isfinite(scene.on[n, 1]) and scene.on[n, 1] < times[-1]:
                death[n] = by_id[seq[-1]].death_time - scene.on[n, 1]
                never_deleted += int(np.isnan(death[n]))
        elif on[:, n].any():
            never_born += 1
    used = set(assigned[assigned >= 0].tolist())
    e = error[np.isfinite(error)]
    return TrackScore(times=times, assigned=assigned, error=error,
                      rms_mm=float(np.sqrt(np.mean(e**2))) if len(e) else np.nan,
                      identity_changes=changes, birth_delay=birth, death_delay=death,
                      coverage=float((assigned >= 0).sum() / max(on.sum(), 1)),
                      spurious_tracks=len(ids) - len(used & set(ids.tolist())),
                      never_born=never_born, never_deleted=never_deleted)


def stonesoup_metrics(scene: LedScene, result: TrackingResult, times, *, c_mm: float = 100.0,
                      threshold_mm: float = MATCH_MM) -> dict:
    """Stone Soup's OSPA (p = 1, cut-off ``c_mm``) and SIAP metrics of a run.

    Truth and tracks are sampled at ``times`` (tracks: their real-time estimate, the last
    state carried forward at constant velocity) and handed to Stone Soup as
    ``GroundTruthPath`` and ``Track`` objects; tracks are associated with truths by
    ``TrackToTruth`` (Euclidean position distance below ``threshold_mm``).

    Returns
    -------
    dict
        ``ospa_mm`` (mean over time), ``siap_completeness``, ``siap_spuriousness``,
        ``siap_ambiguity``, ``siap_position_accuracy_mm``, ``siap_track_number_change_rate``
        (per second). (Stone Soup's CLEAR MOT generator refuses runs in which two tracks
        sit on one truth at the same time, which a newborn ghost near an LED causes, so it
        is not used.)
    """
    from stonesoup.dataassociator.tracktotrack import TrackToTruth
    from stonesoup.measures import Euclidean
    from stonesoup.metricgenerator.manager import MultiManager
    from stonesoup.metricgenerator.ospametric import OSPAMetric
    from stonesoup.metricgenerator.tracktotruthmetrics import SIAPMetrics
    from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
    from stonesoup.types.state import State
    from stonesoup.types.track import Track

    from ..widearea.peers import seconds_to_datetime

    times = np.asarray(times, dtype=float)
    stamps = [seconds_to_datetime(t) for t in times]

    def paths(P, make_path, make_state):
        out = set()
        for n in range(P.shape[1]):
            v = np.nan_to_num(np.gradient(P[:, n], times, axis=0))
            path = make_path()
            for k, when in enumerate(stamps):
                if np.isfinite(P[k, n]).all():
                    path.append(make_state(np.r_[P[k, n], v[k]].reshape(-1, 1),
                                           timestamp=when))
            if len(path):
                out.add(path)
        return out

    truths = paths(scene.positions_at(times), GroundTruthPath, GroundTruthState)
    tracks = paths(result.positions_at(times), Track, State)
    pos, vel = Euclidean(mapping=(0, 1, 2)), Euclidean(mapping=(3, 4, 5))
    manager = MultiManager(
        [OSPAMetric(c=c_mm, p=1, measure=pos),
         SIAPMetrics(position_measure=pos, velocity_measure=vel)],
        associator=TrackToTruth(association_threshold=threshold_mm, measure=pos))
    manager.add_data({"groundtruth_paths": truths, "tracks": tracks})
    m = manager.generate_metrics()
    ospa = m["ospa_generator"]["OSPA distances"].value
    siap = m["siap_generator"]
    return {
        "ospa_mm": float(np.mean([s.value for s in ospa])),
        "siap_completeness": float(siap["SIAP Completeness"].value),
        "siap_spuriousness": float(siap["SIAP Spuriousness"].value),
        "siap_ambiguity": float(siap["SIAP Ambiguity"].value),
        "siap_position_accuracy_mm": float(siap["SIAP Position Accuracy"].value),
        "siap_track_number_change_rate": float(siap["SIAP Rate of Track Number Change"].value),
    }


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
    return StarvationTrial(out[0][0], out[1][0], out[0][1], out[1][1], out[0][2], out[1][2])


def fig35_starvation(*, rng: np.random.Generator | int | None = None, offset: float = 0.004,
                     tolerance: float = 0.010, duration: float = 2.0) -> StarvationTrial:
    """The thesis's Fig. 35: cameras A, B, C at 60 Hz capture at 2, 3 and 4 ms of every
    frame period; A's clock runs ``offset`` s ahead; equal latencies (5 ms). A still LED
    in view of all three."""
    rng = as_rng(rng)
    rig = ceiling_rig()
    cams = [rig[i] for i in (0, 7, 12)]
    clocks = Clocks(rate=np.full(3, 60.0), phase=np.array([0.002, 0.003, 0.004]),
                    offset=np.array([offset, 0.0, 0.0]), latency=np.full(3, 0.005))
    scene = still_led(duration=duration)
    obs = observe(scene, cams, clocks, rng=rng, reflections=0.0)
    times = np.arange(0.3, duration, 0.01)
    return _run_policies(scene, cams, obs, TrackerParams(), tolerance, times)


def offset_sweep(max_offsets, *, rng: np.random.Generator | int | None = None,
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
    cams = ceiling_rig(rng=np.random.default_rng(7))
    on = np.stack([np.full(8, 0.05), np.full(8, np.inf)], axis=1)
    scene = walking_person(duration=duration + 0.05, on=on)
    times = np.arange(0.4, duration, 0.01)
    rows = []
    for m in max_offsets:
        clocks = make_clocks(len(cams), rng=rng, max_offset=m, latency=(0.006, 0.010))
        obs = observe(scene, cams, clocks, rng=rng, duration=duration)
        trial = _run_policies(scene, cams, obs, TrackerParams(), tolerance, times)
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


def _single_track_estimate(result, times):
    est = result.positions_at(times)                  # (T, M, 3)
    if est.shape[1] == 0:
        return np.full((len(times), 3), np.nan)
    # the track alive longest over the window
    best = np.argmax(np.isfinite(est[..., 0]).sum(axis=0))
    return est[:, best]


def still_and_stage(*, rng: np.random.Generator | int | None = None, quantize: bool = True,
                    params: TrackerParams | None = None, duration: float = 4.0,
                    still_duration: float = 2.0) -> StillStage:
    """Track a still LED (``still_duration`` s, scored after the first 0.5 s) and an LED on a
    linear stage (``duration`` s: 0.5 s hold, motion, 0.5 s hold) with the rig; centroids
    rounded to whole pixels by default, as the thesis's detector reported them."""
    rng = as_rng(rng)
    params = TrackerParams() if params is None else params
    cams = ceiling_rig(rng=np.random.default_rng(7))
    clocks = make_clocks(len(cams), rng=rng)
    still = still_led(duration=still_duration)
    res = track(cams,
                observe(still, cams, clocks, rng=rng, quantize=quantize,
                              reflections=0.0).frames,
                params=params)
    ts = np.arange(0.5, still_duration, 0.01)
    est = _single_track_estimate(res, ts)
    stage = linear_stage(duration=duration, hold=0.5)
    res2 = track(cams,
                 observe(stage, cams, clocks, rng=rng, quantize=quantize,
                               reflections=0.0).frames,
                 params=params)
    tg = np.arange(0.6, duration - 0.6, 0.01)
    est2 = _single_track_estimate(res2, tg)
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
                  duration: float = 3.0, camera: int = 0) -> dict:
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
    cams = ceiling_rig(rng=np.random.default_rng(7))
    clocks = make_clocks(len(cams), rng=rng)
    scene = circle_led(duration=duration)
    obs = observe(scene, cams, clocks, rng=rng, reflections=0.0)
    times = np.arange(0.2, duration, 0.005)
    out = {"truth": scene.positions_at(times)[:, 0], "times": times}
    for name, q in densities.items():
        res = track(cams, obs.frames, params=TrackerParams(accel_density=q))
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


def walking_trial(*, rng: np.random.Generator | int | None = None, duration: float = 3.6,
                  cameras=None, params: TrackerParams | None = None, with_stonesoup: bool = False,
                  on=None, monitors=None, reflections: float = 0.05,
                  max_offset: float = 0.004) -> WalkingTrial:
    """Eight LEDs on a walking person, 18 cameras at 30-60 Hz with clock offsets of
    ``±max_offset`` s; clutter from reflections and (default) a monitor in camera 3.

    ``cameras``: indices into the rig to use (default all 18). The observations reach both
    trackers in arrival order (ours) or time-stamp order (Stone Soup).
    """
    import time

    rng = as_rng(rng)
    params = TrackerParams() if params is None else params
    rig = ceiling_rig(rng=np.random.default_rng(7))
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
        from ..widearea.peers import stonesoup_track

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





# ----------------------------------------------------------------------------- detection
def _match_features(det, true_xy, radius: float = 2.0):
    """Per frame: which true LEDs were found (within ``radius`` px) and how many features
    matched no LED. Returns (found (T, N) bool, false (T,) int, error (T, N) px)."""
    T, N = true_xy.shape[:2]
    found = np.zeros((T, N), bool)
    false = np.zeros(T, np.int64)
    err = np.full((T, N), np.nan)
    for t in range(T):
        c = det.centroids(t)
        vis = np.isfinite(true_xy[t]).all(axis=1)
        if len(c) == 0:
            continue
        if vis.any():
            d = np.linalg.norm(true_xy[t][vis][:, None] - c[None], axis=2)
            r, k = linear_sum_assignment(d)
            ok = d[r, k] <= radius
            idx = np.flatnonzero(vis)[r[ok]]
            found[t, idx] = True
            err[t, idx] = d[r[ok], k[ok]]
            false[t] = len(c) - ok.sum()
        else:
            false[t] = len(c)
    return found, false, err


@dataclass(frozen=True, eq=False)
class DetectionTrial:
    """The detector on rendered frames of the walking person in a camera with a monitor.

    Attributes
    ----------
    video : LedVideo
    threshold : Threshold
    invalid : (H, W) bool array
        The monitor's rectangle, marked invalid (as an operator would, Fig. 31).
    runs : dict
        Per run name (``"full"``, ``"full, masked"``, ``"subsampled, masked"``):
        ``detections``, ``rate`` (found / visible LEDs), ``false_per_frame``,
        ``ms_per_frame``, ``tested_fraction``, ``error_px`` (RMS centroid error).
    """

    video: object
    threshold: object
    invalid: np.ndarray
    runs: dict


def detection_trial(*, rng: np.random.Generator | int | None = None, camera: int = 3,
                    duration: float = 2.0, rate: float = 30.0, offset: float = 20.0,
                    minimum: float = 60.0, params=None) -> DetectionTrial:
    """Render the walking person for ``duration`` s in one (half-size) camera with a monitor
    and reflections, then detect with full and sub-sampled search, with and without the
    monitor masked."""
    import time

    from ..synth.widearea import render_led_video, small_camera
    from ..widearea import background_threshold, detect

    rng = as_rng(rng)
    cam = small_camera(ceiling_rig(rng=np.random.default_rng(7))[camera])
    scene = walking_person(duration=duration + 0.1,
                           on=np.stack([np.zeros(8), np.full(8, np.inf)], 1))
    video = render_led_video(scene, cam, np.arange(0, duration, 1 / rate), rng=rng)
    thr = background_threshold(video.background, offset, minimum)
    inv = np.zeros(video.frames.shape[1:], bool)
    x0, y0, x1, y1 = video.monitor.astype(int)
    inv[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = True
    runs = {}
    for name, mode, invalid in (("full", "full", None), ("full, masked", "full", inv),
                                ("subsampled, masked", "subsampled", inv)):
        t0 = time.perf_counter()
        det = detect(video.frames, thr, params=params, invalid=invalid, mode=mode, rng=rng,
                     predicted="previous" if mode == "subsampled" else None)
        sec = time.perf_counter() - t0
        found, false, err = _match_features(det, video.true_xy)
        vis = np.isfinite(video.true_xy).all(axis=2)
        runs[name] = {"detections": det, "rate": float(found.sum() / max(vis.sum(), 1)),
                      "false_per_frame": float(false.mean()),
                      "ms_per_frame": 1e3 * sec / len(video.frames),
                      "tested_fraction": float(det.tested.mean() / inv.size),
                      "error_px": float(np.sqrt(np.nanmean(err**2)))}
    return DetectionTrial(video=video, threshold=thr, invalid=inv, runs=runs)


def _line_deviation_2d(xy):
    c = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - c)
    return np.abs((xy - c) @ vt[1])


def stage_image_deviation(*, rng: np.random.Generator | int | None = None, cameras=(0, 9),
                          duration: float = 3.0, rate: float = 30.0,
                          reflections: float = 0.03) -> dict:
    """Figs. 36-39: the LED on the linear stage rendered in two cameras and detected; the
    distance of each observation from the line fitted to that camera's observations, for
    intensity centroids and for centroids rounded to whole pixels (the thesis's detector
    had no sub-pixel estimate). Specular reflections (``reflections``, as in
    :func:`lsmta.synth.widearea.render_led_video`) add false features; the monitor stays dark.

    The observation of a frame is chosen without the truth: its only feature, or the
    feature nearest the previous frame's pick. Outliers (false features picked) stay in.

    Returns
    -------
    dict
        Per camera index: ``times``, ``xy`` (T, 2) detected centroids (NaN where missed),
        ``deviation`` (T,), ``deviation_rounded`` (T,), ``mean``, ``mean_rounded`` (px),
        ``truth`` (T, 2), ``detected`` (fraction of frames with a pick), ``frames_none`` and
        ``frames_several`` (frames with no feature / more than one), ``picked_far`` (picks
        more than 3 px from the true LED, counted after the fact with the truth).
    """
    from ..synth.widearea import render_led_video, small_camera
    from ..widearea import background_threshold, detect

    rng = as_rng(rng)
    rig = ceiling_rig(rng=np.random.default_rng(7))
    stage = linear_stage(duration=duration, hold=0.3)
    times = np.arange(0.35, duration - 0.35, 1 / rate)      # while the stage moves
    out = {}
    for k in cameras:
        cam = small_camera(rig[k])
        video = render_led_video(stage, cam, times, rng=rng, monitor_flicker=0.0,
                                 reflections=reflections)
        thr = background_threshold(video.background, 20.0, 60.0)
        det = detect(video.frames, thr)
        # the observation is picked without the truth: the only feature of a frame, or,
        # when there are several, the one nearest the previous pick (the first such frame
        # before any pick: the largest feature); outliers stay in
        xy = np.full((len(times), 2), np.nan)
        n_feat = np.zeros(len(times), int)
        last = None
        for t in range(len(times)):
            c = det.centroids(t)
            n_feat[t] = len(c)
            if len(c) == 1:
                xy[t] = c[0]
            elif len(c) > 1:
                if last is None:
                    xy[t] = c[np.argmax(det.area[det.start[t]:det.start[t + 1]])]
                else:
                    xy[t] = c[np.argmin(np.linalg.norm(c - last, axis=1))]
            if len(c):
                last = xy[t]
        ok = np.isfinite(xy).all(axis=1)
        err = np.linalg.norm(xy - video.true_xy[:, 0], axis=1)
        dev = np.full(len(times), np.nan)
        dev_r = np.full(len(times), np.nan)
        dev[ok] = _line_deviation_2d(xy[ok])
        dev_r[ok] = _line_deviation_2d(np.rint(xy[ok]))
        out[k] = {"times": times, "xy": xy, "deviation": dev, "deviation_rounded": dev_r,
                  "mean": float(np.nanmean(dev)), "mean_rounded": float(np.nanmean(dev_r)),
                  "truth": video.true_xy[:, 0], "detected": float(ok.mean()),
                  "frames_none": int((n_feat == 0).sum()),
                  "frames_several": int((n_feat > 1).sum()),
                  "picked_far": int((err[ok] > 3.0).sum()) if ok.any() else 0}
    return out


def lighting_change_trial(*, rng: np.random.Generator | int | None = None, n_frames: int = 30,
                          change: int = 10, fraction: float = 0.01) -> dict:
    """The room lights go up at frame ``change``: the fraction of pixels over threshold
    jumps, :func:`lsmta.widearea.needs_new_threshold` fires, and thresholds recomputed from
    the next five frames, with small bright spots replaced by the local background (grey
    opening, 7 px), bring the false features back down while the LED stays detectable.

    Returns
    -------
    dict
        ``over`` (T,) fraction of pixels over the current threshold, ``recomputed`` (frame
        index or None), ``features`` (T,) features per frame, ``visible`` (T,) LEDs in view.
    """
    from ..synth.widearea import render_led_video, small_camera
    from ..widearea import background_threshold, detect, needs_new_threshold, relearn_threshold

    rng = as_rng(rng)
    cam = small_camera(ceiling_rig(rng=np.random.default_rng(7))[3])
    scene = still_led(duration=2.0, position=(300.0, 200.0, 1200.0))
    video = render_led_video(scene, cam, np.arange(n_frames) / 30.0, rng=rng,
                             lighting_change=change, monitor_flicker=0.0, reflections=0.0)
    inv = np.zeros(video.frames.shape[1:], bool)
    x0, y0, x1, y1 = video.monitor.astype(int)
    inv[y0:y1, x0:x1] = True
    thr = background_threshold(video.background, 20.0, 60.0)
    over, feats, recomputed = [], [], None
    for t in range(n_frames):
        frame = video.frames[t]
        over.append(float((frame > thr.threshold).mean()))
        if recomputed is None and needs_new_threshold(frame, thr, fraction=fraction):
            recomputed = t
            thr = relearn_threshold(video.frames[t:t + 5], 20.0, 60.0)
        feats.append(len(detect(frame, thr, invalid=inv).xy))
    return {"over": np.array(over), "recomputed": recomputed, "features": np.array(feats),
            "visible": np.isfinite(video.true_xy).all(axis=2).sum(axis=1)}


@dataclass(frozen=True, eq=False)
class RenderedTrackingTrial:
    """Rendered images through detection into the tracker (the end-to-end path).

    Attributes
    ----------
    cameras : list of Camera
        The (half-size) cameras used, as the tracker knows them.
    frames : dict
        Per search mode (``"full"``, ``"subsampled"``): the :class:`Frames` the detector
        produced for the tracker (arrival order).
    results : dict
        Per search mode: ``tracks`` (targets created), ``rms_mm`` (3-D RMS error of the
        longest-lived track against truth over ``times``), ``coverage`` (fraction of
        ``times`` with an estimate), ``detect_ms_per_frame``, ``tested_fraction``,
        ``false_per_frame`` (features farther than 3 px from the LED), ``estimate``
        (T, 3) mm.
    centroid_only : dict
        The same scene, cameras and clocks through :func:`observe` (generated centroids,
        rounded to pixels) and the tracker: ``tracks``, ``rms_mm``, ``coverage``.
    times : (T,) array
        Scoring times, s.
    truth : (T, 3) array
        The LED's true position, mm.
    """

    cameras: list
    frames: dict
    results: dict
    centroid_only: dict
    times: np.ndarray
    truth: np.ndarray


def rendered_tracking_trial(*, rng: np.random.Generator | int | None = None, n_cameras: int = 5,
                            duration: float = 1.5, hold: float = 0.3,
                            params: TrackerParams | None = None,
                            modes=("full", "subsampled")) -> RenderedTrackingTrial:
    """An LED on the linear stage rendered in ``n_cameras`` half-size cameras of the rig
    (each at its own rate, phase, clock offset and latency; each with a flickering monitor,
    masked as an operator would, and reflections), detected in every frame, and tracked.

    The cameras are the ``n_cameras`` of the rig that see the stage's path best. The
    sub-sampled search uses windows around the previous frame's features (the tracker runs
    after detection, in batch, so its predictions cannot steer the search here).
    """
    import time

    from ..synth.widearea import render_led_video, small_camera
    from ..widearea import background_threshold, detect

    rng = as_rng(rng)
    params = TrackerParams() if params is None else params
    stage = linear_stage(duration=duration, hold=hold)
    rig = [small_camera(c) for c in ceiling_rig(rng=np.random.default_rng(7))]
    path = stage.positions[::50, 0]
    seen = [cam.in_image(cam.project(path, behind="nan")).mean()
            - 1e-4 * np.linalg.norm(cam.C - path.mean(axis=0)) for cam in rig]
    chosen = np.sort(np.argsort(seen)[::-1][:n_cameras])
    cams = [rig[k] for k in chosen]
    clocks = make_clocks(len(cams), rng=rng)
    videos = []
    for k, cam in enumerate(cams):
        tt = clocks.phase[k] + np.arange(0, duration * clocks.rate[k]) / clocks.rate[k]
        tt = tt[tt < duration]
        videos.append(render_led_video(stage, cam, tt, rng=rng))
    times = np.arange(hold + 0.2, duration - 0.05, 0.01)
    truth = stage.positions_at(times)[:, 0]
    frames, results = {}, {}
    for mode in modes:
        cam_i, stamp, cents, arrival, tested, false, sec = [], [], [], [], [], [], 0.0
        for k, video in enumerate(videos):
            thr = background_threshold(video.background, 20.0, 60.0)
            inv = np.zeros(video.frames.shape[1:], bool)
            x0, y0, x1, y1 = video.monitor.astype(int)
            inv[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = True
            t0 = time.perf_counter()
            det = detect(video.frames, thr, invalid=inv, mode=mode, rng=rng,
                         predicted="previous" if mode == "subsampled" else None)
            sec += time.perf_counter() - t0
            _, fp, _ = _match_features(det, video.true_xy, radius=3.0)
            false.append(fp)
            tested.append(det.tested / inv.size)
            n = len(video.times)
            cam_i.append(np.full(n, k))
            stamp.append(video.times + clocks.offset[k])
            arrival.append(video.times + clocks.latency[k]
                           + clocks.jitter * np.abs(rng.normal(size=n)))
            cents += [det.centroids(t) for t in range(n)]
        arrival = np.concatenate(arrival)
        fr = Frames.from_lists(np.concatenate(cam_i), np.concatenate(stamp), cents,
                               arrival=arrival).reordered(np.argsort(arrival, kind="stable"))
        res = track(cams, fr, params=params)
        est = _single_track_estimate(res, times)
        frames[mode] = fr
        results[mode] = {
            "tracks": len(res.tracks), "estimate": est,
            "rms_mm": float(np.sqrt(np.nanmean(np.sum((est - truth) ** 2, axis=1)))),
            "coverage": float(np.isfinite(est).all(axis=1).mean()),
            "detect_ms_per_frame": 1e3 * sec / fr.n_frames,
            "tested_fraction": float(np.concatenate(tested).mean()),
            "false_per_frame": float(np.concatenate(false).mean())}
    obs = observe(stage, cams, clocks, rng=rng, quantize=True, reflections=0.0)
    res = track(cams, obs.frames, params=params)
    est = _single_track_estimate(res, times)
    centroid_only = {"tracks": len(res.tracks),
                     "rms_mm": float(np.sqrt(np.nanmean(np.sum((est - truth) ** 2, axis=1)))),
                     "coverage": float(np.isfinite(est).all(axis=1).mean())}
    return RenderedTrackingTrial(cameras=cams, frames=frames, results=results,
                                 centroid_only=centroid_only, times=times, truth=truth)


__all__ = ["MATCH_MM", "StarvationTrial", "StillStage", "TrackScore", "WalkingTrial",
           "circle_models", "fig35_starvation", "offset_sweep", "queue_policies",
           "score_tracks", "still_and_stage", "stonesoup_metrics", "walking_trial",
           "DetectionTrial", "detection_trial", "lighting_change_trial", "stage_image_deviation",
           "RenderedTrackingTrial", "rendered_tracking_trial"]
