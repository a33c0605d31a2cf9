"""Whole recordings: labels carried from frame to frame, SAPM only where continuity breaks
(ours, beyond the paper, which labels every frame on its own).

A marker moves continuously: in the next frame it is near where its last two positions
predict (constant velocity). :func:`label_recording` labels the first frame with SAPM and
then, frame by frame, carries each label to the point nearest its prediction when that is

* within the marker's gate, ``gate + speed_gate · |v|`` (``|v|`` its last displacement per
  frame, mm): fast markers predict worse;
* unambiguous: no other point within ``max(2 d, d + gate)`` of the prediction (``d`` the
  chosen point's distance), and no other marker's prediction that close to the point.

Where points are left without a label (a marker back from a gap, a marker moving too fast
to predict, a new person), SAPM (:func:`~lsmta.sapm.identify`, or
:func:`~lsmta.sapm.identify_instances` for several instances) labels the frame again, and
its labels are taken for the points and markers the carrying left free. The per-frame SAPM
stays what it is; this only decides when it is needed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_int, as_scalar
from .identify import SAPMParams, checked_params, identify
from .instances import identify_instances
from .model import MarkerModel


@dataclass(frozen=True)
class TrackParams:
    """How labels are carried between frames.

    Attributes
    ----------
    gate : float
        A marker's gate at rest, mm: how far from its prediction its point may be.
    speed_gate : float
        Added to the gate per mm of the marker's last displacement per frame.
    max_age : int
        Frames a marker may be unseen and still carried (predicted at its last position).
    retry : int
        Points that SAPM left unlabelled are followed as unknown; SAPM is asked about them
        again after this many frames.
    """

    gate: float = 15.0
    speed_gate: float = 0.5
    max_age: int = 1
    retry: int = 10

    def __post_init__(self):
        object.__setattr__(self, "gate", as_scalar(self.gate, "gate", positive=True))
        object.__setattr__(self, "speed_gate", as_scalar(self.speed_gate, "speed_gate",
                                                         nonnegative=True))
        object.__setattr__(self, "max_age", as_int(self.max_age, "max_age"))
        object.__setattr__(self, "retry", as_int(self.retry, "retry"))


@dataclass(frozen=True)
class RecordingLabels:
    """The result of :func:`label_recording`.

    Attributes
    ----------
    labels : (T, N) int array
        Label of every point of every frame: model marker, or ``instance · M + marker``
        for several instances; -1 unlabelled (and for NaN rows).
    carried : (T, N) bool array
        Labels carried from the previous frame (the rest came from SAPM).
    sapm_frames : (F,) int array
        Frames on which SAPM was called.
    seconds : (T,) array
        Wall time per frame.
    """

    labels: np.ndarray
    carried: np.ndarray
    sapm_frames: np.ndarray
    seconds: np.ndarray


def _carry(pred, speed, Q, free, params: TrackParams):
    """Model labels (rows of ``pred``) carried to points of ``Q``: {point: label}."""
    rows = np.flatnonzero(np.isfinite(pred).all(axis=1))
    cols = np.flatnonzero(free)
    if not len(rows) or not len(cols):
        return {}
    d = np.linalg.norm(pred[rows][:, None] - Q[cols][None], axis=-1)
    gate = params.gate + params.speed_gate * speed[rows]
    big = 1e9
    r, c = linear_sum_assignment(np.where(d < gate[:, None], d, big))
    dij = d[r, c]
    inside = dij < gate[r]
    r, c, dij = r[inside], c[inside], dij[inside]
    zone = np.maximum(2 * dij, dij + params.gate)[:, None]
    k = np.arange(len(r))
    near_pt = d[r] < zone                                # another point near the prediction
    near_pr = d[:, c].T < zone                           # another prediction near the point
    near_pt[k, c] = near_pr[k, r] = False
    clear = ~(near_pt.any(axis=1) | near_pr.any(axis=1))
    return dict(zip(cols[c[clear]].tolist(), rows[r[clear]].tolist()))


def _aligned(instance, carried, M: int, n: int) -> np.ndarray:
    """SAPM's instances (numbered best first in each call) renumbered as the carried labels
    number them: each takes the carried instance most of its points hold, when free."""
    out = np.full(len(instance), -1)
    known = (carried >= 0) & (carried < n * M)
    votes = np.zeros((n, n), int)
    for i, c in zip(instance[known], carried[known] // M):
        if i >= 0:
            votes[i, c] += 1
    mapping = -np.ones(n, int)
    for i, c in sorted(((i, c) for i in range(n) for c in range(n)),
                       key=lambda ic: -votes[ic]):
        if mapping[i] < 0 and c not in mapping and votes[i, c] > 0:
            mapping[i] = c
    rest = [c for c in range(n) if c not in mapping]
    for i in range(n):
        if mapping[i] < 0:
            mapping[i] = rest.pop(0)
    out[instance >= 0] = mapping[instance[instance >= 0]]
    return out


def _sapm_step(model, Q, ok, row, L: int, params, n_inst) -> None:
    """SAPM on one frame: its labels taken (``row`` (N,) updated in place) for the points
    and markers the carrying left free."""
    keep = np.flatnonzero(ok)
    if n_inst:
        r = identify_instances(model, Q[keep], n_instances=n_inst, params=params)
        inst = _aligned(r.instance, row[keep], model.n_points, n_inst)
        new = np.where(r.labels >= 0, inst * model.n_points + r.labels, -1)
    else:
        new = identify(model, Q[keep], params=params).labels
    have = set(row[(row >= 0) & (row < L)].tolist())
    for q, lab in zip(keep, new):
        if lab >= 0 and not 0 <= row[q] < L and lab not in have:
            row[q] = lab
            have.add(int(lab))


def label_recording(model: MarkerModel, points, *, params: SAPMParams | None = None,
                    track: TrackParams | None = None,
                    n_instances: int | None = None) -> RecordingLabels:
    """Label every frame of a recording, carrying labels where markers move continuously.

    Parameters
    ----------
    model : MarkerModel
    points : (T, N, 3) array_like
        The frames' points in any order (the order may change from frame to frame), mm,
        NaN rows for absent points. Not modified.
    params : SAPMParams, optional
        The per-frame SAPM, called where carrying leaves points unlabelled.
    track : TrackParams, optional
    n_instances : int, optional
        Several instances of ``model`` in the cloud (labelled by
        :func:`identify_instances`); labels are then ``instance · M + marker``.

    Returns
    -------
    RecordingLabels
    """
    params = checked_params(model, params)
    track = TrackParams() if track is None else track
    if not isinstance(track, TrackParams):
        raise TypeError(f"track: expected a TrackParams, got {type(track).__name__}")
    X = np.asarray(points, float)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"points: expected (T, N, 3), got shape {X.shape}")
    n_inst = as_int(n_instances, "n_instances", allow_none=True)
    T, N = X.shape[:2]
    L = model.n_points * (n_inst or 1)
    labels = np.full((T, N), -1)
    carried = np.zeros((T, N), bool)
    seconds = np.zeros(T)
    last = np.full((L, 3), np.nan)                       # each label's last two positions
    before = np.full((L, 3), np.nan)
    age = np.full(L, 10 ** 6)
    next_unknown = L
    sapm = []
    for f in range(T):
        t0 = time.perf_counter()
        Q = X[f]
        ok = np.isfinite(Q).all(axis=1)
        vel = np.where((age == 0)[:, None] & np.isfinite(before), last - before, 0.0)
        pred = np.where((age <= track.max_age)[:, None], last + vel, np.nan)
        got = _carry(pred, np.linalg.norm(vel, axis=1), Q, ok, track)
        for q, lab in got.items():
            labels[f, q] = lab
            carried[f, q] = True
        # points SAPM left unlabelled are followed too (ids from L on), so that a point the
        # model does not know calls SAPM again only every ``retry`` frames
        unknown = ok & (labels[f] >= L)
        free = ok & (labels[f] < 0)
        if free.any() or (unknown.any() and f - (sapm[-1] if sapm else -10 ** 6)
                          >= track.retry):
            sapm.append(f)
            _sapm_step(model, Q, ok, labels[f], L, params, n_inst)
        for q in np.flatnonzero(ok & (labels[f] < 0)):
            labels[f, q] = next_unknown
            next_unknown += 1
        seen = labels[f] >= 0
        lab_idx = labels[f][seen]
        grow = int(lab_idx.max()) + 1 - len(last) if len(lab_idx) else 0
        if grow > 0:
            last, before = (np.vstack([a, np.full((grow + 64, 3), np.nan)])
                            for a in (last, before))
            age = np.append(age, np.full(grow + 64, 10 ** 6))
        before[lab_idx] = np.where((age[lab_idx] == 0)[:, None], last[lab_idx], np.nan)
        last[lab_idx] = Q[seen]
        age += 1
        age[lab_idx] = 0
        seconds[f] = time.perf_counter() - t0
    labels[labels >= L] = -1
    return RecordingLabels(labels=labels, carried=carried, sapm_frames=np.array(sapm, int),
                           seconds=seconds)
