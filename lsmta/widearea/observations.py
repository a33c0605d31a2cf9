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


@dataclass(frozen=True)
class Screened:
    """What :func:`screen_frame` found in one frame.

    Attributes
    ----------
    xy : (n, 2) array or None
        The frame's finite centroids, px; None when the frame is refused.
    refused : str or None
        Why the frame was refused: ``"unknown_camera"``, ``"nonfinite_stamp"`` or
        ``"backwards_time"`` (a stamp not after that camera's previous one).
    nan_centroids : int
        Centroids left out for holding NaN.
    """

    xy: np.ndarray | None
    refused: str | None
    nan_centroids: int = 0


def screen_frame(frames: Frames, f: int, n_cameras: int, last_stamp) -> Screened:
    """Check frame ``f`` against the cameras known and ``last_stamp`` (K,), the last accepted
    stamp of each camera (s); nothing passed in is changed."""
    c, t = int(frames.camera[f]), float(frames.stamp[f])
    if not 0 <= c < n_cameras:
        return Screened(xy=None, refused="unknown_camera")
    if not np.isfinite(t):
        return Screened(xy=None, refused="nonfinite_stamp")
    if t <= last_stamp[c]:
        return Screened(xy=None, refused="backwards_time")
    xy = frames.centroids(f)
    finite = np.isfinite(xy).all(axis=1)
    return Screened(xy=xy[finite], refused=None, nan_centroids=int((~finite).sum()))


@dataclass
class FrameIntake:
    """A tracker's running record of its input: the last accepted stamp and the frames
    received per camera, and the counters of bad input (one object per run; mutable)."""

    last_stamp: np.ndarray
    received: np.ndarray
    unknown_camera: int = 0
    backwards_time: int = 0
    nonfinite_stamp: int = 0
    empty_frames: int = 0
    nan_centroids: int = 0

    @classmethod
    def initial(cls, n_cameras: int) -> FrameIntake:
        return cls(last_stamp=np.full(n_cameras, -np.inf),
                   received=np.zeros(n_cameras, np.int64))

    def take(self, frames: Frames, f: int) -> np.ndarray | None:
        """Frame ``f``'s finite centroids (counted as received), or None if refused."""
        s = screen_frame(frames, f, len(self.received), self.last_stamp)
        if s.refused is not None:
            setattr(self, s.refused, getattr(self, s.refused) + 1)
            return None
        c = int(frames.camera[f])
        self.last_stamp[c] = float(frames.stamp[f])
        self.received[c] += 1
        self.nan_centroids += s.nan_centroids
        self.empty_frames += int(len(s.xy) == 0)
        return s.xy

    @property
    def rejected(self) -> dict:
        """The counters of bad input, by name."""
        return {k: getattr(self, k) for k in ("unknown_camera", "backwards_time",
                                              "nonfinite_stamp", "empty_frames",
                                              "nan_centroids")}
