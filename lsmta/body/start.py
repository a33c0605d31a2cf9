"""A start for the arm model found in 3-D trajectories, with no user and no true pose.

Plänkers et al. start their fit from joints a user clicks in the first triplet and the
tracker follows (Section 4.2). We find them in the data instead:

1. the filtered trajectories are split into rigidly moving groups
   (:func:`~lsmta.tracking.segmentation.rigid_groups`); the largest is the torso;
2. a functional joint centre (:func:`~lsmta.body.joints.functional_joint`) is estimated
   between the torso and every other group, and between every two other groups, each
   held near the limbs' long axes (:func:`~lsmta.body.joints.segment_axis`); the arm
   is the chain torso -> upper arm -> forearm whose two joints fit best (RMS below
   ``max_joint_rms``) with the shoulder on the body's right (the model is a right arm);
3. the shoulder and the elbow follow from those joints in every frame (from either
   segment's pose where only one is known: a joint is fixed in both); the wrist lies on
   the forearm group's long axis (its members' principal direction, pointing away from
   the elbow) where the forearm's points end (:func:`forearm_length`: the narrow wrist is
   rarely matched, so a hand carried along shows beyond a gap). With too few points it
   lies at ``forearm_ratio`` times the upper arm's length, an anthropometric ratio by
   default: 0.146 / 0.186 of body height for forearm and upper arm (Winter 2009,
   *Biomechanics and Motor Control of Human Movement*, Table 4.1). Where the forearm is
   not tracked, it keeps its last pose relative to the upper arm;
4. the torso frame is the torso group's motion applied to a frame whose z axis is the
   world's ``up`` and whose y axis (forward) is ``forward`` made horizontal (the person
   faces the cameras; a torso seen from the front gives no better direction: only part
   of it is in view); :func:`~lsmta.body.arm.angles_from_joints` then gives the angles
   and the shoulder's place in it, and the limb scales follow from the joints' distances.

The arm's points in each frame are the positions of the two arm groups' trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_array, as_scalar
from ..tracking.segmentation import RigidGroups, rigid_groups
from ..tracking.trajectories import Trajectories
from .arm import angles_from_joints, arm_model
from .fitting import ModelState
from .joints import FunctionalJoint, functional_joint, segment_axis
from .metaballs import MetaballModel

# forearm / upper-arm length from Winter's segment lengths (fractions of body height)
FOREARM_RATIO = 0.146 / 0.186


@dataclass(frozen=True, eq=False)
class ArmStart:
    """The arm model's start from trajectories.

    Attributes
    ----------
    state : ModelState
        Angles per frame, the shoulder in the torso frame, limb scales and template radii.
    torso_poses : (T, 4, 4) array
        Torso frame -> world per frame, mm.
    joints : (T, 3, 3) array
        Shoulder, elbow and wrist in the world per frame, mm.
    points : list of T (N_t, 3) arrays
        The arm groups' points in each frame, mm.
    groups : RigidGroups
    torso, upper_arm, forearm : int
        Their groups.
    shoulder, elbow : FunctionalJoint
    """

    state: ModelState
    torso_poses: np.ndarray
    joints: np.ndarray
    points: list
    groups: RigidGroups
    torso: int
    upper_arm: int
    forearm: int
    shoulder: FunctionalJoint
    elbow: FunctionalJoint


def _fill(x: np.ndarray) -> np.ndarray:
    """Fill NaN frames of ``(T, ...)`` by linear interpolation (nearest at the ends)."""
    x = np.array(x, float)
    T = len(x)
    flat = x.reshape(T, -1)
    ok = np.isfinite(flat).all(axis=1)
    t = np.arange(T)
    for j in range(flat.shape[1]):
        flat[:, j] = np.interp(t, t[ok], flat[ok, j])
    return flat.reshape(x.shape)


def _between(groups: RigidGroups, X: np.ndarray, a: int, b: int):
    """A world point between groups a and b (midpoint of their nearest members in the first
    frame they share) and that frame."""
    both = groups.known[a] & groups.known[b]
    for f in np.flatnonzero(both):
        pa = X[f, (groups.label == a) & np.isfinite(X[f]).all(axis=1)]
        pb = X[f, (groups.label == b) & np.isfinite(X[f]).all(axis=1)]
        if len(pa) and len(pb):
            d, j = cKDTree(pb).query(pa)
            i = int(np.argmin(d))
            return (pa[i] + pb[j[i]]) / 2
    return None


def _joint(groups: RigidGroups, X: np.ndarray, a: int, b: int, axes: dict) \
        -> FunctionalJoint | None:
    if (groups.known[a] & groups.known[b]).sum() < 3:
        return None
    return functional_joint(groups.rotation[a], groups.translation[a], groups.rotation[b],
                            groups.translation[b], parent_line=axes.get(a),
                            child_line=axes.get(b),
                            prior=None if a in axes or b in axes else _between(groups, X, a, b))


def torso_frame(up, forward) -> np.ndarray:
    """Rotation ``(3, 3)`` whose columns are the torso's x (right), y (forward), z (up)."""
    z = as_array(up, "up", shape=(3,))
    z = z / np.linalg.norm(z)
    y = as_array(forward, "forward", shape=(3,))
    y = y - (y @ z) * z
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("forward: expected a direction that is not along up")
    y = y / np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], axis=1)


