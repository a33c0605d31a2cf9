"""The arm: shoulder (three single-DoF joints), elbow, wrist, and three metaball segments.

Frames
    The base frame is the torso's (given per frame by the caller, e.g. from tracking:
    x to the body's right, y forward, z up); the shoulder sits at ``shoulder`` (mm, torso
    frame). The upper arm's bone frame is ``Ry(b) Rx(a) Rz(c)`` in the torso frame (b:
    ab/adduction in the frontal plane, a: flexion, c: rotation about the upper arm), built
    as three joints about their local z: ``b`` (``R_ini = Rx(-90°)`` maps z onto y), ``a``
    (``R_ini`` maps z onto x) and ``c``. This order puts the singular posture (gimbal lock)
    at 90° of flexion, outside an arm wave, whose abduction passes through 90°.
    The elbow flexes about the upper arm's x axis at ``L_upper s_upper`` along its bone;
    the wrist (held at 0 by default) likewise at the end of the forearm. Bones run along
    their bone frame's -z axis.

Motion state: ``(shoulder_b, shoulder_a, shoulder_c, elbow, wrist)`` radians; static
state: scales of ``(upper_arm, forearm, hand)`` and the radii of nine metaballs.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array
from .metaballs import MetaballModel, Segment
from .skeleton import Joint, Skeleton, as_tuple, rot_x, rot_y

JOINTS = ("shoulder_b", "shoulder_a", "shoulder_c", "elbow", "wrist")
LIMBS = ("upper_arm", "forearm", "hand")
_QX = rot_y(np.pi / 2)          # maps z onto x
_QY = rot_x(-np.pi / 2)         # maps z onto y


def arm_model(*, upper: float = 300.0, forearm: float = 265.0, hand: float = 170.0) -> \
        MetaballModel:
    """The right-arm model with template bone lengths (mm)."""
    bone = _QX.T                                      # flexion frame -> bone frame
    joints = (
        Joint(name="shoulder_b", parent=-1, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QY)),
        Joint(name="shoulder_a", parent=0, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QY.T @ _QX)),
        Joint(name="shoulder_c", parent=1, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QX.T)),
        Joint(name="elbow", parent=2, offset=(0.0, 0.0, -upper), rotation=as_tuple(_QX), limb=0),
        Joint(name="wrist", parent=3, offset=tuple(bone @ (0.0, 0.0, -forearm)),
              rotation=as_tuple(np.eye(3)), limb=1),
    )
    skeleton = Skeleton(joints, LIMBS)
    segments = (Segment(name="upper_arm", joint=2, rotation=as_tuple(np.eye(3)), length=upper,
                        limb=0),
                Segment(name="forearm", joint=3, rotation=as_tuple(bone), length=forearm, limb=1),
                Segment(name="hand", joint=4, rotation=as_tuple(bone), length=hand, limb=2))
    return MetaballModel(skeleton, segments)


def base_poses(torso_poses, shoulder) -> np.ndarray:
    """Base frames ``(T, 4, 4)``: the torso poses ``(T, 4, 4)`` moved to the shoulder
    ``(3,)`` or ``(T, 3)`` (torso frame, mm)."""
    P = as_array(torso_poses, "torso_poses", shape=(None, 4, 4))
    q = as_array(shoulder, "shoulder")
    q = np.broadcast_to(q, (len(P), 3))
    out = P.copy()
    out[:, :3, 3] = P[:, :3, 3] + np.einsum("tij,tj->ti", P[:, :3, :3], q)
    return out


def angles_from_joints(torso_poses, shoulder, elbow, wrist):
    """Inverse kinematics of tracked joint positions: the per-frame initialisation (§4.2).

    Parameters
    ----------
    torso_poses : (T, 4, 4) array
        Torso frame -> world.
    shoulder, elbow, wrist : (T, 3) arrays
        Tracked world positions, mm.

    Returns
    -------
    angles : (T, 5) array
        ``(shoulder_b, shoulder_a, shoulder_c, elbow, wrist=0)``, radians.
    shoulder_local : (T, 3) array
        The shoulder in the torso frame, mm.
    lengths : (T, 2) array
        Upper-arm and forearm lengths implied by the joints, mm.
    """
    P = as_array(torso_poses, "torso_poses", shape=(None, 4, 4))
    T = len(P)
    s, e, w = (as_array(x, n, shape=(T, 3)) for x, n in
               ((shoulder, "shoulder"), (elbow, "elbow"), (wrist, "wrist")))
    R = P[:, :3, :3]
    to_local = lambda v: np.einsum("tji,tj->ti", R, v)   # noqa: E731
    u = to_local(e - s)
    f = to_local(w - e)
    lengths = np.stack([np.linalg.norm(u, axis=1), np.linalg.norm(f, axis=1)], axis=1)
    for j, (a, b) in enumerate((("shoulder", "elbow"), ("elbow", "wrist"))):
        bad = np.flatnonzero(lengths[:, j] < 1e-6)
        if bad.size:
            raise ValueError(f"{b}: coincides with {a} in frame(s) {bad.tolist()}; expected "
                             f"distinct joints (a bone of non-zero length)")
    ez = -u / lengths[:, :1]
    fp = f - np.sum(f * ez, axis=1, keepdims=True) * ez
    n = np.linalg.norm(fp, axis=1, keepdims=True)
    ey = np.where(n > 1e-6 * lengths[:, 1:], fp / np.maximum(n, 1e-12),
                  np.cross(ez, [1.0, 0.0, 0.0]))
    ey /= np.linalg.norm(ey, axis=1, keepdims=True)
    ex = np.cross(ey, ez)
    U = np.stack([ex, ey, ez], axis=2)                         # columns
    elbow_angle = np.arctan2(np.sum(f * ey, axis=1), -np.sum(f * ez, axis=1))
    angles = np.concatenate([shoulder_angles(U), elbow_angle[:, None], np.zeros((T, 1))],
                            axis=1)
    shoulder_local = to_local(s - P[:, :3, 3])
    return angles, shoulder_local, lengths


def shoulder_angles(U) -> np.ndarray:
    """Angles ``(b, a, c)`` with ``U = Ry(b) Rx(a) Rz(c)`` for ``U (..., 3, 3)``, radians."""
    U = np.asarray(U, float)
    a = -np.arcsin(np.clip(U[..., 1, 2], -1, 1))
    b = np.arctan2(U[..., 0, 2], U[..., 2, 2])
    c = np.arctan2(U[..., 1, 0], U[..., 1, 1])
    return np.stack([b, a, c], axis=-1)
