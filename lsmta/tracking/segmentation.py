"""Which trajectories move together: rigid groups of 3-D trajectories.

A body is articulated: points on one segment keep their distances while the segment
moves, points on two segments do not. This module splits filtered trajectories into such
rigid groups, with no model of the body, in four steps:

1. *Rigidity of pairs.* For trajectories with at least ``min_length`` frames (at most
   ``max_sample`` of them, drawn at random), the standard deviation of each pair's
   distance over the frames both are present in (at least ``min_common``); pairs that
   share fewer frames count as far apart (``10 tolerance``).
2. *Clustering.* Average-linkage clustering of that dissimilarity
   (:func:`scipy.cluster.hierarchy.linkage`), cut at ``tolerance`` mm; clusters with
   fewer than ``min_size`` members are dropped.
3. *Motion of each group.* A group's frame is its members' positions in its reference
   frame (the frame in which most of them are present); its pose in every other frame is
   the least-squares rigid motion (:func:`~lsmta.rigid.fit_rigid`) of the members with
   known group coordinates, stepping forward and backward from the reference and giving
   members that appear later their group coordinates on the way. Groups whose relative
   pose stays constant over the frames they share are one body, and are merged.
4. *Assignment.* Every trajectory (sampled or not) joins the group whose motion explains
   it best, if its RMS deviation from that motion is below ``tolerance`` over at least
   ``min_common`` frames; otherwise it stays unassigned (label -1).

Poses map group coordinates to the world: ``x_world = R x_group + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import squareform

from .._validate import as_int, as_scalar
from ..rigid import apply_rigid, fit_rigid
from .trajectories import Trajectories


@dataclass(frozen=True)
class RigidGroups:
    """Trajectories split into rigidly moving groups.

    Attributes
    ----------
    label : (N,) int array
        Group of each trajectory, -1 for none (largest group first).
    rotation : (G, T, 3, 3) array
        Rotation of each group's frame in each frame (NaN where unknown).
    translation : (G, T, 3) array
        Its translation, mm (NaN where unknown).
    local : (N, 3) array
        Each assigned trajectory's position in its group's frame, mm (NaN if unassigned).
    deviation : (N,) array
        RMS distance of each assigned trajectory from its group's motion, mm.
    reference : (G,) int array
        The frame in which each group's frame coincides with the world.
    """

    label: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    local: np.ndarray
    deviation: np.ndarray
    reference: np.ndarray

    @property
    def n_groups(self) -> int:
        return self.rotation.shape[0]

    @property
    def sizes(self) -> np.ndarray:
        """``(G,)`` trajectories per group."""
        return np.bincount(self.label[self.label >= 0], minlength=self.n_groups)

    @property
    def known(self) -> np.ndarray:
        """``(G, T)`` bool: the group's pose is known in that frame."""
        return np.isfinite(self.translation).all(axis=2)

    def poses(self, group: int) -> np.ndarray:
        """``(T, 4, 4)`` homogeneous poses of one group (NaN where unknown)."""
        T = self.rotation.shape[1]
        P = np.full((T, 4, 4), np.nan)
        P[:, :3, :3] = self.rotation[group]
        P[:, :3, 3] = self.translation[group]
        P[:, 3] = [0.0, 0.0, 0.0, 1.0]
        return P


def _pair_spread(X: np.ndarray, min_common: int, far: float) -> np.ndarray:
    """``(n, n)`` standard deviation of each pair's distance over their common frames."""
    n = X.shape[1]
    s1 = np.zeros((n, n))
    s2 = np.zeros((n, n))
    cnt = np.zeros((n, n))
    for x in X:
        ok = np.isfinite(x).all(axis=1)
        idx = np.flatnonzero(ok)
        d = np.linalg.norm(x[idx, None] - x[None, idx], axis=2)
        ix = np.ix_(idx, idx)
        s1[ix] += d
        s2[ix] += d * d
        cnt[ix] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / cnt
        sd = np.sqrt(np.clip(s2 / cnt - mean**2, 0.0, None))
    sd = np.where(cnt >= min_common, sd, far)
    np.fill_diagonal(sd, 0.0)
    return sd