def _arm_chain(groups: RigidGroups, X, axes: dict, centre, right, max_joint_rms: float):
    """The chain torso (group 0) -> upper arm -> forearm whose two joints fit best, with the
    shoulder on the body's ``right`` side of the torso's ``centre``."""
    best, report = None, []
    for a in range(1, groups.n_groups):
        ja = _joint(groups, X, 0, a, axes)
        if ja is None:
            continue
        on_right = (np.nanmean(ja.world, axis=0) - centre) @ right > 0
        for b in range(1, groups.n_groups):
            jb = None if b == a else _joint(groups, X, a, b, axes)
            if jb is None:
                continue
            report.append(f"{a}->{b}: {ja.rms:.1f} / {jb.rms:.1f} mm")
            score = ja.rms + jb.rms
            if on_right and max(ja.rms, jb.rms) < max_joint_rms and (best is None
                                                                      or score < best[0]):
                best = (score, a, b, ja, jb)
    if best is None:
        raise ValueError(f"trajectories: no chain torso -> upper arm -> forearm with joints "
                         f"closer than {max_joint_rms:g} mm on the body's right among "
                         f"{groups.n_groups} groups (sizes {groups.sizes.tolist()}; chains: "
                         f"{'; '.join(report) or 'none'})")
    return best[1:]


def _torso_poses(groups: RigidGroups, torso: int, frame0, centre) -> np.ndarray:
    """``(T, 4, 4)``: the torso group's motion applied to ``frame0`` placed at ``centre``."""
    R = _fill(groups.rotation[torso])
    t = _fill(groups.translation[torso])
    poses = np.tile(np.eye(4), (len(R), 1, 1))
    poses[:, :3, :3] = R @ frame0
    poses[:, :3, 3] = np.einsum("tij,j->ti", R, centre) + t
    return poses


def _joint_world(groups: RigidGroups, parent: int, child: int, joint) -> np.ndarray:
    """``(T, 3)`` world positions of a joint: the mean of its two images where both
    segments' poses are known, the one segment's image where only it is known (a joint is
    fixed in both), interpolated over frames where neither is."""
    a = np.einsum("tij,j->ti", groups.rotation[parent], joint.parent_local) \
        + groups.translation[parent]
    b = np.einsum("tij,j->ti", groups.rotation[child], joint.child_local) \
        + groups.translation[child]
    both = np.stack([a, b])
    n = np.isfinite(both).all(axis=2).sum(axis=0)
    mean = np.where(n[:, None] > 0, np.nansum(both, axis=0) / np.maximum(n, 1)[:, None],
                    np.nan)
    return _fill(mean)


def _relative_rotation(groups: RigidGroups, parent: int, child: int) -> np.ndarray:
    """``(T, 3, 3)`` the child's rotation, where unknown held at its nearest known pose
    relative to the parent (a limb that stops being tracked keeps its last joint angle)."""
    Rp, Rc = _fill(groups.rotation[parent]), groups.rotation[child]
    rel = np.einsum("tji,tjk->tik", Rp, Rc)                   # parent -> child, per frame
    known = np.flatnonzero(np.isfinite(rel).all(axis=(1, 2)))
    nearest = known[np.abs(np.arange(len(rel))[:, None] - known[None]).argmin(axis=1)]
    return Rp @ rel[nearest]


def forearm_length(along, *, min_gap: float = 20.0, wide_gap: float = 60.0) -> float | None:
    """Where a forearm's surface points end, mm from the elbow, or None.

    ``along`` are the forearm group's points projected on its axis (mm from the elbow).
    The wrist is narrow and rarely matched, so a hand carried along rigidly shows as a
    second cluster beyond a gap: the forearm ends where the widest gap of the distal half
    that is wider than ``min_gap`` and has at least 5 % of the points (and 3) beyond it
    begins (a few stray points near a tapering tip are no hand; sparse points leave gaps
    of a centimetre by chance, a wrist two or three). A hand is often tracked at only a
    handful of points, fewer than 5 % of the forearm's: failing such a gap, a gap wider
    than ``wide_gap`` with at least 3 points beyond it counts as well (points that move
    rigidly with the forearm that far beyond its last point are on the hand). Without
    either, the forearm ends at the distal end of the points. None with fewer than 20
    points.
    """
    a = np.sort(np.asarray(along, float))
    if len(a) < 20:
        return None
    half = len(a) // 2
    gaps = np.diff(a[half:])
    beyond = len(a) - (half + 1 + np.arange(len(gaps)))          # points after each gap
    ok = (gaps > min_gap) & (beyond >= max(3, 0.05 * len(a)))
    if not ok.any():
        ok = (gaps > wide_gap) & (beyond >= 3)
    if not ok.any():
        return float(a[-1])
    k = int(np.argmax(np.where(ok, gaps, -np.inf)))
    return float(a[half + k])


