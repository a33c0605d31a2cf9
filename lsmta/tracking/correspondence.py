"""Corresponding image points across calibrated views: detections that one 3-D point
explains.

For every pair of views, detections whose rays pass within ``max_ray_distance`` of each
other are intersected (:func:`~lsmta.triangulation.triangulate`) and the 3-D point is
projected into the other views, where the nearest detection within ``max_px`` joins it. A
hypothesis seen in at least ``min_views`` views is scored by its largest reprojection
error; the hypotheses are accepted best first, each detection used once.
"""

from __future__ import annotations

import itertools

import numpy as np

from .._validate import as_array, as_scalar
from ..triangulation import triangulate


def match_views(cameras, detections, *, max_ray_distance: float = 30.0, max_px: float = 20.0,
                min_views: int = 3) -> np.ndarray:
    """Group detections of the K views into 3-D points.

    Parameters
    ----------
    cameras : sequence of K Camera
    detections : sequence of K (M_k, 2) arrays
        Image positions per view, px.
    max_ray_distance : float
        Largest distance between the rays of a starting pair, mm.
    max_px : float
        Largest reprojection error of a member detection, px.
    min_views : int
        Views a point needs (>= 2).

    Returns
    -------
    (K, P, 2) array
        The corresponding image positions of P points, NaN where a view has none; the
        points are in the order of their score (best first).
    """
    cameras = list(cameras)
    K = len(cameras)
    det = [as_array(d, f"detections[{k}]", shape=(None, 2)) for k, d in enumerate(detections)]
    if len(det) != K:
        raise ValueError(f"detections: expected {K} arrays (one per camera), got {len(det)}")
    max_px = as_scalar(max_px, "max_px", positive=True)
    max_ray = as_scalar(max_ray_distance, "max_ray_distance", positive=True)
    if isinstance(min_views, bool) or int(min_views) != min_views or not 2 <= min_views <= K:
        raise ValueError(f"min_views: expected an integer in [2, {K}], got {min_views}")
    rays = [cam.rays(d) if len(d) else None for cam, d in zip(cameras, det)]
    hyps = []                                          # (score, member index per view)
    for a, b in itertools.combinations(range(K), 2):
        if rays[a] is None or rays[b] is None:
            continue
        ia, ib = np.nonzero(ray_distances(rays[a], rays[b]) < max_ray)
        if not ia.size:
            continue
        members = np.full((len(ia), K), -1)
        members[:, a], members[:, b] = ia, ib
        xy = np.full((K, len(ia), 2), np.nan)
        xy[a], xy[b] = det[a][ia], det[b][ib]
        X = triangulate(cameras, xy).points
        for c in set(range(K)) - {a, b}:
            if not len(det[c]):
                continue
            p = np.full((len(ia), 2), np.nan)
            ok = np.isfinite(X).all(axis=1)
            p[ok] = cameras[c].project(X[ok], behind="nan")
            d = np.linalg.norm(p[:, None] - det[c][None], axis=2)
            j = np.nanargmin(np.where(np.isfinite(d), d, np.inf), axis=1)
            near = np.take_along_axis(d, j[:, None], axis=1)[:, 0] < max_px
            members[near, c] = j[near]
        enough = (members >= 0).sum(axis=1) >= min_views
        for m in np.unique(members[enough], axis=0):
            hyps.append((_score(cameras, det, m), tuple(m)))
    used = [set() for _ in range(K)]
    points = []
    for score, m in sorted(hyps):
        if score > max_px or any(i >= 0 and i in used[k] for k, i in enumerate(m)):
            continue
        for k, i in enumerate(m):
            if i >= 0:
                used[k].add(i)
        points.append([det[k][i] if i >= 0 else (np.nan, np.nan) for k, i in enumerate(m)])
    return np.array(points, float).reshape(-1, K, 2).transpose(1, 0, 2)


def ray_distances(r1, r2):
    """Distances ``(n1, n2)`` between the lines of two ray bundles, each
    ``(origins (n, 3), directions (n, 3))`` as :meth:`lsmta.camera.Camera.rays` gives them,
    in the origins' unit (mm)."""
    (o1, d1), (o2, d2) = r1, r2
    d1 = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    d2 = d2 / np.linalg.norm(d2, axis=1, keepdims=True)
    n = np.cross(d1[:, None], d2[None])
    nn = np.linalg.norm(n, axis=2)
    w = o1[:, None] - o2[None]
    return np.abs(np.einsum("abk,abk->ab", w, n)) / np.maximum(nn, 1e-12)


def _score(cameras, det, members) -> float:
    """Largest reprojection error of a hypothesis's members, px."""
    xy = np.full((len(cameras), 1, 2), np.nan)
    for k, i in enumerate(members):
        if i >= 0:
            xy[k, 0] = det[k][i]
    res = triangulate(cameras, xy)
    return float(np.nanmax(res.reprojection_error)) if res.valid[0] else np.inf
