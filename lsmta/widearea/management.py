"""Track birth and death (Davis 2002, §3.6).

Birth: a centroid that no target took is a ray in space. When it passes within a tolerance
(thesis: 15 mm) of a ray from another camera whose unassociated centroid is not stale
(thesis: 70 ms), a new target is created at the midpoint of the two rays' closest points.
Death: a target that fewer than two cameras have observed within a timeout (thesis:
100-300 ms) is removed — whether nobody saw it or only one camera did, since one camera
only places it on a ray.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_array, as_points, as_scalar

PARALLEL_SIN = 0.02  # rays closer to parallel than about 1.1 degrees never give a birth


@dataclass(frozen=True)
class Birth:
    """New targets from pairs of rays.

    Attributes
    ----------
    points : (B, 3) array
        Midpoints of the rays' closest points, mm.
    new : (B,) int array
        Index of the new ray of each pair.
    pool : (B,) int array
        Index of the pooled (earlier) ray of each pair.
    distance : (B,) array
        Closest distance between the two rays, mm.
    """

    points: np.ndarray
    new: np.ndarray
    pool: np.ndarray
    distance: np.ndarray


def ray_distance(o1, d1, o2, d2):
    """Closest distance (mm) and midpoint of every pair of lines.

    Parameters
    ----------
    o1, d1 : (N, 3) arrays
        Origins (mm) and unit directions of the first rays.
    o2, d2 : (M, 3) arrays
        The second rays.

    Returns
    -------
    distance : (N, M) array
        NaN for near-parallel pairs or when a closest point lies behind its origin.
    midpoint : (N, M, 3) array
    """
    o1, d1 = as_points(o1, "o1"), as_points(d1, "d1")
    o2, d2 = as_points(o2, "o2"), as_points(d2, "d2")
    w = o1[:, None, :] - o2[None, :, :]
    b = d1 @ d2.T
    d = np.einsum("nc,nmc->nm", d1, w)
    e = np.einsum("mc,nmc->nm", d2, w)
    denom = 1.0 - b**2
    ok = denom > PARALLEL_SIN**2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(ok, (b * e - d) / denom, np.nan)
        t = np.where(ok, (e - b * d) / denom, np.nan)
    p1 = o1[:, None, :] + s[..., None] * d1[:, None, :]
    p2 = o2[None, :, :] + t[..., None] * d2[None, :, :]
    dist = np.linalg.norm(p1 - p2, axis=2)
    dist = np.where(ok & (s > 0) & (t > 0), dist, np.nan)
    return dist, 0.5 * (p1 + p2)


def find_birth(origins, directions, stamp: float, camera: int, pool_origins, pool_directions,
               pool_stamps, pool_cameras, *, tolerance: float = 15.0, staleness: float = 0.070,
               volume=None) -> Birth:
    """Pair new unassociated rays with pooled ones from other cameras (greedy, closest first).

    Parameters
    ----------
    origins, directions : (N, 3) arrays
        The new frame's unassociated rays (mm, unit directions).
    stamp : float
        Their time stamp, s.
    camera : int
        Their camera.
    pool_origins, pool_directions : (P, 3) arrays
        Earlier unassociated rays.
    pool_stamps : (P,) array
        Their time stamps, s.
    pool_cameras : (P,) int array
        Their cameras.
    tolerance : float
        Largest closest distance between two rays of the same target, mm.
    staleness : float
        Pooled rays older than this relative to ``stamp`` are ignored, s.
    volume : (2, 3) array, optional
        Lower and upper corners of the box where births may happen, mm.

    Returns
    -------
    Birth
    """
    tolerance = as_scalar(tolerance, "tolerance", positive=True)
    staleness = as_scalar(staleness, "staleness", nonnegative=True)
    pool_stamps = as_array(pool_stamps, "pool_stamps", shape=(None,))
    pool_cameras = np.asarray(pool_cameras)
    empty = Birth(points=np.zeros((0, 3)), new=np.zeros(0, np.int64), pool=np.zeros(0, np.int64),
                  distance=np.zeros(0))
    if len(origins) == 0 or len(pool_stamps) == 0:
        return empty
    dist, mid = ray_distance(origins, directions, pool_origins, pool_directions)
    fresh = (np.abs(stamp - pool_stamps) <= staleness) & (pool_cameras != camera)
    ok = np.isfinite(dist) & (dist <= tolerance) & fresh[None, :]
    if volume is not None:
        box = as_array(volume, "volume", shape=(2, 3))
        ok &= np.all((mid >= box[0]) & (mid <= box[1]), axis=2)
    cost = np.where(ok, dist, np.inf)
    new, pool, dists, points = [], [], [], []
    while np.isfinite(cost).any():
        i, j = np.unravel_index(np.argmin(cost), cost.shape)
        new.append(i)
        pool.append(j)
        dists.append(cost[i, j])
        points.append(mid[i, j])
        cost[i, :] = np.inf
        cost[:, j] = np.inf
    if not new:
        return empty
    return Birth(points=np.asarray(points), new=np.asarray(new, np.int64),
                 pool=np.asarray(pool, np.int64), distance=np.asarray(dists))


@dataclass
class RayPool:
    """Unassociated rays waiting for a partner from another camera (mutable; one per run).

    Attributes
    ----------
    origins, directions : (P, 3) arrays
        Ray origins (mm) and unit directions.
    stamps : (P,) array
        Their time stamps, s.
    cameras : (P,) int array
        Their cameras.
    """

    origins: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    stamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cameras: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def refresh(self, stamp: float, camera: int, staleness: float) -> None:
        """Forget rays older than ``staleness`` s before ``stamp`` and rays of ``camera``."""
        self.keep((self.stamps >= stamp - staleness) & (self.cameras != camera))

    def keep(self, mask) -> None:
        """Keep the rays where ``mask`` (P,) is True."""
        self.origins, self.directions = self.origins[mask], self.directions[mask]
        self.stamps, self.cameras = self.stamps[mask], self.cameras[mask]

    def add(self, origins, directions, stamp: float, camera: int) -> None:
        """Add one frame's rays."""
        n = len(origins)
        self.origins = np.concatenate([self.origins, origins])
        self.directions = np.concatenate([self.directions, directions])
        self.stamps = np.concatenate([self.stamps, np.full(n, stamp)])
        self.cameras = np.concatenate([self.cameras, np.full(n, camera, dtype=np.int64)])

    def births(self, origins, directions, stamp: float, camera: int, *, tolerance: float,
               staleness: float, volume=None) -> Birth:
        """:func:`find_birth` of a frame's rays against this pool."""
        return find_birth(origins, directions, stamp, camera, self.origins, self.directions,
                          self.stamps, self.cameras, tolerance=tolerance, staleness=staleness,
                          volume=volume)


def starved(now: float, last_seen, timeout: float) -> np.ndarray:
    """Targets to remove: fewer than two cameras saw them within ``timeout`` s of ``now``.

    Parameters
    ----------
    now : float
        The estimator's time, s.
    last_seen : (M, K) array
        When camera k last observed target m (s; -inf if never).
    timeout : float
        Seconds (thesis: 0.1-0.3).

    Returns
    -------
    (M,) bool array
    """
    last = np.asarray(last_seen, dtype=float)
    if last.ndim != 2:
        raise ValueError("last_seen: expected an (M, K) array of times")
    timeout = as_scalar(timeout, "timeout", positive=True)
    return (last > now - timeout).sum(axis=1) < 2
