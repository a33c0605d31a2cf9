"""The full-body skeleton of the layered model (Plänkers et al. 1999, Fig. 6), with
anatomical joint limits and three metaballs per segment.

Frames as in :mod:`lsmta.body.arm` and the generator's body: x to the body's right, y
forward, z up, mm; the base frame is the pelvis joint's world pose (position and heading).
A three-DoF joint (pelvis, trunk, shoulders, hips) is ``Ry(b) Rx(a) Rz(c)`` in its parent's
frame, built from three single-DoF joints (``b`` ab/adduction, ``a`` flexion, ``c`` twist;
see :mod:`lsmta.body.arm`); the neck has flexion and twist; elbows, wrists, knees and
ankles are hinges about their parent's x axis. At zero angles the body stands upright,
arms hanging, feet forward. Bones run along their bone frame's -z axis; the trunk and head
point up, the feet forward.

Limbs (scales): pelvis, trunk, head, upper arm, forearm, hand, thigh, shank, foot, shared
by the left and right sides. Template lengths are the generator's adult's, a person's
segment lengths are what the scales fit.

Joint limits (degrees, from standard ranges of motion; the sign follows the joint's axis:
positive ``a`` swings a hanging limb forward and bends the trunk backwards, the knee flexes
with negative angles) come from :func:`limits`; :func:`limit_violations` reports angles
outside them. :data:`TEMPLATE_SIZE` gives plausible ball sizes (width, depth per segment,
mm) to start a fit from.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array
from .metaballs import MetaballModel, Segment
from .skeleton import Joint, Skeleton, as_tuple, rot_x, rot_y

LIMBS = ("pelvis", "trunk", "head", "upper_arm", "forearm", "hand", "thigh", "shank", "foot")
LENGTHS = {"pelvis": 150.0, "trunk": 480.0, "head": 240.0, "upper_arm": 300.0,
           "forearm": 265.0, "hand": 170.0, "thigh": 440.0, "shank": 430.0, "foot": 200.0}
# ball widths and depths (mm) of each segment's middle ball (the skin lies at about 0.6 of
# a lone ball's radii)
TEMPLATE_SIZE = {"pelvis": (230.0, 150.0), "trunk": (250.0, 160.0), "head": (130.0, 140.0),
                 "upper_arm": (80.0, 80.0), "forearm": (65.0, 65.0), "hand": (35.0, 70.0),
                 "thigh": (115.0, 115.0), "shank": (85.0, 85.0), "foot": (70.0, 60.0)}
_QX = rot_y(np.pi / 2)          # maps z onto x
_QY = rot_x(-np.pi / 2)         # maps z onto y
_UP = rot_x(np.pi)              # a bone pointing up
_FORWARD = rot_x(np.pi / 2)     # a bone pointing forward (its -z onto +y)

# (lower, upper) in degrees for the right side; b and a and c of the three-DoF joints, hinges
# by name. Positive b swings a limb towards -x: abduction of a right limb is negative, of a
# left limb positive (the left side's b limits are mirrored). Positive a of the trunk and
# neck bends backwards; positive knee angles would bend the knee forwards.
_LIMITS_DEG = {
    "pelvis_b": (-180, 180), "pelvis_a": (-180, 180), "pelvis_c": (-180, 180),
    "trunk_b": (-35, 35), "trunk_a": (-90, 30), "trunk_c": (-45, 45),
    "neck_a": (-70, 60), "neck_c": (-80, 80),
    "shoulder_b": (-180, 50), "shoulder_a": (-60, 180), "shoulder_c": (-90, 90),
    "elbow": (0, 150), "wrist": (-70, 80),
    "hip_b": (-45, 30), "hip_a": (-30, 120), "hip_c": (-45, 45),
    "knee": (-150, 0), "ankle": (-50, 30),
}


def _ball(prefix: str, parent: int, offset, limb: int) -> list[Joint]:
    """Three single-DoF joints at one place: ``Ry(b) Rx(a) Rz(c)`` in the parent's frame."""
    return [Joint(name=f"{prefix}_b", parent=parent, offset=tuple(offset), rotation=as_tuple(_QY),
                  limb=limb),
            Joint(name=f"{prefix}_a", parent=-2, offset=(0.0, 0.0, 0.0),
                  rotation=as_tuple(_QY.T @ _QX)),
            Joint(name=f"{prefix}_c", parent=-2, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QX.T))]


