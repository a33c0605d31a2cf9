"""Davis's mixed-scale system (2002, chapters 2-5, Figs. 4, 5, 50), closed: ceiling cameras
track LEDs on the body, their estimate steers pan-tilt heads, the heads film the face.

What goes in is what a user has: the ceiling cameras' frames with their time stamps and
frames of the empty room, the ceiling cameras and the pan-tilt heads as the library
calibrated them, the heads themselves as devices (they take commands and return a frame and
the angles they report), a first-frame identification of the face markers per head (by
hand), and a face model learnt from an earlier capture. The system sees nothing else; how
realistic those inputs are is the caller's affair (notebook 15 says what its simulation
gives). :func:`capture_mixed_scale` runs the stages:

1. *closed loop*, one tick per pan-tilt frame (``params.video_rate``): every ceiling frame
   that has arrived is searched for LEDs (:func:`~lsmta.widearea.detect`, thresholds
   learnt from the empty room: its maximum plus a multiple of its measured noise) and fed
   to the streaming tracker (:class:`~lsmta.widearea.WideAreaTracker`); the head is the
   highest live target; its position is predicted to the tick plus ``params.lead`` s from
   the tracker's newest frame (its velocity, braking with the head when it slows down:
   :func:`lead_displacement`; 0: the newest estimate, no prediction), moved
   by ``params.aim_offset`` to the face, and every head is aimed at it from its previous
   command (:func:`~lsmta.pantilt.aim`; the first search starts from the angles the heads
   report before any command); each head then grabs its frame at the angles its
   motors reached and reports them. When the head's target dies, the head is coasted on the
   body's other targets plus their last offsets from it (:func:`coast_head`) for up to
   ``params.coast`` s;
2. *marker tracking* in each head's close-up video (:func:`~lsmta.tracking.markers.
   track_markers`), started from the hand identification of the first frame at which the
   heads have followed the same target for ``params.settle`` s;
3. *triangulation* of every frame from a single pair of heads
   (:func:`~lsmta.triangulation.triangulate_single_pair`), each head the calibrated model
   at its read-back angles (:meth:`~lsmta.pantilt.PanTiltCamera.camera_at`);
4. *fill*: occluded and lost markers from the face model
   (:meth:`lsmta.face.FaceModel.fill`), the face per frame; measured markers far from the
   fitted face are dropped as wrong and the face is filled again;
5. *re-acquisition* (``params.reacquire`` passes): lost markers start again where the
   filled face, projected into a head at its read-back angles, falls on a dot
   (:func:`reacquisition_seeds`); tracking, triangulation and fill run again;
6. *body*: every LED track sampled at the frame times.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from tqdm.auto import tqdm

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..face import FaceModel
from ..face.basis import FaceFit
from ..pantilt import PanTiltCamera, aim
from ..tracking.markers import MarkerStatus, track_markers
from ..triangulation import triangulate_single_pair
from ..widearea import (
    EstimatorParams,
    TrackingResult,
    WideAreaTracker,
    detect,
    noise_threshold,
)


@dataclass(frozen=True)
class MixedScaleParams:
    """Settings of :func:`capture_mixed_scale`.

    Attributes
    ----------
    video_rate : float
        Pan-tilt frames and commands per second, Hz.
    lead : float
        Prediction time Δt of the aim point beyond the tick, s (thesis: 0.3; 0: aim at the
        latest estimate).
    accel_window : float
        The lead prediction brakes with the head: each target's acceleration is the change
        of the tracker's velocity estimate over this long, s, and an axis whose speed falls
        is extrapolated at that deceleration until it stops (:func:`lead_displacement`);
        0: constant velocity (which leads to where the head would be had it not stopped:
        a stop is overshot by up to the speed times the lead).
    speed_up : bool
        Also extrapolate an axis whose speed grows at its acceleration (default: constant
        velocity there: an acceleration term overshoots the end of every speed-up and
        follows the step's sway; over walks it saved a few frames at a start but raised the
        median aim error).
    lead_height : bool
        Also predict the height (default: the newest estimate's height; a walking head
        bobs with each step, faster than a lead of 0.3 s can follow, and its vertical
        velocity extrapolated that far misplaces it by more than the bob).
    damping : float
        The damping filter's α in (0, 1], ``S <- S + α (P' - S)`` on the aim point (1: none;
        :class:`lsmta.pantilt.Control`). Default 1: a damped aim lags a moving head by
        (1 - α) / α ticks, and most frames the loop loses are at the walk's start, where the
        motors' dead time already lags the acceleration (undamped, a stop is overshot a
        little more).
    start, stop : float
        Clock times of the first pan-tilt frame and of the end of the recording, s.
    aim_offset : (3,)
        From the head LED to the face, world mm (measured once on the person).
    head_margin : float
        The head is the highest live target; the current one is kept unless another is
        higher by more than this, mm (:func:`head_target`).
    threshold_sigmas : float
        The LED thresholds: each pixel's maximum over the empty-room frames plus this many
        times the image noise measured in them (:func:`~lsmta.widearea.noise_threshold`),
        no fixed floor (a floor of 60 grey levels over a background of 30 missed the head
        LED seen dim by a far ceiling camera; 4 to 5 keep noise from passing).
    estimator : EstimatorParams
        The wide-area tracker's settings; default: a walking head's acceleration density
        (1e6 mm²/s³, notebook 12's), a target that dies and is born again within 0.3 s and
        100 mm of where it would be keeps its identity (``rejoin``), the rest
        :class:`~lsmta.widearea.EstimatorParams`'s.
    tol_px : float
        Aiming tolerance (:func:`~lsmta.pantilt.aim`), px.
    min_angle_deg : float
        Smallest ray angle of a triangulated marker, degrees.
    max_reprojection_px : float
        A triangulated marker whose intersection reprojects farther than this from its
        image in either head is dropped (a marker tracked onto its neighbour in one head), px.
    max_fill_mm : float
        After a first fill, measured markers farther than this from the fitted face are
        dropped as wrong, and the face is filled again, mm.
    coast : float
        When the head's target dies (the LED seen by fewer than two ceiling cameras, at the
        rig's edge), the aim follows the body's other targets, each plus its last offset
        from the head, for up to this long, s (0: the highest live target at once, a
        shoulder; :func:`coast_head`).
    body_radius : float
        The targets within this distance of the head are the body it coasts on, mm.
    settle : float
        The markers are identified in the first frame at which the same head target has
        been aimed at for this long (its motors have caught up), s.
    reacquire : int
        Passes of re-acquisition: lost markers restarted where the filled face, projected
        into a head at its read-back angles, falls on a dot, then tracking, triangulation
        and fill again (0: markers lost stay lost, notebook 13's rule).
    dot_contrast : float
        A projected marker starts again only where the image is brighter than its 9 x 9
        neighbourhood's median by this much, grey levels (a dot is there, not skin).
    """

    video_rate: float = 30.0
    lead: float = 0.3
    accel_window: float = 0.2
    speed_up: bool = False
    lead_height: bool = False
    damping: float = 1.0
    start: float = 0.9
    stop: float | None = None
    aim_offset: tuple = (0.0, -80.0, -150.0)
    head_margin: float = 200.0
    threshold_sigmas: float = 5.0
    estimator: EstimatorParams = field(
        default_factory=lambda: EstimatorParams(accel_density=1e6, rejoin=0.3))
    tol_px: float = 0.5
    min_angle_deg: float = 2.0
    max_reprojection_px: float = 1.0
    max_fill_mm: float = 3.0
    coast: float = 2.0
    body_radius: float = 600.0
    settle: float = 0.5
    reacquire: int = 2
    dot_contrast: float = 30.0

    def __post_init__(self):
        for key in ("video_rate", "threshold_sigmas", "tol_px",
                    "min_angle_deg", "max_reprojection_px", "max_fill_mm", "dot_contrast",
                    "head_margin", "body_radius"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("lead", "start", "settle", "coast", "accel_window"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        if isinstance(self.reacquire, bool) or int(self.reacquire) != self.reacquire \
                or self.reacquire < 0:
            raise ValueError(f"reacquire: expected an integer >= 0, got {self.reacquire!r}")
        for key in ("speed_up", "lead_height"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise TypeError(f"{key}: expected a bool, got {getattr(self, key)!r}")
        if not 0 < as_scalar(self.damping, "damping") <= 1:
            raise ValueError(f"damping: expected a number in (0, 1], got {self.damping}")
        if self.stop is not None and not as_scalar(self.stop, "stop") > self.start:
            raise ValueError(f"stop: expected a time after start={self.start}, got {self.stop}")
        as_array(self.aim_offset, "aim_offset", shape=(3,))
        if not isinstance(self.estimator, EstimatorParams):
            raise TypeError("estimator: expected an lsmta.widearea.EstimatorParams")


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


@dataclass(frozen=True, eq=False)
class MixedScaleCapture:
    """Everything :func:`capture_mixed_scale` measured, stage by stage.

    Attributes
    ----------
    times : (F,) array
        Pan-tilt frame (and command) times, s.
    tracking : TrackingResult
        The wide-area tracker at the end.
    head_id : (F,) int array
        The target taken for the head at each tick (-1: none alive, no command).
    coasted : (F,) bool array
        The head's target had died and the aim came from the body's other targets
        (``params.coast``).
    aim_points : (F, 3) array
        Where the heads were aimed (predicted head + offset), mm; NaN without a command.
    commands, settings : (K, F, 2) arrays
        Commanded and read-back pan and tilt per head and frame, degrees.
    images : (K, F, H, W) uint8 array or None
        The close-up videos (``keep_images``).
    markers : list of K MarkerTracks
        The last pass of the marker tracker.
    xy : (K, F, M, 2) array
        Marker positions found (tracked or second search), px; NaN elsewhere.
    points : (F, M, 3) array
        Triangulated markers, mm (NaN: not seen by both heads of the pair, or dropped by
        the reprojection or the fill check).
    pairs : (F, 2) int array
        The heads used in each frame.
    face : FaceFit
        The face per frame, gaps filled from the face model.
    body : (F, N, 3) array
        Every LED track's position at the frame times, mm (NaN when not alive).
    seconds : dict of str -> float
    params : MixedScaleParams
    """

    times: np.ndarray
    tracking: TrackingResult
    head_id: np.ndarray
    coasted: np.ndarray
    aim_points: np.ndarray
    commands: np.ndarray
    settings: np.ndarray
    images: np.ndarray | None
    markers: list
    xy: np.ndarray
    points: np.ndarray
    pairs: np.ndarray
    face: FaceFit
    body: np.ndarray
    seconds: dict
    params: MixedScaleParams

    def summary(self) -> list:
        """One row per stage: ``{"stage", "seconds", "result"}``."""
        tr = self.tracking
        found = np.isfinite(self.xy).all(axis=3)
        rows = [
            ("closed loop", f"{len(self.times)} ticks, {len(tr.tracks)} LED tracks, "
                            f"{int(tr.frames_used.sum())} ceiling frames used; commands in "
                            f"{int((self.head_id >= 0).sum())} ticks "
                            f"({int(self.coasted.sum())} coasted on the body)"),
            ("marker tracking", f"{found.mean():.1%} of marker images found per head"),
            ("triangulation", f"{np.isfinite(self.points).all(axis=2).mean():.1%} of markers "
                              "triangulated"),
            ("fill", f"{int(self.face.fitted.sum())} of {len(self.times)} frames fitted"),
            ("re-acquisition", f"{self.params.reacquire} pass(es): lost markers restarted "
                               "from the filled face"),
            ("body", f"{self.body.shape[1]} LED tracks at the frame times"),
        ]
        return [{"stage": s, "seconds": self.seconds.get(s, float("nan")), "result": r}
                for s, r in rows]


@dataclass
class _State:
    """What the stages of :func:`capture_mixed_scale` hand on."""

    feed: CeilingFeed
    heads: list
    devices: list
    identify: list
    face_model: FaceModel
    params: MixedScaleParams
    keep_images: bool
    progress: bool
    times: np.ndarray
    thresholds: list | None = None
    tracker: WideAreaTracker | None = None
    head_id: np.ndarray | None = None
    coasted: np.ndarray | None = None
    head_since: np.ndarray | None = None
    hid: int = -1
    offsets: dict = field(default_factory=dict)
    velocities: dict = field(default_factory=dict)
    last_head: np.ndarray | None = None
    lost_at: float = np.nan
    aim_points: np.ndarray | None = None
    commands: np.ndarray | None = None
    settings: np.ndarray | None = None
    images: list | None = None
    markers: list | None = None
    starts: list | None = None
    first: int = 0
    xy: np.ndarray | None = None
    points: np.ndarray | None = None
    pairs: np.ndarray | None = None
    face: FaceFit | None = None
    body: np.ndarray | None = None


def head_target(tracker: WideAreaTracker, t: float, lead: float, *, previous: int = -1,
                margin: float = 200.0):
    """The head and its aim point (mm): the live targets predicted to ``t + lead`` (the
    tick plus the heads' latency, by the tracker's constant-velocity model, from its newest
    ceiling frame; with ``lead`` 0 the newest estimate, no prediction at all; the loop of
    :func:`capture_mixed_scale` moves them by :func:`lead_displacement` instead), or
    ``(-1, None)`` when no target is alive. The head is the highest
    target; the ``previous`` head stays the head while it lives and no other target is more
    than ``margin`` mm higher (so the aim does not flap between targets at the same height,
    and moves to the head LED once its track is born when a shoulder had to stand in for
    it)."""
    t = as_scalar(t, "t")
    as_scalar(margin, "margin", nonnegative=True)
    e = _targets_at(tracker, t, lead)
    i = _highest(e, previous, margin)
    return (-1, None) if i < 0 else (int(e.ids[i]), e.states[i, :3].copy())


def _targets_at(tracker: WideAreaTracker, t: float, lead: float):
    as_scalar(lead, "lead", nonnegative=True)
    return tracker.predict(t + lead) if lead > 0 else tracker.estimate()


def lead_displacement(velocity, acceleration, dt, *, speed_up: bool = False) -> np.ndarray:
    """How far targets move in ``dt`` s, axis by axis: on an axis whose speed falls
    (acceleration against velocity) at constant deceleration until that axis's velocity
    reaches zero, then still (a braking head stops; the displacement never turns back);
    on an axis whose speed grows, at constant velocity (``speed_up``: at constant
    acceleration).

    Parameters
    ----------
    velocity, acceleration : (N, 3) arrays
        mm/s and mm/s².
    dt : float or (N,) array
        Prediction time, s (>= 0).
    speed_up : bool

    Returns
    -------
    (N, 3) array
        Displacement, mm.
    """
    v = as_array(velocity, "velocity", shape=(None, 3))
    a = as_array(acceleration, "acceleration", shape=v.shape)
    dt = np.broadcast_to(np.asarray(dt, float), (len(v),))[:, None]
    if not (np.isfinite(dt).all() and (dt >= 0).all()):
        raise ValueError("dt: expected finite prediction times >= 0")
    braking = a * v < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(braking, np.minimum(dt, -v / np.where(braking, a, 1.0)), dt)
    a = np.where(braking | speed_up, a, 0.0)
    return v * tau + 0.5 * a * tau**2


def _predicted(st: _State, t: float):
    """The live targets at ``t + params.lead`` (the newest estimate when ``lead`` is 0): the
    tracker's newest estimate moved by :func:`lead_displacement`, each target's acceleration
    the change of its estimated velocity over the last ``params.accel_window`` s (0, or a
    target younger than that: constant velocity). Logs the velocities."""
    p = st.params
    e = st.tracker.estimate()
    log = st.velocities
    for i, x in zip(e.ids.tolist(), e.states):
        h = log.setdefault(i, [])
        if not h or e.time > h[-1][0]:
            h.append((e.time, x[3:].copy()))
        while len(h) > 2 and h[1][0] <= e.time - p.accel_window - 0.5:
            h.pop(0)
    if p.lead == 0 or not len(e.ids):
        return e
    acc = np.zeros((len(e.ids), 3))
    if p.accel_window > 0:
        for j, i in enumerate(e.ids.tolist()):
            old = [(s, v) for s, v in log[i] if s <= e.time - p.accel_window]
            if old:
                acc[j] = (e.states[j, 3:] - old[-1][1]) / (e.time - old[-1][0])
    states = e.states.copy()
    d = lead_displacement(e.states[:, 3:], acc, max(t + p.lead - e.time, 0.0),
                          speed_up=p.speed_up)
    if not p.lead_height:
        d[:, 2] = 0.0
    states[:, :3] += d
    return replace(e, time=t + p.lead, states=states)


def _highest(e, previous: int, margin: float) -> int:
    """Row of the head in the estimate ``e`` (:func:`head_target`'s rule), -1 for none."""
    if not len(e.ids):
        return -1
    i = int(np.argmax(e.states[:, 2]))
    same = np.flatnonzero(e.ids == previous)
    if len(same) and e.states[i, 2] - e.states[same[0], 2] <= margin:
        i = int(same[0])
    return i


def body_offsets(ids, positions, head: int, radius: float) -> dict:
    """``{id: head position - its position}`` (mm) of the targets within ``radius`` mm of
    the head (row ``head`` of ``positions``, ``(N, 3)`` mm; ``ids`` ``(N,)``), the head
    excepted: the body the head coasts on when its target dies (:func:`coast_head`)."""
    X = as_array(positions, "positions", shape=(None, 3))
    ids = as_array(ids, "ids", shape=(len(X),))
    if not 0 <= head < len(X):
        raise ValueError(f"head: expected a row of positions (0 to {len(X) - 1}), got {head}")
    as_scalar(radius, "radius", positive=True)
    d = X[head] - X
    near = np.linalg.norm(d, axis=1) <= radius
    near[head] = False
    return {int(i): d[j].copy() for j, i in zip(np.flatnonzero(near), ids[near].astype(int))}


def coast_head(ids, positions, offsets: dict, held) -> np.ndarray:
    """The head while its target is dead, mm: the mean over the body's targets still alive
    (``ids`` ``(N,)``, ``positions`` ``(N, 3)`` mm) of their position plus their offset from
    the head (``offsets``, :func:`body_offsets` of the last tick the head lived); ``held``
    (the head's last aim, ``(3,)`` mm) when none of them lives."""
    X = as_array(positions, "positions", shape=(None, 3))
    ids = as_array(ids, "ids", shape=(len(X),))
    held = as_array(held, "held", shape=(3,))
    rows = [j for j, i in enumerate(ids.astype(int)) if int(i) in offsets]
    if not rows:
        return held.copy()
    return np.mean([X[j] + offsets[int(ids[j])] for j in rows], axis=0)


def _aim_head(st: _State, t: float):
    """The head's target and point at tick ``t`` (stage of the closed loop): the head rule
    of :func:`head_target` while the head's target lives; when it dies, coasting on the
    body (:func:`coast_head`) for up to ``params.coast`` s, until a target about as high as
    the coasted head (within ``params.head_margin``) appears. Returns ``(id, point or None,
    coasted)``."""
    p = st.params
    e = _predicted(st, t)
    if st.hid >= 0 and st.hid not in e.ids and p.coast > 0:
        st.lost_at = t if np.isnan(st.lost_at) else st.lost_at
        if t - st.lost_at <= p.coast:
            X = coast_head(e.ids, e.states[:, :3], st.offsets, st.last_head)
            if not len(e.ids) or e.states[:, 2].max() < X[2] - p.head_margin:
                st.last_head = X
                return st.hid, X, True
    i = _highest(e, st.hid, p.head_margin)
    if i < 0:
        st.hid, st.lost_at = -1, np.nan
        return -1, None, False
    st.hid, st.lost_at = int(e.ids[i]), np.nan
    st.last_head = e.states[i, :3].copy()
    st.offsets = body_offsets(e.ids, e.states[:, :3], i, p.body_radius)
    return st.hid, st.last_head.copy(), False


def _ceiling_queue(feed: CeilingFeed) -> np.ndarray:
    """Rows (arrival, camera, frame) of every ceiling frame, in arrival order."""
    arrival = feed.stamps if feed.arrival is None else feed.arrival
    rows = [np.c_[np.asarray(a, float), np.full(len(a), k), np.arange(len(a))]
            for k, a in enumerate(arrival)]
    q = np.concatenate(rows)
    return q[np.argsort(q[:, 0], kind="stable")]


def _closed_loop(st: _State) -> None:
    p, feed = st.params, st.feed
    st.thresholds = [noise_threshold(b, sigmas=p.threshold_sigmas) for b in feed.backgrounds]
    st.tracker = WideAreaTracker(feed.cameras, params=p.estimator)
    queue, q = _ceiling_queue(feed), 0
    K, F = len(st.heads), len(st.times)
    st.head_id = np.full(F, -1)
    st.coasted = np.zeros(F, bool)
    st.head_since = np.full(F, np.nan)
    st.aim_points = np.full((F, 3), np.nan)
    st.commands = np.full((K, F, 2), np.nan)
    st.settings = np.full((K, F, 2), np.nan)
    images = []
    smooth, hid, since = None, -1, np.nan
    # the loop runs from the first ceiling frame; frames are kept from params.start on
    ticks = np.r_[np.arange(queue[0, 0], st.times[0] - 1e-9, 1.0 / p.video_rate), st.times]
    # the aim's search starts from the angles each head reports before its first command
    current = [_grab(device, ticks[0], k)[1] for k, device in enumerate(st.devices)]
    first = len(ticks) - F
    for i, t in enumerate(tqdm(ticks, desc="closed loop", disable=not st.progress,
                               leave=False)):
        while q < len(queue) and queue[q, 0] <= t:
            _feed_ceiling(st, int(queue[q, 1]), int(queue[q, 2]))
            q += 1
        new, X, coasted = _aim_head(st, t)
        if new != hid:
            hid, since = new, (t if new >= 0 else np.nan)
        if X is not None:
            X = X + np.asarray(p.aim_offset, float)
            smooth = X if smooth is None else smooth + p.damping * (X - smooth)
            X = smooth
            for k, (model, device) in enumerate(zip(st.heads, st.devices)):
                current[k] = aim(model, X[None], current=current[k], tol_px=p.tol_px).settings[0]
                device.command(t, current[k])
        if i < first:
            continue
        f = i - first
        st.head_id[f], st.head_since[f], st.coasted[f] = hid, since, coasted
        if X is not None:
            st.aim_points[f] = X
            st.commands[:, f] = current
        grabbed = [_grab(device, t, k) for k, device in enumerate(st.devices)]
        st.settings[:, f] = [s for _, s in grabbed]
        images.append(np.stack([img for img, _ in grabbed]))
    st.images = np.stack(images, axis=1)


def _feed_ceiling(st: _State, k: int, i: int) -> None:
    feed = st.feed
    inv = None if feed.invalid is None else feed.invalid[k]
    xy = detect(feed.frames[k][i], st.thresholds[k], invalid=inv).centroids(0)
    st.tracker.feed(k, float(feed.stamps[k][i]), xy)


def _grab(device, t: float, k: int):
    img, s = device.grab(t)
    img = np.asarray(img)
    s = np.asarray(s, float)
    if img.ndim != 2 or s.shape != (2,) or not np.isfinite(s).all():
        raise ValueError(f"devices: head {k}'s grab({t:.3f}) returned an image of shape "
                         f"{img.shape} and a setting {s}; expected (H, W) and finite "
                         "(pan, tilt) degrees")
    return img, s


def first_settled(times, head_since, settle: float) -> int:
    """The first frame at which the heads have been aimed at the same target for
    ``settle`` s (``head_since``: when the frame's head target became the head, NaN for
    none), or 0 when there is none."""
    with np.errstate(invalid="ignore"):
        ok = np.flatnonzero(np.asarray(times) - np.asarray(head_since) >= settle)
    return int(ok[0]) if len(ok) else 0


def _marker_tracking(st: _State) -> None:
    p = st.params
    st.first = first_settled(st.times, st.head_since, p.settle)
    st.starts = [as_array(f(st.times[st.first], st.settings[k, st.first]),
                          f"identify[{k}](...)", shape=(None, 2), allow_nan=True)
                 for k, f in enumerate(st.identify)]
    _track(st, None)


def _track(st: _State, seeds) -> None:
    st.markers, xy = [], []
    K, F = st.images.shape[:2]
    for k, start in enumerate(st.starts):
        s = np.full((F, len(start), 2), np.nan) if seeds is None else seeds[k].copy()
        s[st.first] = start                     # frame 0's start is its initial position
        initial = start if st.first == 0 else np.full((len(start), 2), np.nan)
        tr = track_markers(st.images[k], initial, seeds=s)
        ok = np.isin(tr.status, (MarkerStatus.TRACKED, MarkerStatus.SECOND_SEARCH))
        st.markers.append(tr)
        xy.append(np.where(ok[..., None], tr.xy, np.nan))
    st.xy = np.stack(xy)


_NINE = np.stack(np.meshgrid(np.arange(-4, 5), np.arange(-4, 5)), -1).reshape(-1, 2)  # (x, y)


def reacquisition_seeds(images, heads, settings, face, found, *, dot_contrast: float = 30.0,
                        crowd_px: float = 6.0) -> np.ndarray:
    """Where lost markers may start again: the filled face projected into each head.

    Parameters
    ----------
    images : (K, F, H, W) array
    heads : sequence of K PanTiltCamera
        As calibrated.
    settings : (K, F, 2) array
        Read-back angles, degrees.
    face : (F, M, 3) array
        The filled face, mm (NaN where not fitted).
    found : (K, F, M) bool array
        Markers the tracker has in each frame (they are not restarted).
    dot_contrast : float
        The image at the projection must exceed the median of its 9 x 9 neighbourhood by
        this many grey levels (a dot, not skin; a marker turned away draws none).
    crowd_px : float
        Projections closer than this to another one are not used (their dots merge).

    Returns
    -------
    (K, F, M, 2) array
        Seeds for :func:`~lsmta.tracking.markers.track_markers`, px (NaN elsewhere).
    """
    if np.ndim(images) != 4:
        raise ValueError(f"images: expected an array of shape (K, F, H, W), got shape "
                         f"{np.shape(images)}")
    K, F, H, W = np.shape(images)
    heads = list(heads)
    if len(heads) != K or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError(f"heads: expected {K} lsmta.pantilt.PanTiltCamera (one per image "
                        "sequence)")
    settings = as_array(settings, "settings", shape=(K, F, 2))
    face = as_array(face, "face", shape=(F, None, 3), allow_nan=True)
    M = face.shape[1]
    found = np.asarray(found)
    if found.dtype != bool or found.shape != (K, F, M):
        raise ValueError(f"found: expected a bool array of shape ({K}, {F}, {M}), got "
                         f"{found.dtype} {found.shape}")
    as_scalar(dot_contrast, "dot_contrast", nonnegative=True)
    as_scalar(crowd_px, "crowd_px", nonnegative=True)
    seeds = np.full((K, F, M, 2), np.nan)
    for k, head in enumerate(heads):
        for f in np.flatnonzero(np.isfinite(face).all(axis=(1, 2))):
            cam = head.camera_at(*settings[k, f])
            p = cam.project(face[f], behind="nan")
            finite = np.isfinite(p).all(axis=1)
            d = np.nan_to_num(np.linalg.norm(p[:, None] - p[None], axis=2), nan=np.inf)
            np.fill_diagonal(d, np.inf)
            c = np.rint(np.where(finite[:, None], p, -100.0)).astype(int)
            ok = finite & ~found[k, f] & (c[:, 0] >= 4) & (c[:, 0] < W - 4) & (c[:, 1] >= 4) \
                & (c[:, 1] < H - 4) & (d.min(axis=1) >= crowd_px)
            m = np.flatnonzero(ok)
            patch = images[k, f][c[m, 1, None] + _NINE[:, 1], c[m, 0, None] + _NINE[:, 0]]
            dot = patch[:, 40].astype(float) - np.median(patch, axis=1) >= dot_contrast
            seeds[k, f, m[dot]] = p[m[dot]]
    return seeds


def _reacquisition(st: _State) -> None:
    for _ in range(st.params.reacquire):
        seeds = reacquisition_seeds(st.images, st.heads, st.settings, st.face.frames,
                                    np.isfinite(st.xy).all(axis=3),
                                    dot_contrast=st.params.dot_contrast)
        if not np.isfinite(seeds).any():
            break
        _track(st, seeds)
        _triangulation(st)
        _fill(st)


def _triangulation(st: _State) -> None:
    K, F, M = st.xy.shape[:3]
    st.points = np.full((F, M, 3), np.nan)
    st.pairs = np.zeros((F, 2), int)
    for f in range(F):
        cams = [h.camera_at(*st.settings[k, f]) for k, h in enumerate(st.heads)]
        r = triangulate_single_pair(cams, st.xy[:, f], min_angle_deg=st.params.min_angle_deg)
        with np.errstate(invalid="ignore"):
            bad = np.fmax.reduce(r.intersection.reprojection_error, axis=0) \
                > st.params.max_reprojection_px
        st.points[f] = np.where(bad[:, None], np.nan, r.intersection.points)
        st.pairs[f] = r.pair


def _fill(st: _State) -> None:
    first = st.face_model.fill(st.points)
    with np.errstate(invalid="ignore"):
        wrong = np.linalg.norm(st.points - first.model, axis=2) > st.params.max_fill_mm
    st.points = np.where(wrong[..., None], np.nan, st.points)
    st.face = st.face_model.fill(st.points) if wrong.any() else first


def _body(st: _State) -> None:
    st.body = st.tracker.result().positions_at(st.times)


STAGES = (("closed loop", _closed_loop), ("marker tracking", _marker_tracking),
          ("triangulation", _triangulation), ("fill", _fill),
          ("re-acquisition", _reacquisition), ("body", _body))


def _check_feed(feed) -> CeilingFeed:
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


def _check_heads(heads, devices, identify) -> tuple:
    heads, devices, identify = list(heads), list(devices), list(identify)
    if len(heads) < 2 or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError("heads: expected at least 2 calibrated lsmta.pantilt.PanTiltCamera")
    for name, v in (("devices", devices), ("identify", identify)):
        if len(v) != len(heads):
            raise ValueError(f"{name}: expected one per head ({len(heads)}), got {len(v)}")
    for k, d in enumerate(devices):
        if not (callable(getattr(d, "command", None)) and callable(getattr(d, "grab", None))):
            raise TypeError(f"devices[{k}]: expected an object with command(t, setting) and "
                            "grab(t) -> (image, setting)")
    for k, f in enumerate(identify):
        if not callable(f):
            raise TypeError(f"identify[{k}]: expected a callable (t, setting) -> (M, 2) px")
    return heads, devices, identify


def capture_mixed_scale(ceiling: CeilingFeed, heads, devices, identify, face_model: FaceModel, *,
                        params: MixedScaleParams | None = None, keep_images: bool = True,
                        progress: bool = True) -> MixedScaleCapture:
    """Run the mixed-scale system: LEDs tracked from the ceiling steer the pan-tilt heads,
    whose close-up videos give the face per frame (see the module).

    Parameters
    ----------
    ceiling : CeilingFeed
        The ceiling cameras (calibrated), their frames, stamps and empty-room frames.
    heads : sequence of K >= 2 PanTiltCamera
        The pan-tilt heads as calibrated (notebook 11's procedure).
    devices : sequence of K objects
        The heads themselves: ``command(t, setting)`` sends a (pan, tilt) in degrees at time
        ``t`` (s); ``grab(t)`` returns the frame ``(H, W)`` at ``t`` and the setting the head
        reports (its motors' angles, degrees).
    identify : sequence of K callables
        ``identify[k](t, setting)``: the M face markers identified by hand in head k's frame
        at time ``t`` (the first frame at which the heads have followed the same target
        for ``params.settle`` s), ``(M, 2)`` px, NaN for markers not seen.
    face_model : lsmta.face.FaceModel
        Learnt from an earlier capture of the same markers (:func:`lsmta.face.learn`).
    params : MixedScaleParams, optional
    keep_images : bool
        Keep the close-up videos in the result.
    progress : bool

    Returns
    -------
    MixedScaleCapture
        Nothing passed in is modified.
    """
    feed = _check_feed(ceiling)
    heads, devices, identify = _check_heads(heads, devices, identify)
    if not isinstance(face_model, FaceModel):
        raise TypeError(f"face_model: expected an lsmta.face.FaceModel, got "
                        f"{type(face_model).__name__}")
    p = MixedScaleParams() if params is None else params
    if not isinstance(p, MixedScaleParams):
        raise TypeError(f"params: expected a MixedScaleParams, got {type(p).__name__}")
    last = max(float(np.max(s)) for s in feed.stamps)
    stop = last if p.stop is None else min(p.stop, last)
    times = np.arange(p.start, stop, 1.0 / p.video_rate)
    if len(times) < 3:
        raise ValueError(f"params.start: the recording from {p.start} s to {stop:.3f} s (the "
                         "last ceiling stamp or params.stop) has fewer than 3 frames")
    st = _State(feed=feed, heads=heads, devices=devices, identify=identify,
                face_model=face_model, params=p, keep_images=keep_images, progress=progress,
                times=times)
    seconds = {}
    for name, stage in tqdm(STAGES, desc="mixed-scale system", disable=not progress):
        t0 = time.perf_counter()
        stage(st)
        seconds[name] = time.perf_counter() - t0
    return MixedScaleCapture(times=times, tracking=st.tracker.result(), head_id=st.head_id,
                             coasted=st.coasted, aim_points=st.aim_points, commands=st.commands,
                             settings=st.settings,
                             images=st.images if keep_images else None, markers=st.markers,
                             xy=st.xy, points=st.points, pairs=st.pairs, face=st.face,
                             body=st.body, seconds=seconds, params=p)

