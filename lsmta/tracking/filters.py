"""The two trajectory filters of the LSMTA paper (Fig. 12).

*Threshold filter*: a trajectory whose speed over the step into a frame
(:attr:`Trajectories.step_speed`) exceeds ``max_speed`` (mm/s), or whose acceleration
exceeds ``max_acceleration`` (mm/s²), fails in that frame (a jump fails where it lands).

*Uniformity filter*: space is divided into cubic voxels of ``voxel`` mm; in every frame the
mean velocity of the trajectories in each voxel is computed, pooled over ``window`` frames
either side (local in space and time). A trajectory whose velocity differs from its local
mean (of the *other* trajectories: its own velocity is left out) by more than
``max_deviation`` mm/s fails in that frame; voxels with fewer than ``min_neighbours`` other
trajectories give no verdict.

*Drift filter* (ours, not in the paper): the uniformity test applied to the displacement
accumulated over ``window`` frames instead of the per-frame velocity. A trajectory that slides
slowly off its surface point (a millimetre a frame) looks slow and locally uniform in every
single frame, but its drift adds up while its neighbours' local motion does not. For each
frame t and each trajectory present at t - window and t, the displacement x[t] - x[t-window]
is compared with the displacement predicted at its position from its ``k`` nearest
neighbours (within ``radius`` mm at frame t - window, the trajectory itself left out): a
local affine motion fitted by least squares (``local="affine"``; it follows the rotation of
a limb, which a mean would not) or the component-wise median of their displacements
(``local="median"``, robust). A deviation above ``max_drift`` mm fails the trajectory at t.

A failing trajectory is *truncated* at its first failure (the positions from that frame on
become NaN); if fewer than ``min_length`` frames remain, it is *removed*. Each filter
reports what it removed or truncated, and why.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar
from .trajectories import Trajectories


class Reason(enum.IntEnum):
    """Why a filter cut a trajectory."""

    KEPT = 0
    SPEED = 1          #: speed above the threshold
    ACCELERATION = 2   #: acceleration above the threshold
    NOT_UNIFORM = 3    #: velocity differs from the local mean
    DRIFT = 4          #: accumulated displacement differs from the neighbours' local motion


@dataclass(frozen=True)
class FilterReport:
    """What one filter did to N trajectories.

    Attributes
    ----------
    trajectories : Trajectories
        The filtered trajectories (same N; cut frames are NaN).
    cut_frame : (N,) int array
        First removed frame (-1: untouched).
    removed : (N,) bool array
        Removed entirely (cut before ``min_length`` frames remained).
    truncated : (N,) bool array
        Cut, but at least ``min_length`` frames kept.
    reason : (N,) int array
        :class:`Reason` of the cut.
    """

    trajectories: Trajectories
    cut_frame: np.ndarray
    removed: np.ndarray
    truncated: np.ndarray
    reason: np.ndarray

    def summary(self) -> dict:
        """Counts of removed and truncated trajectories per reason."""
        out = {}
        for r in Reason:
            if r == Reason.KEPT:
                continue
            sel = self.reason == r
            out[r.name.lower()] = {"removed": int((sel & self.removed).sum()),
                                   "truncated": int((sel & self.truncated).sum())}
        return out


def _cut(traj: Trajectories, fail, reasons, min_length: int) -> FilterReport:
    """Truncate each trajectory at its first failing frame (fail (T, N), reasons (T, N))."""
    T, N = fail.shape
    any_fail = fail.any(axis=0)
    first = np.where(any_fail, fail.argmax(axis=0), -1)
    keep = np.ones((T, N), bool)
    frames = np.arange(T)[:, None]
    keep &= ~(any_fail[None, :] & (frames >= first[None, :]))
    before = traj.present
    left = (before & keep).sum(axis=0)
    removed = any_fail & (left < min_length)
    keep[:, removed] = False
    reason = np.zeros(N, np.int64)
    reason[any_fail] = reasons[first[any_fail], np.flatnonzero(any_fail)]
    return FilterReport(trajectories=traj.keep_frames(keep), cut_frame=first,
                        removed=removed & before.any(axis=0),
                        truncated=any_fail & ~removed, reason=reason)


def _check(traj, min_length):
    if not isinstance(traj, Trajectories):
        raise TypeError(f"trajectories: expected lsmta.tracking.Trajectories, got "
                        f"{type(traj).__name__}")
    as_int(min_length, "min_length", unit="frames")


def threshold_filter(trajectories: Trajectories, *, max_speed: float = 3000.0,
                     max_acceleration: float = 30000.0, min_length: int = 3) -> FilterReport:
    """Cut trajectories where speed or acceleration exceed their thresholds.

    Parameters
    ----------
    trajectories : Trajectories
    max_speed : float
        mm/s.
    max_acceleration : float
        mm/s².
    min_length : int
        A trajectory left with fewer frames is removed.
    """
    _check(trajectories, min_length)
    max_speed = as_scalar(max_speed, "max_speed", positive=True)
    max_acceleration = as_scalar(max_acceleration, "max_acceleration", positive=True)
    with np.errstate(invalid="ignore"):
        fast = trajectories.step_speed > max_speed
        jerk = np.linalg.norm(trajectories.acceleration, axis=2) > max_acceleration
    reasons = np.where(fast, Reason.SPEED, Reason.ACCELERATION)
    return _cut(trajectories, fast | jerk, reasons, min_length)


def uniformity_filter(trajectories: Trajectories, *, voxel: float = 100.0,
                      max_deviation: float = 400.0, window: int = 1, min_neighbours: int = 3,
                      min_length: int = 3) -> FilterReport:
    """Cut trajectories whose velocity differs from the local mean (space and time).

    Parameters
    ----------
    trajectories : Trajectories
    voxel : float
        Voxel edge in mm.
    max_deviation : float
        Largest accepted distance between a velocity and its local mean, mm/s.
    window : int
        Frames either side pooled into the local mean.
    min_neighbours : int
        Fewest other trajectories in the voxel (over the window) for a verdict.
    min_length : int
        A trajectory left with fewer frames is removed.
    """
    _check(trajectories, min_length)
    voxel = as_scalar(voxel, "voxel", positive=True)
    max_deviation = as_scalar(max_deviation, "max_deviation", positive=True)
    as_int(window, "window", minimum=0, unit="frames")
    x = trajectories.xyz
    v = trajectories.velocity
    T, N, _ = x.shape
    ok = np.isfinite(v).all(axis=2) & np.isfinite(x).all(axis=2)
    tt, nn = np.nonzero(ok)
    fail = np.zeros((T, N), bool)
    if tt.size == 0:
        return _cut(trajectories, fail, np.zeros((T, N), np.int64), min_length)
    vox = np.floor(x[tt, nn] / voxel).astype(np.int64)
    vox -= vox.min(axis=0)
    span = vox.max(axis=0) + 1
    cell = (vox[:, 0] * span[1] + vox[:, 1]) * span[2] + vox[:, 2]
    key = cell * T + tt
    uniq, inv = np.unique(key, return_inverse=True)
    sums = np.zeros((len(uniq), 3))
    np.add.at(sums, inv, v[tt, nn])
    counts = np.bincount(inv, minlength=len(uniq)).astype(float)
    # pool each observation's voxel over the time window
    tot = np.zeros((len(tt), 3))
    cnt = np.zeros(len(tt))
    for d in range(-int(window), int(window) + 1):
        want = cell * T + (tt + d)
        valid = (tt + d >= 0) & (tt + d < T)
        pos = np.searchsorted(uniq, want)
        hit = valid & (pos < len(uniq))
        hit[hit] &= uniq[pos[hit]] == want[hit]
        tot[hit] += sums[pos[hit]]
        cnt[hit] += counts[pos[hit]]
    # leave the trajectory's own velocities out of its local mean
    cellmap = np.full((T, N), -1, np.int64)
    cellmap[tt, nn] = cell
    own = np.zeros((len(tt), 3))
    own_n = np.zeros(len(tt))
    for d in range(-int(window), int(window) + 1):
        ts = tt + d
        valid = (ts >= 0) & (ts < T)
        same = np.zeros(len(tt), bool)
        same[valid] = cellmap[ts[valid], nn[valid]] == cell[valid]
        own[same] += v[ts[same], nn[same]]
        own_n[same] += 1
    others = cnt - own_n
    judged = others >= min_neighbours
    mean = np.where(judged[:, None], (tot - own) / np.maximum(others, 1)[:, None], np.nan)
    dev = np.linalg.norm(v[tt, nn] - mean, axis=1)
    bad = judged & (dev > max_deviation)
    fail[tt[bad], nn[bad]] = True
    return _cut(trajectories, fail, np.full((T, N), int(Reason.NOT_UNIFORM)), min_length)




def _local_prediction(centre, p, d, nb, valid, local: str, ridge: float):
    """Displacement predicted at m points from their neighbours.

    centre : (m, 3) the points; p, d : (n, 3) all positions and displacements;
    nb, valid : (m, k) neighbour indices into p and which of them count. Returns (m, 3).
    """
    if local == "median":
        return np.nanmedian(np.where(valid[..., None], d[nb], np.nan), axis=1)
    # affine: d_j = b + A (p_j - p_i), weighted least squares with a small ridge on A
    # (a patch of surface is nearly flat, so A is undetermined along its normal); b is the
    # prediction at the point itself
    w = valid.astype(float)[..., None]
    rel = p[nb] - centre[:, None]
    design = np.concatenate([np.ones(rel.shape[:2] + (1,)), rel], axis=2) * w
    lhs = np.einsum("nki,nkj->nij", design, design) + np.diag([0.0, ridge, ridge, ridge])
    rhs = np.einsum("nki,nkj->nij", design, d[nb] * w)
    return np.linalg.solve(lhs, rhs)[:, 0]


def drift_deviation(trajectories: Trajectories, *, window: int = 10, k: int = 10,
                    radius: float = 200.0, min_neighbours: int = 5,
                    local: str = "affine", ridge: float = 100.0) -> np.ndarray:
    """Deviation of each trajectory's accumulated displacement from its neighbours' motion.

    Parameters
    ----------
    trajectories : Trajectories
    window : int
        Frames over which the displacement is accumulated (>= 1).
    k : int
        Neighbours considered (nearest at frame t - window).
    radius : float
        Farthest neighbour, mm.
    min_neighbours : int
        Fewest neighbours within ``radius`` for a verdict.
    local : {"affine", "median"}
        Local motion model of the neighbours.
    ridge : float
        Ridge on the affine part (mm², per neighbour weight); ``"affine"`` only.

    Returns
    -------
    (T, N) array
        |displacement - predicted| in mm at frame t (NaN: no verdict).
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"trajectories: expected lsmta.tracking.Trajectories, got "
                        f"{type(trajectories).__name__}")
    for name, val in (("window", window), ("k", k), ("min_neighbours", min_neighbours)):
        as_int(val, name)
    if min_neighbours > k:
        raise ValueError(f"min_neighbours: expected at most k={k}, got {min_neighbours}")
    radius = as_scalar(radius, "radius", positive=True)
    ridge = as_scalar(ridge, "ridge", nonnegative=True)
    if local not in ("affine", "median"):
        raise ValueError(f"local: expected 'affine' or 'median', got {local!r}")
    x = trajectories.xyz
    T, N, _ = x.shape
    window, k = int(window), int(k)
    present = trajectories.present
    dev = np.full((T, N), np.nan)
    for t in range(window, T):
        idx = np.flatnonzero(present[t - window] & present[t])
        if len(idx) < min_neighbours + 1:
            continue
        p = x[t - window, idx]
        d = x[t, idx] - p
        dist, nb = cKDTree(p).query(p, k=min(k + 1, len(idx)), distance_upper_bound=radius)
        # the nearest is the point itself: leave it out
        dist, nb = dist[:, 1:], np.minimum(nb[:, 1:], len(idx) - 1)
        valid = np.isfinite(dist)
        judged = valid.sum(axis=1) >= min_neighbours
        if not judged.any():
            continue
        pred = _local_prediction(p[judged], p, d, nb[judged], valid[judged], local, ridge)
        dev[t, idx[judged]] = np.linalg.norm(d[judged] - pred, axis=1)
    return dev