def full_body_model() -> MetaballModel:
    """The full-body model with template lengths: 15 segments, 3 metaballs each."""
    joints: list[Joint] = []
    index: dict[str, int] = {}
    limb = {name: k for k, name in enumerate(LIMBS)}

    def add(group):
        for j in group:
            parent = len(joints) - 1 if j.parent == -2 else j.parent
            joints.append(Joint(name=j.name, parent=parent, offset=j.offset, rotation=j.rotation,
                                limb=j.limb))
            index[j.name] = len(joints) - 1

    def bone(length):                       # a hinge's child offset along the bone
        return tuple(_QX.T @ (0.0, 0.0, -length))

    add(_ball("pelvis", -1, (0.0, 0.0, 0.0), -1))
    add(_ball("trunk", index["pelvis_c"], (0.0, 0.0, 100.0), limb["pelvis"]))
    add([Joint(name="neck_a", parent=index["trunk_c"], offset=(0.0, 0.0, LENGTHS["trunk"]),
               rotation=as_tuple(_QX), limb=limb["trunk"]),
         Joint(name="neck_c", parent=-2, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QX.T))])
    for side, x in (("r", 1.0), ("l", -1.0)):
        add([Joint(name=j.name.replace("shoulder", f"shoulder_{side}"), parent=j.parent,
                   offset=j.offset, rotation=j.rotation, limb=j.limb)
             for j in _ball("shoulder", index["trunk_c"], (205.0 * x, 0.0, 430.0), limb["trunk"])])
        add([Joint(name=f"elbow_{side}", parent=index[f"shoulder_{side}_c"],
                   offset=(0.0, 0.0, -LENGTHS["upper_arm"]), rotation=as_tuple(_QX),
                   limb=limb["upper_arm"]),
             Joint(name=f"wrist_{side}", parent=-2, offset=bone(LENGTHS["forearm"]),
                   rotation=as_tuple(np.eye(3)), limb=limb["forearm"])])
        add([Joint(name=j.name.replace("hip", f"hip_{side}"), parent=j.parent, offset=j.offset,
                   rotation=j.rotation, limb=j.limb)
             for j in _ball("hip", index["pelvis_c"], (95.0 * x, 0.0, -20.0), limb["pelvis"])])
        add([Joint(name=f"knee_{side}", parent=index[f"hip_{side}_c"],
                   offset=(0.0, 0.0, -LENGTHS["thigh"]), rotation=as_tuple(_QX),
                   limb=limb["thigh"]),
             Joint(name=f"ankle_{side}", parent=-2, offset=bone(LENGTHS["shank"]),
                   rotation=as_tuple(np.eye(3)), limb=limb["shank"])])
    skeleton = Skeleton(tuple(joints), LIMBS)

    def seg(name, joint, rotation, limb_name):
        return Segment(name=name, joint=index[joint], rotation=as_tuple(rotation),
                       length=LENGTHS[limb_name], limb=limb[limb_name])

    segments = [seg("pelvis", "pelvis_c", np.eye(3), "pelvis"),
                seg("trunk", "trunk_c", _UP, "trunk"),
                seg("head", "neck_c", _UP, "head")]
    for s in ("r", "l"):
        segments += [seg(f"upper_arm_{s}", f"shoulder_{s}_c", np.eye(3), "upper_arm"),
                     seg(f"forearm_{s}", f"elbow_{s}", _QX.T, "forearm"),
                     seg(f"hand_{s}", f"wrist_{s}", _QX.T, "hand"),
                     seg(f"thigh_{s}", f"hip_{s}_c", np.eye(3), "thigh"),
                     seg(f"shank_{s}", f"knee_{s}", _QX.T, "shank"),
                     seg(f"foot_{s}", f"ankle_{s}", _QX.T @ _FORWARD, "foot")]
    return MetaballModel(skeleton, tuple(segments))


def limits(model: MetaballModel) -> np.ndarray:
    """Joint limits ``(J, 2)`` in radians (lower, upper) for the joints of ``model``
    (:func:`full_body_model`); left joints mirror the right's ab/adduction."""
    out = []
    for name in model.skeleton.names:
        left = "_l_" in name or name.endswith("_l")
        key = name.replace("_r_", "_").replace("_l_", "_")
        key = key[:-2] if key.endswith(("_r", "_l")) else key
        if key not in _LIMITS_DEG:
            raise ValueError(f"model: joint {name!r} has no anatomical limit")
        lo, hi = _LIMITS_DEG[key]
        if left and key.endswith("_b"):
            lo, hi = -hi, -lo
        out.append(np.radians([lo, hi]))
    return np.array(out)


def limit_violations(model: MetaballModel, angles) -> np.ndarray:
    """How far each angle of ``angles (T, J)`` lies outside its limit (radians, 0 inside)."""
    lim = limits(model)
    a = as_array(angles, "angles", shape=(None, len(lim)))
    return np.maximum(lim[:, 0] - a, 0.0) + np.maximum(a - lim[:, 1], 0.0)


def template_size(model: MetaballModel) -> np.ndarray:
    """:data:`TEMPLATE_SIZE` as the ``(S, 2)`` sizes of ``model``'s segments (for
    :meth:`MetaballModel.simplified_radii`)."""
    return np.array([TEMPLATE_SIZE[model.skeleton.limbs[s.limb]] for s in model.segments])
