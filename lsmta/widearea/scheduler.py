"""Which queued frame the central estimator processes next (Davis 2002, §3.5).

Frames arrive from the camera machines at ``arrival`` (estimator clock) and wait in one
queue per camera. Processing one frame takes ``service_time`` seconds; when frames arrive
faster than that, some must be skipped. The policies:

``"fifo"``
    Every frame in arrival order (no skipping; the estimator falls behind if overloaded).
``"newest"``
    Drain all queues and process only the frame with the newest time stamp: a camera whose
    clock runs behind the others, or that reports later, is never chosen (starvation).
``"round_robin"``
    Cameras in turn; the newest frame of that camera's queue, its older frames dropped.
    No camera starves, but a slow camera's frame may have waited long.
``"random_recent"`` (the thesis's choice)
    Choose a camera at random among the frames that arrived during the last processing
    interval, use its newest frame, then empty all queues, so that only recent frames
    compete and a slow camera still gets its chance whenever it has something new.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_rng, as_scalar

POLICIES = ("fifo", "newest", "round_robin", "random_recent")


@dataclass(frozen=True)
class Schedule:
    """The frames an estimator processed, in order.

    Attributes
    ----------
    order : (P,) int array
        Indices of the processed frames, in processing order.
    started : (P,) array
        When each was taken up (s, estimator clock).
    skipped : (F,) bool array
        Frames that were dropped from a queue without being processed.
    """

    order: np.ndarray
    started: np.ndarray
    skipped: np.ndarray


def schedule(arrival, camera, stamp, policy: str, service_time: float, *,
             rng: np.random.Generator | int | None = None) -> Schedule:
    """Simulate the estimator's queues for ``F`` frames.

    Parameters
    ----------
    arrival : (F,) array
        Arrival time of each frame at the estimator, seconds.
    camera : (F,) int array
        Camera index of each frame.
    stamp : (F,) array
        Time stamp of each frame (its camera's clock), seconds.
    policy : str
        One of :data:`POLICIES`.
    service_time : float
        Seconds the estimator spends on one frame (> 0).
    rng : numpy.random.Generator, int or None
        Required for ``"random_recent"``.

    Returns
    -------
    Schedule
    """
    arrival = as_array(arrival, "arrival", shape=(None,))
    F = len(arrival)
    cam = np.asarray(camera)
    if cam.shape != (F,) or not np.issubdtype(cam.dtype, np.integer):
        raise ValueError(f"camera: expected {F} integer camera indices")
    stamp = as_array(stamp, "stamp", shape=(F,))
    if policy not in POLICIES:
        raise ValueError(f"policy: expected one of {POLICIES}, got {policy!r}")
    service = as_scalar(service_time, "service_time", positive=True)
    if policy == "random_recent":
        if rng is None:
            raise ValueError("rng: the 'random_recent' policy needs a numpy.random.Generator or "
                             "a seed")
        rng = as_rng(rng)
    by_arrival = np.argsort(arrival, kind="stable")
    cameras = np.unique(cam)
    queued = np.zeros(F, bool)
    done = np.zeros(F, bool)
    order, started = [], []
    nxt = 0          # next frame (in arrival order) not yet queued
    clock = -np.inf
    rr = 0           # round-robin position in ``cameras``
    while True:
        if not queued.any():
            if nxt >= F:
                break
            clock = max(clock, arrival[by_arrival[nxt]])
        while nxt < F and arrival[by_arrival[nxt]] <= clock:
            queued[by_arrival[nxt]] = True
            nxt += 1
        waiting = np.flatnonzero(queued)
        pick, drop, rr = _pick(policy, waiting, arrival, stamp, cam, cameras, rr, rng)
        queued[drop] = False
        queued[pick] = False
        done[pick] = True
        order.append(pick)
        started.append(clock)
        clock += service
    order = np.asarray(order, dtype=np.int64)
    skipped = ~done
    return Schedule(order=order, started=np.asarray(started, float), skipped=skipped)


def _pick(policy: str, waiting, arrival, stamp, cam, cameras, rr: int, rng):
    """The frame a policy processes among the ``waiting`` ones and the frames it drops from
    the queues; ``rr`` is the round-robin position in ``cameras`` (returned, moved on)."""
    if policy == "fifo":
        pick = waiting[np.argmin(arrival[waiting])]
        drop = np.zeros(0, np.int64)
    elif policy == "newest":
        pick = waiting[np.argmax(stamp[waiting])]
        drop = waiting
    elif policy == "round_robin":
        present = set(cam[waiting].tolist())
        for step in range(len(cameras)):
            c = cameras[(rr + step) % len(cameras)]
            if c in present:
                rr = (rr + step + 1) % len(cameras)
                break
        mine = waiting[cam[waiting] == c]
        pick = mine[np.argmax(stamp[mine])]
        drop = mine
    else:  # random_recent
        c = rng.choice(np.unique(cam[waiting]))
        mine = waiting[cam[waiting] == c]
        pick = mine[np.argmax(stamp[mine])]
        drop = waiting
    return pick, drop, rr