def _wrist(groups: RigidGroups, upper: int, fore: int, axis, elbow_joint, shoulder, elbow,
           ratio: float) -> np.ndarray:
    """``(T, 3)``: on the forearm's long axis, pointing away from the elbow, where the
    forearm's points end (:func:`forearm_length`), or ``ratio`` times the upper arm's
    length when too few points say."""
    u = axis.direction
    local = groups.local[groups.label == fore]
    if (local.mean(axis=0) - elbow_joint.child_local) @ u < 0:
        u = -u
    d = np.einsum("tij,j->ti", _relative_rotation(groups, upper, fore), u)
    length = forearm_length((local - elbow_joint.child_local) @ u)
    if length is None:
        length = ratio * float(np.median(np.linalg.norm(elbow - shoulder, axis=1)))
    return elbow + length * d / np.linalg.norm(d, axis=1, keepdims=True)


def arm_start(trajectories: Trajectories, *, forward, up=(0.0, 0.0, 1.0),
              model: MetaballModel | None = None, groups: RigidGroups | None = None,
              tolerance: float = 4.0, max_joint_rms: float = 15.0,
              forearm_ratio: float = FOREARM_RATIO, size=((70.0, 70.0), (70.0, 70.0),
                                                        (42.0, 42.0)),
              rng: np.random.Generator | int | None = None) -> ArmStart:
    """Find the right arm in trajectories and start the arm model there.

    Parameters
    ----------
    trajectories : Trajectories
        Filtered 3-D trajectories of the body, mm.
    forward : (3,) array
        The direction the person faces, world (e.g. towards the cameras); made horizontal.
    up : (3,) array
        The world's up direction.
    model : MetaballModel, optional
        The arm model (default :func:`~lsmta.body.arm.arm_model`).
    groups : RigidGroups, optional
        Rigid groups already found; default: :func:`rigid_groups` with ``tolerance``.
    tolerance : float
        Rigidity tolerance of :func:`rigid_groups`, mm.
    max_joint_rms : float
        A joint whose two images stay further apart than this (RMS, mm) does not connect
        two groups.
    forearm_ratio : float
        Forearm length over upper-arm length (anthropometric by default, see the module
        docstring).
    size : (3, 2) array
        Width and depth of each segment's template balls, mm.
    rng : numpy.random.Generator, int or None
        For :func:`rigid_groups`' sample.

    Returns
    -------
    ArmStart

    Raises
    ------
    ValueError
        When no chain torso -> upper arm -> forearm is found: say which groups there were.
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"trajectories: expected lsmta.tracking.Trajectories, got "
                        f"{type(trajectories).__name__}")
    model = arm_model() if model is None else model
    max_joint_rms = as_scalar(max_joint_rms, "max_joint_rms", positive=True)
    forearm_ratio = as_scalar(forearm_ratio, "forearm_ratio", positive=True)
    X = np.asarray(trajectories.xyz)
    T = X.shape[0]
    if groups is None:
        groups = rigid_groups(trajectories, tolerance=tolerance, rng=rng)
    G = groups.n_groups
    if G < 3:
        raise ValueError(f"trajectories: {G} rigidly moving group(s) found (sizes "
                         f"{groups.sizes.tolist()}); the arm needs a torso, an upper arm and a "
                         "forearm that move differently")
    torso = 0
    centre = np.nanmean(X[groups.reference[torso], groups.label == torso], axis=0)
    frame0 = torso_frame(up, forward)
    # a limb's bone runs along its long axis, through its joints (not the torso's)
    axes = {g: segment_axis(groups.local[groups.label == g]) for g in range(1, G)}
    upper, fore, j_sh, j_el = _arm_chain(groups, X, axes, centre, frame0[:, 0], max_joint_rms)
    torso_poses = _torso_poses(groups, torso, frame0, centre)
    shoulder = _joint_world(groups, torso, upper, j_sh)
    elbow = _joint_world(groups, upper, fore, j_el)
    wrist = _wrist(groups, upper, fore, axes[fore], j_el, shoulder, elbow, forearm_ratio)
    angles, shoulder_local, lengths = angles_from_joints(torso_poses, shoulder, elbow, wrist)
    scales = np.array([lengths[:, 0].mean() / model.segments[0].length,
                       lengths[:, 1].mean() / model.segments[1].length, 1.0])
    size = as_array(size, "size", shape=(model.n_segments, 2))
    state = ModelState(angles=angles, shoulder=shoulder_local, scales=scales,
                       radii=model.simplified_radii(size, scales))
    arm = np.isin(groups.label, [upper, fore])
    points = [X[t, arm & np.isfinite(X[t]).all(axis=1)] for t in range(T)]
    return ArmStart(state=state, torso_poses=torso_poses,
                    joints=np.stack([shoulder, elbow, wrist], axis=1), points=points,
                    groups=groups, torso=torso, upper_arm=upper, forearm=fore,
                    shoulder=j_sh, elbow=j_el)
