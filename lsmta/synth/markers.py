"""Marker models and random articulated poses with ground truth (Holstein & Li 2002, 4.1).

Two human marker models built in code: the paper's 13-segment, 44-marker model (up to 6
markers a segment, torso the root; no hands) and a 15-segment, 49-marker full-body model
(with hands). Joint markers (neck, shoulders, elbows, wrists, waist, hips, knees, ankles)
are shared by the two segments they join. Coordinates are a standing adult, mm: x to the
subject's left, y forward, z up, feet on z = 0. The layouts within a segment are
deliberately not symmetric, like real marker placements.

A random pose applies one random translation to the whole body and, down the tree, a
random rotation to each segment about its joint (the root about its centroid), the angle
uniform in [0, level] rad about a uniformly random axis; children move with their parents.
Segmental distortion adds N(0, ψ·l̄_s)/√6 per coordinate to each marker (a joint marker
takes its parent's l̄_s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_int, as_rng, as_scalar
from ..sapm.model import MarkerModel

_AXIAL = {
    "neck": (0, -40, 1450), "sternum": (0, 100, 1300), "back": (30, -110, 1210),
    "waist": (0, -60, 1050), "sacrum": (0, -100, 980),
    "head_top": (0, 0, 1720), "head_front": (-40, 95, 1640), "head_back": (10, -90, 1650),
}
# one side (x > 0 is the subject's left); the right side mirrors x
_SIDE = {
    "temple": (70, 60, 1620), "sho": (180, 0, 1420), "elbow": (200, -10, 1130),
    "wrist": (210, 20, 870), "hip": (90, 30, 950), "asis": (120, 90, 1000),
    "knee": (95, 40, 520), "ankle": (90, 10, 90),
    "uarm_lat": (250, 0, 1280), "uarm_ant": (200, 45, 1230),
    "farm_lat": (240, 10, 1000), "farm_ant": (205, 50, 1040), "hand": (215, 30, 780),
    "knuckle2": (230, 50, 790), "knuckle5": (215, -20, 800), "finger": (225, 20, 700),
    "thigh_lat": (150, 20, 750), "thigh_ant": (100, 90, 700),
    "shank_lat": (135, 30, 330), "shank_ant": (95, 80, 280),
    "heel": (85, -40, 40), "toe": (100, 150, 30),
}


def _positions() -> dict:
    out = {k: np.array(v, float) for k, v in _AXIAL.items()}
    for side, sign in (("L", 1.0), ("R", -1.0)):
        for k, v in _SIDE.items():
            out[side + k] = np.array(v, float) * (sign, 1, 1)
    return out


def _limbs(side: str, hands: bool) -> tuple[dict, dict]:
    S = side
    segs = {
        f"{S}upper_arm": [f"{S}sho", f"{S}elbow", f"{S}uarm_lat", f"{S}uarm_ant"],
        f"{S}forearm": [f"{S}elbow", f"{S}wrist", f"{S}farm_lat", f"{S}farm_ant"]
        + ([] if hands else [f"{S}hand"]),
        f"{S}thigh": [f"{S}hip", f"{S}knee", f"{S}thigh_lat", f"{S}thigh_ant"],
        f"{S}shank": [f"{S}knee", f"{S}ankle", f"{S}shank_lat", f"{S}shank_ant"],
        f"{S}foot": [f"{S}ankle", f"{S}heel", f"{S}toe"],
    }
    parents = {f"{S}upper_arm": "torso", f"{S}forearm": f"{S}upper_arm", f"{S}thigh": "pelvis",
               f"{S}shank": f"{S}thigh", f"{S}foot": f"{S}shank"}
    if hands:
        segs[f"{S}hand"] = [f"{S}wrist", f"{S}knuckle2", f"{S}knuckle5", f"{S}finger"]
        parents[f"{S}hand"] = f"{S}forearm"
    return segs, parents


def human_model(*, hands: bool = False) -> MarkerModel:
    """The paper's human marker model.

    Parameters
    ----------
    hands : bool
        False: 13 segments, 44 markers (the model of the paper's Fig. 2); True: 15
        segments, 49 markers (the size of the paper's full-body protocol of Fig. 4).
    """
    segments = {
        "torso": ["neck", "Lsho", "Rsho", "sternum", "back", "waist"],
        "head": ["neck", "head_top", "Ltemple", "head_front"] + (["head_back"] if hands else []),
        "pelvis": ["waist", "Lhip", "Rhip", "Lasis", "Rasis", "sacrum"],
    }
    parents = {"torso": None, "head": "torso", "pelvis": "torso"}
    for side in "LR":
        s, p = _limbs(side, hands)
        segments.update(s)
        parents.update(p)
    pos = _positions()
    used = list(dict.fromkeys(k for labs in segments.values() for k in labs))
    return MarkerModel.from_labelled_frame({k: pos[k] for k in used}, segments, parents)


@dataclass(frozen=True)
class MarkerPose:
    """A generated pose and its truth.

    Attributes
    ----------
    observed : (N, 3) array
        Shuffled observed points, mm (markers that are not missing, plus extras).
    truth : (N,) int array
        Model marker index of each observed point, -1 for an extra point.
    points : (M, 3) array
        True positions of every model marker before distortion, mm.
    """

    observed: np.ndarray
    truth: np.ndarray
    points: np.ndarray


def _random_rotations(rng, n, level):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, level, n)
    return Rotation.from_rotvec(axis * angle[:, None]).as_matrix()


def random_pose(model: MarkerModel, *, rng: np.random.Generator | int | None = None,
                level: float = np.pi, distortion: float = 0.0, n_missing: int = 0, n_extra: int = 0,
                translation: float = 2000.0) -> MarkerPose:
    """A random articulated pose of ``model`` (Section 4.1 of the paper).

    Parameters
    ----------
    model : MarkerModel
    rng : numpy.random.Generator, int or None
    level : float
        Configuration level: rotation angles uniform in [0, level] rad (paper: 0..4).
    distortion : float
        ψ, the segmental distortion as a fraction of l̄_s (paper: 0..0.10).
    n_missing : int
        Markers removed at random (occlusion).
    n_extra : int
        Extra points uniform in the pose's bounding box enlarged by 10 % (noise).
    translation : float
        The common translation is uniform in ±translation mm per axis.
    """
    rng = as_rng(rng)
    level = as_scalar(level, "level", nonnegative=True)
    distortion = as_scalar(distortion, "distortion", nonnegative=True)
    M = model.n_points
    if not 0 <= n_missing <= M - 3:
        raise ValueError(f"n_missing: expected 0..{M - 3}, got {n_missing}")
    if n_extra < 0:
        raise ValueError(f"n_extra: expected >= 0, got {n_extra}")
    S = model.n_segments
    rot = _random_rotations(rng, S, level)
    A = np.zeros((S, 3, 3))
    b = np.zeros((S, 3))
    root = model.root_of_tree
    for s in model.tree_order(root):
        p = model.parent[s]
        c = model.points[model.members[s]].mean(axis=0) if p < 0 else model.joint[s]
        # local motion x -> rot (x - c) + c, then the parent's
        La, Lb = rot[s], c - rot[s] @ c
        if p < 0:
            A[s], b[s] = La, Lb + rng.uniform(-translation, translation, 3)
        else:
            A[s], b[s] = A[p] @ La, A[p] @ Lb + b[p]
    owner = model.point_segment
    points = np.einsum("mij,mj->mi", A[owner], model.points) + b[owner]
    noisy = points + rng.normal(size=points.shape) * (
        distortion * model.mean_length[owner] / np.sqrt(6.0))[:, None]
    keep = np.sort(rng.permutation(M)[: M - n_missing])
    obs, truth = noisy[keep], keep
    if n_extra:
        lo, hi = points.min(axis=0), points.max(axis=0)
        pad = 0.05 * (hi - lo)
        extra = rng.uniform(lo - pad, hi + pad, size=(n_extra, 3))
        obs = np.vstack([obs, extra])
        truth = np.concatenate([truth, np.full(n_extra, -1)])
    order = rng.permutation(len(obs))
    points.setflags(write=False)
    return MarkerPose(observed=obs[order], truth=truth[order], points=points)


@dataclass(frozen=True)
class MarkerClip:
    """A generated labelled clip and its truth.

    Attributes
    ----------
    points : (T, M, 3) array
        Every marker in every frame (the model's order), mm, with the segmental distortion.
    joints : (T, S, 3) array
        The true centre of rotation of each segment with its parent per frame, mm (NaN for
        the root).
    rotations : (T, S, 3, 3) array
        Each segment's true rotation, model -> world.
    """

    points: np.ndarray
    joints: np.ndarray
    rotations: np.ndarray


def marker_clip(model: MarkerModel, n_frames: int, *, rng: np.random.Generator | int | None = None,
                amplitude: float = 1.0, distortion=0.0, speed: float = 1.0) -> MarkerClip:
    """A smooth articulated motion of ``model`` (a labelled range-of-motion clip).

    Every segment turns about its joint with its parent (the root about its centroid) like
    a ball joint: its rotation vector is ``amplitude * sin(2 pi f_k t + phase_k) u_k``
    summed over two random perpendicular axes u_k, ``f_k`` uniform in [0.5, 1.5] ``speed``
    cycles over the clip; children move with their parents. Each
    marker of segment s then gets N(0, ψ_s l̄_s)/√6 per coordinate and frame, ψ =
    ``distortion`` (a scalar or (S,) per segment; a joint marker takes its parent's).

    Parameters
    ----------
    model : MarkerModel
    n_frames : int
    rng : numpy.random.Generator, int or None
    amplitude : float
        Largest turn of a joint, rad (0: a still clip).
    distortion : float or (S,) array
        ψ_s, a fraction of l̄_s.
    speed : float
        Cycles of the slowest joint over the clip, about.
    """
    rng = as_rng(rng)
    amplitude = as_scalar(amplitude, "amplitude", nonnegative=True)
    as_int(n_frames, "n_frames")
    S, T = model.n_segments, int(n_frames)
    psi = np.broadcast_to(np.asarray(distortion, float), (S,))
    if (psi < 0).any() or not np.isfinite(psi).all():
        raise ValueError(f"distortion: expected finite fractions >= 0, got {distortion}")
    axes = Rotation.random(S, random_state=rng.integers(1 << 31)).as_matrix()[:, :2]  # (S, 2, 3)
    freq = speed * rng.uniform(0.5, 1.5, (S, 2))
    phase = rng.uniform(0, 2 * np.pi, (S, 2))
    t = np.linspace(0, 1, T)
    angle = amplitude * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None])  # (T,S,2)
    rotvec = np.einsum("tsk,skj->tsj", angle, axes)
    rot = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(T, S, 3, 3)
    A = np.zeros((T, S, 3, 3))
    b = np.zeros((T, S, 3))
    joints = np.full((T, S, 3), np.nan)
    for s in model.tree_order(model.root_of_tree):
        p = model.parent[s]
        c = model.points[model.members[s]].mean(axis=0) if p < 0 else model.joint[s]
        La, Lb = rot[:, s], c - rot[:, s] @ c
        if p < 0:
            A[:, s], b[:, s] = La, Lb
        else:
            A[:, s] = A[:, p] @ La
            b[:, s] = np.einsum("tij,tj->ti", A[:, p], Lb) + b[:, p]
            joints[:, s] = np.einsum("tij,j->ti", A[:, p], c) + b[:, p]
    owner = model.point_segment
    points = np.einsum("tmij,mj->tmi", A[:, owner], model.points) + b[:, owner]
    sigma = psi[owner] * model.mean_length[owner] / np.sqrt(6.0)
    points = points + rng.normal(size=points.shape) * sigma[None, :, None]
    return MarkerClip(points=points, joints=joints, rotations=A)
