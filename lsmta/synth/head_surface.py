"""The generated head as a closed surface, and markers hidden by it (self-occlusion).

Davis (2002, thesis section 5.3, Fig. 59): when the head turns, the face itself hides half
of its markers from one camera. Here a marker is hidden from a camera when the line of
sight from the camera centre to the marker passes through the head before it reaches the
marker (ray casting), so the nose can hide a cheek marker and the far cheek disappears
behind the face, not only markers whose surface turns away (compare
:func:`lsmta.synth.face.visible`).

The head (:class:`HeadShape`), in the head frame of :mod:`lsmta.synth.face` (x to the
viewer's right, y up, z out of the face; mm), is the region over the ellipse
``(x/a)^2 + (y/b)^2 < 1`` between two sheets:

* the **front sheet** ``z = front(x, y)``: by default the generator's own face surface
  (the half-ellipsoid with nose, eye sockets, lips and chin on which the neutral markers
  sit, :func:`lsmta.synth.face._depth`), or a plain half-ellipsoid ``front * sqrt(r)``;
* the **back sheet** ``z = -back * sqrt(r)``, a half-ellipsoid closing the back of the head,

with ``r = 1 - (x/a)^2 - (y/b)^2``. A sphere of radius ``R`` is ``HeadShape(a=R, b=R,
front=R, back=R, face=False)``. The neck and the rest of the body are not modelled.

Expressions move the markers off the neutral face (lips pushed forward, the jaw opened),
and the surface moves with them: every marker's displacement ``d_m`` from its place on the
neutral sheet, ``(u_m, v_m)`` in x, y, is interpolated over the whole head by a thin-plate
spline (with its affine part, so it passes exactly through every marker and carries on
smoothly past the outermost ones), and each column ``(u, v)`` of the head, both sheets, is
moved by ``D(u, v)``: the open jaw carries the chin and the skin around it down and back,
so no marker hides itself and the closed-jaw chin hides nothing. The neutral places come
from ``neutral`` (:attr:`lsmta.synth.face.MarkedFace.neutral`); without it each marker is
taken to have moved along z only, from the sheet nearer to it. ``D`` and its derivatives
are sampled on a grid of ``grid`` mm over the neutral outline, per frame; the neutral column
``(u, v)`` of a point ``(x, y)`` on a line of sight is found by a Newton step on
``(u, v) + D_xy(u, v) = (x, y)`` from the previous sample's column (the first from the
marker's own). Between markers the surface is this interpolation, not the generator's own
expression fields; a line of sight that grazes the surface can switch between seen and
hidden as the face moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator

from .._validate import as_array, as_scalar
from .face import _A, _B, _C, _depth

# the generator's face features rise at most this far above the plain half-ellipsoid, mm
_FEATURES_MM = 30.0


@dataclass(frozen=True)
class HeadShape:
    """A closed head in the head frame (see the module docstring), mm.

    Attributes
    ----------
    a, b : float
        Half-width (x) and half-height (y) of the head's outline, mm.
    front : float
        Depth of the front sheet at the centre (z > 0), mm.
    back : float
        Depth of the back sheet at the centre (z < 0), mm.
    face : bool
        The front sheet is the generator's face (nose, eye sockets, lips, chin; requires the
        generator's ``a``, ``b``, ``front``: 80, 110, 95 mm) rather than a plain
        half-ellipsoid.
    """

    a: float = _A
    b: float = _B
    front: float = _C
    back: float = 110.0
    face: bool = True

    def __post_init__(self):
        if not isinstance(self.face, (bool, np.bool_)):
            raise TypeError(f"face: expected a bool, got {type(self.face).__name__}")
        for name in ("a", "b", "front", "back"):
            as_scalar(getattr(self, name), name, positive=True)
        if self.face and (self.a, self.b, self.front) != (_A, _B, _C):
            raise ValueError(f"face: the generator's face needs a={_A}, b={_B}, front={_C} "
                             f"(mm); use face=False for another shape")

    def sheets(self, x, y):
        """``(r, front_z, back_z)`` at head-frame ``x, y`` (mm, any matching shapes):
        ``r = 1 - (x/a)^2 - (y/b)^2`` (the head is where ``r > 0``) and the heights of the
        two sheets, mm."""
        r = 1 - (x / self.a) ** 2 - (y / self.b) ** 2
        back = -self.back * np.sqrt(np.clip(r, 0, None))
        front = _depth(x, y) if self.face else self.front * np.sqrt(np.clip(r, 0, None))
        return r, front, back

    def bounds(self) -> np.ndarray:
        """``(2, 3)`` corners of a box holding the head, mm."""
        top = self.front + (_FEATURES_MM if self.face else 0.0)
        return np.array([[-self.a, -self.b, -self.back], [self.a, self.b, top]])


def _exit_distance(origin, direction, box):
    """Distance along each ray (origin + s * direction, unit direction) to where it leaves
    the box (slab method); 0 where it misses the box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        s0 = (box[0] - origin) * inv
        s1 = (box[1] - origin) * inv
    far = np.nanmin(np.maximum(s0, s1), axis=-1)
    near = np.nanmax(np.minimum(s0, s1), axis=-1)
    return np.where(far >= np.maximum(near, 0), far, 0.0)