def _group_motion(X: np.ndarray, members: np.ndarray, tolerance: float):
    """Poses ``R (T, 3, 3)``, ``t (T, 3)`` of one group and its reference frame.

    Steps out from the reference frame; in each frame the rigid fit is done twice, the
    second time without members more than ``3 tolerance`` off the first fit.
    """
    T = X.shape[0]
    present = np.isfinite(X[:, members]).all(axis=2)
    ref = int(np.argmax(present.sum(axis=1)))
    local = np.full((len(members), 3), np.nan)
    local[present[ref]] = X[ref, members[present[ref]]]
    R = np.full((T, 3, 3), np.nan)
    t = np.full((T, 3), np.nan)
    R[ref], t[ref] = np.eye(3), np.zeros(3)
    for order in (range(ref + 1, T), range(ref - 1, -1, -1)):
        for f in order:
            use = present[f] & np.isfinite(local).all(axis=1)
            if use.sum() < 4:
                continue
            P, Q = local[use], X[f, members[use]]
            Rf, tf = fit_rigid(P, Q)
            good = np.linalg.norm(apply_rigid(Rf, tf, P) - Q, axis=1) <= 3 * tolerance
            if good.sum() < 4:
                continue
            R[f], t[f] = fit_rigid(P[good], Q[good])
            new = present[f] & ~np.isfinite(local).all(axis=1)
            local[new] = (X[f, members[new]] - t[f]) @ R[f]
    return R, t, ref


def _explain(X: np.ndarray, R: np.ndarray, t: np.ndarray, min_common: int):
    """Group coordinates ``(N, 3)`` of every trajectory under one group's motion and its
    RMS deviation from it ``(N,)`` (inf with fewer than ``min_common`` common frames)."""
    known = np.isfinite(t).all(axis=1)
    Rk, tk, Xk = R[known], t[known], X[known]                   # (F, ...), (F, N, 3)
    loc = np.einsum("fji,fnj->fni", Rk, Xk - tk[:, None])      # world -> group
    ok = np.isfinite(loc).all(axis=2)
    n = ok.sum(axis=0)
    mean = np.where(n[:, None] > 0, np.nansum(np.where(ok[..., None], loc, 0.0), axis=0)
                    / np.maximum(n, 1)[:, None], np.nan)
    back = np.einsum("fij,nj->fni", Rk, mean) + tk[:, None]
    d2 = np.where(ok, np.sum((back - Xk) ** 2, axis=2), 0.0)
    dev = np.sqrt(d2.sum(axis=0) / np.maximum(n, 1))
    return mean, np.where(n >= min_common, dev, np.inf)


def _same_body(Ra, ta, Rb, tb, local_b, min_common, tolerance) -> bool:
    """Do two groups keep a constant relative pose over the frames they share?"""
    both = np.isfinite(ta).all(axis=1) & np.isfinite(tb).all(axis=1)
    if both.sum() < min_common or not len(local_b):
        return False
    world = np.einsum("fij,nj->fni", Rb[both], local_b) + tb[both][:, None]
    in_a = np.einsum("fji,fnj->fni", Ra[both], world - ta[both][:, None])
    spread = np.sqrt(np.mean(np.sum((in_a - in_a.mean(axis=0)) ** 2, axis=2)))
    return bool(spread < tolerance)


