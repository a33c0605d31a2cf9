"""Tracking in real video without truth: the four synchronised views of Pose2Sim's demo.

The copy in ``data/pose2sim_demo/`` holds the four videos (1080-1088 x 1920 px, 60 fps,
100 frames, one person walking on a treadmill with skin markers) and their Qualisys
calibration (loaded by :func:`lsmta.data.load_demo`). Without truth, tracking is judged by
what needs none:

* the *forward-backward error*: a point tracked from frame 0 to the last frame and back
  from its end position should return to its start (for a frame-to-frame tracker this
  measures how reversible each step is, not its drift: going back retraces the same frame
  pairs; for anchored templates the way back uses the last frame's template, so the error
  also contains the change of appearance over the sequence);
* the *multi-view reprojection residual*: a marker tracked in several views and
  intersected with the calibrated cameras should reproject onto its tracked positions;
* the *epipolar consistency* of the calibration itself, measured with the markers found in
  two views (:func:`epipolar_partners`), which says how far that residual can go down;
  :func:`score_hypotheses` asks it of every reading of the file (image flips, camera
  orders) against chance, :func:`blob_centre` / :func:`pair_ray_distances` of one large
  object all views see (coarse), and :func:`persistent_pairs` of tracks through time (which
  also finds the views' time offset).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_array, as_rng
from ..tracking.correspondence import ray_distances
from ..tracking.points import Tracks
from ..triangulation import triangulate


def skin_points(colour, *, avoid=None, max_points: int = 150, min_distance: float = 12.0,
                quality: float = 0.02, min_skin: float = 60.0,
                max_hue: float = 25.0) -> np.ndarray:
    """Natural skin texture worth tracking: Shi-Tomasi corners
    (``cv2.goodFeaturesToTrack``) of a colour frame inside its skin (a 17 px mean of the
    saturation above ``min_skin`` and of the hue below ``max_hue``), at least
    ``min_distance`` px from each other and from the points ``avoid`` (e.g. the markers).
    Returns ``(M, 2)`` positions, px."""
    hsv = cv2.cvtColor(colour, cv2.COLOR_BGR2HSV).astype(np.float64)
    skin = (cv2.blur(hsv[..., 1], (17, 17)) > min_skin) & (cv2.blur(hsv[..., 0], (17, 17))
                                                          < max_hue)
    mask = cv2.erode(skin.astype(np.uint8), np.ones((9, 9), np.uint8))
    if avoid is not None:
        for x, y in np.asarray(avoid, float).reshape(-1, 2):
            cv2.circle(mask, (int(round(x)), int(round(y))), int(min_distance), 0, -1)
    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    pts = cv2.goodFeaturesToTrack(grey, maxCorners=max_points, qualityLevel=quality,
                                  minDistance=min_distance, mask=mask)
    return np.zeros((0, 2)) if pts is None else pts.reshape(-1, 2).astype(float)


def forward_backward(track, grey, xy0) -> tuple[Tracks, np.ndarray]:
    """Track forward with ``track(frames, xy0)`` and back from the end positions of the
    tracks alive in the last frame; returns the forward tracks and the error ``(N,)`` at
    frame 0, px (NaN where the track did not reach the end or did not come back).

    ``track`` takes a ``(T, H, W)`` sequence and ``(N, 2)`` start positions and returns
    single-view :class:`~lsmta.tracking.Tracks`."""
    fwd = track(grey, xy0)
    end = fwd.xy[-1, 0]
    alive = np.isfinite(end).all(axis=1)
    err = np.full(len(xy0), np.nan)
    if alive.any():
        back = track(grey[::-1], end[alive])
        err[alive] = np.linalg.norm(back.xy[-1, 0] - xy0[alive], axis=1)
    return fwd, err


def epipolar_partners(cameras, detections, a: int, b: int, *, max_ray_distance: float,
                      shift: float = 0.0, rng: np.random.Generator | int | None = None) -> int:
    """How many detections of views ``a`` and ``b`` pair up, one to one, with rays passing
    within ``max_ray_distance`` mm of each other (greedy, closest first). With ``shift``
    every detection is first moved by a uniform random offset of up to ``shift`` px: the
    control, the count that chance alone gives."""
    da = np.asarray(detections[a], float)
    db = np.asarray(detections[b], float)
    if shift:
        rng = as_rng(rng)
        da = da + rng.uniform(-shift, shift, da.shape)
        db = db + rng.uniform(-shift, shift, db.shape)
    if not len(da) or not len(db):
        return 0
    D = ray_distances(cameras[a].rays(da), cameras[b].rays(db))
    used_a, used_b, n = set(), set(), 0
    for i, j in zip(*np.unravel_index(np.argsort(D, axis=None), D.shape)):
        if D[i, j] > max_ray_distance:
            break
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            n += 1
    return n


def reprojection_residuals(cameras, xy) -> np.ndarray:
    """Largest reprojection error ``(T, P)`` of P points tracked in K views over T frames,
    ``xy`` ``(T, K, P, 2)``, px: each frame's positions seen in at least two views are
    intersected (NaN where fewer)."""
    T, K, P, _ = xy.shape
    out = np.full((T, P), np.nan)
    for t in range(T):
        seen = np.isfinite(xy[t]).all(axis=2).sum(axis=0) >= 2
        if seen.any():
            res = triangulate(cameras, xy[t][:, seen])
            with np.errstate(invalid="ignore"):
                out[t, seen] = np.where(res.valid, np.nanmax(res.reprojection_error, axis=0),
                                        np.nan)
    return out


IMAGE_TRANSFORMS = ("identity", "flip_u", "flip_v", "rotate_180")


def transform_xy(xy, size, kind: str) -> np.ndarray:
    """Image positions ``xy`` ``(N, 2)`` of a ``size = (W, H)`` image as they would be in
    the image flipped (``"flip_u"``: ``u -> W - 1 - u``, ``"flip_v"``: ``v -> H - 1 - v``),
    turned by 180 degrees (both) or left as they are (``"identity"``)."""
    if kind not in IMAGE_TRANSFORMS:
        raise ValueError(f"kind: expected one of {IMAGE_TRANSFORMS}, got {kind!r}")
    out = as_array(xy, "xy", shape=(None, 2), allow_nan=True).copy()
    W, H = size
    if kind in ("flip_u", "rotate_180"):
        out[:, 0] = W - 1 - out[:, 0]
    if kind in ("flip_v", "rotate_180"):
        out[:, 1] = H - 1 - out[:, 1]
    return out


@dataclass(frozen=True)
class HypothesisScores:
    """How well detections of K views fit the calibration under alternative readings.

    Attributes
    ----------
    names : list of str
        One per hypothesis: ``"<transform> <order>"`` (the calibration camera given to each
        video, e.g. ``"identity 0123"``).
    pairs : list of (a, b)
        The video pairs, in the column order of ``counts``.
    counts : (H, n_pairs) int array
        Detections paired within ``max_ray_distance`` (:func:`epipolar_partners`).
    chance_mean, chance_std : (n_pairs,) arrays
        The same count after random shifts of the detections (identity reading).
    z : (H, n_pairs) array
        ``(counts - chance_mean) / chance_std``.
    """

    names: list
    pairs: list
    counts: np.ndarray
    chance_mean: np.ndarray
    chance_std: np.ndarray
    z: np.ndarray


def score_hypotheses(cameras, detections, sizes, *, max_ray_distance: float = 3.0,
                     shift: float = 30.0, trials: int = 10, permutations: bool = True,
                     rng: np.random.Generator | int | None = None) -> HypothesisScores:
    """Score readings of a calibration against detections in its K views, with no truth.

    Each hypothesis applies one of :data:`IMAGE_TRANSFORMS` to every view's detections and
    gives video ``k`` the calibration camera ``order[k]`` (every permutation if
    ``permutations``, else only the file's order). Its score per video pair is the number
    of detections paired by rays within ``max_ray_distance`` mm; a right reading pairs far
    more than ``trials`` random shifts of up to ``shift`` px do.

    Parameters
    ----------
    cameras : sequence of K Camera
    detections : sequence of K (M_k, 2) arrays, px
    sizes : sequence of K (W, H)
        The videos' image sizes, px.
    """
    K = len(cameras)
    if len(detections) != K or len(sizes) != K:
        raise ValueError(f"detections, sizes: expected {K} of each (one per camera), got "
                         f"{len(detections)} and {len(sizes)}")
    rng = as_rng(rng)
    pairs = list(itertools.combinations(range(K), 2))
    orders = list(itertools.permutations(range(K))) if permutations else [tuple(range(K))]
    names, counts = [], []
    for kind in IMAGE_TRANSFORMS:
        det = [transform_xy(d, s, kind) for d, s in zip(detections, sizes)]
        for order in orders:
            cams = [cameras[o] for o in order]
            names.append(f"{kind} {''.join(map(str, order))}")
            counts.append([epipolar_partners(cams, det, a, b,
                                             max_ray_distance=max_ray_distance)
                           for a, b in pairs])
    chance = np.array([[epipolar_partners(cameras, detections, a, b,
                                          max_ray_distance=max_ray_distance, shift=shift,
                                          rng=rng) for a, b in pairs]
                       for _ in range(trials)], float)
    counts = np.array(counts)
    mean, std = chance.mean(axis=0), np.maximum(chance.std(axis=0), 1.0)
    return HypothesisScores(names=names, pairs=pairs, counts=counts, chance_mean=mean,
                            chance_std=std, z=(counts - mean) / std)


def blob_centre(colour, *, hue=(80, 100), min_saturation: int = 120,
                min_value: int = 100) -> np.ndarray:
    """Centroid ``(2,)`` px of the largest region of a colour frame (BGR) whose hue lies in
    ``hue`` (OpenCV's 0-180 scale) and is saturated and bright enough: e.g. the demo's cyan
    cap, one object seen by every view (NaN if none)."""
    hsv = cv2.cvtColor(np.asarray(colour, np.uint8), cv2.COLOR_BGR2HSV)
    mask = ((hsv[..., 0] > hue[0]) & (hsv[..., 0] < hue[1]) & (hsv[..., 1] > min_saturation)
            & (hsv[..., 2] > min_value)).astype(np.uint8)
    n, _, stats, centres = cv2.connectedComponentsWithStats(mask)
    if n < 2:
        return np.full(2, np.nan)
    return centres[1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))].astype(float)


def pair_ray_distances(cameras, xy) -> np.ndarray:
    """How close the rays through one point seen in each of K views pass, per view pair
    (in ``itertools.combinations`` order): ``xy`` ``(K, 2)`` px -> ``(K (K - 1) / 2,)`` mm."""
    xy = np.asarray(xy, float).reshape(len(cameras), 2)
    return np.array([ray_distances(cameras[a].rays(xy[[a]]), cameras[b].rays(xy[[b]]))[0, 0]
                     for a, b in itertools.combinations(range(len(cameras)), 2)])


def persistent_pairs(camera_a, camera_b, xy_a, xy_b, *, lag: int = 0,
                     max_ray_distance: float = 8.0, min_frames: int = 8,
                     min_motion: float = 15.0, step: int = 2) -> int:
    """How many pairs of moving tracks of two views stay on meeting rays through time.

    Frame ``t`` of view a is paired with frame ``t + lag`` of view b. A pair of tracks
    counts when, over at least ``min_frames`` of the frames ``0, step, 2 step, ...`` where
    both are alive, the median distance of their rays is below ``max_ray_distance`` (mm).
    Only tracks alive in 20 frames or more that move by more than ``min_motion`` px take
    part (a static background point pairs at every lag). Markers that truly correspond
    stay paired at the right lag and drift apart at others, so the count against ``lag``
    peaks at the views' time offset; the counts far from the peak are chance.

    Parameters
    ----------
    camera_a, camera_b : Camera
    xy_a, xy_b : (T, N_a, 2), (T, N_b, 2) arrays
        Tracks in each view, px in the cameras' pixels, NaN where not tracked.
    """
    def moving(xy):
        alive = np.isfinite(xy).all(axis=2)
        keep = alive.sum(axis=0) >= 20
        span = np.zeros(xy.shape[1])
        span[keep] = (np.nanmax(xy[:, keep], axis=0)
                      - np.nanmin(xy[:, keep], axis=0)).max(axis=1)
        return xy[:, span > min_motion]

    xa = moving(as_array(xy_a, "xy_a", shape=(None, None, 2), allow_nan=True))
    xb = moving(as_array(xy_b, "xy_b", shape=(None, None, 2), allow_nan=True))
    T = min(len(xa), len(xb))
    frames = np.arange(max(0, -lag), min(T, T - lag), step)
    if not xa.shape[1] or not xb.shape[1] or not len(frames):
        return 0
    D = np.full((len(frames), xa.shape[1], xb.shape[1]), np.nan)
    for n, t in enumerate(frames):
        pa, pb = xa[t], xb[t + lag]
        fa, fb = np.isfinite(pa).all(axis=1), np.isfinite(pb).all(axis=1)
        if fa.any() and fb.any():
            D[n][np.ix_(fa, fb)] = ray_distances(camera_a.rays(pa[fa]), camera_b.rays(pb[fb]))
    enough = np.isfinite(D).sum(axis=0) >= min_frames
    med = np.full(enough.shape, np.inf)
    med[enough] = np.nanmedian(D[:, enough], axis=0)
    return int((med < max_ray_distance).sum())
