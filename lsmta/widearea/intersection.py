"""The synchronised alternative to the Kalman integration (Davis 2002, §3.4, Fig. 33):
3-D points by intersecting rays separately at each time instant.

Commercial systems synchronise their cameras, so that the frames of one instant see the
same scene and "all points at which several rays intersect are determined to be the 3D
location of a target". Run on unsynchronised cameras, this method treats the frame of
every camera nearest to an instant as taken at that instant. :func:`intersect_instants`
does exactly that: per instant, each camera's frame whose stamp is nearest (within half a
period), all its centroids as rays; pairs of rays of different cameras that pass within
``tolerance`` start a point (closest first), every further ray within ``tolerance`` of it
joins (one ray per camera), and each point is the least-squares intersection of its rays
(:func:`lsmta.triangulation.intersect_rays`). The points carry no identity from one instant
to the next.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_scalar
from ..camera import Camera
from ..triangulation import intersect_rays
from .management import ray_distance
from .observations import Frames


@dataclass(frozen=True)
class InstantPoints:
    """Points intersected at T instants.

    Attributes
    ----------
    times : (T,) array
        The instants, s.
    start : (T + 1,) int array
        Instant ``t`` holds points ``start[t]:start[t + 1]``.
    points : (P, 3) array
        mm.
    n_rays : (P,) int array
        Rays (cameras) of each point.
    """

    times: np.ndarray
    start: np.ndarray
    points: np.ndarray
    n_rays: np.ndarray

    def at(self, t: int) -> np.ndarray:
        """The ``(n, 3)`` points of instant ``t``."""
        return self.points[self.start[t]:self.start[t + 1]]


def intersect_instants(cameras, frames: Frames, times, *, window: float,
                       tolerance: float = 15.0, min_rays: int = 2) -> InstantPoints:
    """Per-instant ray intersection (see the module).

    Parameters
    ----------
    cameras : sequence of K Camera
    frames : Frames
        Every camera's frames (any order; stamps by each camera's clock).
    times : (T,) array
        The instants, s.
    window : float
        A camera's frame belongs to an instant when its stamp is within ``window / 2`` of
        it (the nearest such frame), s.
    tolerance : float
        Largest distance of a ray from a point's rays (closest approach), mm.
    min_rays : int
        Points with fewer rays are left out.

    Returns
    -------
    InstantPoints
    """
    cams = list(cameras)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    if not isinstance(frames, Frames):
        raise TypeError("frames: expected lsmta.widearea.Frames")
    times = as_array(times, "times", shape=(None,))
    half = 0.5 * as_scalar(window, "window", positive=True)
    tolerance = as_scalar(tolerance, "tolerance", positive=True)
    min_rays = as_int(min_rays, "min_rays", minimum=2)
    ok = (frames.camera >= 0) & (frames.camera < len(cams)) & np.isfinite(frames.stamp)
    per_cam = [np.flatnonzero(ok & (frames.camera == k)) for k in range(len(cams))]
    per_cam = [f[np.argsort(frames.stamp[f], kind="stable")] for f in per_cam]
    pts, nr, start = [], [], [0]
    for t in times:
        o, d, cam = _rays_at(cams, frames, per_cam, t, half)
        P, n = _cluster(o, d, cam, tolerance, min_rays)
        pts.append(P)
        nr.append(n)
        start.append(start[-1] + len(P))
    return InstantPoints(times=times, start=np.asarray(start, np.int64),
                         points=np.concatenate(pts) if pts else np.zeros((0, 3)),
                         n_rays=np.concatenate(nr).astype(np.int64) if nr
                         else np.zeros(0, np.int64))


def _rays_at(cams, frames: Frames, per_cam, t: float, half: float):
    """The rays of every camera's frame nearest instant ``t`` (within ``half`` s)."""
    o, d, cam = [], [], []
    for k, idx in enumerate(per_cam):
        if not len(idx):
            continue
        s = frames.stamp[idx]
        i = int(np.clip(np.searchsorted(s, t), 1, len(s) - 1)) if len(s) > 1 else 0
        if len(s) > 1 and abs(s[i - 1] - t) <= abs(s[i] - t):
            i -= 1
        if abs(s[i] - t) > half:
            continue
        xy = frames.centroids(idx[i])
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            ok, dk = cams[k].rays(xy)
            o.append(ok)
            d.append(dk)
            cam.append(np.full(len(xy), k))
    if not o:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(o), np.concatenate(d), np.concatenate(cam)


def _cluster(o, d, cam, tolerance: float, min_rays: int):
    """Greedy: the closest pair of free rays of different cameras starts a point, every
    free ray of another camera within ``tolerance`` of the pair's midpoint joins it; points
    are the least-squares intersections of their rays."""
    n = len(o)
    if n < 2:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    dist, mid = ray_distance(o, d, o, d)
    dist = np.where(cam[:, None] != cam[None, :], dist, np.nan)
    cost = np.where(np.isfinite(dist) & (dist <= tolerance), dist, np.inf)
    free = np.ones(n, bool)
    groups = []
    while np.isfinite(cost).any():
        i, j = np.unravel_index(np.argmin(cost), cost.shape)
        w = mid[i, j] - o
        perp = np.linalg.norm(w - np.einsum("nc,nc->n", w, d)[:, None] * d, axis=1)
        members = [i, j]
        for r in np.argsort(perp):
            if perp[r] > tolerance:
                break
            if free[r] and r not in members and cam[r] not in cam[members]:
                members.append(r)
        free[members] = False
        cost[members, :] = np.inf
        cost[:, members] = np.inf
        if len(members) >= min_rays:
            groups.append(members)
    if not groups:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    inter = _intersect(groups, o, d)
    return inter.points[inter.valid], inter.n_rays[inter.valid]


def _intersect(groups, o, d):
    """Least-squares intersections of groups of rays."""
    K = max(len(g) for g in groups)
    O = np.full((K, len(groups), 3), np.nan)
    D = np.full((K, len(groups), 3), np.nan)
    for g, members in enumerate(groups):
        O[:len(members), g] = o[members]
        D[:len(members), g] = d[members]
    return intersect_rays(O, D, min_angle_deg=0.0)
