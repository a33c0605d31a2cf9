"""The full-body skeleton of the layered model (Plänkers et al. 1999, Fig. 6), with
anatomical joint limits and three metaballs per segment.

Frames as in :mod:`lsmta.body.arm` and the generator's body: x to the body's right, y
forward, z up, mm; the base frame is the pelvis joint's world pose (position and heading).
A three-DoF joint (pelvis, trunk, shoulders, hips) is ``Ry(b) Rx(a) Rz(c)`` in its parent's
frame, built from three single-DoF joints (``b`` ab/adduction, ``a`` flexion, ``c`` twist;
see :mod:`lsmta.body.arm`); the neck has flexion and twist; each clavicle lifts its
shoulder about the forward axis at the top of the sternum; elbows, wrists, knees and
ankles are hinges about their parent's x axis. At zero angles the body stands upright,
arms hanging, feet forward. Bones run along their bone frame's -z axis; the trunk and head
point up, the feet forward.

Limbs (scales): pelvis, trunk, head, upper arm, forearm, hand, thigh, shank, foot, shared
by the left and right sides. The template is built from published anthropometry scaled by
one stature ``H`` (:func:`template_lengths`), not from any one person: a person's segment
lengths are what the scales fit. Segment lengths as shares of ``H`` (Winter, *Biomechanics
and Motor Control of Human Movement*, 4th ed. 2009, Fig. 4.1): upper arm 0.186, forearm
0.146, hand 0.108, thigh 0.245, shank 0.246, foot 0.152, shoulder width 0.259, hip (greater
trochanter) height 0.530, shoulder height 0.818, chin 0.870. From de Leva (1996, J.
Biomech. 29, 1223-1230; Zatsiorsky-Seluyanov's data): the lower trunk (hip joints to
omphalion) 145.7 / 1741 = 0.0837. Our choices, stated: the hip joints lie a quarter of
Winter's hip width (0.191) either side of the midline; the neck joint lies halfway between
the shoulders' and the chin's height; the head reaches the vertex (1.0); the pelvis segment
runs from the hip joints up to 0.1.

Joint limits (degrees, from standard ranges of motion; the sign follows the joint's axis:
positive ``a`` swings a hanging limb forward and bends the trunk backwards, the knee flexes
with negative angles) come from :func:`limits`; :func:`limit_violations` reports angles
outside them. :data:`TEMPLATE_SIZE` gives plausible ball sizes (width, depth per segment,
mm) to start a fit from.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array, as_scalar
from .metaballs import MetaballModel, Segment
from .skeleton import Joint, Skeleton, as_tuple, rot_x, rot_y

LIMBS = ("pelvis", "trunk", "shoulders", "head", "upper_arm", "forearm", "hand", "thigh",
         "shank", "foot")
# shares of the stature (module docstring); "hip_x", "shoulder_x": half widths
RATIOS = {"upper_arm": 0.186, "forearm": 0.146, "hand": 0.108, "thigh": 0.245, "shank": 0.246,
          "foot": 0.152, "shoulder_x": 0.259 / 2, "hip_x": 0.191 / 4, "lower_trunk": 0.0837,
          "shoulder_z": 0.818 - 0.530 - 0.0837, "trunk": (0.818 + 0.870) / 2 - 0.530 - 0.0837,
          "head": 1.0 - (0.818 + 0.870) / 2, "pelvis": 0.1}
STATURE = 1750.0                 # mm, the default stature of the template
# ball widths and depths (mm) of each segment's middle ball at STATURE (the skin lies at
# about 0.6 of a lone ball's radii); scaled with the stature
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
    "neck_a": (-70, 60), "neck_c": (-80, 80), "clavicle": (-30, 10),
    "shoulder_b": (-180, 50), "shoulder_a": (-60, 180), "shoulder_c": (-90, 90),
    "elbow": (0, 150), "wrist": (-70, 80),
    "hip_b": (-45, 30), "hip_a": (-30, 120), "hip_c": (-45, 45),
    "knee": (-150, 0), "ankle": (-50, 30),
}


def _ball(prefix: str, parent: int, offset, limb: int, rotation=None) -> list[Joint]:
    """Three single-DoF joints at one place: ``Ry(b) Rx(a) Rz(c)`` in the body-aligned frame
    ``rotation`` (relative to the parent's frame)."""
    R = np.eye(3) if rotation is None else np.asarray(rotation, float)
    return [Joint(name=f"{prefix}_b", parent=parent, offset=tuple(offset),
                  rotation=as_tuple(R.T @ _QY), limb=limb),
            Joint(name=f"{prefix}_a", parent=-2, offset=(0.0, 0.0, 0.0),
                  rotation=as_tuple(_QY.T @ _QX)),
            Joint(name=f"{prefix}_c", parent=-2, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QX.T))]