def drift_filter(trajectories: Trajectories, *, max_drift: float = 8.0, window: int = 10,
                 k: int = 10, radius: float = 200.0, min_neighbours: int = 5,
                 local: str = "affine", ridge: float = 100.0,
                 min_length: int = 3) -> FilterReport:
    """Cut trajectories whose displacement over ``window`` frames leaves the local motion.

    The uniformity test of the paper on accumulated instead of per-frame motion (ours; see
    the module docstring). Parameters as :func:`drift_deviation`, and

    max_drift : float
        Largest accepted deviation, mm.
    min_length : int
        A trajectory left with fewer frames is removed.

    The trajectory is truncated at the first frame t whose window fails.
    """
    _check(trajectories, min_length)
    max_drift = as_scalar(max_drift, "max_drift", positive=True)
    dev = drift_deviation(trajectories, window=window, k=k, radius=radius,
                          min_neighbours=min_neighbours, local=local, ridge=ridge)
    with np.errstate(invalid="ignore"):
        fail = dev > max_drift
    return _cut(trajectories, fail, np.full(fail.shape, int(Reason.DRIFT)), min_length)


def apply_filters(trajectories: Trajectories, *, max_speed: float = 2000.0,
                  max_acceleration: float = 40000.0, voxel: float = 150.0,
                  max_deviation: float = 400.0, window: int = 10, max_drift: float = 8.0,
                  local: str = "affine") -> tuple[FilterReport, FilterReport, FilterReport]:
    """The paper's two filters, then ours, in a chain (notebook 05's committed values).

    :func:`threshold_filter` (``max_speed`` mm/s, ``max_acceleration`` mm/s²), then
    :func:`uniformity_filter` on its result (``voxel`` mm, ``max_deviation`` mm/s), then
    :func:`drift_filter` on that (``window`` frames, ``max_drift`` mm, ``local``).

    Returns
    -------
    (FilterReport, FilterReport, FilterReport)
        The three reports; the last one's ``trajectories`` is the final result.
    """
    first = threshold_filter(trajectories, max_speed=max_speed,
                             max_acceleration=max_acceleration)
    second = uniformity_filter(first.trajectories, voxel=voxel, max_deviation=max_deviation)
    third = drift_filter(second.trajectories, window=window, max_drift=max_drift, local=local)
    return first, second, third