def rigid_groups(trajectories: Trajectories, *, tolerance: float = 4.0, min_length: int = 6,
                 min_common: int = 5, min_size: int = 12, max_sample: int = 700,
                 rng: np.random.Generator | int | None = None) -> RigidGroups:
    """Split trajectories into groups that move rigidly (see the module docstring).

    Parameters
    ----------
    trajectories : Trajectories
        Filtered trajectories, ``(T, N, 3)`` mm.
    tolerance : float
        Largest spread of a pair's distance, and largest RMS deviation of a trajectory
        from its group's motion, for points on one rigid body, mm (a few times the
        points' 3-D noise).
    min_length : int
        Trajectories shorter than this do not take part in the clustering.
    min_common : int
        Frames two trajectories (or a trajectory and a group) must share to be compared.
    min_size : int
        Smallest group.
    max_sample : int
        At most this many trajectories are clustered (the pairwise step is quadratic).
    rng : numpy.random.Generator, int or None
        Draws the sample when there are more candidates than ``max_sample``.

    Returns
    -------
    RigidGroups
        No group at all (``n_groups == 0``) when no cluster reaches ``min_size``.
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"trajectories: expected lsmta.tracking.Trajectories, got "
                        f"{type(trajectories).__name__}")
    tolerance = as_scalar(tolerance, "tolerance", positive=True)
    for name, v, lo in (("min_length", min_length, 2), ("min_common", min_common, 2),
                        ("min_size", min_size, 4), ("max_sample", max_sample, 2)):
        as_int(v, name, minimum=lo)
    rng = np.random.default_rng(rng)
    X = np.asarray(trajectories.xyz)
    cand = np.flatnonzero(trajectories.length >= min_length)
    if len(cand) > max_sample:
        cand = np.sort(rng.choice(cand, max_sample, replace=False))
    groups = _clusters(X, cand, tolerance, min_common, min_size)
    motions = [_group_motion(X, m, tolerance) for m in groups]
    _merge_bodies(X, groups, motions, min_common, tolerance)
    label, loc, dev = _assign(X, motions, min_common, tolerance)
    return _largest_first(label, loc, dev, motions, min_size, X.shape[0])


def _clusters(X, cand, tolerance: float, min_common: int, min_size: int) -> list:
    """Steps 1 and 2: average-linkage clusters of the candidates ``cand`` by the spread
    of their pair distances, those with at least ``min_size`` members."""
    groups = []
    if len(cand) >= min_size:
        sd = _pair_spread(X[:, cand], min_common, 10 * tolerance)
        cut = fcluster(linkage(squareform(sd, checks=False), "average"), tolerance,
                       criterion="distance")
        for c in np.unique(cut):
            members = cand[cut == c]
            if len(members) >= min_size:
                groups.append(members)
    return groups


def _merge_bodies(X, groups: list, motions: list, min_common: int, tolerance: float) -> None:
    """Step 3: merge (in place) groups that keep a constant relative pose, one pair at a
    time, until no pair is one body."""
    merged = True
    while merged and len(groups) > 1:
        merged = False
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                Ra, ta, _ = motions[a]
                Rb, tb, _ = motions[b]
                lb, _ = _explain(X[:, groups[b]], Rb, tb, 1)
                if _same_body(Ra, ta, Rb, tb, lb[np.isfinite(lb).all(axis=1)],
                              min_common, tolerance):
                    groups[a] = np.union1d(groups[a], groups[b])
                    motions[a] = _group_motion(X, groups[a], tolerance)
                    del groups[b], motions[b]
                    merged = True
                    break
            if merged:
                break


def _assign(X, motions: list, min_common: int, tolerance: float):
    """Step 4: every trajectory's group (the motion that explains it best, -1 if none
    within ``tolerance``), and its coordinates ``(G, N, 3)`` and deviations ``(G, N)``
    under every group's motion."""
    N = X.shape[1]
    G = len(motions)
    dev = np.full((G, N), np.inf)
    loc = np.full((G, N, 3), np.nan)
    for g, (R, t, _) in enumerate(motions):
        loc[g], dev[g] = _explain(X, R, t, min_common)
    label = np.full(N, -1)
    if G:
        best = np.argmin(dev, axis=0)
        ok = dev[best, np.arange(N)] < tolerance
        label[ok] = best[ok]
    return label, loc, dev


def _largest_first(label, loc, dev, motions: list, min_size: int, T: int) -> RigidGroups:
    """The result with the largest group first; groups left with fewer than ``min_size``
    members are dropped (their trajectories unassigned)."""
    G, N = dev.shape
    sizes = np.bincount(label[label >= 0], minlength=G)
    order = [g for g in np.argsort(-sizes, kind="stable") if sizes[g] >= min_size]
    remap = np.full(G + 1, -1)
    remap[np.asarray(order, int)] = np.arange(len(order))
    label = remap[label]
    rot = np.stack([motions[g][0] for g in order]) if order else np.zeros((0, T, 3, 3))
    trans = np.stack([motions[g][1] for g in order]) if order else np.zeros((0, T, 3))
    ref = np.array([motions[g][2] for g in order], int)
    local = np.full((N, 3), np.nan)
    deviation = np.full(N, np.nan)
    for new, g in enumerate(order):
        m = label == new
        local[m] = loc[g, m]
        deviation[m] = dev[g, m]
    return RigidGroups(label=label, rotation=rot, translation=trans, local=local,
                       deviation=deviation, reference=ref)
