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

Expressions move the markers off the neutral face (lips pushed forward, the jaw opened).
So that a marker never hides itself, the sheet nearer to the marker whose line of sight is
cast is moved locally, along z, to pass through that marker: by its offset from the sheet
times ``exp(-d^2 / (2 spread^2))``, ``d`` the distance in x, y from the marker. The other
markers' displacements do not reshape the surface (our simplification).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
                   step: float = 0.5, start: float = 1.0, tolerance: float = 0.2,
                   spread: float = 12.0) -> np.ndarray:
    """Which markers each camera sees past the head itself (ray casting).

    A marker is hidden from a camera when a point of the segment from the marker towards
    the camera centre lies inside the head (:class:`HeadShape`, posed by ``R``, ``t``) by
    more than ``tolerance``. The segment is sampled every ``step`` mm from ``start`` mm
    off the marker to where it leaves the head's bounding box (or reaches the camera).
    Vectorised over frames, cameras and markers (a loop over the samples only).

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
    step : float
        Sampling interval along the line of sight, mm (> 0; features thinner than this can
        be missed).
    start : float
        First sample's distance from the marker, mm (>= 0).
    tolerance : float
        How far inside the head a sample must be to hide the marker, mm (>= 0); grazing
        lines of sight closer to the surface than this pass.
    spread : float
        Width (standard deviation, mm) of the local move of the sheet through the marker
        (module docstring).

    Returns
    -------
    (T, C, M) bool array
        True where camera ``c`` sees marker ``m`` in frame ``t`` (not hidden by the head;
        the image bounds and the camera's viewing direction are not checked here).

    Raises
    ------
    ValueError
        Shapes that do not match, non-finite values, ``R`` not rotations, a non-positive
        ``step`` or ``spread``, a negative ``start`` or ``tolerance``, a camera centre
        inside the head's bounding box.
    """
    shape = HeadShape() if shape is None else shape
    if not isinstance(shape, HeadShape):
        raise TypeError(f"shape: expected a HeadShape, got {type(shape).__name__}")
    P, Rm, tv, C = _checked(points, R, t, camera_centres)
    step = as_scalar(step, "step", positive=True)
    start = as_scalar(start, "start", nonnegative=True)
    tol = as_scalar(tolerance, "tolerance", nonnegative=True)
    spread = as_scalar(spread, "spread", positive=True)
    box = shape.bounds()
    # everything in the head frame
    head = np.einsum("tji,tmj->tmi", Rm, P - tv[:, None])                  # (T, M, 3)
    cam = np.einsum("tji,tcj->tci", Rm, C - tv[:, None])                   # (T, C, 3)
    if ((cam > box[0]) & (cam < box[1])).all(axis=-1).any():
        raise ValueError("camera_centres: a camera centre lies inside the head's bounding box")
    return _march(shape, head, cam, box, step=step, start=start, tol=tol, spread=spread)


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


def _march(shape, head, cam, box, *, step, start, tol, spread):
    """(T, C, M) bool: lines of sight from the head-frame markers ``head`` (T, M, 3) to the
    head-frame camera centres ``cam`` (T, C, 3) that stay out of the head, sampled."""
    ray = cam[:, :, None] - head[:, None]                                   # (T, C, M, 3)
    length = np.linalg.norm(ray, axis=-1)
    u = ray / length[..., None]
    origin = np.broadcast_to(head[:, None], ray.shape)
    reach = np.minimum(_exit_distance(origin, u, box), length)              # (T, C, M)

    # each marker's offset from the sheet nearer to it (0 outside the outline)
    r, fz, bz = shape.sheets(head[..., 0], head[..., 1])
    on_front = head[..., 2] >= 0.5 * (fz + bz)
    inside_outline = r > 0
    off_front = np.where(inside_outline & on_front, head[..., 2] - fz, 0.0)[:, None]
    off_back = np.where(inside_outline & ~on_front, head[..., 2] - bz, 0.0)[:, None]
    mx, my = head[:, None, :, 0], head[:, None, :, 1]

    seen = np.ones(length.shape, dtype=bool)
    n = int(np.ceil(max(float(reach.max(initial=0.0)) - start, 0.0) / step)) + 1
    for k in range(n):
        s = start + k * step
        live = seen & (s <= reach)
        if not live.any():
            break
        q = origin + s * u
        x, y, z = q[..., 0], q[..., 1], q[..., 2]
        r_q, fq, bq = shape.sheets(x, y)
        g = np.exp(-((x - mx) ** 2 + (y - my) ** 2) / (2 * spread ** 2))
        fq = fq + off_front * g
        bq = bq + off_back * g
        inside = (r_q > 0) & (z < fq - tol) & (z > bq + tol)
        seen &= ~(live & inside)
    return seen
