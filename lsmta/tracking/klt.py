"""The peer: OpenCV's pyramidal Lucas-Kanade (KLT) tracker with a forward-backward check.

Each camera is tracked on its own (``cv2.calcOpticalFlowPyrLK`` from frame ``t`` to ``t + 1``
and back); a point whose backward track misses its start by more than ``fb_threshold``
pixels, or that OpenCV loses, or that is lost in any camera, stops. The result has the same
form as :func:`~lsmta.tracking.points.track_points`'s, so trajectories and scores are made
the same way.
"""

from __future__ import annotations

import cv2
import numpy as np

from .._validate import as_array, as_int, as_scalar
from .points import Tracks, TrackStatus, as_sequences


def track_klt(images, initial_xy, *, window: int = 21, levels: int = 3,
              fb_threshold: float = 0.5) -> Tracks:
    """Track points through K image sequences with pyramidal KLT (per camera).

    Parameters
    ----------
    images : (K, T, H, W) array or sequence of K image sequences
    initial_xy : (K, N, 2) array
        Positions at frame 0 (pixels).
    window : int
        LK window size in pixels (odd, >= 3).
    levels : int
        Pyramid levels above the full image (>= 0).
    fb_threshold : float
        Largest forward-backward error in pixels (> 0).

    Returns
    -------
    Tracks
    """
    as_int(window, "window", minimum=3, odd=True, unit="pixels")
    as_int(levels, "levels", minimum=0, unit="pyramid levels")
    fb_threshold = as_scalar(fb_threshold, "fb_threshold", positive=True)
    seq = as_sequences(images)
    K, T = seq.shape[:2]
    xy0 = as_array(initial_xy, "initial_xy", shape=(K, None, 2), allow_nan=True)
    N = xy0.shape[1]
    started = np.isfinite(xy0).all(axis=(0, 2))
    if not started.any():
        raise ValueError("initial_xy: the first frame has no point matched in every camera; "
                         "nothing to track")
    u8 = seq if seq.dtype == np.uint8 else np.clip(np.rint(seq), 0, 255).astype(np.uint8)
    xy = np.full((T, K, N, 2), np.nan)
    xy[0][:, started] = xy0[:, started]
    alive = started.copy()
    end = np.where(started, 0, -1)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    lk = dict(winSize=(int(window), int(window)), maxLevel=int(levels), criteria=crit)
    for t in range(T - 1):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        ok = np.ones(idx.size, bool)
        new = np.full((K, idx.size, 2), np.nan)
        for k in range(K):
            p0 = xy[t, k, idx].astype(np.float32).reshape(-1, 1, 2)
            p1, s1, _ = cv2.calcOpticalFlowPyrLK(u8[k, t], u8[k, t + 1], p0, None, **lk)
            pb, sb, _ = cv2.calcOpticalFlowPyrLK(u8[k, t + 1], u8[k, t], p1, None, **lk)
            fb = np.linalg.norm(pb.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
            H, W = u8.shape[2:]
            q = p1.reshape(-1, 2).astype(float)
            inside = (q[:, 0] >= 0) & (q[:, 0] <= W - 1) & (q[:, 1] >= 0) & (q[:, 1] <= H - 1)
            ok &= (s1.ravel() == 1) & (sb.ravel() == 1) & (fb <= fb_threshold) & inside
            new[k] = q
        acc = idx[ok]
        xy[t + 1][:, acc] = new[:, ok]
        end[acc] = t + 1
        alive[idx[~ok]] = False
    status = np.where(~started, TrackStatus.NOT_STARTED,
                      np.where(end == T - 1, TrackStatus.ALIVE, TrackStatus.LOST))
    # KLT's template is the previous frame's window: "anchored" in every tracked frame
    anchor = np.where(np.isfinite(xy).all(axis=(1, 3)), np.arange(T)[:, None], -1)
    return Tracks(xy=xy, start=np.zeros(N, np.int64), end=end.astype(np.int64),
                  status=status.astype(np.int64), retried=np.zeros((T, N), bool),
                  added=np.zeros(N, bool), origin=np.full(N, -1, np.int64), anchor=anchor,
                  recovered=np.zeros((T, N), bool))
