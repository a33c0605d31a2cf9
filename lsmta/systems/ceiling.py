"""The mixed-scale system's ceiling input (:func:`~lsmta.systems.capture_mixed_scale`): the
ceiling cameras' frames with their time stamps and the empty room's frames as a user has
them (:class:`CeilingFeed`), checked, and the order in which they reach the estimator."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array
from ..camera import Camera


@dataclass(frozen=True, eq=False)
class CeilingFeed:
    """The ceiling cameras' input.

    Attributes
    ----------
    cameras : list of K Camera
        As calibrated.
    frames : list of K (T_k, H, W) uint8 arrays
    stamps : list of K (T_k,) arrays
        Each frame's time stamp by its camera's clock, s (increasing).
    backgrounds : list of K (B, H, W) arrays
        Frames of the empty room (the thresholds are learnt from them).
    arrival : list of K (T_k,) arrays, optional
        When each frame reaches the estimator, s (default: its stamp).
    invalid : list of K (H, W) bool arrays, optional
        Pixels never searched (a monitor masked by the operator).
    """

    cameras: list
    frames: list
    stamps: list
    backgrounds: list
    arrival: list | None = None
    invalid: list | None = None


def check_ceiling_feed(feed) -> CeilingFeed:
    """``feed`` checked: a :class:`CeilingFeed` of K >= 2 cameras, one entry per camera in
    each list, uint8 frames of each camera's image size, increasing stamps, empty-room
    frames of the same size. Errors name the field as ``ceiling.<field>[k]``."""
    if not isinstance(feed, CeilingFeed):
        raise TypeError(f"ceiling: expected a CeilingFeed, got {type(feed).__name__}")
    cams = list(feed.cameras)
    if len(cams) < 2 or not all(isinstance(c, Camera) for c in cams):
        raise TypeError("ceiling.cameras: expected at least 2 lsmta.camera.Camera")
    K = len(cams)
    for name in ("frames", "stamps", "backgrounds", "arrival", "invalid"):
        v = getattr(feed, name)
        if v is not None and len(v) != K:
            raise ValueError(f"ceiling.{name}: expected one entry per camera ({K}), got {len(v)}")
    for k, cam in enumerate(cams):
        fr = np.asarray(feed.frames[k])
        if fr.ndim != 3 or fr.shape[1:] != (cam.height, cam.width) or fr.dtype != np.uint8:
            raise ValueError(f"ceiling.frames[{k}]: expected uint8 frames of shape (T, "
                             f"{cam.height}, {cam.width}), got {fr.dtype} {fr.shape}")
        st = as_array(feed.stamps[k], f"ceiling.stamps[{k}]", shape=(len(fr),))
        if np.any(np.diff(st) <= 0):
            raise ValueError(f"ceiling.stamps[{k}]: expected increasing time stamps")
        if feed.arrival is not None:
            as_array(feed.arrival[k], f"ceiling.arrival[{k}]", shape=(len(fr),))
        bg = np.asarray(feed.backgrounds[k])
        if bg.ndim != 3 or bg.shape[1:] != fr.shape[1:]:
            raise ValueError(f"ceiling.backgrounds[{k}]: expected empty-room frames of shape "
                             f"(B, {cam.height}, {cam.width}), got {bg.shape}")
    return feed


def arrival_order(feed: CeilingFeed) -> np.ndarray:
    """Rows ``(arrival s, camera, frame)`` of every ceiling frame, in arrival order (stamps
    where ``feed.arrival`` is None), ``(N, 3)``."""
    arrival = feed.stamps if feed.arrival is None else feed.arrival
    rows = [np.c_[np.asarray(a, float), np.full(len(a), k), np.arange(len(a))]
            for k, a in enumerate(arrival)]
    q = np.concatenate(rows)
    return q[np.argsort(q[:, 0], kind="stable")]
