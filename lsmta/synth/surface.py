"""Exact distances to the true body surface (for scoring skins after the fact).

The distance from a point ``y`` to the ellipsoid with semi-axes ``e`` is found as in
Eberly's "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid": by
symmetry take ``|y|``; the closest point is ``x_i = e_i^2 y_i / (t + e_i^2)`` where ``t``
is the root, above ``-min(e)^2``, of ``sum (e_i y_i / (t + e_i^2))^2 = 1`` (decreasing in
``t`` there), found by bisection. (Points deep inside, on a symmetry plane, where that root
does not exist, get the bound; they lie far from any skin being scored.)
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array
from .body import Body


def distance_to_ellipsoid(points, radii, *, n_iter: int = 80) -> np.ndarray:
    """Signed distance ``(N,)`` (mm; negative inside) of ``points (N, 3)`` in the
    ellipsoid's own frame (centred, axes aligned) to the ellipsoid ``radii (3,)``."""
    y = np.abs(as_array(points, "points", shape=(None, 3)))
    e = as_array(radii, "radii", shape=(3,))
    if not (e > 0).all():
        raise ValueError(f"radii: expected positive semi-axes, got {e}")
    e2 = e * e
    lo = np.full(len(y), -e2.min() * (1 - 1e-12))
    hi = np.maximum(np.linalg.norm(y, axis=1) * e.max(), 1.0)
    for _ in range(n_iter):
        t = 0.5 * (lo + hi)
        f = np.sum((e * y / (t[:, None] + e2)) ** 2, axis=1) - 1.0
        lo, hi = np.where(f > 0, t, lo), np.where(f > 0, hi, t)
    t = 0.5 * (lo + hi)
    x = e2 * y / (t[:, None] + e2)
    d = np.linalg.norm(x - y, axis=1)
    inside = np.sum((y / e) ** 2, axis=1) < 1.0
    return np.where(inside, -d, d)


def distance_to_body(body: Body, poses, points) -> np.ndarray:
    """Distance ``(N,)`` (mm) of world ``points (N, 3)`` to the surface of the union of the
    body's ellipsoids in one frame (``poses (P, 4, 4)`` from ``Body.part_poses``): the
    smallest distance to any part's surface, made negative when the point is inside a
    part (exact outside the body; inside, the distance to the nearest part surface)."""
    pts = as_array(points, "points", shape=(None, 3))
    poses = as_array(poses, "poses", shape=(len(body.parts), 4, 4))
    d = np.stack([distance_to_ellipsoid((pts - poses[p, :3, 3]) @ poses[p, :3, :3]
                                        - np.asarray(spec.centre, float), spec.radii)
                  for p, spec in enumerate(body.parts)], axis=1)
    inside = (d < 0).any(axis=1)
    return np.where(inside, -np.abs(d).min(axis=1), d.min(axis=1))
