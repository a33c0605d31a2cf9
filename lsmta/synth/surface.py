"""Exact distances to the true body surface (for scoring skins after the fact).

The distance from a point ``y`` to the ellipsoid with semi-axes ``e`` is found as in
Eberly's "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid": by
symmetry take ``|y|``; the closest point is ``x_i = e_i^2 y_i / (t + e_i^2)`` where ``t``
is the root, above ``-min(e)^2``, of ``sum (e_i y_i / (t + e_i^2))^2 = 1`` (decreasing in
``t`` there), found by bisection. (Points deep inside, on a symmetry plane, where that root
does not exist, get the bound; they lie far from any skin being scored.) The bisection
runs compiled, one point per pass of a ``prange`` loop (numba).
"""

from __future__ import annotations

import numba as nb
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
    return _ellipsoid_distance(np.ascontiguousarray(y), np.ascontiguousarray(e), int(n_iter))


@nb.njit(cache=True, error_model="numpy", parallel=True)
def _ellipsoid_distance(y, e, n_iter):
    """:func:`distance_to_ellipsoid` of ``|points| (N, 3)``, per point."""
    e2 = e * e
    low = -e2.min() * (1 - 1e-12)
    top = e.max()
    out = np.empty(len(y))
    for n in nb.prange(len(y)):
        y0, y1, y2 = y[n, 0], y[n, 1], y[n, 2]
        lo = low
        hi = max(np.sqrt(y0 * y0 + y1 * y1 + y2 * y2) * top, 1.0)
        for _ in range(n_iter):
            t = 0.5 * (lo + hi)
            a = e[0] * y0 / (t + e2[0])
            b = e[1] * y1 / (t + e2[1])
            c = e[2] * y2 / (t + e2[2])
            if a * a + b * b + c * c - 1.0 > 0:
                lo = t
            else:
                hi = t
        t = 0.5 * (lo + hi)
        x0 = e2[0] * y0 / (t + e2[0]) - y0
        x1 = e2[1] * y1 / (t + e2[1]) - y1
        x2 = e2[2] * y2 / (t + e2[2]) - y2
        d = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        q0, q1, q2 = y0 / e[0], y1 / e[1], y2 / e[2]
        out[n] = -d if q0 * q0 + q1 * q1 + q2 * q2 < 1.0 else d
    return out


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
