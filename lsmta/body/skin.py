"""The skin: cross-sections of the implicit surface, a B-spline patch per body part, and
its polygonal tessellation (Plänkers et al. 1999, Section 3.1 and Fig. 6).

Sampling
    Each body part has an axis inside its skin (for a metaball segment, the segment from
    its first to its last ball centre). Rays leave the axis in ``n_sections``
    cross-sections perpendicular to it, ``n_around`` per section; two caps of rays fan out
    from the axis' end points, so that the patch closes over the part's ends. Each ray
    marches outwards in ``n_march`` steps up to ``reach`` and the first crossing of the
    level ``F = T`` is refined by bisection: the sample is the ray's length ``r(u, v)``,
    ``u`` along the part (cap, sections, cap), ``v`` around it.
B-spline patch
    ``r(u, v)`` is interpolated by a bicubic tensor-product B-spline (SciPy's
    ``make_interp_spline``; periodic in ``v``, not-a-knot in ``u``), so the patch passes
    through the samples; its control points are the samples transformed by the inverse
    interpolation matrix. (Plänkers et al. use the samples themselves as the control
    points, which pulls the surface inwards on convex parts by about the square of the
    sample spacing times the curvature; interpolating removes that bias.) The surface is
    ``x(u, v) = o(u) + r(u, v) d(u, v)``, the same ray parametrisation as the samples,
    so the poles of the caps (where every ``v`` gives the same ray) stay single points.
Tessellation
    The patch is evaluated on a finer ``(n_u, n_v)`` grid, quads between neighbouring
    rows (wrapping round in ``v``) and triangle fans at the two poles give a closed
    triangle mesh; pyvista merges the patches and reports open edges (a watertight mesh
    has none). Patches of different parts overlap at the joints: the merged mesh is
    closed part by part, not one boolean union.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from .._validate import as_array, as_int, as_scalar, freeze
from ._kernels import ball_field
from .metaballs import THRESHOLD, MetaballModel, _radii


@dataclass(frozen=True)
class SkinParams:
    """Sampling and tessellation of a skin patch.

    Attributes
    ----------
    n_sections : int
        Cross-sections along the axis (>= 2).
    n_around : int
        Rays per cross-section (>= 6).
    n_cap : int
        Rows of rays in each end cap (>= 2), from the pole to just short of the sections.
    n_march : int
        Steps of the outward march before the bisection.
    n_bisect : int
        Bisection steps (each halves the bracket).
    n_u, n_v : int
        Tessellation grid along and around the part.
    threshold : float
        ``T`` of the implicit surface ``F = T``.
    """

    n_sections: int = 12
    n_around: int = 24
    n_cap: int = 5
    n_march: int = 48
    n_bisect: int = 30
    n_u: int = 60
    n_v: int = 48
    threshold: float = THRESHOLD

    def __post_init__(self):
        for name, low in (("n_sections", 2), ("n_around", 6), ("n_cap", 2), ("n_march", 2),
                          ("n_bisect", 1), ("n_u", 4), ("n_v", 6)):
            as_int(getattr(self, name), name, minimum=low)
        t = as_scalar(self.threshold, "threshold", positive=True)
        if not t < 1:
            raise ValueError(f"threshold: expected a number in (0, 1), got {t}")


@dataclass(frozen=True, eq=False)
class SkinPatch:
    """One body part's B-spline skin.

    Attributes
    ----------
    samples : (U, V, 3) array
        The ray-cast surface samples (mm): ``U = 2 n_cap + n_sections`` rows of
        ``V = n_around``.
    radius : (U, V) array
        Each sample's distance from its ray origin (mm).
    vertices : (M, 3) array
        Tessellation vertices (mm).
    faces : (F, 3) int array
        Triangles (vertex indices).
    """

    samples: np.ndarray
    radius: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        freeze(self, ("samples", "radius", "vertices", "faces"))


def _frame(axis_start: np.ndarray, axis_end: np.ndarray):
    a = axis_end - axis_start
    length = np.linalg.norm(a)
    a = a / length
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return a, e1, np.cross(a, e1)


def _rays(axis_start, axis_end, u, v, n_cap: int, n_sections: int):
    """Ray origins ``(U, 3)`` and directions ``(U, V, 3)`` at parameters ``u`` (in row
    units: ``[0, n_cap)`` start cap, then the sections, then the end cap) and angles ``v``."""
    a, e1, e2 = _frame(axis_start, axis_end)
    last = 2 * n_cap + n_sections - 1
    s = np.clip((u - n_cap) / (n_sections - 1), 0.0, 1.0)          # along the axis
    phi = np.where(u < n_cap, 0.5 * np.pi * u / n_cap,
                   np.where(u > last - n_cap, 0.5 * np.pi * (1 + (u - (last - n_cap)) / n_cap),
                            0.5 * np.pi))
    origin = axis_start + s[:, None] * (axis_end - axis_start)
    radial = np.cos(v)[:, None] * e1 + np.sin(v)[:, None] * e2          # (V, 3)
    dirs = (-np.cos(phi))[:, None, None] * a + np.sin(phi)[:, None, None] * radial[None]
    return origin, dirs


def _march(level: Callable, origin, dirs, reach: float, n_march: int, n_bisect: int):
    """Distance along each ray ``(U, V)`` to the first crossing of ``level(x) = 0`` (level
    positive inside, negative outside)."""
    U, V = dirs.shape[:2]
    steps = np.linspace(0.0, reach, n_march + 1)
    pts = origin[:, None, None, :] + steps[None, None, :, None] * dirs[:, :, None, :]
    val = level(pts.reshape(-1, 3)).reshape(U, V, n_march + 1)
    if not (val[..., 0] > 0).all():
        raise ValueError("axis_start, axis_end: the axis must lie inside the surface")
    out = val < 0
    if not out.any(axis=2).all():
        raise ValueError(f"reach: {reach} mm does not leave the surface along every ray")
    k = np.argmax(out, axis=2)                                           # first step outside
    lo, hi = steps[k - 1], steps[k]
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        inside = level((origin[:, None, :] + mid[..., None] * dirs).reshape(-1, 3)) \
            .reshape(U, V) > 0
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    return 0.5 * (lo + hi)


def _interpolate(radius: np.ndarray, u_fine: np.ndarray, v_fine: np.ndarray) -> np.ndarray:
    """Bicubic B-spline through ``radius (U, V)`` (rows at u = 0..U-1, periodic columns),
    evaluated at ``u_fine x v_fine``."""
    U, V = radius.shape
    v = 2 * np.pi * np.arange(V + 1) / V
    around = make_interp_spline(v, np.concatenate([radius, radius[:, :1]], axis=1), k=3,
                                axis=1, bc_type="periodic")(v_fine)             # (U, v_fine)
    return make_interp_spline(np.arange(U, dtype=float), around, k=3, axis=0)(u_fine)


def _tessellate(grid: np.ndarray):
    """Closed triangle mesh of a ``(n_u, n_v, 3)`` grid whose first and last rows are poles."""
    n_u, n_v = grid.shape[:2]
    body = grid[1:-1].reshape(-1, 3)
    vertices = np.vstack([grid[0, :1], body, grid[-1, :1]])
    idx = 1 + np.arange((n_u - 2) * n_v).reshape(n_u - 2, n_v)
    nxt = np.roll(idx, -1, axis=1)
    quads_a = np.stack([idx[:-1], idx[1:], nxt[1:]], -1).reshape(-1, 3)
    quads_b = np.stack([idx[:-1], nxt[1:], nxt[:-1]], -1).reshape(-1, 3)
    top = np.stack([np.zeros(n_v, int), idx[0], nxt[0]], -1)
    bottom = np.stack([np.full(n_v, len(vertices) - 1), nxt[-1], idx[-1]], -1)
    return vertices, np.vstack([top, quads_a, quads_b, bottom])


def skin_patch(level: Callable, axis_start, axis_end, *, reach: float,
               params: SkinParams | None = None) -> SkinPatch:
    """The B-spline skin of one body part around the axis ``axis_start -> axis_end``.

    Parameters
    ----------
    level : callable
        ``level(points (M, 3)) -> (M,)``: positive inside the surface, negative outside,
        zero on it (e.g. ``F - T`` of the part's metaballs), world mm.
    axis_start, axis_end : (3,) arrays
        The axis, inside the surface (mm).
    reach : float
        Longest ray (mm): beyond the surface in every direction from the axis.
    params : SkinParams, optional

    Returns
    -------
    SkinPatch
    """
    p = SkinParams() if params is None else params
    if not isinstance(p, SkinParams):
        raise TypeError(f"params: expected SkinParams, got {type(p).__name__}")
    a0 = as_array(axis_start, "axis_start", shape=(3,))
    a1 = as_array(axis_end, "axis_end", shape=(3,))
    if np.linalg.norm(a1 - a0) == 0:
        raise ValueError("axis_end: must differ from axis_start")
    reach = as_scalar(reach, "reach", positive=True)
    U = 2 * p.n_cap + p.n_sections
    v = 2 * np.pi * np.arange(p.n_around) / p.n_around
    origin, dirs = _rays(a0, a1, np.arange(U, dtype=float), v, p.n_cap, p.n_sections)
    radius = _march(level, origin, dirs, reach, p.n_march, p.n_bisect)
    samples = origin[:, None, :] + radius[..., None] * dirs
    u_fine = np.linspace(0.0, U - 1.0, p.n_u)
    v_fine = 2 * np.pi * np.arange(p.n_v) / p.n_v
    r_fine = _interpolate(radius, u_fine, v_fine)
    o_fine, d_fine = _rays(a0, a1, u_fine, v_fine, p.n_cap, p.n_sections)
    vertices, faces = _tessellate(o_fine[:, None, :] + r_fine[..., None] * d_fine)
    return SkinPatch(samples=samples, radius=radius, vertices=vertices, faces=faces)


def model_skin(model: MetaballModel, angles, scales, radii, *, base=None,
               params: SkinParams | None = None) -> list:
    """A :class:`SkinPatch` per segment of ``model`` in one frame (``angles (1, J)``,
    ``scales (L,)``, ``radii (S, 3, 3)`` mm, ``base (1, 4, 4)``), each from its own
    segment's metaballs, the axis running from the first to the last ball centre."""
    p = SkinParams() if params is None else params
    angles = as_array(angles, "angles", shape=(1, None))
    radii = _radii(radii, shape=(model.n_segments, 3, 3))
    poses = model.ball_poses(angles, scales, base=base)[0]                   # (S, 3, 4, 4)
    out = []
    for k in range(model.n_segments):
        P, r_k = np.ascontiguousarray(poses[k]), np.ascontiguousarray(radii[k])

        def level(x, P=P, r=r_k):
            return ball_field(np.ascontiguousarray(x, float), P, r) - p.threshold

        out.append(skin_patch(level, P[0, :3, 3], P[-1, :3, 3], reach=2.0 * float(radii[k].max()),
                              params=p))
    return out


def merge_patches(patches):
    """One pyvista ``PolyData`` of all patches (duplicate vertices merged)."""
    import pyvista as pv  # deferred: importing pyvista (VTK) takes ~0.5 s; only this needs it

    meshes = []
    for patch in patches:
        faces = np.hstack([np.full((len(patch.faces), 1), 3), patch.faces]).ravel()
        meshes.append(pv.PolyData(np.asarray(patch.vertices), faces))
    return pv.merge(meshes).clean()