def self_occlusion(points, R, t, camera_centres, *, shape: HeadShape | None = None,
                   neutral=None, step: float = 0.5, start: float = 1.0,
                   tolerance: float = 0.2, grid: float = 2.0, return_hit: bool = False):
    """Which markers each camera sees past the head itself (ray casting).

    A marker is hidden from a camera when a point of the segment from the marker towards
    the camera centre lies inside the head (:class:`HeadShape`, deformed by the expression
    as in the module docstring, posed by ``R``, ``t``) by more than ``tolerance``. The
    segment is sampled every ``step`` mm from ``start`` mm off the marker to where it
    leaves the head's bounding box (or reaches the camera). Vectorised over frames,
    cameras and markers (a loop over the samples only).

    Parameters
    ----------
    points : (T, M, 3) array
        Markers in the world, mm (e.g. :attr:`lsmta.synth.face.FaceSequence.world`). Not
        modified.
    R : (T, 3, 3) array
        Head-to-world rotations (``world = head @ R.T + t``).
    t : (T, 3) array
        Head origin in the world, mm.
    camera_centres : (C, 3) or (T, C, 3) array
        Camera centres in the world, mm: fixed, or one set per frame.
    shape : HeadShape, optional
        The head; default ``HeadShape()``: the generator's face closed by a half-ellipsoid
        110 mm deep behind it.
    neutral : (M, 3) array, optional
        The markers on the neutral face, head frame, mm (x, y used: displacements from the
        front sheet there). Default: each marker moved along z from the nearer sheet.
    step : float
        Sampling interval along the line of sight, mm (> 0; thinner features can be missed).
    start : float
        First sample's distance from the marker, mm (>= 0).
    tolerance : float
        How far inside the head a sample must be to hide the marker, mm (>= 0); grazing
        lines of sight closer to the surface than this pass.
    grid : float
        Spacing of the grid on which the expression's deformation is sampled, mm (> 0).
    return_hit : bool
        Also return where each hidden line of sight first enters the head.

    Returns
    -------
    seen : (T, C, M) bool array
        True where camera ``c`` sees marker ``m`` in frame ``t`` (not hidden by the head;
        the image bounds and the camera's viewing direction are not checked here).
    hit : (T, C, M, 3) array
        Only with ``return_hit``: the first sample inside the head on each hidden line of
        sight, head frame, mm (what hid the marker); NaN where seen.

    Raises
    ------
    ValueError
        Shapes that do not match, non-finite values, ``R`` not rotations, a non-positive
        ``step`` or ``grid``, a negative ``start`` or ``tolerance``, a camera centre inside
        the head's bounding box, markers whose displacements no smooth surface can carry.
    TypeError
        ``shape`` not a :class:`HeadShape`, ``return_hit`` not a bool.
    """
    shape = HeadShape() if shape is None else shape
    if not isinstance(shape, HeadShape):
        raise TypeError(f"shape: expected a HeadShape, got {type(shape).__name__}")
    if not isinstance(return_hit, (bool, np.bool_)):
        raise TypeError(f"return_hit: expected a bool, got {type(return_hit).__name__}")
    P, Rm, tv, C = _checked(points, R, t, camera_centres)
    if neutral is not None:
        neutral = as_array(neutral, "neutral", shape=(P.shape[1], 3))
    step = as_scalar(step, "step", positive=True)
    start = as_scalar(start, "start", nonnegative=True)
    tol = as_scalar(tolerance, "tolerance", nonnegative=True)
    h = as_scalar(grid, "grid", positive=True)
    # everything in the head frame
    head = np.einsum("tji,tmj->tmi", Rm, P - tv[:, None])                  # (T, M, 3)
    cam = np.einsum("tji,tcj->tci", Rm, C - tv[:, None])                   # (T, C, 3)
    warp = _Deformation(shape, head, neutral, h)
    box = warp.bounds()
    if ((cam > box[0]) & (cam < box[1])).all(axis=-1).any():
        raise ValueError("camera_centres: a camera centre lies inside the head's bounding box")
    seen, hit = _march(shape, warp, head, cam, box, step=step, start=start, tol=tol)
    return (seen, hit) if return_hit else seen


