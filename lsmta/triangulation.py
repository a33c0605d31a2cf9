"""Forward intersection: 3-D points from rays of two or more cameras.

The point that minimises the sum of squared perpendicular distances to its rays solves
the 3x3 system ``sum_k (I - d_k d_k^T) X = sum_k (I - d_k d_k^T) o_k`` (``o_k`` ray
origin, ``d_k`` unit direction), which this module solves for all points at once. On
noise-free rays the solution is exact up to round-off.

Near-parallel rays
    The depth of the intersection is uncertain by about ``sigma / sin(angle)`` for a
    ray uncertainty ``sigma`` and an intersection angle ``angle``; at an angle of zero the
    system is singular. A point whose largest angle between any two of its rays is below
    ``min_angle_deg`` is not intersected: its coordinates are NaN and ``valid`` is False.
    The same happens to a point seen by fewer than two cameras, and to exactly parallel
    rays (angle below ``PARALLEL_DEG``) even with ``min_angle_deg=0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validate import as_array
from .camera import Camera

# rays closer to parallel than this are never intersected, whatever min_angle_deg says
PARALLEL_DEG = 1e-6


@dataclass(frozen=True)
class Intersection:
    """Result of a forward intersection of N points from K cameras.

    Attributes
    ----------
    points : (N, 3) array
        Intersected points in mm; NaN where ``valid`` is False.
    valid : (N,) bool array
        At least two rays, and an intersection angle of at least ``min_angle_deg``.
    n_rays : (N,) int array
        How many rays each point had.
    angle_deg : (N,) array
        Largest acute angle between the lines of two of the point's rays, in degrees, in
        [0, 90] (NaN with < 2 rays).
    ray_distance : (K, N) array
        Perpendicular distance from the point to each ray, in mm (NaN for missing rays).
    reprojection_error : (K, N) array or None
        Distance in pixels between the given image point and the projected intersection
        (NaN for missing observations); None when rays, not cameras, were given.
    """

    points: np.ndarray
    valid: np.ndarray
    n_rays: np.ndarray
    angle_deg: np.ndarray
    ray_distance: np.ndarray
    reprojection_error: np.ndarray | None = None

    @property
    def rms_ray_distance(self) -> np.ndarray:
        """Root mean square ray distance per point (mm)."""
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.nanmean(self.ray_distance**2, axis=0))


def intersect_rays(origins, directions, *, min_angle_deg: float = 0.5) -> Intersection:
    """Least-squares intersection of K rays per point.

    Parameters
    ----------
    origins : (K, N, 3) array
        Ray origins in mm; NaN rows mark missing rays.
    directions : (K, N, 3) array
        Ray directions (need not be unit length); NaN rows mark missing rays.
    min_angle_deg : float
        Smallest accepted intersection angle, in degrees.

    Returns
    -------
    Intersection
    """
    o = as_array(origins, "origins", shape=(None, None, 3), allow_nan=True)
    d = as_array(directions, "directions", shape=(None, None, 3), allow_nan=True)
    if o.shape != d.shape:
        raise ValueError(f"directions: expected the shape of origins {o.shape}, got {d.shape}")
    if not 0 <= min_angle_deg < 90:
        raise ValueError(f"min_angle_deg: expected a value in [0, 90), got {min_angle_deg}")
    norms = np.linalg.norm(d, axis=2, keepdims=True)
    present = np.isfinite(o).all(axis=2) & np.isfinite(d).all(axis=2) & (norms[..., 0] > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(present[..., None], d / norms, 0.0)
    o0 = np.where(present[..., None], o, 0.0)
    n_rays = present.sum(axis=0)

    # largest pairwise angle between rays of the same point
    cos = np.einsum("knc,lnc->nkl", u, u)
    pair = present.T[:, :, None] & present.T[:, None, :]
    cos = np.where(pair, np.abs(cos), 1.0)
    with np.errstate(invalid="ignore"):
        angle = np.degrees(np.arccos(np.clip(cos.min(axis=(1, 2)), -1.0, 1.0)))
    angle = np.where(n_rays >= 2, angle, np.nan)
    valid = (n_rays >= 2) & (angle >= min_angle_deg) & (angle > PARALLEL_DEG)

    eye = np.eye(3)
    P = eye - u[..., :, None] * u[..., None, :]                # (K, N, 3, 3)
    P = P * present[..., None, None]
    A = P.sum(axis=0)
    b = np.einsum("knij,knj->ni", P, o0)
    points = np.full((o.shape[1], 3), np.nan)
    if valid.any():
        points[valid] = np.linalg.solve(A[valid], b[valid][..., None])[..., 0]

    diff = points[None] - o0
    perp = diff - np.einsum("knc,knc->kn", diff, u)[..., None] * u
    ray_distance = np.where(present, np.linalg.norm(perp, axis=2), np.nan)
    return Intersection(points=points, valid=valid, n_rays=n_rays, angle_deg=angle,
                        ray_distance=ray_distance)


def triangulate(cameras, xy, *, min_angle_deg: float = 0.5) -> Intersection:
    """Forward intersection of image points measured in K cameras.

    Parameters
    ----------
    cameras : sequence of K :class:`~lsmta.camera.Camera`
    xy : (K, N, 2) array
        Image points in pixels, one row per camera; NaN marks a point not seen by that
        camera, and so does a position where the camera's lens model cannot be inverted
        (a fitted distortion that folds over; :meth:`~lsmta.camera.Camera.invertible`).
    min_angle_deg : float
        Smallest accepted intersection angle, in degrees (see the module docstring).

    Returns
    -------
    Intersection
        With ``reprojection_error`` filled in (NaN where a camera did not see the point).
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    xy = as_array(xy, "xy", shape=(len(cameras), None, 2), allow_nan=True)
    K, N, _ = xy.shape
    origins = np.full((K, N, 3), np.nan)
    directions = np.full((K, N, 3), np.nan)
    seen = np.isfinite(xy).all(axis=2)                                     # (K, N)
    for k, cam in enumerate(cameras):
        if cam.has_distortion and seen[k].any():      # no ray where the lens model folds
            idx = np.flatnonzero(seen[k])
            seen[k, idx] = cam.invertible(xy[k, idx])
        if seen[k].any():
            origins[k, seen[k]], directions[k, seen[k]] = cam.rays(xy[k, seen[k]])
    result = intersect_rays(origins, directions, min_angle_deg=min_angle_deg)
    reproj = np.full((K, N), np.nan)
    for k, cam in enumerate(cameras):
        ok = result.valid & seen[k]
        if ok.any():
            proj = cam.project(result.points[ok], behind="nan")
            reproj[k, ok] = np.linalg.norm(proj - xy[k, ok], axis=1)
    return Intersection(points=result.points, valid=result.valid, n_rays=result.n_rays,
                        angle_deg=result.angle_deg, ray_distance=result.ray_distance,
                        reprojection_error=reproj)


