"""Functional joints from a range-of-motion clip: what each movement identifies.

A controlled study on **the generator's points** (a truth input, said here and in every
result): each body part's measured points are points of the generator's surface
(:meth:`lsmta.synth.body.Body.sample_surface`), followed through the motion by their
body-local identity (the tracking is perfect), with Gaussian noise; a point is missing
(NaN) in a frame where it lies inside another part, and, for the papers' three cameras in
front (``cameras``), where fewer than two cameras see it (ray-cast occlusion by the body,
:func:`lsmta.synth.render.project_surface_points`). The system's own surface points are
another study (issue 36, item 1). The library then finds every joint from the two
neighbouring segments' points alone (:mod:`lsmta.body.functional_joints`); the truth is
compared after the fact: the centre against the true joint (the child part's origin) in
every frame, and the distances between found centres within one segment against the
generator's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_int, as_rng, as_scalar
from ..body.functional_joints import (
    JointCentre,
    JointStatus,
    SegmentMotion,
    fit_joint,
    frame_mask,
    segment_motion,
)
from ..synth.body import Body, Motion, inside_parts
from ..synth.render import Scene, project_surface_points

# joint -> (parent part, child part)
JOINTS = {"spine": ("pelvis", "torso"), "neck": ("torso", "head")} | {
    f"{j}_{s}": (p.format(s), c.format(s)) for s in ("r", "l") for j, p, c in (
        ("shoulder", "torso", "upper_arm_{}"), ("elbow", "upper_arm_{}", "forearm_{}"),
        ("wrist", "forearm_{}", "hand_{}"), ("hip", "pelvis", "thigh_{}"),
        ("knee", "thigh_{}", "shank_{}"), ("ankle", "shank_{}", "foot_{}"))}
MAJOR = ("spine", "shoulder_r", "shoulder_l", "elbow_r", "elbow_l", "hip_r", "hip_l", "knee_r",
         "knee_l")
# length -> (segment, joint, joint): the distance between two centres in that segment's frame
LENGTHS = {"trunk": ("torso", "spine", "neck"),
           "shoulder width": ("torso", "shoulder_r", "shoulder_l"),
           "hip width": ("pelvis", "hip_r", "hip_l")} | {
    f"{k}_{s}": (k + f"_{s}", f"{a}_{s}", f"{b}_{s}") for s in ("r", "l") for k, a, b in (
        ("upper_arm", "shoulder", "elbow"), ("forearm", "elbow", "wrist"),
        ("thigh", "hip", "knee"), ("shank", "knee", "ankle"))}


@dataclass(frozen=True, eq=False)
class SegmentPoints:
    """Measured points of every part over a motion (the study's input).

    Attributes
    ----------
    points : dict
        Part name -> ``(T, n, 3)`` world points, mm, NaN where not measured.
    seen : float
        Share of (frame, point) entries measured.
    """

    points: dict
    seen: float


def segment_points(body: Body, motion: Motion, *, n_per_part: int = 100,
                   noise_mm: float = 1.0, cameras=None,
                   rng: np.random.Generator | int | None = None) -> SegmentPoints:
    """Points of the generator's surface per part, as measured (module docstring).

    Parameters
    ----------
    body : Body
        The generator's body.
    motion : Motion
        Its motion, T frames.
    n_per_part : int
        Surface points drawn on each part.
    noise_mm : float
        Gaussian noise per coordinate, mm.
    cameras : sequence of Camera, optional
        Keep a point only in frames where at least two of them see it (at most two
        cameras: where all do); default: every point outside the other parts.
    rng : Generator, int or None
        The surface points and the noise.

    Returns
    -------
    SegmentPoints
        ``points[part]`` of shape ``(T, n_per_part, 3)``, mm, NaN where not measured.
    """
    rng = as_rng(rng)
    n = as_int(n_per_part, "n_per_part", minimum=3)
    noise = as_scalar(noise_mm, "noise_mm", nonnegative=True)
    part, local = body.sample_surface(n_per_part=n, rng=rng)
    world = body.to_world(motion, part, local)
    poses = body.part_poses(motion)
    hidden = np.stack([inside_parts(body, poses[f], world[f], exclude=part)
                       for f in range(motion.n_frames)])
    if cameras is not None:
        cameras = list(cameras)
        vis = project_surface_points(Scene(body=body, motion=motion), cameras, part,
                                     local).visible
        hidden |= vis.sum(axis=1) < min(2, len(cameras))
    measured = world + rng.normal(0.0, noise, world.shape)
    measured[hidden] = np.nan
    return SegmentPoints(points={name: measured[:, part == k] for k, name in
                                 enumerate(body.names)},
                         seen=float(1 - hidden.mean()))


def segment_motions(data: SegmentPoints) -> dict:
    """Each part's rigid motion from its points (:func:`segment_motion`)."""
    return {name: segment_motion(p) for name, p in data.points.items()}


def fit_joints(motions: dict, *, frames=None, max_centre_sd: float = 5.0) -> dict:
    """Every joint of :data:`JOINTS` from its two segments' motions.

    Parameters
    ----------
    motions : dict
        Part name -> :class:`SegmentMotion` (:func:`segment_motions`), every part of
        :data:`JOINTS`, all over the same T frames.
    frames : sequence of int or (T,) bool array, optional
        The frames to use (default all), as :func:`~lsmta.body.functional_joints.fit_joint`.
    max_centre_sd : float
        As :func:`~lsmta.body.functional_joints.fit_joint`, mm.

    Returns
    -------
    dict
        Joint name -> :class:`JointCentre`; a joint whose two segments share fewer than 3
        posed frames among ``frames`` is left out (and only such a joint).

    Raises
    ------
    ValueError
        ``max_centre_sd`` not positive, ``frames`` not indices or a mask of the T frames,
        or motions over different frame counts.
    TypeError
        A motion that is not a :class:`SegmentMotion`.
    KeyError
        A part of :data:`JOINTS` missing from ``motions``.
    """
    max_sd = as_scalar(max_centre_sd, "max_centre_sd", positive=True)
    parts = {p for pair in JOINTS.values() for p in pair}
    for name in parts:
        if name not in motions:
            raise KeyError(f"motions: expected a SegmentMotion of part {name!r}")
        if not isinstance(motions[name], SegmentMotion):
            raise TypeError(f"motions[{name!r}]: expected a SegmentMotion, got "
                            f"{type(motions[name]).__name__}")
    counts = {motions[name].n_frames for name in parts}
    if len(counts) != 1:
        raise ValueError(f"motions: expected one frame count for all parts, got {sorted(counts)}")
    chosen = frame_mask(frames, counts.pop())
    out = {}
    for name, (p, c) in JOINTS.items():
        if (chosen & motions[p].known & motions[c].known).sum() < 3:
            continue                                   # too few frames: not seen
        out[name] = fit_joint(motions[p], motions[c], frames=chosen, max_centre_sd=max_sd)
    return out


def _centre_in(joint: JointCentre, segment: str, parent: str) -> np.ndarray:
    return joint.parent_centre if segment == parent else joint.child_centre


def joint_scores(joints: dict, body: Body, motion: Motion) -> dict:
    """Per joint: status, determinacy and the centre's error against the true joint.

    Parameters
    ----------
    joints : dict
        Joint name -> :class:`JointCentre` (:func:`fit_joints`).
    body : Body
        The generator's body (the truth, after the fact).
    motion : Motion
        The motion the joints were fitted on, T frames.

    Returns
    -------
    dict
        Joint name (every one of :data:`JOINTS`) -> dict: ``status`` (a
        :class:`JointStatus` name, or ``"NOT_SEEN"`` where its segments share fewer than 3
        posed frames: nothing else then), ``determinacy``, ``axis_determinacy``,
        ``residual_mm``, ``centre_sd_mm``, ``n_frames``, and ``centre_error_rms_mm`` /
        ``centre_error_max_mm``: the centre's distance from the true joint (the child
        part's origin), RMS and worst over the frames the fit used (where ``world`` is
        finite), mm; None without a centre.
    """
    poses = body.part_poses(motion)
    out = {name: {"status": "NOT_SEEN"} for name in JOINTS if name not in joints}
    for name, j in joints.items():
        true = poses[:, body.index(JOINTS[name][1]), :3, 3]
        err = np.linalg.norm(j.world - true, axis=1)
        ok = np.isfinite(err)
        out[name] = {"status": j.status.name, "determinacy": j.determinacy,
                     "axis_determinacy": j.axis_determinacy, "residual_mm": j.residual,
                     "centre_sd_mm": j.centre_sd, "n_frames": j.n_frames,
                     "centre_error_rms_mm": float(np.sqrt(np.mean(err[ok] ** 2)))
                     if ok.any() else None,
                     "centre_error_max_mm": float(err[ok].max()) if ok.any() else None}
    return out


def length_scores(joints: dict, body: Body) -> dict:
    """Per length of :data:`LENGTHS`: the distance between two found centres in one
    segment's frame against the generator's.

    Parameters
    ----------
    joints : dict
        Joint name -> :class:`JointCentre` (:func:`fit_joints`).
    body : Body
        The generator's body (the true lengths).

    Returns
    -------
    dict
        Length name -> ``{"found_mm", "true_mm", "error_pct"}``: found and true distance,
        mm, and the error in % of the truth; ``found_mm`` and ``error_pct`` are None where a
        centre is missing (UNDETERMINED or not fitted).
    """
    out = {}
    for name, (segment, a, b) in LENGTHS.items():
        ends_true = []
        for j in (a, b):
            parent, child = JOINTS[j]
            ends_true.append(np.zeros(3) if segment == child
                             else np.asarray(body.parts[body.index(child)].joint, float))
        true = float(np.linalg.norm(ends_true[0] - ends_true[1]))
        found = None
        if a in joints and b in joints:
            ca = _centre_in(joints[a], segment, JOINTS[a][0])
            cb = _centre_in(joints[b], segment, JOINTS[b][0])
            d = float(np.linalg.norm(ca - cb))
            found = d if np.isfinite(d) else None
        out[name] = {"found_mm": found, "true_mm": true,
                     "error_pct": None if found is None else 100 * (found - true) / true}
    return out


def identified(joints: dict, *, status: JointStatus = JointStatus.CENTRE) -> list:
    """Names of the joints whose status is ``status`` or better (CENTRE < AXIS)."""
    return [k for k, j in joints.items() if j.status <= status]


def movement_table(motions: dict, motion: Motion, *, max_centre_sd: float = 5.0) -> dict:
    """What each movement identifies: every joint fitted from one phase's frames alone.

    Parameters
    ----------
    motions : dict
        Part name -> :class:`SegmentMotion` over ``motion``'s frames (:func:`segment_motions`).
    motion : Motion
        The clip, with named phases (:attr:`Motion.phases`).
    max_centre_sd : float
        As :func:`fit_joints`, mm.

    Returns
    -------
    dict
        Phase name -> joint name -> ``{"status", "determinacy", "axis_determinacy",
        "centre_sd_mm"}`` (``{"status": "NOT_SEEN"}`` as in :func:`joint_scores`).
    """
    out = {}
    for phase, start, stop in motion.phases:
        joints = fit_joints(motions, frames=np.arange(start, stop), max_centre_sd=max_centre_sd)
        out[phase] = {k: {"status": "NOT_SEEN"} if k not in joints else
                      {"status": joints[k].status.name, "determinacy": joints[k].determinacy,
                       "axis_determinacy": joints[k].axis_determinacy,
                       "centre_sd_mm": joints[k].centre_sd} for k in JOINTS}
    return out

