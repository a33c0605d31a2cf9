"""Wide-area trials on rendered LED images (Davis 2002, §3.3; notebook 09): the detector
with full and sub-sampled search, a lighting change, the linear stage's image deviation,
and the end-to-end path rendered frames -> detection -> tracker -> 3-D error.

* :func:`detection_trial` — the walking person in one camera with a monitor: detection
  rate, false features, pixels tested, centroid error;
* :func:`lighting_change_trial` — the lights go up; thresholds relearnt;
* :func:`stage_image_deviation` — Figs. 36-39, intensity centroids against whole pixels;
* :func:`rendered_tracking_trial` — an LED on the stage rendered in several cameras,
  detected, tracked and scored in 3-D.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_rng
from ..synth.widearea import (
    linear_stage,
    make_clocks,
    observe,
    render_led_video,
    small_camera,
    still_led,
    walking_person,
)
from ..widearea import (
    EstimatorParams,
    Frames,
    background_threshold,
    detect,
    needs_new_threshold,
    relearn_threshold,
    track,
)
from .track_scores import longest_track_estimate
from .widearea import trial_rig


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
    inv[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = True
    runs = {}
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
            inv[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = True
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
    obs = observe(stage, cams, clocks, rng=rng, quantize=True, reflections=0.0)
    res = track(cams, obs.frames, params=params)
    est = longest_track_estimate(res, times)
    centroid_only = {"tracks": len(res.tracks),
                     "rms_mm": float(np.sqrt(np.nanmean(np.sum((est - truth) ** 2, axis=1)))),
                     "coverage": float(np.isfinite(est).all(axis=1).mean())}
    return RenderedTrackingTrial(cameras=cams, frames=frames, results=results,
                                 centroid_only=centroid_only, times=times, truth=truth)
