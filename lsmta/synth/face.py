"""A synthetic marked face: 76 markers, expression modes, rigid head motion, occlusion.

Head frame: x to the face's left-to-right as seen from the front (viewer's right), y up,
z out of the face (forward); origin near the centre of the head; millimetres. The face
surface is a half-ellipsoid (160 mm wide, 220 mm tall, 95 mm deep) with a nose, eye
sockets, lips and a chin; 76 markers sit on it at hand-placed positions (forehead, brows,
around the eyes, nose, cheeks, lips, chin, jaw line). Six expression modes move them as
smooth displacement fields: jaw open (a rotation of everything below the mouth about a
hinge behind the cheeks), smile, brows up, pucker, frown and a sideways mouth shift. The
four markers under the eyes, the eye corners, the temples and the upper two forehead rows
are never moved by an expression (``MarkedFace.rigid``; the thesis's Fig. 64 uses such
markers to measure accuracy). The face closed into a head, and markers hidden by it, are in
:mod:`lsmta.synth.head_surface`.

World frame as in :mod:`lsmta.synth.rigs`: X right, Y away from the cameras, Z up. At zero
head rotation the face looks along -Y (towards cameras placed at negative Y).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from .._validate import as_array, as_int, as_rng, as_scalar
from ..camera import Camera

MODES = ("jaw_open", "smile", "brows_up", "pucker", "frown", "mouth_shift")

# surface shape, mm
_A, _B, _C = 80.0, 110.0, 95.0


def _sym(pts):
    """Points (x, y) with x > 0 mirrored to -x (x == 0 kept once)."""
    out = []
    for x, y in pts:
        out.append((x, y))
        if x != 0:
            out.append((-x, y))
    return out


_LAYOUT = {
    "forehead_top": _sym([(10, 88), (30, 88)]),
    "forehead": _sym([(0, 75), (20, 75), (40, 75)]),
    "forehead_low": _sym([(10, 60), (30, 60)]),
    "glabella": [(0, 45)],
    "brow": _sym([(15, 38), (30, 38), (45, 38)]),
    "eye_corner": _sym([(14, 20), (52, 20)]),
    "under_eye": _sym([(22, 5), (40, 5)]),
    "temple": _sym([(68, 20), (60, 50)]),
    "nose": [(0, 25), (0, 10), (0, -8), (0, -22)] + _sym([(14, -15)]),
    "cheek": _sym([(55, -5), (35, -20), (55, -20), (45, -35), (62, -35)]),
    "nasolabial": _sym([(25, -30)]),
    "upper_lip": _sym([(0, -42), (10, -42), (20, -42)]),
    "mouth_corner": _sym([(28, -50)]),
    "lower_lip": _sym([(0, -58), (10, -58), (20, -58)]),
    "chin": _sym([(0, -75), (15, -75), (0, -90), (18, -90), (20, -70)]),
    "jaw": _sym([(55, -60), (40, -80), (65, -45)]),
}


def _depth(x, y):
    """Face surface z(x, y) in the head frame, mm."""
    r = np.clip(1 - (x / _A) ** 2 - (y / _B) ** 2, 0.02, None)
    z = _C * np.sqrt(r)
    z = z + 24 * np.exp(-(x / 13) ** 2 - ((y + 2) / 26) ** 2)           # nose
    z = z - 7 * np.exp(-((np.abs(x) - 32) / 13) ** 2 - ((y - 18) / 9) ** 2)  # eye sockets
    z = z + 6 * np.exp(-(x / 24) ** 2 - ((y + 50) / 11) ** 2)            # lips
    z = z + 5 * np.exp(-(x / 20) ** 2 - ((y + 82) / 10) ** 2)            # chin
    return z


def _normals(x, y, h=0.5):
    dzdx = (_depth(x + h, y) - _depth(x - h, y)) / (2 * h)
    dzdy = (_depth(x, y + h) - _depth(x, y - h)) / (2 * h)
    n = np.stack([-dzdx, -dzdy, np.ones_like(x)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


@dataclass(frozen=True)
class MarkedFace:
    """The generator's marked face (the library's learned face model is
    :class:`lsmta.face.FaceModel`).

    Attributes
    ----------
    labels : tuple of str, length M (76)
        ``<group>_<index>`` names.
    groups : tuple of str, length M
        Anatomical group of each marker (keys of the layout: ``"under_eye"``, ``"lips"``...).
    neutral : (M, 3) array
        Neutral marker positions in the head frame, mm.
    normals : (M, 3) array
        Unit outward surface normals at the neutral markers (head frame).
    modes : (E, M, 3) array
        Displacement of every marker at full strength of each expression mode, mm.
    mode_names : tuple of str, length E
    rigid : (M,) bool array
        Markers no expression moves (under the eyes, upper forehead).
    """

    labels: tuple
    groups: tuple
    neutral: np.ndarray
    normals: np.ndarray
    modes: np.ndarray
    mode_names: tuple
    rigid: np.ndarray

    def group(self, name: str) -> np.ndarray:
        """Indices of the markers of one group."""
        idx = np.flatnonzero(np.array(self.groups) == name)
        if not len(idx):
            raise ValueError(f"name: no group {name!r}; groups are {sorted(set(self.groups))}")
        return idx

    def shapes(self, weights) -> np.ndarray:
        """Marker positions in the head frame, ``(T, M, 3)`` mm, for expression weights
        ``(T, E)`` (0 = neutral, 1 = full mode)."""
        w = as_array(weights, "weights", shape=(None, len(self.mode_names)))
        return self.neutral + np.einsum("te,emk->tmk", w, self.modes)


def _gauss(x, y, cx, cy, s):
    return np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s ** 2))


def face_model() -> MarkedFace:
    """The 76-marker face (deterministic)."""
    labels, groups, xy = [], [], []
    for g, pts in _LAYOUT.items():
        for i, p in enumerate(pts):
            labels.append(f"{g}_{i}")
            groups.append(g)
            xy.append(p)
    xy = np.array(xy, dtype=float)
    x, y = xy[:, 0], xy[:, 1]
    neutral = np.stack([x, y, _depth(x, y)], axis=1)
    normals = _normals(x, y)
    M = len(x)
    g = np.array(groups)
    rigid = np.isin(g, ["under_eye", "forehead_top", "forehead", "temple", "eye_corner"])
    modes = np.zeros((len(MODES), M, 3))
    # jaw open: rotate about a hinge axis parallel to x through (0, -25, -60)
    infl = np.clip((-38 - y) / 14, 0, 1)
    infl = infl * infl * (3 - 2 * infl)
    pivot = np.array([0.0, -25.0, -60.0])
    Rj = Rotation.from_rotvec([np.radians(16), 0, 0]).as_matrix()
    modes[0] = infl[:, None] * ((neutral - pivot) @ Rj.T + pivot - neutral)
    # smile: mouth corners out, up and back; cheeks up
    sx = np.sign(x)
    gc = _gauss(np.abs(x), y, 28, -50, 14)
    gk = _gauss(np.abs(x), y, 45, -25, 18)
    modes[1, :, 0] = 9 * sx * gc
    modes[1, :, 1] = 6 * gc + 5 * gk
    modes[1, :, 2] = -4 * gc + 1.5 * gk
    # brows up
    gb = np.exp(-((y - 38) / 12) ** 2) * (y > 25)
    modes[2, :, 1] = 9 * gb
    modes[2, :, 2] = 1.0 * gb
    # pucker: lips towards the centre and forward
    gl = _gauss(x, y, 0, -50, 17)
    modes[3, :, 0] = -0.4 * x * gl
    modes[3, :, 1] = -0.15 * (y + 50) * gl
    modes[3, :, 2] = 11 * gl
    # frown: inner brows down and in
    gf = np.exp(-((y - 40) / 10) ** 2) * np.exp(-((np.abs(x) - 12) / 18) ** 2)
    modes[4, :, 0] = -5 * sx * gf
    modes[4, :, 1] = -6 * gf
    # mouth shift sideways
    gm = _gauss(x, y, 0, -52, 22)
    modes[5, :, 0] = 8 * gm
    modes[5, :, 2] = -1.5 * gm * np.tanh(x / 15)
    modes[:, rigid] = 0.0
    return MarkedFace(labels=tuple(labels), groups=tuple(groups), neutral=neutral, normals=normals,
                     modes=modes, mode_names=MODES, rigid=rigid)


def expression_weights(n_frames: int, *, rng: np.random.Generator | int | None = None,
                       hold: float = 25.0, activity: float = 0.5,
                       modes: int = len(MODES)) -> np.ndarray:
    """Smooth, combined expression weights in [0, 1].

    Each mode gets knots every ``hold`` frames on average; a knot is 0 with probability
    ``1 - activity`` and uniform in (0.3, 1] otherwise; a monotone cubic (PCHIP) joins
    them, so weights stay in [0, 1] and change smoothly.

    Returns
    -------
    (n_frames, modes) array
    """
    rng = as_rng(rng)
    T = as_int(n_frames, "n_frames")
    hold = as_scalar(hold, "hold", positive=True)
    out = np.empty((T, modes))
    t = np.arange(T)
    for e in range(modes):
        knots = [0.0]
        while knots[-1] < T - 1:
            knots.append(knots[-1] + rng.uniform(0.5, 1.5) * hold)
        knots = np.array(knots)
        vals = np.where(rng.random(len(knots)) < activity, rng.uniform(0.3, 1.0, len(knots)),
                        0.0)
        vals[0] = 0.0
        out[:, e] = np.clip(PchipInterpolator(knots, vals)(t), 0, 1)
    return out


def head_motion(n_frames: int, *, rng: np.random.Generator | int | None = None,
                travel: float = 2000.0, height: float = 1650.0, yaw_deg: float = 50.0,
                pitch_deg: float = 12.0, roll_deg: float = 8.0):
    """Rigid head motion over a room-scale path.

    The head walks ``travel`` mm along X (with a gentle sway in Y) at ``height`` mm,
    turning left and right by up to ``yaw_deg`` (about the head's vertical axis) and
    nodding / tilting by up to ``pitch_deg`` / ``roll_deg``; all smooth, random phases.

    Returns
    -------
    R : (T, 3, 3) array
        Head-to-world rotations.
    t : (T, 3) array
        Head origin in the world, mm. World points: ``head @ R.T + t``.
    """
    rng = as_rng(rng)
    T = int(n_frames)
    s = np.linspace(0, 1, T)
    ph = rng.uniform(0, 2 * np.pi, 5)
    cyc = rng.uniform(1.0, 2.0, 3)
    yaw = yaw_deg * np.sin(2 * np.pi * cyc[0] * s + ph[0])
    pitch = pitch_deg * np.sin(2 * np.pi * cyc[1] * s + ph[1])
    roll = roll_deg * np.sin(2 * np.pi * cyc[2] * s + ph[2])
    # columns: head x -> world X, head y -> world Z, head z -> world -Y
    base = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)
    local = Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], axis=1), degrees=True)
    R = base @ local.as_matrix()
    t = np.stack([travel * (s - 0.5), 300 * np.sin(2 * np.pi * s + ph[3]),
                  height + 30 * np.sin(4 * np.pi * s + ph[4])], axis=1)
    return R, t


def head_turn(n_frames: int, *, yaw_deg: float = 80.0, turns: float = 1.0,
              position=(0.0, 0.0, 1650.0)):
    """A head standing still and turning from side to side about its vertical axis, with
    no nod or tilt: yaw ``yaw_deg * sin(2 pi turns s)`` for ``s`` from 0 to 1 over the
    frames (positive turns the face towards world +X). At zero yaw the face looks along
    -Y, towards cameras at negative Y.

    Parameters
    ----------
    n_frames : int
        Number of frames T.
    yaw_deg : float
        Largest turn either way, degrees (0 keeps the head facing -Y).
    turns : float
        Number of full left-right cycles over the frames (> 0).
    position : (3,) array_like
        Head origin in the world, mm (the same in every frame).

    Returns
    -------
    R : (T, 3, 3) array
        Head-to-world rotations.
    t : (T, 3) array
        Head origin in the world, mm.
    """
    T = as_int(n_frames, "n_frames")
    yaw_deg = as_scalar(yaw_deg, "yaw_deg")
    turns = as_scalar(turns, "turns", positive=True)
    pos = as_array(position, "position", shape=(3,))
    yaw = yaw_deg * np.sin(2 * np.pi * turns * np.linspace(0, 1, T))
    base = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)
    R = base @ Rotation.from_euler("Y", yaw[:, None], degrees=True).as_matrix()
    return R, np.tile(pos, (T, 1))


@dataclass(frozen=True)
class FaceSequence:
    """A generated face sequence (ground truth).

    Attributes
    ----------
    head : (T, M, 3) array
        Markers in the head frame, mm (expressions only).
    world : (T, M, 3) array
        Markers in the world, mm.
    normals : (T, M, 3) array
        Outward unit normals in the world: those of the neutral face under the head pose
        (expressions do not tilt them).
    weights : (T, E) array
        Expression weights.
    R : (T, 3, 3) array
    t : (T, 3) array
        Head pose, ``world = head @ R.T + t``.
    neutral : (M, 3) array or None
        The markers on the neutral face, head frame, mm (:attr:`MarkedFace.neutral`; the
        head's surface moves from there with the expression in
        :func:`lsmta.synth.head_surface.self_occlusion`).
    """

    head: np.ndarray
    world: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    R: np.ndarray
    t: np.ndarray
    neutral: np.ndarray | None = None


def face_sequence(model: MarkedFace, n_frames: int, *, rng: np.random.Generator | int | None = None,
                  moving: bool = True, hold: float = 25.0, activity: float = 0.5,
                  modes: int = len(MODES), motion=None) -> FaceSequence:
    """Expressions (:func:`expression_weights` with ``hold``, ``activity`` and ``modes``)
    on the face, with :func:`head_motion` if ``moving`` else a still head facing the
    cameras at the room's centre; ``motion``, a pair ``(R (T, 3, 3), t (T, 3) mm)`` such
    as :func:`head_turn` returns, is used instead when given (then leave ``moving`` at its
    default).

    Raises
    ------
    ValueError
        ``motion`` not a pair of arrays of those shapes, or given together with
        ``moving=False``.
    """
    rng = as_rng(rng)
    if motion is not None:
        if not moving:
            raise ValueError("moving: ignored when motion is given; pass one or the other")
        if not isinstance(motion, (tuple, list)) or len(motion) != 2:
            raise ValueError("motion: expected a pair (R, t) of arrays of shapes (T, 3, 3) and "
                             f"(T, 3), such as head_turn returns; got {type(motion).__name__}"
                             + (f" of length {len(motion)}" if hasattr(motion, "__len__") else ""))
    w = expression_weights(n_frames, rng=rng, hold=hold, activity=activity, modes=modes)
    head = model.shapes(w)
    if motion is not None:
        R = as_array(motion[0], "motion[0] (R)", shape=(len(w), 3, 3))
        t = as_array(motion[1], "motion[1] (t)", shape=(len(w), 3))
    elif moving:
        R, t = head_motion(n_frames, rng=rng)
    else:
        base = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)
        R = np.broadcast_to(base, (n_frames, 3, 3)).copy()
        t = np.tile([0.0, 0.0, 1650.0], (n_frames, 1))
    world = np.einsum("tij,tmj->tmi", R, head) + t[:, None]
    normals = np.einsum("tij,mj->tmi", R, model.normals)
    return FaceSequence(head=head, world=world, normals=normals, weights=w, R=R, t=t,
                        neutral=model.neutral)


def face_cameras(target, *, positions=None, f: float = 2400.0, width: int = 640,
                 height: int = 480) -> list[Camera]:
    """Narrow-field cameras aimed at ``target`` (e.g. the head position of one frame),
    like the thesis's guided pan-tilt cameras. Default positions: four cameras 3 m in
    front of the room's centre line, spread 3.2 m along X, at 2.2 m height."""
    target = as_array(target, "target", shape=(3,))
    if positions is None:
        positions = [(-1600.0, -3000.0, 2200.0), (-550.0, -3200.0, 2200.0),
                     (550.0, -3200.0, 2200.0), (1600.0, -3000.0, 2200.0)]
    return [Camera.look_at(p, target, f=f, width=width, height=height, name=f"pt{i}")
            for i, p in enumerate(positions)]


#: :func:`visible`'s default ``min_cos``: the normals rule's cosine between a marker's normal and
#: its line of sight (above it, the marker is seen)
VISIBLE_MIN_COS = 0.3


def visible(points, normals, centre, *, min_cos: float = VISIBLE_MIN_COS) -> np.ndarray:
    """Markers a camera at ``centre`` sees: the surface faces the camera with
    ``cos(angle between normal and line of sight) > min_cos`` (so half the face
    disappears as the head turns away). A stand-in: the face itself hiding markers
    (the nose in front of a cheek) is :func:`lsmta.synth.head_surface.self_occlusion`.

    Parameters
    ----------
    points, normals : (..., M, 3) arrays
        World positions (mm) and unit normals.
    centre : (3,) array
        Camera centre, mm.

    Returns
    -------
    (..., M) bool array
    """
    p = np.asarray(points, dtype=float)
    n = np.asarray(normals, dtype=float)
    v = np.asarray(centre, dtype=float) - p
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return (v * n).sum(axis=-1) > min_cos


def occlusion_schedule(n_frames: int, n_markers: int, start: int, end: int, *,
                       rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Markers removed at will: ``start`` visible at the first frame falling linearly to
    ``end`` at the last; markers disappear in a random order and stay hidden.

    Returns
    -------
    (n_frames, n_markers) bool array
        True where the marker is observed.
    """
    rng = as_rng(rng)
    if not 0 <= end <= start <= n_markers:
        raise ValueError(f"start, end: expected 0 <= end <= start <= {n_markers}")
    order = rng.permutation(n_markers)
    counts = np.round(np.linspace(start, end, int(n_frames))).astype(int)
    rank = np.empty(n_markers, dtype=int)
    rank[order] = np.arange(n_markers)
    return rank[None, :] < counts[:, None]
