"""Steering pan-tilt heads at a moving target (Davis 2002, Sections 4.3-4.4): the policy
between the wide-area estimate of the targets and the heads' commands.

Three components, each with its own memory, in the order of one command tick
(:class:`Steering` chains them, one :meth:`Steering.step` per tick):

:class:`LeadPredictor`
    The live targets at the tick plus the lead Δt: the newest estimate moved by
    :func:`lead_displacement` (braking with a target that slows down; the height held),
    each target's acceleration the change of its estimated velocity over a window.
:class:`HeadChooser`
    The head is the highest live target, kept while it lives unless another is higher by
    a margin (:func:`head_target`'s rule); when its target dies, the head is coasted on the
    body's other targets plus their last offsets from it (:func:`body_offsets`,
    :func:`coast_head`).
:class:`Pointer`
    The damping filter ``S <- S + α (P' - S)`` on the aim point, and every head aimed at S
    by the local search of :func:`~lsmta.pantilt.aim` from its previous command.

:func:`~lsmta.pantilt.simulate_tracking` steers with a :class:`Pointer` (its prediction is
the thesis's ``P + Δt V`` of a constant-velocity filter); the mixed-scale system
(:func:`lsmta.systems.capture_mixed_scale`) with a :class:`Steering`. Estimates are
:class:`lsmta.widearea.TargetEstimate` (``time``, ``ids`` ``(M,)``, ``states`` ``(M, 6)``
in mm and mm/s). The lead prediction is not the tracker's
:meth:`~lsmta.widearea.WideAreaTracker.predict`: that one extrapolates every axis at
constant velocity, this one brakes and holds the height.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_scalar, freeze
from .aiming import aim
from .model import PanTiltCamera


@dataclass(frozen=True)
class SteeringParams:
    """Settings of :class:`Steering` (the mixed-scale system's defaults).

    Attributes
    ----------
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
    aim_offset : (3,)
        From the head LED to the face, world mm (measured once on the person).
    head_margin : float
        The head is the highest live target; the current one is kept unless another is
        higher by more than this, mm (:func:`head_target`).
    coast : float
        When the head's target dies (the LED seen by fewer than two ceiling cameras, at the
        rig's edge), the aim follows the body's other targets, each plus its last offset
        from the head, for up to this long, s (0: the highest live target at once, a
        shoulder; :func:`coast_head`).
    body_radius : float
        The targets within this distance of the head are the body it coasts on, mm.
    tol_px : float
        Aiming tolerance (:func:`~lsmta.pantilt.aim`), px.
    """

    lead: float = 0.3
    accel_window: float = 0.2
    speed_up: bool = False
    lead_height: bool = False
    damping: float = 1.0
    aim_offset: tuple = (0.0, -80.0, -150.0)
    head_margin: float = 200.0
    coast: float = 2.0
    body_radius: float = 600.0
    tol_px: float = 0.5

    def __post_init__(self):
        for key in ("tol_px", "head_margin", "body_radius"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("lead", "coast", "accel_window"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        for key in ("speed_up", "lead_height"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise TypeError(f"{key}: expected a bool, got {getattr(self, key)!r}")
        if not 0 < as_scalar(self.damping, "damping") <= 1:
            raise ValueError(f"damping: expected a number in (0, 1], got {self.damping}")
        as_array(self.aim_offset, "aim_offset", shape=(3,))


# ---------------------------------------------------------------------- lead prediction
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


class LeadPredictor:
    """The live targets at a tick plus ``params.lead`` (see the module); it remembers each
    target's velocity estimates over the last ``params.accel_window`` s."""

    def __init__(self, *, params: SteeringParams | None = None):
        self.params = _params(params)
        self._velocities = {}

    def predict(self, estimate, t: float):
        """The live targets at ``t + params.lead`` (the newest estimate when ``lead`` is 0):
        ``estimate`` (the tracker's newest) moved by :func:`lead_displacement`, each
        target's acceleration the change of its estimated velocity over the last
        ``params.accel_window`` s (0, or a target younger than that: constant velocity).
        Logs the velocities. Returns an estimate like ``estimate``."""
        p = self.params
        e = estimate
        log = self._velocities
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


# ---------------------------------------------------------------------- head choice
def head_target(tracker, t: float, lead: float, *, previous: int = -1,
                margin: float = 200.0):
    """The head and its aim point (mm): the live targets predicted to ``t + lead`` (the
    tick plus the heads' latency, by the tracker's constant-velocity model, from its newest
    ceiling frame; with ``lead`` 0 the newest estimate, no prediction at all; a
    :class:`Steering` moves them by :func:`lead_displacement` instead), or
    ``(-1, None)`` when no target is alive. The head is the highest
    target; the ``previous`` head stays the head while it lives and no other target is more
    than ``margin`` mm higher (so the aim does not flap between targets at the same height,
    and moves to the head LED once its track is born when a shoulder had to stand in for
    it). ``tracker``: a :class:`lsmta.widearea.WideAreaTracker`."""
    t = as_scalar(t, "t")
    as_scalar(margin, "margin", nonnegative=True)
    as_scalar(lead, "lead", nonnegative=True)
    e = tracker.predict(t + lead) if lead > 0 else tracker.estimate()
    i = _highest(e, previous, margin)
    return (-1, None) if i < 0 else (int(e.ids[i]), e.states[i, :3].copy())


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


class HeadChooser:
    """Which target is the head, tick by tick (see the module); it remembers the head, when
    its target died, the body's offsets from it and its last position."""

    def __init__(self, *, params: SteeringParams | None = None):
        self.params = _params(params)
        self.head = -1
        self._lost_at = np.nan
        self._offsets = {}
        self._last = None

    def choose(self, predicted, t: float) -> tuple:
        """The head's target and point at tick ``t`` from the ``predicted`` live targets: the
        rule of :func:`head_target` while the head's target lives; when it dies, coasting on
        the body (:func:`coast_head`) for up to ``params.coast`` s, until a target about as
        high as the coasted head (within ``params.head_margin``) appears. Returns ``(id,
        point (3,) mm or None, coasted)``; id -1 and no point when no target lives."""
        p, e = self.params, predicted
        if self.head >= 0 and self.head not in e.ids and p.coast > 0:
            self._lost_at = t if np.isnan(self._lost_at) else self._lost_at
            if t - self._lost_at <= p.coast:
                X = coast_head(e.ids, e.states[:, :3], self._offsets, self._last)
                if not len(e.ids) or e.states[:, 2].max() < X[2] - p.head_margin:
                    self._last = X
                    return self.head, X, True
        i = _highest(e, self.head, p.head_margin)
        if i < 0:
            self.head, self._lost_at = -1, np.nan
            return -1, None, False
        self.head, self._lost_at = int(e.ids[i]), np.nan
        self._last = e.states[i, :3].copy()
        self._offsets = body_offsets(e.ids, e.states[:, :3], i, p.body_radius)
        return self.head, self._last.copy(), False


# ---------------------------------------------------------------------- damped aim
class Pointer:
    """Pan-tilt heads aimed at one damped point per command (see the module).

    Parameters
    ----------
    heads : sequence of K PanTiltCamera
        The models the controller aims with (as calibrated).
    start : sequence of K (2,) arrays
        Each head's setting before the first command (pan, tilt degrees): the first
        search starts there.
    damping : float
        α in (0, 1] (1: no damping).
    tol_px : float
        Aiming tolerance of :func:`~lsmta.pantilt.aim`, px.
    """

    def __init__(self, heads, start, *, damping: float = 1.0, tol_px: float = 0.5):
        self.heads = list(heads)
        if not self.heads or not all(isinstance(h, PanTiltCamera) for h in self.heads):
            raise TypeError("heads: expected a non-empty sequence of lsmta.pantilt.PanTiltCamera")
        start = list(start)
        if len(start) != len(self.heads):
            raise ValueError(f"start: expected one setting per head ({len(self.heads)}), got "
                             f"{len(start)}")
        self.current = [as_array(s, f"start[{k}]", shape=(2,)) for k, s in enumerate(start)]
        if not 0 < as_scalar(damping, "damping") <= 1:
            raise ValueError(f"damping: expected a number in (0, 1], got {damping}")
        self.damping = damping
        self.tol_px = as_scalar(tol_px, "tol_px", positive=True)
        self.smoothed = None

    def point(self, target) -> tuple:
        """Damp the aim point ``target`` ``(3,)`` mm into :attr:`smoothed`, aim every head
        at it from its previous command (:attr:`current`, updated); one
        :class:`~lsmta.pantilt.Aim` per head."""
        smooth = self.smoothed
        smooth = target if smooth is None else smooth + self.damping * (target - smooth)
        self.smoothed = smooth
        aims = []
        for k, model in enumerate(self.heads):
            a = aim(model, smooth[None], current=self.current[k], tol_px=self.tol_px)
            self.current[k] = a.settings[0]
            aims.append(a)
        return tuple(aims)


# ---------------------------------------------------------------------- the three chained
@dataclass(frozen=True, eq=False)
class SteeringStep:
    """What :meth:`Steering.step` decided at one tick.

    Attributes
    ----------
    head_id : int
        The target taken for the head (-1: none alive, no command).
    since : float
        When ``head_id`` became the head, s (NaN for none).
    coasted : bool
        The head's target had died and the point came from the body's other targets.
    aim_point : (3,) array or None
        The damped aim point (predicted head + offset), mm; None without a command.
    settings : (K, 2) array or None
        The commands, pan and tilt per head, degrees; None without a command.
    """

    head_id: int
    since: float
    coasted: bool
    aim_point: np.ndarray | None
    settings: np.ndarray | None

    def __post_init__(self):
        if self.aim_point is not None:
            freeze(self, ("aim_point", "settings"))


class Steering:
    """Steer K pan-tilt heads at a moving head from the wide-area estimates: lead
    prediction, head choice (with coasting), damped aim (see the module).

    Parameters
    ----------
    heads : sequence of K PanTiltCamera
        As calibrated.
    start : sequence of K (2,) arrays
        The settings the heads report before the first command, degrees.
    params : SteeringParams, optional
    """

    def __init__(self, heads, start, *, params: SteeringParams | None = None):
        p = _params(params)
        self.params = p
        self.predictor = LeadPredictor(params=p)
        self.chooser = HeadChooser(params=p)
        self.pointer = Pointer(heads, start, damping=p.damping, tol_px=p.tol_px)
        self._head, self._since = -1, np.nan

    def step(self, estimate, t: float) -> SteeringStep:
        """One command tick at time ``t`` (s) from the tracker's newest ``estimate``
        (:meth:`lsmta.widearea.WideAreaTracker.estimate`)."""
        e = self.predictor.predict(estimate, t)
        new, X, coasted = self.chooser.choose(e, t)
        if new != self._head:
            self._head, self._since = new, (t if new >= 0 else np.nan)
        if X is None:
            return SteeringStep(head_id=self._head, since=self._since, coasted=coasted,
                                aim_point=None, settings=None)
        self.pointer.point(X + np.asarray(self.params.aim_offset, float))
        return SteeringStep(head_id=self._head, since=self._since, coasted=coasted,
                            aim_point=self.pointer.smoothed.copy(),
                            settings=np.array(self.pointer.current))


def _params(params) -> SteeringParams:
    p = SteeringParams() if params is None else params
    if not isinstance(p, SteeringParams):
        raise TypeError(f"params: expected a SteeringParams, got {type(p).__name__}")
    return p
