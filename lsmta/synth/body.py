"""A textured articulated human: ellipsoidal body parts on a skeleton, and two motions.

Body frame (rest pose)
    x to the body's right, y forward (the direction the body faces), z up; mm. Every part
    has its own frame whose origin is its proximal joint; limbs hang along -z at rest.
Joint angles
    Each part carries three angles ``(a, b, c)`` in radians, applied as
    ``R = Rz(c) @ Ry(b) @ Rx(a)`` in the parent's frame: ``a`` is flexion (positive swings
    a hanging limb forward), ``b`` is ab/adduction (positive swings it towards -x, i.e.
    outwards for a left limb), ``c`` is twist about the limb. The root part (pelvis)
    uses the same angles for the whole body's orientation in the world (``c`` is the
    heading: 0 faces +Y, -pi/2 faces +X) and :attr:`Motion.root_position` for its place.
Texture
    Each part carries a solid texture: a sum of random 3-D sinusoids in the part's own
    frame, so a surface point keeps its grey value however the part moves, and the
    texture is band-limited by construction (wavelengths in a chosen band). ``contrast``
    is the relative standard deviation of the albedo modulation: about 0.3 looks like
    patterned clothing, 0.05 like skin or plain jeans.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_rng, as_scalar


@dataclass(frozen=True)
class Part:
    """One rigid body part: an ellipsoid in the frame of its proximal joint.

    Attributes
    ----------
    name : str
    parent : int
        Index of the parent part, -1 for the root.
    joint : (3,) tuple
        Position of this part's joint in the parent's frame (mm); for the root, in the
        body frame relative to :attr:`Motion.root_position`.
    centre : (3,) tuple
        Ellipsoid centre in the part's frame (mm).
    radii : (3,) tuple
        Ellipsoid semi-axes along the part's x, y, z (mm).
    albedo : float
        Mean reflectance in [0, 1].
    """

    name: str
    parent: int
    joint: tuple
    centre: tuple
    radii: tuple
    albedo: float


# name, parent, joint (in parent frame), centre, radii, albedo
_PARTS = [
    ("pelvis", None, (0, 0, 0), (0, 0, 30), (165, 105, 115), 0.50),
    ("torso", "pelvis", (0, 0, 100), (0, 0, 230), (175, 110, 260), 0.62),
    ("head", "torso", (0, 0, 480), (0, 10, 125), (80, 95, 115), 0.70),
    ("upper_arm_r", "torso", (205, 0, 430), (0, 0, -150), (50, 50, 165), 0.62),
    ("forearm_r", "upper_arm_r", (0, 0, -300), (0, 0, -130), (40, 40, 145), 0.68),
    ("hand_r", "forearm_r", (0, 0, -265), (0, 0, -80), (22, 45, 85), 0.72),
    ("upper_arm_l", "torso", (-205, 0, 430), (0, 0, -150), (50, 50, 165), 0.62),
    ("forearm_l", "upper_arm_l", (0, 0, -300), (0, 0, -130), (40, 40, 145), 0.68),
    ("hand_l", "forearm_l", (0, 0, -265), (0, 0, -80), (22, 45, 85), 0.72),
    ("thigh_r", "pelvis", (95, 0, -20), (0, 0, -220), (78, 78, 245), 0.40),
    ("shank_r", "thigh_r", (0, 0, -440), (0, 0, -210), (55, 55, 230), 0.40),
    ("foot_r", "shank_r", (0, 0, -430), (0, 60, -35), (45, 115, 38), 0.30),
    ("thigh_l", "pelvis", (-95, 0, -20), (0, 0, -220), (78, 78, 245), 0.40),
    ("shank_l", "thigh_l", (0, 0, -440), (0, 0, -210), (55, 55, 230), 0.40),
    ("foot_l", "shank_l", (0, 0, -430), (0, 60, -35), (45, 115, 38), 0.30),
]
STANDING_PELVIS_HEIGHT = 960.0  # mm, with the feet on the floor


@dataclass(frozen=True, eq=False)
class SolidTexture:
    """Band-limited solid texture: per part, a sum of random 3-D sinusoids.

    ``value(part, p) = 1 + contrast[part] * sum_k a_k sin(2 pi (p . u_k) / l_k + phi_k)``
    with unit directions ``u_k``, wavelengths ``l_k`` (mm), phases ``phi_k`` and
    amplitudes ``a_k = sqrt(2 / n)``, so that the sum has unit variance.

    Attributes
    ----------
    directions : (P, n, 3) array
    wavelengths : (P, n) array, mm
    phases : (P, n) array, radians
    contrast : (P,) array
    """

    directions: np.ndarray
    wavelengths: np.ndarray
    phases: np.ndarray
    contrast: np.ndarray

    @classmethod
    def random(cls, n_parts: int, contrast, *, rng: np.random.Generator | int | None = None,
               wavelength=(25.0, 120.0), n_waves: int = 24) -> SolidTexture:
        """Draw a texture for ``n_parts`` parts; ``contrast`` is a scalar or ``(n_parts,)``."""
        rng = as_rng(rng)
        lo, hi = (as_scalar(w, "wavelength", positive=True) for w in wavelength)
        if not lo <= hi:
            raise ValueError(f"wavelength: expected (shortest, longest), got {wavelength}")
        u = rng.normal(size=(n_parts, n_waves, 3))
        u /= np.linalg.norm(u, axis=2, keepdims=True)
        lam = np.exp(rng.uniform(np.log(lo), np.log(hi), size=(n_parts, n_waves)))
        phi = rng.uniform(0, 2 * np.pi, size=(n_parts, n_waves))
        c = as_array(contrast, "contrast")
        if c.ndim > 1 or c.size not in (1, n_parts):
            raise ValueError(f"contrast: expected a number or {n_parts} numbers (one per part), "
                             f"got shape {c.shape}")
        c = np.broadcast_to(c.reshape(-1), (n_parts,)).copy()
        if np.any(c < 0):
            raise ValueError("contrast: expected values >= 0")
        return cls(directions=u, wavelengths=lam, phases=phi, contrast=c)

    def value(self, part, points) -> np.ndarray:
        """Texture values ``(M,)`` at part-local ``points`` ``(M, 3)`` on parts ``part`` ``(M,)``.

        Both arguments are used as given (no validation: this is the renderer's inner loop).
        """
        part = np.asarray(part, dtype=int)
        points = np.asarray(points, dtype=float)
        out = np.zeros(len(points))
        n = self.directions.shape[1]
        amp = np.sqrt(2.0 / n)
        for p in np.unique(part):
            sel = part == p
            pts = points[sel]
            k = 2 * np.pi / self.wavelengths[p]
            acc = np.zeros(len(pts))
            for j in range(n):
                acc += np.sin(k[j] * (pts @ self.directions[p, j]) + self.phases[p, j])
            out[sel] = 1.0 + self.contrast[p] * amp * acc
        return out


@dataclass(frozen=True, eq=False)
class Body:
    """An articulated body: parts on a tree, and their solid texture.

    Use :func:`make_body` for the standard adult.
    """

    parts: tuple
    texture: SolidTexture

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parts]

    def index(self, name: str) -> int:
        """Index of the part called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"part: unknown part {name!r}; parts are {self.names}") from None

    def part_poses(self, motion: Motion, *, frames=None) -> np.ndarray:
        """World transforms of every part, ``(T, P, 4, 4)``: part frame -> world (mm).

        Parameters
        ----------
        motion : Motion
        frames : int or sequence of int, optional
            Frame indices (default: all frames of the motion).
        """
        frames = motion._frames(frames)
        angles = motion.joint_angles[frames]                 # (T, P, 3)
        T, P = angles.shape[:2]
        if P != len(self.parts):
            raise ValueError(f"motion: has angles for {P} parts, the body has {len(self.parts)}")
        rot = _euler_zyx(angles)                              # (T, P, 3, 3)
        poses = np.zeros((T, P, 4, 4))
        poses[..., 3, 3] = 1.0
        for i, part in enumerate(self.parts):
            local = np.zeros((T, 4, 4))
            local[:, :3, :3] = rot[:, i]
            local[:, :3, 3] = part.joint
            local[:, 3, 3] = 1.0
            if part.parent < 0:
                local[:, :3, 3] += motion.root_position[frames]
                poses[:, i] = local
            else:
                poses[:, i] = poses[:, part.parent] @ local
        return poses

    def to_world(self, motion: Motion, part, local_points, *, frames=None) -> np.ndarray:
        """World coordinates ``(T, N, 3)`` of part-local points ``(N, 3)`` on parts ``(N,)``."""
        part = self._part_indices(part, local_points)
        pts = as_array(local_points, "local_points", shape=(None, 3))
        poses = self.part_poses(motion, frames=frames)[:, part]     # (T, N, 4, 4)
        return np.einsum("tnij,nj->tni", poses[..., :3, :3], pts) + poses[..., :3, 3]

    def sample_surface(self, *, n_per_part: int = 100, parts=None,
                       rng: np.random.Generator | int | None = None):
        """Points on the part ellipsoids, in part-local coordinates.

        Directions are drawn uniformly on the unit sphere and stretched by the radii (so
        the points are denser where an ellipsoid is more curved).

        Returns
        -------
        part : (M,) int array
        local_points : (M, 3) array, mm
        """
        rng = as_rng(rng)
        idx = range(len(self.parts)) if parts is None else [
            self.index(p) if isinstance(p, str) else int(p) for p in parts]
        part_ids, points = [], []
        for i in idx:
            u = rng.normal(size=(n_per_part, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            points.append(np.asarray(self.parts[i].centre) + u * np.asarray(self.parts[i].radii))
            part_ids.append(np.full(n_per_part, i))
        return np.concatenate(part_ids), np.concatenate(points)

    def _part_indices(self, part, local_points) -> np.ndarray:
        n = len(np.asarray(local_points))
        if isinstance(part, str):
            return np.full(n, self.index(part))
        part = np.asarray(part)
        if part.ndim == 0:
            part = np.full(n, int(part))
        if part.shape != (n,) or not np.issubdtype(part.dtype, np.integer):
            raise ValueError(f"part: expected a part name, an index or ({n},) integer indices")
        if part.size and (part.min() < 0 or part.max() >= len(self.parts)):
            raise ValueError(f"part: indices must lie in [0, {len(self.parts) - 1}]")
        return part


def make_body(*, rng: np.random.Generator | int | None = None, contrast=0.3,
              wavelength=(25.0, 120.0), n_waves: int = 24) -> Body:
    """The standard adult (about 1.75 m) with a random solid texture.

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        Draws the texture.
    contrast : float or mapping
        Texture contrast (relative standard deviation of the albedo); a mapping from part
        name to contrast sets parts individually, e.g. ``{"thigh_r": 0.05, ...}``, parts
        not named get 0.3.
    wavelength : (float, float)
        Shortest and longest texture wavelength in mm. At 4.5 m from the triplet rig one
        pixel covers about 4.7 mm, so the default band spans about 5 to 25 pixels.
    n_waves : int
        Sinusoids per part.
    """
    rng = as_rng(rng)
    index = {}
    parts = []
    for name, parent, joint, centre, radii, albedo in _PARTS:
        index[name] = len(parts)
        parts.append(Part(name=name, parent=-1 if parent is None else index[parent], joint=joint,
                          centre=centre, radii=radii, albedo=albedo))
    if isinstance(contrast, Mapping):
        unknown = set(contrast) - set(index)
        if unknown:
            raise ValueError(f"contrast: unknown part names {sorted(unknown)}")
        contrast = [contrast.get(p.name, 0.3) for p in parts]
    texture = SolidTexture.random(len(parts), contrast, rng=rng, wavelength=wavelength,
                                  n_waves=n_waves)
    return Body(parts=tuple(parts), texture=texture)


@dataclass(frozen=True, eq=False)
class Motion:
    """Joint angles and root position per frame: the ground truth of a motion.

    Attributes
    ----------
    name : str
    fps : float
        Frame rate (Hz).
    root_position : (T, 3) array
        Position of the pelvis joint in the world (mm).
    joint_angles : (T, P, 3) array
        Angles ``(flexion, abduction, twist)`` per part in radians (module docstring).
    part_names : tuple of str
    phases : tuple of (str, int, int)
        Named movements of the clip: ``(name, first frame, stop frame)`` (stop exclusive),
        in order; empty for a motion of one movement (:func:`range_of_motion` fills it).
    """

    name: str
    fps: float
    root_position: np.ndarray
    joint_angles: np.ndarray
    part_names: tuple
    phases: tuple = ()

    def __post_init__(self):
        # ground truth: keep private, read-only copies
        for key in ("root_position", "joint_angles"):
            arr = np.array(getattr(self, key), dtype=float)
            arr.flags.writeable = False
            object.__setattr__(self, key, arr)
        T = len(self.root_position)
        try:
            phases = tuple((n, a, b) for n, a, b in self.phases)
        except (TypeError, ValueError):
            raise ValueError(f"phases: expected (name, start, stop) triples, got "
                             f"{self.phases!r}") from None
        for n, a, b in phases:
            if not isinstance(n, str) or not all(
                    isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in (a, b)):
                raise ValueError(f"phases: expected (str, int, int) triples, got {(n, a, b)!r}")
            if not 0 <= a <= b <= T:
                raise ValueError(f"phases: expected 0 <= start <= stop <= n_frames={T}, got "
                                 f"{(n, a, b)!r}")
        object.__setattr__(self, "phases", tuple((n, int(a), int(b)) for n, a, b in phases))

    @property
    def n_frames(self) -> int:
        return len(self.root_position)

    @property
    def times(self) -> np.ndarray:
        """Frame times in seconds, ``(T,)``."""
        return np.arange(self.n_frames) / self.fps

    def angle(self, part: str) -> np.ndarray:
        """The ``(T, 3)`` angles of the named part (radians)."""
        if part not in self.part_names:
            raise ValueError(f"part: unknown part {part!r}; parts are {list(self.part_names)}")
        return self.joint_angles[:, self.part_names.index(part)]

    def phase_frames(self, name: str) -> np.ndarray:
        """Frame indices ``(n,)`` of the movement called ``name`` (:attr:`phases`)."""
        for phase, start, stop in self.phases:
            if phase == name:
                return np.arange(start, stop)
        raise ValueError(f"name: the motion has no phase {name!r}; its phases are "
                         f"{[p[0] for p in self.phases]}")

    def _frames(self, frames) -> np.ndarray:
        if frames is None:
            return np.arange(self.n_frames)
        f = np.atleast_1d(np.asarray(frames))
        if not np.issubdtype(f.dtype, np.integer) or f.ndim != 1:
            raise ValueError("frames: expected an integer frame index or a 1-D sequence of them")
        if f.size and (f.min() < 0 or f.max() >= self.n_frames):
            raise ValueError(f"frames: indices must lie in [0, {self.n_frames - 1}]")
        return f


def _euler_zyx(angles: np.ndarray) -> np.ndarray:
    """``Rz(c) @ Ry(b) @ Rx(a)`` for angles ``(..., 3)`` = (a, b, c)."""
    a, b, c = angles[..., 0], angles[..., 1], angles[..., 2]
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    R = np.empty(angles.shape[:-1] + (3, 3))
    R[..., 0, 0] = cc * cb
    R[..., 0, 1] = cc * sb * sa - sc * ca
    R[..., 0, 2] = cc * sb * ca + sc * sa
    R[..., 1, 0] = sc * cb
    R[..., 1, 1] = sc * sb * sa + cc * ca
    R[..., 1, 2] = sc * sb * ca - cc * sa
    R[..., 2, 0] = -sb
    R[..., 2, 1] = cb * sa
    R[..., 2, 2] = cb * ca
    return R


def _empty_angles(n_frames: int):
    names = tuple(p[0] for p in _PARTS)
    return names, np.zeros((n_frames, len(names), 3))


def walk(*, n_frames: int = 50, fps: float = 25.0, start=(-1300.0, 0.0), heading_deg=0.0,
         speed: float = 1300.0, stride: float = 1.4e3, phase: float = 0.0) -> Motion:
    """A walk cycle along a straight line across the volume.

    Parameters
    ----------
    n_frames : int
        Number of frames.
    fps : float
        Frame rate in Hz (25 Hz: the full frames of PAL video).
    start : (float, float)
        Starting (X, Y) of the pelvis on the floor plan, mm.
    heading_deg : float
        Walking direction on the floor plan, degrees anticlockwise from +X (0: walking to
        the right across the cameras' view).
    speed : float
        Walking speed in mm/s.
    stride : float
        Length of one gait cycle (two steps) in mm.
    phase : float
        Gait phase at frame 0, radians.
    """
    as_int(n_frames, "n_frames")
    fps = as_scalar(fps, "fps", positive=True)
    speed = as_scalar(speed, "speed", nonnegative=True)
    stride = as_scalar(stride, "stride", positive=True)
    names, ang = _empty_angles(int(n_frames))
    t = np.arange(n_frames) / fps
    phi = 2 * np.pi * speed / stride * t + phase
    h = np.radians(heading_deg)
    direction = np.array([np.cos(h), np.sin(h)])
    start = as_array(start, "start", shape=(2,))
    root = np.zeros((int(n_frames), 3))
    root[:, :2] = start + (speed * t)[:, None] * direction
    root[:, 2] = STANDING_PELVIS_HEIGHT - 25 + 15 * np.cos(2 * phi)
    i = {n: k for k, n in enumerate(names)}
    ang[:, i["pelvis"], 2] = h - np.pi / 2 + 0.06 * np.sin(phi)
    ang[:, i["pelvis"], 1] = 0.04 * np.sin(2 * phi)
    ang[:, i["torso"], 2] = -0.10 * np.sin(phi)
    ang[:, i["torso"], 0] = 0.05
    ang[:, i["head"], 2] = 0.06 * np.sin(phi)
    for side, sign in (("r", 1.0), ("l", -1.0)):
        p = phi if side == "r" else phi + np.pi
        ang[:, i[f"thigh_{side}"], 0] = 0.05 + 0.38 * np.sin(p)
        ang[:, i[f"shank_{side}"], 0] = -(0.08 + 0.55 * (0.5 + 0.5 * np.sin(p + 1.2)) ** 2)
        ang[:, i[f"foot_{side}"], 0] = 0.12 * np.sin(p - 0.6)
        ang[:, i[f"upper_arm_{side}"], 0] = -0.35 * np.sin(p)
        ang[:, i[f"upper_arm_{side}"], 1] = -sign * 0.12
        ang[:, i[f"forearm_{side}"], 0] = 0.35 + 0.2 * (0.5 - 0.5 * np.sin(p))
    return Motion(name="walk", fps=fps, root_position=root, joint_angles=ang, part_names=names)


def arm_wave(*, n_frames: int = 50, fps: float = 25.0, position=(0.0, 0.0),
             heading_deg: float = -90.0, wave_hz: float = 0.8) -> Motion:
    """A seated person, facing the rig, raising and waving the right arm.

    The pelvis rests on an (invisible) seat 480 mm high; the left hand lies on the lap.
    The right shoulder abducts from about 30 to 120 degrees and the elbow flexes and
    extends while the arm waves.

    Parameters
    ----------
    n_frames : int
    fps : float
        Frame rate in Hz.
    position : (float, float)
        (X, Y) of the pelvis on the floor plan, mm.
    heading_deg : float
        Facing direction, degrees anticlockwise from +X (-90: facing the rig at -Y).
    wave_hz : float
        Frequency of the elbow's waving motion.
    """
    as_int(n_frames, "n_frames")
    fps = as_scalar(fps, "fps", positive=True)
    names, ang = _empty_angles(int(n_frames))
    t = np.arange(n_frames) / fps
    position = as_array(position, "position", shape=(2,))
    root = np.zeros((int(n_frames), 3))
    root[:, :2] = position
    root[:, 2] = 480.0 + 110.0
    i = {n: k for k, n in enumerate(names)}
    ang[:, i["pelvis"], 2] = np.radians(heading_deg) - np.pi / 2
    for side in ("r", "l"):
        ang[:, i[f"thigh_{side}"], 0] = 1.50
        ang[:, i[f"shank_{side}"], 0] = -1.45
        ang[:, i[f"foot_{side}"], 0] = 0.05
    ang[:, i["thigh_r"], 1] = 0.08
    ang[:, i["thigh_l"], 1] = -0.08
    raise_ = 0.5 - 0.5 * np.cos(2 * np.pi * 0.25 * t)      # raise the arm over ~2 s
    ang[:, i["upper_arm_r"], 1] = -(0.5 + 1.6 * raise_)
    ang[:, i["upper_arm_r"], 0] = 0.3 * raise_
    ang[:, i["forearm_r"], 0] = 0.3 + raise_ * (0.9 + 0.6 * np.sin(2 * np.pi * wave_hz * t))
    ang[:, i["forearm_r"], 2] = 0.3 * raise_
    ang[:, i["upper_arm_l"], 0] = 0.45
    ang[:, i["upper_arm_l"], 1] = 0.1
    ang[:, i["forearm_l"], 0] = 1.1
    ang[:, i["head"], 2] = 0.15 * np.sin(2 * np.pi * 0.3 * t)
    return Motion(name="arm_wave", fps=fps, root_position=root, joint_angles=ang, part_names=names)


RANGE_OF_MOTION_PHASES = ("trunk_bend", "trunk_twist", "arms_sideways", "arms_forward",
                          "leg_circles", "squat")
_LEG = (440.0, 430.0)            # thigh and shank lengths of _PARTS (hip-knee, knee-ankle), mm
_HIP = (95.0, -20.0)             # hip joints in the pelvis frame: (+-x, z), mm


def _angles_zyx(R: np.ndarray) -> np.ndarray:
    """Angles ``(..., 3)`` = (a, b, c) with ``Rz(c) @ Ry(b) @ Rx(a) = R`` (the inverse of
    :func:`_euler_zyx`; at ``|b| = pi/2`` the split between ``a`` and ``c`` puts a = 0)."""
    b = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    cb = np.hypot(R[..., 0, 0], R[..., 1, 0])
    lock = cb < 1e-9
    a = np.where(lock, 0.0, np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    c = np.where(lock, np.arctan2(-R[..., 0, 1], R[..., 1, 1]),
                 np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([a, b, c], axis=-1)


def _rot(a=0.0, b=0.0, c=0.0, *, n: int) -> np.ndarray:
    """``(n, 3, 3)`` rotations ``Rz(c) Ry(b) Rx(a)`` from scalars or ``(n,)`` arrays."""
    return _euler_zyx(np.stack(np.broadcast_arrays(a, b, c, np.zeros(n))[:3], axis=-1))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _leg(hip: np.ndarray, ankle: np.ndarray, forward: np.ndarray):
    """World rotations ``(T, 3, 3)`` of a thigh and a shank reaching from ``hip`` ``(T, 3)``
    to a planted ``ankle`` ``(3,)``, the knee bending towards ``forward`` ``(T, 3)`` (a pure
    hinge about the thigh's and the shank's common x axis)."""
    l1, l2 = _LEG
    d = ankle - hip
    D = np.linalg.norm(d, axis=1)
    d = d / D[:, None]
    cos1 = np.clip((l1 * l1 + D * D - l2 * l2) / (2 * l1 * D), -1.0, 1.0)
    e = _unit(forward - np.sum(forward * d, axis=1)[:, None] * d)
    knee = hip + l1 * (cos1[:, None] * d + np.sqrt(1 - cos1 ** 2)[:, None] * e)
    out = []
    for z in (_unit(hip - knee), _unit(knee - ankle)):
        y = _unit(e - np.sum(e * z, axis=1)[:, None] * z)
        out.append(np.stack([np.cross(y, z), y, z], axis=2))
    return out


def _phase_curves(n_frames: int, movements) -> tuple:
    """Per movement its frames and an eased 0..1 clock; and the ``phases`` tuple."""
    edges = np.round(np.linspace(0, n_frames, len(movements) + 1)).astype(int)
    clocks, phases = {}, []
    for name, lo, hi in zip(movements, edges[:-1], edges[1:]):
        u = np.arange(hi - lo) / max(hi - lo, 1)
        clocks[name] = (slice(lo, hi), u - np.sin(2 * np.pi * u) / (2 * np.pi))
        phases.append((name, int(lo), int(hi)))
    return clocks, tuple(phases)


def range_of_motion(*, n_frames: int = 200, fps: float = 25.0, position=(0.0, 0.0),
                    heading_deg: float = -90.0, movements=RANGE_OF_MOTION_PHASES) -> Motion:
    """A range-of-motion clip, as motion-capture practice records before the take.

    One named phase per movement (frames split evenly, in the order given; each starts and
    ends standing with the arms hanging; :attr:`Motion.phases`, :meth:`Motion.phase_frames`):

    ``trunk_bend``
        the trunk bends forward and to either side in one circle (up to 75 deg forward:
        35 at the hips, the pelvis tilting on the legs, 40 in the spine; 25 deg sideways in
        the spine and 8 deg of pelvic tilt); the head stays half level.
    ``trunk_twist``
        the trunk twists +-35 deg in the spine and +-12 deg at the hips (the pelvis turns on
        the legs); the head turns back by 14 deg.
    ``arms_sideways``
        both arms raised sideways to 150 deg, turning outwards (palms up) by 60 deg.
    ``arms_forward``
        both arms raised forwards to 150 deg; the elbows flex to about 110 deg twice and the
        wrists flex and extend +-50 deg on the way.
    ``leg_circles``
        each leg in turn draws a circle from the hip (flexion +-25 deg, abduction to 30
        deg, the knee bent 15 deg): the functional hip movement of gait laboratories (a
        star or circumduction; Camomilla et al. 2006, J. Biomech. 39, 1096-1106), not in
        issue 36's list, added because the trunk's movements turn the pelvis on the legs
        only a little sideways. The
        pelvis stays over both feet (a weight shift would tilt the standing shank sideways,
        which the model's hinge ankle cannot follow).
    ``squat``
        a half squat (hips 250 mm down and 180 mm back, pelvis tilted 35 deg forward, the
        arms forward 70 deg for balance).

    The ankles of the standing legs stay planted and their feet flat: each reaches from
    its hip to its ankle (the knee bending forwards), the hips lowered where a straight leg
    would not reach. Every joint stays inside the anatomical limits of
    :func:`lsmta.body.full_body.limits` (read in that model's angle order); the knees,
    elbows and wrists move as pure hinges.

    The true joint angles (:attr:`Motion.joint_angles`, ``(a, b, c)`` with ``Rz(c) Ry(b)
    Rx(a)``, read back by ``_angles_zyx``) jump near gimbal lock: where an arm is raised
    to about 90 deg and past, ``b`` nears +-90 deg and ``a`` and ``c`` trade large, sudden
    amounts (a smooth rotation, jumpy angles). Compare such joints as rotations, not angle
    by angle.

    Parameters
    ----------
    n_frames : int
        Frames of the whole clip (at least 4 per movement).
    fps : float
        Frame rate in Hz.
    position : (float, float)
        (X, Y) of the pelvis on the floor plan, mm.
    heading_deg : float
        Facing direction, degrees anticlockwise from +X (-90: facing the rig at -Y).
    movements : sequence of str
        Which movements, in which order (names of :data:`RANGE_OF_MOTION_PHASES`).
    """
    if isinstance(movements, str):
        movements = (movements,)
    try:
        movements = tuple(movements)
    except TypeError:
        raise ValueError(f"movements: expected a sequence of names among "
                         f"{RANGE_OF_MOTION_PHASES}, got {movements!r}") from None
    unknown = [m for m in movements if m not in RANGE_OF_MOTION_PHASES]
    if unknown or not movements or len(set(movements)) != len(movements):
        raise ValueError(f"movements: expected distinct names among {RANGE_OF_MOTION_PHASES}, "
                         f"got {movements}")
    T = as_int(n_frames, "n_frames")
    if T < 4 * len(movements):
        raise ValueError(f"n_frames: expected at least {4 * len(movements)} frames (4 per "
                         f"movement), got {T}")
    fps = as_scalar(fps, "fps", positive=True)
    position = as_array(position, "position", shape=(2,))
    heading = np.radians(as_scalar(heading_deg, "heading_deg")) - np.pi / 2
    clocks, phases = _phase_curves(T, movements)
    names, _ = _empty_angles(T)
    curves = _movement_curves(clocks, T)
    return _assemble_range_of_motion(names, {n: k for k, n in enumerate(names)}, T, fps,
                                     position, heading, phases, **curves)


def _movement_curves(clocks: dict, T: int) -> dict:
    """The movement curves of :func:`range_of_motion` (its docstring) for the phases'
    clocks: angles of the pelvis, trunk, head and arms, the hip midpoint's drop, legs in
    the air."""
    z = np.zeros(T)
    # angles of the trunk, pelvis, head and arms; world place of the hip midpoint (body frame)
    pel = {"a": z.copy(), "b": z.copy(), "c": z.copy()}
    torso = {"a": z.copy(), "b": z.copy(), "c": z.copy()}
    head = {"a": z.copy(), "c": z.copy()}
    hip_back, hip_down = z.copy(), z.copy()
    free = {side: (np.zeros(T, bool), z.copy(), z.copy(), z.copy()) for side in ("r", "l")}
    raise_side, turn_out, raise_fwd = z.copy(), z.copy(), z.copy()
    elbow, wrist = np.full(T, 0.15), z.copy()
    for name, (f, s) in clocks.items():
        up, swing = 0.5 - 0.5 * np.cos(2 * np.pi * s), np.sin(2 * np.pi * s)
        if name == "trunk_bend":
            pel["a"][f], torso["a"][f] = np.radians(-35) * up, np.radians(-40) * up
            pel["b"][f], torso["b"][f] = np.radians(8) * swing, np.radians(25) * swing
            head["a"][f] = np.radians(20) * up
        elif name == "trunk_twist":
            pel["c"][f], torso["c"][f] = np.radians(12) * swing, np.radians(35) * swing
            head["c"][f] = np.radians(-14) * swing
        elif name == "arms_sideways":
            raise_side[f], turn_out[f] = np.radians(150) * up, np.radians(60) * up
        elif name == "arms_forward":
            raise_fwd[f] = np.radians(150) * up
            elbow[f] = 0.15 + 1.8 * np.sin(2 * np.pi * s) ** 2
            wrist[f] = np.radians(50) * np.sin(4 * np.pi * s)
        elif name == "leg_circles":
            for half, side, x in ((s < 0.5, "r", 1.0), (s >= 0.5, "l", -1.0)):
                sub = np.where(half, (2 * s) % 1.0, 0.0)
                env = np.where(half, np.sin(np.pi * sub) ** 2, 0.0)
                mask, a, b, knee = free[side]
                idx = np.arange(T)[f][half & (sub > 0)]
                mask[idx] = True
                theta = 2 * np.pi * sub[half & (sub > 0)]
                a[idx] = np.radians(25) * np.sin(theta)
                b[idx] = -x * np.radians(15) * (1 - np.cos(theta))
                knee[idx] = -np.radians(15) * env[half & (sub > 0)]
        else:                                                  # squat
            hip_back[f], hip_down[f] = 180.0 * up, 250.0 * up
            pel["a"][f], torso["a"][f] = np.radians(-35) * up, np.radians(-10) * up
            raise_fwd[f] = np.radians(70) * up
    return {"pel": pel, "torso": torso, "head": head, "hip": (hip_back, hip_down), "free": free,
            "arms": (raise_side, turn_out, raise_fwd, elbow, wrist)}


def _assemble_range_of_motion(names, i, T, fps, position, heading, phases, *, pel, torso, head,
                              hip, free, arms) -> Motion:
    """Joint angles and root of :func:`range_of_motion` from its movement curves."""
    ang = np.zeros((T, len(names), 3))
    Rh = _rot(c=heading, n=T)                                   # the body's heading
    Rp = _rot(pel["a"], pel["b"], heading + pel["c"], n=T)      # pelvis in the world
    hip_mid = np.array([0.0, 0.0, _HIP[1]])
    standing = np.array([position[0], position[1], STANDING_PELVIS_HEIGHT + _HIP[1]])
    H = standing + np.einsum("tij,tj->ti", Rh, np.stack([0 * hip[0], -hip[0], -hip[1]], 1))
    root = H - np.einsum("tij,j->ti", Rp, hip_mid)
    ankles, hips = {}, {}
    for side, x in (("r", 1.0), ("l", -1.0)):
        ankles[side] = standing + Rh[0] @ (np.array([x * _HIP[0], 0.0, _HIP[1] - sum(_LEG)])
                                           - hip_mid)
        hips[side] = root + np.einsum("tij,j->ti", Rp, [x * _HIP[0], 0.0, _HIP[1]])
    # lower the hips where a straight leg would not reach its planted ankle
    excess = np.zeros(T)
    for side in ("r", "l"):
        horiz = np.linalg.norm((hips[side] - ankles[side])[:, :2], axis=1)
        reach = ankles[side][2] + np.sqrt(sum(_LEG) ** 2 - horiz ** 2) - 1e-6
        excess = np.maximum(excess, np.where(free[side][0], 0.0, hips[side][:, 2] - reach))
    root[:, 2] -= excess
    forward = np.einsum("tij,j->ti", Rh, [0.0, 1.0, 0.0])
    for side in ("r", "l"):
        hips[side][:, 2] -= excess
        thigh, shank = _leg(hips[side], ankles[side], forward)
        ang[:, i[f"thigh_{side}"]] = _angles_zyx(np.swapaxes(Rp, 1, 2) @ thigh)
        ang[:, i[f"shank_{side}"]] = _angles_zyx(np.swapaxes(thigh, 1, 2) @ shank)
        ang[:, i[f"foot_{side}"]] = _angles_zyx(np.swapaxes(shank, 1, 2) @ Rh)
        mask, a, b, knee = free[side]           # a leg in the air: its own angles
        ang[mask, i[f"thigh_{side}"]] = np.stack([a[mask], b[mask], 0 * a[mask]], axis=1)
        ang[mask, i[f"shank_{side}"]] = np.stack([knee[mask], 0 * a[mask], 0 * a[mask]], axis=1)
        ang[mask, i[f"foot_{side}"]] = 0.0
    ang[:, i["pelvis"]] = np.stack([pel["a"], pel["b"], heading + pel["c"]], axis=1)
    ang[:, i["torso"]] = np.stack([torso["a"], torso["b"], torso["c"]], axis=1)
    ang[:, i["head"]] = _angles_zyx(_rot(c=head["c"], n=T) @ _rot(a=head["a"], n=T))
    raise_side, turn_out, raise_fwd, elbow, wrist = arms
    for side, x in (("r", 1.0), ("l", -1.0)):
        arm = (_rot(a=raise_fwd, n=T) @ _rot(b=-x * (0.1 + raise_side), n=T)
               @ _rot(c=-x * turn_out, n=T))
        ang[:, i[f"upper_arm_{side}"]] = _angles_zyx(arm)
        ang[:, i[f"forearm_{side}"], 0] = elbow
        ang[:, i[f"hand_{side}"], 0] = wrist
    return Motion(name="range_of_motion", fps=fps, root_position=root, joint_angles=ang,
                  part_names=names, phases=phases)


def inside_parts(body: Body, poses, points, *, exclude=None) -> np.ndarray:
    """Which world points ``(N, 3)`` lie inside any part ellipsoid of one frame.

    Parameters
    ----------
    poses : (P, 4, 4) array
        Part -> world transforms of one frame.
    exclude : (N,) int array, optional
        For each point, a part not to test (the part it was sampled on).
    """
    pts = as_array(points, "points", shape=(None, 3))
    out = np.zeros(len(pts), bool)
    for p, spec in enumerate(body.parts):
        local = (pts - poses[p, :3, 3]) @ poses[p, :3, :3] - np.asarray(spec.centre)
        inside = np.sum((local / np.asarray(spec.radii)) ** 2, axis=1) < 1.0
        if exclude is not None:
            inside &= exclude != p
        out |= inside
    return out


def surface_samples(body: Body, motion: Motion, frame: int, *,
                    rng: np.random.Generator | int | None = None,
                    parts=("upper_arm_r", "forearm_r", "hand_r"), n: int = 1500,
                    noise_mm: float = 0.0, outlier_share: float = 0.0,
                    outlier_range_mm: float = 150.0, view_from=None):
    """Noisy samples of the true skin of some parts in one frame, with planted outliers.

    Points are drawn on the part ellipsoids (uniform in direction), those inside another
    part are discarded (so the samples lie on the body's outer surface), optionally only
    those facing ``view_from`` (a world point: the rig) are kept, and ``n`` are returned.
    Isotropic Gaussian noise of ``noise_mm`` per coordinate is added; a share
    ``outlier_share`` of the points is replaced by points drawn uniformly in the samples'
    bounding box grown by ``outlier_range_mm``.

    Returns
    -------
    points : (n, 3) array, world mm
    truth : (n, 3) array
        The noise-free surface point (NaN for outliers).
    part : (n,) int array
        Part of each sample (-1 for outliers).
    """
    rng = as_rng(rng)
    noise = as_scalar(noise_mm, "noise_mm", nonnegative=True)
    share = as_scalar(outlier_share, "outlier_share", nonnegative=True)
    if share >= 1:
        raise ValueError(f"outlier_share: expected a value in [0, 1), got {share}")
    poses = body.part_poses(motion, frames=frame)[0]
    part, local = body.sample_surface(n_per_part=4 * n, rng=rng, parts=parts)
    world = np.einsum("nij,nj->ni", poses[part, :3, :3], local) + poses[part, :3, 3]
    keep = ~inside_parts(body, poses, world, exclude=part)
    if view_from is not None:
        c = np.asarray([body.parts[p].centre for p in part])
        r = np.asarray([body.parts[p].radii for p in part])
        normal_local = (local - c) / r ** 2
        normal = np.einsum("nij,nj->ni", poses[part, :3, :3], normal_local)
        keep &= np.sum(normal * (np.asarray(view_from, float) - world), axis=1) > 0
    idx = np.flatnonzero(keep)
    if len(idx) < n:
        raise ValueError(f"n: only {len(idx)} surface samples survive; ask for fewer")
    idx = rng.choice(idx, n, replace=False)
    truth = world[idx]
    part = part[idx].copy()
    points = truth + rng.normal(0.0, noise, truth.shape) if noise > 0 else truth.copy()
    n_out = int(round(share * n))
    if n_out:
        which = rng.choice(n, n_out, replace=False)
        lo = truth.min(axis=0) - outlier_range_mm
        hi = truth.max(axis=0) + outlier_range_mm
        points[which] = rng.uniform(lo, hi, (n_out, 3))
        truth = truth.copy()
        truth[which] = np.nan
        part[which] = -1
    return points, truth, part