def template_lengths(*, stature: float = STATURE) -> dict:
    """The template's lengths (mm) for a stature (mm): :data:`RATIOS` times ``stature``."""
    H = as_scalar(stature, "stature", positive=True)
    return {k: v * H for k, v in RATIOS.items()}


def full_body_model(*, stature: float = STATURE) -> MetaballModel:
    """The full-body template for a stature (mm): 30 single-DoF joints, 15 segments of 3
    metaballs; lengths from anthropometry (module docstring), limb scales 1."""
    L = template_lengths(stature=stature)
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
    add(_ball("trunk", index["pelvis_c"], (0.0, 0.0, L["lower_trunk"]), limb["trunk"]))
    add([Joint(name="neck_a", parent=index["trunk_c"], offset=(0.0, 0.0, L["trunk"]),
               rotation=as_tuple(_QX), limb=limb["trunk"]),
         Joint(name="neck_c", parent=-2, offset=(0.0, 0.0, 0.0), rotation=as_tuple(_QX.T))])
    for side, x in (("r", 1.0), ("l", -1.0)):
        # the shoulder girdle: elevation about the forward axis at the top of the sternum
        add([Joint(name=f"clavicle_{side}", parent=index["trunk_c"],
                   offset=(0.0, 0.0, L["shoulder_z"]), rotation=as_tuple(_QY),
                   limb=limb["trunk"])])
        add([Joint(name=j.name.replace("shoulder", f"shoulder_{side}"), parent=j.parent,
                   offset=j.offset, rotation=j.rotation, limb=j.limb)
             for j in _ball("shoulder", index[f"clavicle_{side}"],
                            tuple(_QY.T @ (L["shoulder_x"] * x, 0.0, 0.0)), limb["shoulders"],
                            rotation=_QY)])
        add([Joint(name=f"elbow_{side}", parent=index[f"shoulder_{side}_c"],
                   offset=(0.0, 0.0, -L["upper_arm"]), rotation=as_tuple(_QX),
                   limb=limb["upper_arm"]),
             Joint(name=f"wrist_{side}", parent=-2, offset=bone(L["forearm"]),
                   rotation=as_tuple(np.eye(3)), limb=limb["forearm"])])
        add([Joint(name=j.name.replace("hip", f"hip_{side}"), parent=j.parent, offset=j.offset,
                   rotation=j.rotation, limb=j.limb)
             for j in _ball("hip", index["pelvis_c"], (L["hip_x"] * x, 0.0, 0.0),
                            limb["pelvis"])])
        add([Joint(name=f"knee_{side}", parent=index[f"hip_{side}_c"],
                   offset=(0.0, 0.0, -L["thigh"]), rotation=as_tuple(_QX),
                   limb=limb["thigh"]),
             Joint(name=f"ankle_{side}", parent=-2, offset=bone(L["shank"]),
                   rotation=as_tuple(np.eye(3)), limb=limb["shank"])])
    skeleton = Skeleton(tuple(joints), LIMBS)

    def seg(name, joint, rotation, limb_name):
        return Segment(name=name, joint=index[joint], rotation=as_tuple(rotation),
                       length=L[limb_name], limb=limb[limb_name])

    segments = [seg("pelvis", "pelvis_c", _UP, "pelvis"),
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
        if left and (key.endswith("_b") or key == "clavicle"):
            lo, hi = -hi, -lo
        out.append(np.radians([lo, hi]))
    return np.array(out)


def limit_violations(model: MetaballModel, angles) -> np.ndarray:
    """How far each angle of ``angles (T, J)`` lies outside its limit (radians, 0 inside)."""
    lim = limits(model)
    a = as_array(angles, "angles", shape=(None, len(lim)))
    return np.maximum(lim[:, 0] - a, 0.0) + np.maximum(a - lim[:, 1], 0.0)


def template_size(model: MetaballModel, *, stature: float = STATURE) -> np.ndarray:
    """:data:`TEMPLATE_SIZE` scaled to ``stature`` (mm) as the ``(S, 2)`` sizes of
    ``model``'s segments (for :meth:`MetaballModel.simplified_radii`)."""
    k = as_scalar(stature, "stature", positive=True) / STATURE
    return k * np.array([TEMPLATE_SIZE[model.skeleton.limbs[s.limb]] for s in model.segments])