@dataclass(frozen=True)
class VoxelCloud:
    """Points thinned by :func:`voxel_filter`.

    Attributes
    ----------
    points : (M, 3) array
        Centre of gravity of the input points in each occupied voxel (mm).
    members : (N,) int array
        For each input point, the index of its output point.
    counts : (M,) int array
        Input points per output point.
    """

    points: np.ndarray
    members: np.ndarray
    counts: np.ndarray

    def mean_of(self, values) -> np.ndarray:
        """Per-voxel mean of per-input-point ``values`` ``(N, ...)``, e.g. image positions."""
        values = np.asarray(values, float)
        out = np.zeros((len(self.points),) + values.shape[1:])
        used = self.members >= 0
        np.add.at(out, self.members[used], values[used])
        return out / self.counts.reshape((-1,) + (1,) * (values.ndim - 1))


def voxel_filter(points, voxel: float) -> VoxelCloud:
    """Replace the points in each cubic voxel of side ``voxel`` mm by their centre of gravity.

    Evens out the density of a point cloud and averages noise (LSMTA paper, Section 2.2).
    Non-finite rows are dropped (their ``members`` entry is -1).
    """
    P = as_array(points, "points", shape=(None, 3), allow_nan=True)
    if not voxel > 0:
        raise ValueError(f"voxel: expected a positive size in mm, got {voxel}")
    finite = np.isfinite(P).all(axis=1)
    keys = np.floor(P[finite] / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, P[finite])
    members = np.full(len(P), -1, dtype=np.int64)
    members[finite] = inverse
    return VoxelCloud(points=sums / counts[:, None], members=members, counts=counts)


@dataclass(frozen=True)
class PairIntersection:
    """Result of :func:`triangulate_single_pair`.

    Attributes
    ----------
    pair : (2,) int array
        Indices of the two cameras used for every point.
    intersection : Intersection
        The forward intersection from that pair alone (NaN where not seen by both).
    counts : (K, K) int array
        Points seen by both cameras of each pair.
    """

    pair: np.ndarray
    intersection: Intersection
    counts: np.ndarray


def triangulate_single_pair(cameras, xy, *, min_angle_deg: float = 0.5) -> PairIntersection:
    """Intersect all points of one frame from a single camera pair (Davis 2002, sec. 5.2).

    With camera poses known only approximately, points from different pairs carry
    uncorrelated biases; from one pair the error is shared and the shape is kept. The
    pair seeing the most points is used (ties: the lower indices).

    Parameters
    ----------
    cameras : sequence of K >= 2 :class:`~lsmta.camera.Camera`
    xy : (K, N, 2) array
        Image points in pixels; NaN where a camera does not see the point.
    min_angle_deg : float
        As in :func:`triangulate`.

    Returns
    -------
    PairIntersection
    """
    cameras = list(cameras)
    if len(cameras) < 2 or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a sequence of at least two lsmta.camera.Camera")
    xy = as_array(xy, "xy", shape=(len(cameras), None, 2), allow_nan=True)
    seen = np.isfinite(xy).all(axis=2)
    counts = (seen[:, None, :] & seen[None, :, :]).sum(axis=2)
    np.fill_diagonal(counts, -1)
    i, j = np.unravel_index(np.argmax(counts), counts.shape)
    i, j = sorted((int(i), int(j)))
    np.fill_diagonal(counts, seen.sum(axis=1))
    inter = triangulate([cameras[i], cameras[j]], xy[[i, j]], min_angle_deg=min_angle_deg)
    return PairIntersection(pair=np.array([i, j]), intersection=inter, counts=counts)