def _checked(points, R, t, camera_centres):
    """The arguments of :func:`self_occlusion` as float arrays, centres as (T, C, 3)."""
    P = as_array(points, "points", shape=(None, None, 3))
    T = P.shape[0]
    Rm = as_array(R, "R", shape=(T, 3, 3))
    tv = as_array(t, "t", shape=(T, 3))
    eye = np.einsum("tij,tkj->tik", Rm, Rm)
    if not np.allclose(eye, np.eye(3), atol=1e-6) or (np.linalg.det(Rm) < 0).any():
        raise ValueError("R: expected proper rotations (R @ R.T == I, det(R) == +1) in every "
                         "frame")
    C = as_array(camera_centres, "camera_centres")
    if C.ndim == 2 and C.shape[1] == 3:
        C = np.broadcast_to(C, (T,) + C.shape)
    elif not (C.ndim == 3 and C.shape[0] == T and C.shape[2] == 3):
        raise ValueError(f"camera_centres: expected an array of shape (C, 3) or ({T}, C, 3), "
                         f"got shape {C.shape}")
    return P, Rm, tv, C


def _bilinear(table, lo, h, x, y, frame):
    """Bilinear look-up of ``table`` (T, nx, ny, K) sampled every ``h`` mm from ``lo``
    (x0, y0) at points ``x, y`` of frames ``frame`` (matching shapes), clamped to the
    grid: (..., K)."""
    T, nx, ny, K = table.shape
    fx = np.clip((x - lo[0]) / h, 0, nx - 1)
    fy = np.clip((y - lo[1]) / h, 0, ny - 1)
    i = np.minimum(fx.astype(np.int64), nx - 2)
    j = np.minimum(fy.astype(np.int64), ny - 2)
    ax = (fx - i)[..., None]
    ay = (fy - j)[..., None]
    flat = table.reshape(-1, K)
    k = (frame * nx + i) * ny + j
    return ((1 - ax) * ((1 - ay) * np.take(flat, k, axis=0) + ay * np.take(flat, k + 1, axis=0))
            + ax * ((1 - ay) * np.take(flat, k + ny, axis=0)
                    + ay * np.take(flat, k + ny + 1, axis=0)))


