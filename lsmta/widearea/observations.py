"""The input of the wide-area tracker: camera frames, each a set of 2-D LED centroids
time-stamped by its own camera's clock."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array


@dataclass(frozen=True)
class Frames:
    """Frames reported by the cameras, in the order they reached the estimator.

    Attributes
    ----------
    camera : (F,) int array
        Index of the camera that reported each frame.
    stamp : (F,) array
        Capture time of each frame in seconds, by that camera's clock (non-finite
        stamps are accepted here and counted and skipped by the tracker).
    start : (F + 1,) int array
        Frame ``f`` holds centroids ``xy[start[f]:start[f + 1]]``.
    xy : (M, 2) array
        Centroids in pixels; non-finite rows are counted and skipped by the tracker.
    arrival : (F,) array or None
        When each frame reached the estimator (s, estimator clock); used by the queue
        policies of :mod:`lsmta.widearea.scheduler`.
    """

    camera: np.ndarray
    stamp: np.ndarray
    start: np.ndarray
    xy: np.ndarray
    arrival: np.ndarray | None = None

    def __post_init__(self):
        cam = np.asarray(self.camera)
        if cam.ndim != 1 or not np.issubdtype(cam.dtype, np.integer):
            raise ValueError("camera: expected a 1-D integer array (camera index per frame)")
        F = len(cam)
        stamp = as_array(self.stamp, "stamp", shape=(F,), finite=False)
        start = np.asarray(self.start)
        if (start.shape != (F + 1,) or not np.issubdtype(start.dtype, np.integer)
                or (F >= 0 and start[0] != 0) or np.any(np.diff(start) < 0)):
            raise ValueError(f"start: expected {F + 1} non-decreasing integer offsets from 0")
        xy = as_array(self.xy, "xy", shape=(int(start[-1]), 2), finite=False)
        arrival = None if self.arrival is None else as_array(self.arrival, "arrival",
                                                             shape=(F,))
        for key, value in (("camera", cam.astype(np.int64)), ("stamp", stamp),
                           ("start", start.astype(np.int64)), ("xy", xy),
                           ("arrival", arrival)):
            if value is not None:
                value = value.copy()
                value.flags.writeable = False
            object.__setattr__(self, key, value)

    @property
    def n_frames(self) -> int:
        return len(self.camera)

    def centroids(self, f: int) -> np.ndarray:
        """The ``(n, 2)`` centroids of frame ``f`` (pixels)."""
        return self.xy[self.start[f]:self.start[f + 1]]

    def reordered(self, order) -> Frames:
        """The frames in ``order`` (indices into this object; repeats allowed)."""
        order = np.asarray(order, dtype=np.int64)
        counts = self.start[order + 1] - self.start[order]
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        idx = (np.concatenate([np.arange(self.start[f], self.start[f + 1]) for f in order])
               if len(order) else np.zeros(0, np.int64)).astype(np.int64)
        return Frames(camera=self.camera[order], stamp=self.stamp[order], start=start,
                      xy=self.xy[idx].reshape(-1, 2),
                      arrival=None if self.arrival is None else self.arrival[order])

    @classmethod
    def from_lists(cls, camera, stamp, centroids, *, arrival=None) -> Frames:
        """Frames from per-frame lists: ``centroids[f]`` is an ``(n_f, 2)`` array."""
        pts = [np.asarray(c, dtype=float).reshape(-1, 2) for c in centroids]
        start = np.concatenate([[0], np.cumsum([len(p) for p in pts])]).astype(np.int64)
        xy = np.concatenate(pts) if pts else np.zeros((0, 2))
        return cls(camera=np.asarray(camera, dtype=np.int64), stamp=np.asarray(stamp, float),
                   start=start, xy=xy, arrival=arrival)


def screen_frame(frames: Frames, f: int, n_cameras: int, last_stamp: np.ndarray,
                 received: np.ndarray, bad: dict) -> np.ndarray | None:
    """The finite centroids of frame ``f``, or None if the frame is refused.

    Refused frames come from an unknown camera, carry a non-finite stamp, or a stamp not
    after that camera's previous one; each refusal, NaN centroid and empty frame is
    counted in ``bad`` (keys ``unknown_camera``, ``nonfinite_stamp``, ``backwards_time``,
    ``nan_centroids``, ``empty_frames``). ``last_stamp`` and ``received`` (per camera) are
    the caller's running state and are updated for accepted frames.
    """
    c, t = int(frames.camera[f]), float(frames.stamp[f])
    if not 0 <= c < n_cameras:
        bad["unknown_camera"] += 1
        return None
    if not np.isfinite(t):
        bad["nonfinite_stamp"] += 1
        return None
    if t <= last_stamp[c]:
        bad["backwards_time"] += 1
        return None
    last_stamp[c] = t
    received[c] += 1
    xy = frames.centroids(f)
    finite = np.isfinite(xy).all(axis=1)
    bad["nan_centroids"] += int((~finite).sum())
    if not finite.any():
        bad["empty_frames"] += 1
    return xy[finite]
