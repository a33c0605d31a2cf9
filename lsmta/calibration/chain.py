"""Cameras chained through shared parts of a calibration path, and a datum from a known
distance (Davis 2002, §3.2: "cameras not all of which have overlapping working volumes").

When no one object is seen by all cameras, the cameras are linked through the parts of the
LED path that neighbours share. :func:`chain_cameras` starts from the relative orientation
of the camera ``first`` and the camera that shares most of the path with it (OpenCV's
essential matrix, :func:`~lsmta.calibration.relative_orientation_start`), intersects the
path they share, and then adds one camera at a time: the one that sees most of the path
intersected so far, by space resection (OpenCV ``solvePnPRansac``); the path is intersected
again with every camera chained so far before the next one. Only the nominal interior
orientation enters (principal distance, image centre, no distortion); the result is an
approximation for :func:`~lsmta.calibration.virtual_object.alternate` or
:func:`~lsmta.calibration.virtual_object.joint_adjustment`.

A single LED path fixes neither where the rig is nor its size. :func:`datum_from_distance`
moves the cameras by a similarity so that one camera has a stated pose (for example its
tape-measured position and orientation) and two marks, seen by the cameras, are a stated
distance apart (for example the LED put on two floor marks measured with a tape).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_scalar
from ..camera import Camera
from ..triangulation import triangulate
from .approximations import next_camera, relative_orientation_start, resect_pnp


@dataclass(frozen=True, eq=False)
class ChainStart:
    """Approximate cameras from a chain of shared path segments.

    Attributes
    ----------
    cameras : list of K Camera
        Nominal interior orientation, no distortion; exterior orientation in the frame of
        camera ``order[0]`` (its centre at the origin, its axes the world axes) with the
        base of the first pair one unit long.
    points : (N, 3) array
        The path intersected with all chained cameras (NaN where fewer than two see it).
    order : (K,) int array
        The order in which the cameras joined the chain.
    parent : (K,) int array
        For each camera, the chained camera it shares most of the path with when it joins
        (-1 for the first).
    shared : (K, K) int array
        Path positions seen by both cameras of each pair (the diagonal: by the camera).
    """

    cameras: list
    points: np.ndarray
    order: np.ndarray
    parent: np.ndarray
    shared: np.ndarray


def shared_points(xy) -> np.ndarray:
    """``(K, K)`` counts of the points seen by both cameras of each pair, for observations
    ``xy`` ``(K, N, 2)`` (NaN: not seen); the diagonal counts each camera's points."""
    xy = as_array(xy, "xy", shape=(None, None, 2), allow_nan=True)
    seen = np.isfinite(xy).all(axis=2).astype(np.int64)
    return seen @ seen.T


def chain_cameras(cameras, xy, *, first: int = 0, min_shared: int = 12,
                  threshold_px: float = 3.0) -> ChainStart:
    """Approximations of K cameras that see only parts of one path (see the module).

    Parameters
    ----------
    cameras : sequence of K Camera
        Cameras with the nominal interior orientation (their exterior orientation and
        distortion are ignored).
    xy : (K, N, 2) array
        Observations of the path, px (NaN: not seen).
    first : int
        The camera that defines the frame.
    min_shared : int
        A camera joins only when it sees at least this many intersected points.
    threshold_px : float
        RANSAC thresholds (essential matrix; resection: twice this), px.

    Returns
    -------
    ChainStart

    Raises
    ------
    ValueError
        When a camera cannot be reached through shared points (named, with the most
        intersected points it sees).
    """
    cams = list(cameras)
    K = len(cams)
    if K < 2 or not all(isinstance(c, Camera) for c in cams):
        raise TypeError("cameras: expected a sequence of at least two lsmta.camera.Camera")
    xy = as_array(xy, "xy", shape=(K, None, 2), allow_nan=True)
    if int(first) != first or not 0 <= first < K:
        raise ValueError(f"first: expected a camera index in [0, {K - 1}], got {first}")
    as_int(min_shared, "min_shared", minimum=6)
    shared = shared_points(xy)
    others = np.delete(np.arange(K), first)
    second = int(others[np.argmax(shared[first, others])])
    pair, _ = relative_orientation_start([cams[first], cams[second]], xy[[first, second]],
                                         pair=(0, 1), threshold_px=threshold_px)
    out = [c.replace(R=np.eye(3), C=np.zeros(3), k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
                     b1=0.0, b2=0.0) for c in cams]
    out[first], out[second] = pair
    order, parent = [first, second], np.full(K, -1, np.int64)
    parent[second] = first
    while len(order) < K:
        k, m, X = next_camera(out, order, xy)
        if m.sum() < min_shared:
            raise ValueError(f"xy: camera {cams[k].name or k} sees {int(m.sum())} intersected "
                             f"point(s) of the chain; it needs >= {min_shared} to join")
        out[k] = resect_pnp(out[k], X[m], xy[k, m], max_error_px=2 * threshold_px)
        parent[k] = order[int(np.argmax(shared[k, order]))]
        order.append(k)
    X = triangulate(out, xy, min_angle_deg=0.0).points
    return ChainStart(cameras=out, points=X, order=np.asarray(order, np.int64), parent=parent,
                      shared=shared)


def datum_from_distance(cameras, marks_xy, distance: float, *, pose: Camera,
                        camera: int = 0) -> list:
    """Move and scale cameras so that camera ``camera`` has the pose of ``pose`` and the
    two marks seen in ``marks_xy`` are ``distance`` apart (a similarity; the images do not
    change).

    Parameters
    ----------
    cameras : sequence of K Camera
    marks_xy : (K, 2, 2) array
        Image coordinates of the two marks in every camera, px (NaN: not seen; each mark
        must be seen by at least two cameras).
    distance : float
        The known distance between the marks, mm.
    pose : Camera
        Its rotation ``R`` and centre ``C`` are given to camera ``camera``.
    camera : int

    Returns
    -------
    list of K Camera
    """
    cams = list(cameras)
    K = len(cams)
    marks_xy = as_array(marks_xy, "marks_xy", shape=(K, 2, 2), allow_nan=True)
    distance = as_scalar(distance, "distance", positive=True)
    if not isinstance(pose, Camera):
        raise TypeError("pose: expected an lsmta.camera.Camera")
    if int(camera) != camera or not 0 <= camera < K:
        raise ValueError(f"camera: expected an index in [0, {K - 1}], got {camera}")
    M = triangulate(cams, marks_xy, min_angle_deg=0.0).points
    if not np.isfinite(M).all():
        raise ValueError("marks_xy: each mark must be seen by at least two cameras")
    s = distance / np.linalg.norm(M[1] - M[0])
    Rg = pose.R.T @ cams[camera].R
    t = pose.C - s * Rg @ cams[camera].C
    return [c.replace(R=c.R @ Rg.T, C=s * Rg @ c.C + t) for c in cams]