class _Deformation:
    """The expression's deformation of the head, per frame, sampled on a grid over the
    neutral head's outline (module docstring): ``D(u, v)`` and its derivatives, so that
    the neutral column ``(u, v)`` of a moved point ``(x, y)`` is found by Newton's method
    on ``(u, v) + D_xy(u, v) = (x, y)``."""

    def __init__(self, shape, head, neutral, h):
        T, M, _ = head.shape
        self._base = shape.bounds()
        if neutral is None:     # moved along z only, from the nearer sheet
            r, fz, bz = shape.sheets(head[..., 0], head[..., 1])
            on_front = head[..., 2] >= 0.5 * (fz + bz)
            dz = np.where(r > 0, head[..., 2] - np.where(on_front, fz, bz), 0.0)
            self.uv = head[..., :2]
            d = np.concatenate([np.zeros((T, M, 2)), dz[..., None]], axis=-1)
        else:
            self.uv = np.broadcast_to(neutral[:, :2], (T, M, 2))
            _, fz, _ = shape.sheets(self.uv[..., 0], self.uv[..., 1])
            d = head - np.concatenate([self.uv, fz[..., None]], axis=-1)
        moved = np.flatnonzero(np.abs(d).max(axis=(1, 2)) > 1e-9)            # frames
        self.h = h
        self.grow = np.zeros((2, 3))
        self.table = None
        if not len(moved):
            return
        us = np.arange(-shape.a - 4 * h, shape.a + 4 * h + h, h)
        vs = np.arange(-shape.b - 4 * h, shape.b + 4 * h + h, h)
        self.lo = np.array([us[0], vs[0]])
        gu, gv = np.meshgrid(us, vs, indexing="ij")
        nodes = np.stack([gu.ravel(), gv.ravel()], axis=1)

        def spline(uv, values):     # the thin-plate spline through values, at the nodes
            try:
                return RBFInterpolator(uv, values, kernel="thin_plate_spline",
                                       degree=1 if M >= 3 else 0)(nodes)
            except (np.linalg.LinAlgError, ValueError) as err:
                raise ValueError("points: no smooth surface passes through these displaced "
                                 f"markers ({err})") from None

        # D, dD/du, dD/dv on the grid (float32: ample for mm)
        table = np.zeros((T, len(us), len(vs), 9), dtype=np.float32)
        if neutral is not None:     # the same markers' places: one spline per unit move
            W = spline(self.uv[0], np.eye(M)).astype(np.float32)              # (nodes, M)
            dm = d[moved].transpose(1, 0, 2).reshape(M, -1).astype(np.float32)
            table[moved, ..., :3] = (W @ dm).reshape(len(us), len(vs), len(moved), 3).transpose(
                2, 0, 1, 3)
        else:
            for f in moved:
                table[f, ..., :3] = spline(self.uv[f], d[f]).reshape(len(us), len(vs), 3)
        field = table[..., :3]
        table[..., 3:6] = np.gradient(field, h, axis=1)
        table[..., 6:9] = np.gradient(field, h, axis=2)
        self.table = table
        inside = (1 - (gu / shape.a) ** 2 - (gv / shape.b) ** 2) > 0
        reach = field[:, inside]                                            # (T, n, 3)
        self.grow = np.array([np.minimum(reach.min(axis=(0, 1)), 0),
                              np.maximum(reach.max(axis=(0, 1)), 0)]) + np.array([[-h], [h]])

    def bounds(self):
        return self._base + self.grow

    def columns(self, x, y, frame, uv):
        """``(u, v, lift)`` of the moved points ``x, y`` (frames ``frame``): one Newton step
        on ``(u, v) + D_xy(u, v) = (x, y)`` from ``uv`` (..., 2; the previous sample's
        columns, updated in place), the lift ``D_z`` to first order."""
        if self.table is None:
            return x, y, 0.0
        look = _bilinear(self.table, self.lo, self.h, uv[..., 0], uv[..., 1], frame)
        ex = x - uv[..., 0] - look[..., 0]
        ey = y - uv[..., 1] - look[..., 1]
        a, b = 1 + look[..., 3], look[..., 6]          # d(u + Dx)/du, d(u + Dx)/dv
        c, e = look[..., 4], 1 + look[..., 7]          # d(v + Dy)/du, d(v + Dy)/dv
        det = a * e - b * c
        det = np.where(np.abs(det) > 1e-6, det, 1e-6)
        su = np.clip((e * ex - b * ey) / det, -10, 10)
        sv = np.clip((a * ey - c * ex) / det, -10, 10)
        uv[..., 0] += su
        uv[..., 1] += sv
        return uv[..., 0], uv[..., 1], look[..., 2] + look[..., 5] * su + look[..., 8] * sv


def _march(shape, warp, head, cam, box, *, step, start, tol):
    """(T, C, M) bool: lines of sight from the head-frame markers ``head`` (T, M, 3) to the
    head-frame camera centres ``cam`` (T, C, 3) that stay out of the (deformed) head,
    sampled; and the first sample inside the head on each hidden one (T, C, M, 3)."""
    ray = cam[:, :, None] - head[:, None]                                   # (T, C, M, 3)
    size = ray.shape[:-1]
    length = np.linalg.norm(ray, axis=-1)
    u = (ray / length[..., None]).reshape(-1, 3)
    origin = np.broadcast_to(head[:, None], ray.shape).reshape(-1, 3)
    reach = np.minimum(_exit_distance(origin, u, box), length.ravel())     # (N,)
    frame = np.broadcast_to(np.arange(len(head))[:, None, None], size).ravel()
    uv = np.broadcast_to(warp.uv[:, None], size + (2,)).reshape(-1, 2).copy()  # warm starts

    seen = np.ones(len(reach), dtype=bool)
    hit = np.full((len(reach), 3), np.nan)
    live = np.flatnonzero(reach >= start)              # the lines of sight still marched
    s = start
    while len(live):
        q = origin[live] + s * u[live]
        cuv = uv[live]
        cu, cv, lift = warp.columns(q[:, 0], q[:, 1], frame[live], cuv)
        uv[live] = cuv
        r_q, fq, bq = shape.sheets(cu, cv)
        z = q[:, 2] - lift
        now = (r_q > 0) & (z < fq - tol) & (z > bq + tol)
        seen[live[now]] = False
        hit[live[now]] = q[now]
        s += step
        live = live[~now & (reach[live] >= s)]
    return seen.reshape(size), hit.reshape(size + (3,))
