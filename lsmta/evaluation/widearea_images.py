"""Wide-area trials on rendered LED images (Davis 2002, §3.3; notebook 09): the detector
with full and sub-sampled search, a lighting change, the linear stage's image deviation,
and the end-to-end path rendered frames -> detection -> tracker -> 3-D error.

* :func:`detection_trial` — the walking person in one camera with a monitor: detection
  rate, false features, pixels tested, centroid error;
* :func:`lighting_change_trial` — the lights go up; thresholds relearnt;
* :func:`stage_image_deviation` — Figs. 36-39, intensity centroids against whole pixels;
* :func:`rendered_tracking_trial` — an LED on the stage rendered in several cameras,
  detected, tracked and scored in 3-D;
* :func:`guided_detection_trial` — the walking person rendered in several cameras, frame by
  frame through the streaming tracker, whose predictions place the search windows; timed
  against the full search of the same frames.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_rng, as_scalar
from ..synth.widearea import (
    LedCentroidParams,
    LedVideoParams,
    linear_stage,
    make_clocks,
    observe_leds,
    render_led_video,
    small_camera,
    still_led,
    walking_person,
)
from ..widearea import (
    DetectionParams,
    EstimatorParams,
    Frames,
    WideAreaTracker,
    background_threshold,
    detect,
    needs_new_threshold,
    relearn_threshold,
    search_frame,
    search_setup,
    track,
)
from .track_scores import longest_track_estimate, score_led_tracks
from .widearea import trial_rig

#: pixels by which the operator's mask grows the monitor's true rectangle on every side
MONITOR_MASK_GROWTH_PX = 2


def match_features(det, true_xy, *, radius: float = 2.0):
    """Per frame of detections ``det``: which true LEDs ``true_xy`` (T, N, 2) were found
    (within ``radius`` px; Hungarian on distances) and how many features matched no LED.

    Returns
    -------
    found : (T, N) bool array
    false : (T,) int array
    error : (T, N) array
        px, NaN where not found.
    """
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


def detection_trial(*, rng: np.random.Generator | int | None = None, rig=None, camera: int = 3,
                    duration: float = 2.0, rate: float = 30.0, offset: float = 20.0,
                    minimum: float = 60.0, params=None) -> DetectionTrial:
    """Render the walking person for ``duration`` s in one (half-size) camera with a monitor
    and reflections, then detect with full and sub-sampled search, with and without the
    monitor masked."""
    rng = as_rng(rng)
    cam = small_camera(trial_rig(rig)[camera])
    scene = walking_person(duration=duration + 0.1,
                           on=np.stack([np.zeros(8), np.full(8, np.inf)], 1))
    video = render_led_video(scene, cam, np.arange(0, duration, 1 / rate), rng=rng)
    thr = background_threshold(video.background, offset, minimum)
    inv = np.zeros(video.frames.shape[1:], bool)
    x0, y0, x1, y1 = video.monitor.astype(int)
    g = MONITOR_MASK_GROWTH_PX
    inv[max(y0 - g, 0):y1 + g, max(x0 - g, 0):x1 + g] = True
    runs = {}
    detect(video.frames[:1], thr, params=params, invalid=inv, mode="subsampled",
           rng=0)                                   # compile the search before timing it
    for name, mode, invalid in (("full", "full", None), ("full, masked", "full", inv),
                                ("subsampled, masked", "subsampled", inv)):
        t0 = time.perf_counter()
        det = detect(video.frames, thr, params=params, invalid=invalid, mode=mode, rng=rng,
                     predicted="previous" if mode == "subsampled" else None)
        sec = time.perf_counter() - t0
        found, false, err = match_features(det, video.true_xy)
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


def stage_image_deviation(*, rng: np.random.Generator | int | None = None, rig=None,
                          cameras=(0, 9),
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
    rng = as_rng(rng)
    rig = trial_rig(rig)
    stage = linear_stage(duration=duration, hold=0.3)
    times = np.arange(0.35, duration - 0.35, 1 / rate)      # while the stage moves
    out = {}
    for k in cameras:
        cam = small_camera(rig[k])
        video = render_led_video(stage, cam, times, rng=rng,
                                 params=LedVideoParams(monitor_flicker=0.0,
                                                       reflections=reflections))
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


def lighting_change_trial(*, rng: np.random.Generator | int | None = None, rig=None,
                          n_frames: int = 30,
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
    rng = as_rng(rng)
    cam = small_camera(trial_rig(rig)[3])
    scene = still_led(duration=2.0, position=(300.0, 200.0, 1200.0))
    video = render_led_video(scene, cam, np.arange(n_frames) / 30.0, rng=rng,
                             lighting_change=change,
                             params=LedVideoParams(monitor_flicker=0.0, reflections=0.0))
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
        The same scene, cameras and clocks through
        :func:`~lsmta.synth.widearea.observe_leds` (generated centroids, rounded to pixels)
        and the tracker: ``tracks``, ``rms_mm``, ``coverage``.
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


def rendered_tracking_trial(*, rng: np.random.Generator | int | None = None, rig=None,
                            n_cameras: int = 5,
                            duration: float = 1.5, hold: float = 0.3,
                            params: EstimatorParams | None = None,
                            modes=("full", "subsampled")) -> RenderedTrackingTrial:
    """An LED on the linear stage rendered in ``n_cameras`` half-size cameras of the rig
    (each at its own rate, phase, clock offset and latency; each with a flickering monitor,
    masked as an operator would, and reflections), detected in every frame, and tracked.

    The cameras are the ``n_cameras`` of the rig that see the stage's path best. The
    sub-sampled search uses windows around the previous frame's features (the tracker runs
    after detection, in batch, so its predictions cannot steer the search here).
    """
    rng = as_rng(rng)
    params = EstimatorParams() if params is None else params
    stage = linear_stage(duration=duration, hold=hold)
    rig = [small_camera(c) for c in trial_rig(rig)]
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
            g = MONITOR_MASK_GROWTH_PX
            inv[max(y0 - g, 0):y1 + g, max(x0 - g, 0):x1 + g] = True
            t0 = time.perf_counter()
            det = detect(video.frames, thr, invalid=inv, mode=mode, rng=rng,
                         predicted="previous" if mode == "subsampled" else None)
            sec += time.perf_counter() - t0
            _, fp, _ = match_features(det, video.true_xy, radius=3.0)
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
        est = longest_track_estimate(res, times)
        frames[mode] = fr
        results[mode] = {
            "tracks": len(res.tracks), "estimate": est,
            "rms_mm": float(np.sqrt(np.nanmean(np.sum((est - truth) ** 2, axis=1)))),
            "coverage": float(np.isfinite(est).all(axis=1).mean()),
            "detect_ms_per_frame": 1e3 * sec / fr.n_frames,
            "tested_fraction": float(np.concatenate(tested).mean()),
            "false_per_frame": float(np.concatenate(false).mean())}
    obs = observe_leds(stage, cams, clocks, rng=rng,
                       params=LedCentroidParams(quantize=True, reflections=0.0))
    res = track(cams, obs.frames, params=params)
    est = longest_track_estimate(res, times)
    centroid_only = {"tracks": len(res.tracks),
                     "rms_mm": float(np.sqrt(np.nanmean(np.sum((est - truth) ** 2, axis=1)))),
                     "coverage": float(np.isfinite(est).all(axis=1).mean())}
    return RenderedTrackingTrial(cameras=cams, frames=frames, results=results,
                                 centroid_only=centroid_only, times=times, truth=truth)


# ----------------------------------------------------------------------------- guided search
@dataclass(frozen=True, eq=False)
class GuidedDetectionTrial:
    """Rendered frames of the walking person, searched fully (batch, per camera) and by the
    tracker-guided search (frame by frame, in arrival order, inside the streaming tracker's
    step: :meth:`lsmta.widearea.WideAreaTracker.feed_detect`).

    Attributes
    ----------
    cameras : list of Camera
        The cameras used (as the tracker knows them).
    n_frames : int
    seconds : dict
        CPU time of each search over all frames, s, the fastest of ``repeats`` replays of
        the same frames (windows and grid offsets as in the tracked run): ``"full"`` (NumPy
        comparison and OpenCV components, each camera's frames as one batch),
        ``"compiled full"`` (the compiled loop testing every pixel), ``"guided"`` (windows
        of the tracker's gate plus 3 px around its predictions, at least ``2 unobserved_px``
        wide where the camera has not observed the target, as in the tracked run),
        ``"guided, 40 x 40 windows"`` (the thesis's fixed windows around the same
        predictions and waiting features; along the waiting rays the same windows as
        ``"guided"``, of half-size ``band_px``); ``"tracker"``: the tracker's own work in
        the guided run (prediction, association, update, births; compilation on first use
        included; CPU time).
    tested_fraction : dict
        Mean fraction of the pixels tested per frame, per search.
    full_found : int
        LEDs the full search found (a feature within 3 px of the LED's true projection).
    guided_found : int
        Of those, the ones the guided search found at the same place (within 0.01 px).
    missed_new : int
        Of the misses, those before the guided search's first find of that LED in that
        camera (in any earlier frame of that camera). Other cameras may track the LED by
        then: their windows reach this camera only through the tracker's prediction.
    missed_unfound : int
        Of ``missed_new``, those before any camera's guided search had found that LED
        (earlier in arrival order): an LED new to every camera, which nothing predicts yet
        and only the grid can find.
    scores : dict
        ``"full"`` (the full search's features tracked by the batch tracker) and
        ``"guided"`` (the streaming run): LedTrackScore against the LEDs.
    grid : str
        The guided search's grid for new LEDs (:attr:`lsmta.widearea.DetectionParams.grid`).
    unobserved_px : float or None
        The trial's ``unobserved_px``: least half-size, px, of the windows around targets a
        camera has not observed yet (None: no least).
    band_px : float or None
        The trial's ``band_px``: half-size, px, of the windows along the other cameras'
        waiting rays (None: the tracker's ``gate_px``).
    """

    cameras: list
    n_frames: int
    seconds: dict
    tested_fraction: dict
    full_found: int
    guided_found: int
    missed_new: int
    missed_unfound: int
    scores: dict
    grid: str
    unobserved_px: float | None = 20.0
    band_px: float | None = None

    @property
    def speedup(self) -> float:
        """Full search time / guided search time."""
        return self.seconds["full"] / self.seconds["guided"]


def _walk_videos(rng, rig, n_cameras, duration, scale):
    """The walking person rendered in the cameras that see its path best, each at its own
    rate, phase, clock offset and latency; per video its invalid mask (the monitor, grown
    by ``MONITOR_MASK_GROWTH_PX``); the frames in arrival order as (arrival, camera, frame)."""
    k = np.arange(8)
    scene = walking_person(duration=duration + 0.1,
                           on=np.stack([0.1 + 0.05 * k, np.full(8, np.inf)], axis=1))
    rig = [small_camera(c, scale=scale) for c in trial_rig(rig)]
    path = scene.positions[::50].reshape(-1, 3)
    seen = [cam.in_image(cam.project(path, behind="nan")).mean() for cam in rig]
    cams = [rig[i] for i in np.sort(np.argsort(seen)[::-1][:n_cameras])]
    clocks = make_clocks(len(cams), rng=rng)
    videos, masks, order = [], [], []
    for c, cam in enumerate(cams):
        tt = clocks.phase[c] + np.arange(0, duration * clocks.rate[c]) / clocks.rate[c]
        tt = tt[tt < duration]
        v = render_led_video(scene, cam, tt, rng=rng)
        inv = np.zeros(v.frames.shape[1:], bool)
        x0, y0, x1, y1 = v.monitor.astype(int)
        g = MONITOR_MASK_GROWTH_PX
        inv[max(y0 - g, 0):y1 + g, max(x0 - g, 0):x1 + g] = True
        videos.append(v)
        masks.append(inv)
        arrival = tt + clocks.latency[c] + clocks.jitter * np.abs(rng.normal(size=len(tt)))
        order += [(a, c, i) for i, a in enumerate(arrival)]
    order.sort()
    return scene, cams, clocks, videos, masks, order


def guided_detection_trial(*, rng: np.random.Generator | int | None = None, rig=None,
                           n_cameras: int = 8, duration: float = 1.6, scale: float = 0.5,
                           repeats: int = 3, params: EstimatorParams | None = None,
                           detection: DetectionParams | None = None,
                           unobserved_px: float | None = 20.0,
                           band_px: float | None = None) -> GuidedDetectionTrial:
    """The walking person (eight LEDs, on from 0.1-0.45 s) rendered in the ``n_cameras``
    cameras of the rig (``scale``: 0.5 for 320 x 240) that see its path best (truth as
    input: an operator would pick them), with a flickering monitor (masked) and reflections.
    Every frame is searched fully, and by the guided search inside the streaming tracker's
    step, frame by frame in arrival order (windows of the gate plus 3 px around the tracker's
    predictions for that camera and stamp, whose gate follows each prediction's uncertainty,
    at least 40 x 40 (``unobserved_px``) around a target the camera has not observed yet
    (:meth:`lsmta.widearea.ImagePrediction.windows`: its prediction there is unchecked),
    40 x 40 windows around the camera's features still waiting in the birth pool, a band
    along the images of the other cameras' waiting rays (``ImagePrediction.partners``;
    :func:`guided_search_windows`), and for new LEDs the grid of ``detection``: by default
    every pixel of one row in 5, jittered, ``DetectionParams(grid="rows")``; ``"points"``:
    the thesis's jittered 5 x 5 grid), then timed on the same frames, windows and offsets.

    ``unobserved_px``: the least half-size, px, of the window around a target the camera
    has not observed yet (20: the thesis's 40 x 40 as a minimum; None: the gate plus 3 px
    for every target). ``band_px``: the half-size, px, of the windows along the rays (None:
    the tracker's ``gate_px``). ``unobserved_px=None, band_px=10.5``: the lean window rule
    (``gate_px / 2 + 3``) designed on seeds 2002, 7 and 11; seeds 101, 202, 303, 404 and
    505 were reported before it was designed and 303 was profiled while designing it;
    held out: 606, 707, 808, 909 and 1111 (``experiments/widearea_detection_benchmark.py``)."""
    unobserved_px = _half_px(unobserved_px, "unobserved_px")
    band_px = _half_px(band_px, "band_px")
    rng = as_rng(rng)
    params = EstimatorParams() if params is None else params
    det = DetectionParams(grid="rows") if detection is None else detection
    scene, cams, clocks, videos, masks, order = _walk_videos(rng, rig, n_cameras, duration,
                                                              scale)
    thr = [background_threshold(v.background, 20.0, 60.0) for v in videos]
    full = [detect(v.frames, t_, invalid=m, params=det) for v, t_, m in zip(videos, thr, masks)]
    setups = [search_setup(t_, invalid=m, params=det) for t_, m in zip(thr, masks)]
    tracker = WideAreaTracker(cams, params=params)
    runs = []          # (camera, frame, centres, half-sizes: gate, 40 x 40; jitter)
    guided = [[np.zeros((0, 2))] * len(v.frames) for v in videos]
    tested = []

    def guided_search(c, i):
        def search(pred):
            jit = tuple(int(j) for j in rng.integers(0, det.k, 2))
            xy, half, fixed = guided_search_windows(
                pred, window=det.window, gate_px=params.gate_px, band_px=band_px,
                unobserved_px=unobserved_px)
            f = search_frame(videos[c].frames[i], setups[c], windows=xy, half_sizes=half,
                             jitter=jit)
            runs.append((c, i, xy, half, fixed, jit))
            guided[c][i] = f.xy
            tested.append(f.tested)
            return f.xy
        return search

    for v, st in zip(videos, setups):                         # compile before timing
        search_frame(v.frames[0], st, windows=np.zeros((1, 2)), jitter=(0, 0))
    t0 = time.process_time()
    for _, c, i in order:
        tracker.feed_detect(c, videos[c].times[i] + clocks.offset[c], guided_search(c, i))
    seconds = {"tracker + guided": time.process_time() - t0}
    seconds.update(_replay_times(videos, thr, masks, setups, runs, det, repeats))
    seconds["tracker"] = seconds.pop("tracker + guided") - seconds["guided"]
    full_found, guided_found, missed_new, missed_unfound = _same_detections(
        videos, full, guided, order)
    stamps = [v.times + clocks.offset[c] for c, v in enumerate(videos)]
    fr = Frames.from_lists([c for _, c, _ in order], [stamps[c][i] for _, c, i in order],
                           [full[c].centroids(i) for _, c, i in order])
    times = np.arange(0.0, duration, 1 / 60)
    scores = {"full": score_led_tracks(scene, track(cams, fr, params=params), times),
              "guided": score_led_tracks(scene, tracker.result(), times)}
    size = videos[0].frames[0].size
    return GuidedDetectionTrial(
        cameras=cams, n_frames=len(order), seconds=seconds,
        tested_fraction={"full": 1.0, "guided": float(np.mean(tested)) / size},
        full_found=full_found, guided_found=guided_found, missed_new=missed_new,
        missed_unfound=missed_unfound, scores=scores, grid=det.grid,
        unobserved_px=unobserved_px, band_px=band_px)


def guided_search_windows(pred, *, window: float, gate_px: float,
                          band_px: float | None = None, unobserved_px: float | None = 20.0):
    """The guided search's windows in one frame (:func:`guided_detection_trial`).

    Parameters
    ----------
    pred : lsmta.widearea.ImagePrediction
        The tracker's prediction into the frame's camera (M targets, P waiting features,
        Q points along the other cameras' waiting rays).
    window : float
        The thesis's window side, px (:attr:`lsmta.widearea.DetectionParams.window`, 40).
    gate_px : float
        The tracker's largest gate, px (:attr:`lsmta.widearea.EstimatorParams.gate_px`).
    band_px : float or None
        Half-size, px (> 0), of the windows around the Q points along the waiting rays
        (None: ``gate_px``).
    unobserved_px : float or None
        Least half-size, px, of the window around a target the camera has not observed
        (:meth:`lsmta.widearea.ImagePrediction.windows`; None: no least).

    Returns
    -------
    xy : (M + P + Q, 2) array
        The windows' centres, px: targets, waiting features, points along the rays.
    half : (M + P + Q,) array
        Half-sizes, px: the gate plus 3 px around targets (at least ``unobserved_px``
        where unobserved), ``window / 2`` around waiting features, ``band_px`` along rays.
    fixed : (M + P + Q,) array
        The same with ``window / 2`` around the targets too (the thesis's fixed windows).
    """
    band_px = _half_px(band_px, "band_px")
    band = np.full(len(pred.partners), gate_px if band_px is None else band_px)
    xy = np.concatenate([pred.xy, pred.waiting, pred.partners])
    fixed = np.concatenate([np.full(len(pred.xy) + len(pred.waiting), window / 2), band])
    _, near = pred.windows(margin_px=3.0, unobserved_px=unobserved_px)
    half = np.concatenate([near, np.full(len(pred.waiting), window / 2), band])
    return xy, half, fixed


def _half_px(value, name: str):
    """None, or a positive finite float (bools, NumPy's too, refused), naming ``name``."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected a positive number of pixels or None, got a bool")
    return as_scalar(value, name, positive=True)


@contextmanager
def one_opencv_thread():
    """OpenCV on one thread inside the block (restored after): CPU time then counts the work
    only. On two threads the full search's ``cv2.connectedComponents`` took 1.8x the CPU time
    on the idle machine (0.14 against 0.077 ms per 640 x 480 frame) for about the same wall
    time: its idle worker waits counted as CPU time."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def _replay_times(videos, thr, masks, setups, runs, det, repeats: int) -> dict:
    """Fastest of ``repeats`` timings (CPU time of this process, ``time.process_time``, with
    OpenCV on one thread: on a shared machine the wall clock also counts the waits) of each
    search over all frames (interleaved). Every search goes through one camera's frames after
    the other, as the full search's batches do (and as Davis's cameras, each digitised by its
    own machine, did)."""
    with one_opencv_thread():
        return _replay_times_timed(videos, thr, masks, setups, runs, det, repeats)


def _replay_times_timed(videos, thr, masks, setups, runs, det, repeats: int) -> dict:
    out = {"full": [], "compiled full": [], "guided": [], "guided, 40 x 40 windows": []}
    runs = sorted(runs, key=lambda r: (r[0], r[1]))
    for _ in range(int(repeats)):
        t0 = time.process_time()
        for v, t_, m in zip(videos, thr, masks):
            detect(v.frames, t_, invalid=m, params=det)
        t1 = time.process_time()
        for v, st in zip(videos, setups):
            for f in v.frames:
                search_frame(f, st, full=True)
        t2 = time.process_time()
        for c, i, xy, half, _, jit in runs:
            search_frame(videos[c].frames[i], setups[c], windows=xy, half_sizes=half,
                         jitter=jit)
        t3 = time.process_time()
        for c, i, xy, _, fixed, jit in runs:
            search_frame(videos[c].frames[i], setups[c], windows=xy, half_sizes=fixed,
                         jitter=jit)
        t4 = time.process_time()
        for key, dt in zip(out, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            out[key].append(dt)
    return {k: float(min(v)) for k, v in out.items()}


def _same_detections(videos, full, guided, order):
    """LEDs the full search found (within 3 px of the truth), how many of them the guided
    search found at the same place (0.01 px), and how many of the misses came before the
    guided search's first find of that LED in that camera, and before any camera's (the
    frames taken in arrival ``order``)."""
    n_full = n_same = n_new = n_unfound = 0
    found = [match_features(full[c], v.true_xy, radius=3.0)[0] for c, v in enumerate(videos)]
    seen = [np.zeros(v.true_xy.shape[1], bool) for v in videos]   # found in that camera
    anywhere = np.zeros(videos[0].true_xy.shape[1], bool)          # found in any camera
    for _, c, i in order:
        fx, g, v = full[c].centroids(i), guided[c][i], videos[c]
        for n in np.flatnonzero(found[c][i]):
            j = np.argmin(np.linalg.norm(fx - v.true_xy[i, n], axis=1))
            same = len(g) > 0 and np.linalg.norm(g - fx[j], axis=1).min() < 0.01
            n_full += 1
            n_same += int(same)
            n_new += int(not same and not seen[c][n])
            n_unfound += int(not same and not anywhere[n])
            seen[c][n] |= same
            anywhere[n] |= same
    return n_full, n_same, n_new, n_unfound
