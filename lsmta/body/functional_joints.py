"""Functional joint centres and axes from the measured points of two neighbouring segments.

Motion-capture practice finds the joints from a range-of-motion clip: each segment's points
move rigidly, and the joint is where two segments turn about each other.

1. **Segment motion.** Each frame's points of a segment are fitted rigidly
   (:func:`lsmta.rigid.fit_one`) onto the segment's reference shape: its points in one
   reference frame (the frame with the most points, unless a shape is given), which is
   also the segment's frame. NaN marks a point not seen in a frame.
2. **SCoRE** (symmetrical centre of rotation estimation; Ehrig, Taylor, Duda & Heller
   2006, J. Biomech. 39, 2798-2809). A point ``c_p`` fixed in the parent and ``c_c`` fixed
   in the child coincide in every frame: ``R_p(t) c_p + t_p(t) = R_c(t) c_c + t_c(t)``.
   Stacked over the frames: ``A x = b`` with ``A (3T, 6) = [R_p, -R_c]``, ``x = (c_p,
   c_c)``, solved by least squares.
3. **Determinacy.** ``A``'s singular values say what the motion identified. With rotation
   about two or more axes all six are large: the centre is fixed (a ball joint: hip,
   shoulder). About one axis only (a hinge: knee, elbow, or a shoulder that only abducts)
   the smallest is near zero: the centre may slide along that axis, and the right singular
   vector of the smallest value is the axis itself, in both frames (SARA, the symmetrical
   axis of rotation approach; Ehrig, Taylor, Duda & Heller 2007, J. Biomech. 40,
   2150-2157). Then the reported point is the point on the axis nearest the two segments'
   points (the point of the solution line closest to both segments' centroids). With too
   little rotation even the axis is not fixed.

   The decision is statistical. The least-squares covariance of ``x`` is
   ``sigma^2 V diag(1 / s_i^2) V^T`` (``A = U diag(s) V^T``), with ``sigma`` the RMS gap of
   the fit per coordinate (never below ``noise_floor``); the centre's standard deviation
   (``centre_sd``) is the larger of ``c_p``'s and ``c_c``'s, each along its worst direction
   (the square root of the largest eigenvalue of its 3 x 3 block). Along the least-fixed
   direction ``v`` of the stacked ``(c_p, c_c)`` that is about ``sigma / s_min`` times
   ``max(|v[:3]|, |v[3:]|)``, each centre taking about ``1 / sqrt(2)`` of ``v``: not
   ``sigma / s_min`` itself, the stacked 6-vector's. The centre counts as fixed where
   ``centre_sd`` is at most ``max_centre_sd``; the axis where the same standard deviation
   without the least-fixed direction (the centre across the axis) is. So a hinge whose
   poses wobble by noise is not taken for a ball joint, and more frames of a still joint
   do not undo what one movement fixed. ``determinacy`` (``s_min / sqrt(T)``) describes
   the motion alone: moving the stacked ``(c_p, c_c)`` by a unit vector along ``v`` (each
   centre by about 0.7 mm) changes the gap between the centre's two images by that much,
   RMS over the frames (about the RMS rotation in radians away from the joint's main axis).

:func:`lsmta.body.joints.functional_joint` solves the same SCoRE system from given poses,
with priors that pick a hinge's centre (the limb's long axis); this module starts from the
points and says what the motion itself determined.

Units: mm; rotations are segment frame -> world.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_scalar, freeze
from ..rigid import fit_one


class JointStatus(enum.IntEnum):
    """What the motion identified of a joint."""

    CENTRE = 0         # rotation about two or more axes: the centre is fixed
    AXIS = 1           # about one axis: the axis is fixed, the centre only up to a slide on it
    UNDETERMINED = 2   # too little rotation: neither


@dataclass(frozen=True, eq=False)
class SegmentMotion:
    """The rigid motion of one segment, fitted to its points frame by frame.

    Attributes
    ----------
    rotation : (T, 3, 3) array
        Segment frame -> world rotation per frame; NaN where too few points were seen.
    translation : (T, 3) array
        Segment frame -> world translation per frame, mm; NaN likewise.
    reference : (n, 3) array
        The points in the segment's frame (NaN: a point not in the reference), mm.
    reference_frame : int
        The frame whose world positions define the segment's frame (-1: a given shape).
    residual : (T,) array
        RMS distance of the fitted reference to the frame's points, mm (NaN where unknown).
    n_points : (T,) int array
        Points used per frame.
    centroid : (3,) array
        Centroid of the reference points in the segment's frame, mm.
    """

    rotation: np.ndarray
    translation: np.ndarray
    reference: np.ndarray
    reference_frame: int
    residual: np.ndarray
    n_points: np.ndarray
    centroid: np.ndarray

    def __post_init__(self):
        freeze(self, ("rotation", "translation", "reference", "residual", "n_points",
                      "centroid"))

    @property
    def n_frames(self) -> int:
        return len(self.translation)

    @property
    def known(self) -> np.ndarray:
        """``(T,)`` bool: frames with a pose."""
        return np.isfinite(self.translation).all(axis=1)


@dataclass(frozen=True, eq=False)
class JointCentre:
    """A joint between two segments found from their motion (module docstring).

    Attributes
    ----------
    status : JointStatus
    parent_centre, child_centre : (3,) arrays
        The centre in the parent's and the child's frame (their :class:`SegmentMotion`
        frames), mm: SCoRE's centre (CENTRE), the point of the axis nearest the segments'
        points (AXIS), NaN (UNDETERMINED).
    parent_axis, child_axis : (3,) unit arrays
        The least-fixed direction of the centre in each frame: the joint's axis for a
        hinge (AXIS; also reported for CENTRE); NaN (UNDETERMINED).
    world : (T, 3) array
        The centre in the world per frame (mean of its two images), mm; NaN outside the
        frames used (not chosen, or a pose unknown) and everywhere when UNDETERMINED.
    residual : float
        RMS distance between the centre's two images over the frames used, mm; NaN when
        UNDETERMINED (no centre).
    singular_values : (6,) array
        Of SCoRE's design matrix, descending.
    determinacy : float
        ``s_min / sqrt(n_frames)``, a property of the motion alone (module docstring): the
        RMS change of the gap per frame for a unit step of the stacked ``(c_p, c_c)`` along
        its least-fixed direction; about 0 for a hinge.
    axis_determinacy : float
        The same of the second smallest singular value: whether one axis is fixed.
    condition : float
        ``s_max / s_min`` of the design matrix.
    centre_sd : float
        Least-squares standard deviation of the centre along its worst direction, mm: the
        larger of ``c_p``'s and ``c_c``'s, from the covariance ``sigma^2 (A^T A)^-1`` with
        ``sigma^2 = |A x - b|^2 / (3 n - 6)`` (at least ``noise_floor^2``); about
        ``sigma / s_min * max(|v[:3]|, |v[3:]|)`` (module docstring). ``inf`` for a hinge's
        exact axis. The status compares it with ``max_centre_sd``.
    n_frames : int
        Frames used (both poses known).
    parent, child : SegmentMotion
        The two segments' motions (their frames are the centres' frames).
    """

    status: JointStatus
    parent_centre: np.ndarray
    child_centre: np.ndarray
    parent_axis: np.ndarray
    child_axis: np.ndarray
    world: np.ndarray
    residual: float
    singular_values: np.ndarray
    determinacy: float
    axis_determinacy: float
    condition: float
    centre_sd: float
    n_frames: int
    parent: SegmentMotion
    child: SegmentMotion

    def __post_init__(self):
        freeze(self, ("parent_centre", "child_centre", "parent_axis", "child_axis", "world",
                      "singular_values"))


def segment_motion(points, *, reference=None, min_points: int = 6) -> SegmentMotion:
    """Rigid motion of a segment from its points per frame (step 1 of the module docstring).

    Parameters
    ----------
    points : (T, n, 3) array
        World positions of ``n`` points rigidly attached to the segment, mm; NaN where a
        point is not seen (a point with any NaN coordinate counts as missing). Not modified.
    reference : (n, 3) array, optional
        The points in the segment's own frame (NaN: unknown). Default: their positions in
        the frame that sees the most of them, which then defines the segment's frame.
    min_points : int
        Fewest points (>= 3) seen in a frame for a pose; fewer leave it NaN (a few noisy
        points close together give a poor rotation).

    Returns
    -------
    SegmentMotion
    """
    return _segment_motion(points, reference, min_points, "points")


def _segment_motion(points, reference, min_points, name: str) -> SegmentMotion:
    P = as_array(points, name, shape=(None, None, 3), allow_nan=True)
    T, n = P.shape[:2]
    k = as_int(min_points, "min_points", minimum=3)
    if T < 1 or n < 3:
        raise ValueError(f"{name}: expected (T, n, 3) with T >= 1 frames and n >= 3 points, "
                         f"got shape {P.shape}")
    seen = np.isfinite(P).all(axis=2)
    if reference is None:
        ref_frame = int(np.argmax(seen.sum(axis=1)))
        ref = np.where(seen[ref_frame][:, None], P[ref_frame], np.nan)
    else:
        ref_frame = -1
        ref = as_array(reference, "reference", shape=(n, 3), allow_nan=True)
    usable = np.isfinite(ref).all(axis=1)
    if usable.sum() < k:
        raise ValueError(f"{name}: the reference holds {int(usable.sum())} points; expected "
                         f"at least min_points={k}")
    R = np.full((T, 3, 3), np.nan)
    t = np.full((T, 3), np.nan)
    resid = np.full(T, np.nan)
    counts = np.zeros(T, int)
    for f in range(T):
        use = seen[f] & usable
        counts[f] = use.sum()
        if counts[f] >= k:
            R[f], t[f], d = fit_one(np.ascontiguousarray(ref[use]), np.ascontiguousarray(P[f, use]))
            resid[f] = np.sqrt(np.mean(d ** 2))
    return SegmentMotion(rotation=R, translation=t, reference=ref, reference_frame=ref_frame,
                         residual=resid, n_points=counts, centroid=ref[usable].mean(axis=0))


def frame_mask(frames, T: int) -> np.ndarray:
    """(T,) bool mask of the chosen frames: ``frames`` None (all), frame indices, or a (T,)
    boolean mask (copied). Raises ValueError for anything else."""
    if frames is None:
        return np.ones(T, bool)
    f = np.asarray(frames)
    if f.dtype == bool:
        if f.shape != (T,):
            raise ValueError(f"frames: expected a ({T},) boolean mask, got shape {f.shape}")
        return f.copy()
    if f.ndim != 1 or not np.issubdtype(f.dtype, np.integer) or (
            f.size and (f.min() < 0 or f.max() >= T)):
        raise ValueError(f"frames: expected frame indices in [0, {T - 1}] or a ({T},) boolean "
                         "mask")
    mask = np.zeros(T, bool)
    mask[f] = True
    return mask


def fit_joint(parent: SegmentMotion, child: SegmentMotion, *, frames=None,
              max_centre_sd: float = 5.0, noise_floor: float = 1.0) -> JointCentre:
    """The joint between two segments from their motions (SCoRE, SARA; module docstring).

    Parameters
    ----------
    parent, child : SegmentMotion
        The two segments' motions over the same frames (:func:`segment_motion`).
    frames : sequence of int or (T,) bool array, optional
        The frames to use (default all; e.g. one movement of a clip). Frames where either
        pose is unknown are left out.
    max_centre_sd : float
        Largest standard deviation (mm) of the centre (``JointCentre.centre_sd``: either
        segment's centre, along its worst direction) for it to count as fixed by the motion;
        the same without the least-fixed direction, for the axis (module docstring).
    noise_floor : float
        Least gap noise per coordinate assumed, mm: skin, markers and surface points never
        let two segments share one point better than about 1 mm, and noise-free data would
        otherwise fix any centre that turns at all.

    Returns
    -------
    JointCentre
    """
    for name, seg in (("parent", parent), ("child", child)):
        if not isinstance(seg, SegmentMotion):
            raise TypeError(f"{name}: expected a SegmentMotion, got {type(seg).__name__}")
    if parent.n_frames != child.n_frames:
        raise ValueError(f"child: expected {parent.n_frames} frames like parent, got "
                         f"{child.n_frames}")
    max_sd = as_scalar(max_centre_sd, "max_centre_sd", positive=True)
    floor = as_scalar(noise_floor, "noise_floor", positive=True)
    use = np.flatnonzero(frame_mask(frames, parent.n_frames) & parent.known & child.known)
    n = use.size
    if n < 3:
        raise ValueError(f"parent, child: the segments share {n} frame(s) with known poses "
                         "among those chosen; a joint needs at least 3")
    Rp, tp, Rc, tc = parent.rotation, parent.translation, child.rotation, child.translation
    A = np.concatenate([Rp[use], -Rc[use]], axis=2).reshape(-1, 6)
    b = (tc[use] - tp[use]).reshape(-1)
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    x = Vt.T @ ((U.T @ b) / np.maximum(s, s[0] * 1e-12))
    sigma = max(np.sqrt(np.sum((A @ x - b) ** 2) / max(3 * n - 6, 1)), floor)
    centre_sd = _centre_sd(s, Vt, sigma, 6)
    status = (JointStatus.CENTRE if centre_sd <= max_sd else
              JointStatus.AXIS if _centre_sd(s, Vt, sigma, 5) <= max_sd
              else JointStatus.UNDETERMINED)
    v = Vt[-1]
    if status != JointStatus.CENTRE:         # the point of the axis nearest both segments
        x = Vt[:5].T @ ((U[:, :5].T @ b) / s[:5])
        x = x + v * (v @ (np.concatenate([parent.centroid, child.centroid]) - x))
    cp, cc = x[:3], x[3:]
    world = np.full((parent.n_frames, 3), np.nan)          # only the frames used
    world[use] = (np.einsum("tij,j->ti", Rp[use], cp) + tp[use]
                  + np.einsum("tij,j->ti", Rc[use], cc) + tc[use]) / 2
    gap = (np.einsum("tij,j->ti", Rp[use], cp) + tp[use]
           - np.einsum("tij,j->ti", Rc[use], cc) - tc[use])
    residual = float(np.sqrt(np.mean(np.sum(gap ** 2, axis=1))))
    axes = [v[:3] / np.linalg.norm(v[:3]), v[3:] / np.linalg.norm(v[3:])]
    if status == JointStatus.UNDETERMINED:
        cp, cc = np.full(3, np.nan), np.full(3, np.nan)
        axes = [np.full(3, np.nan), np.full(3, np.nan)]
        world[:] = np.nan
        residual = float("nan")
    return JointCentre(status=status, parent_centre=cp, child_centre=cc, parent_axis=axes[0],
                       child_axis=axes[1], world=world, residual=residual,
                       singular_values=s, determinacy=float(s[-1] / np.sqrt(n)),
                       axis_determinacy=float(s[-2] / np.sqrt(n)),
                       condition=float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
                       centre_sd=centre_sd,
                       n_frames=int(n), parent=parent, child=child)


def _centre_sd(s, Vt, sigma: float, k: int) -> float:
    """Standard deviation (mm) of the worse of the two centres along its worst direction,
    from the first ``k`` singular directions of the covariance ``sigma^2 V diag(s^-2) V^T``
    (``k = 6``: all; ``k = 5``: without the least-fixed one). ``inf`` if one is 0."""
    if s[k - 1] <= 0:
        return float("inf")
    V = Vt[:k].T * (sigma / s[:k])                          # (6, k): cov = V V^T
    return float(max(np.sqrt(np.linalg.eigvalsh(V[i:i + 3] @ V[i:i + 3].T)[-1])
                     for i in (0, 3)))


def fit_joint_from_points(parent_points, child_points, *, frames=None, min_points: int = 6,
                          max_centre_sd: float = 5.0, noise_floor: float = 1.0) -> JointCentre:
    """The joint between two segments from their points: :func:`segment_motion` of each
    (frames: the frame that sees most of its points), then :func:`fit_joint`.

    Parameters
    ----------
    parent_points, child_points : (T, n_p, 3), (T, n_c, 3) arrays
        Points rigidly attached to the parent and to the child, mm; NaN where not seen.
    frames, max_centre_sd, noise_floor
        As :func:`fit_joint`.
    min_points
        As :func:`segment_motion`.

    Returns
    -------
    JointCentre
        Its ``parent`` and ``child`` motions in the frames of their best-seen frames.

    Raises
    ------
    ValueError
        Points of the wrong shape, too few points, different frame counts, or as
        :func:`fit_joint`.
    """
    parent = _segment_motion(parent_points, None, min_points, "parent_points")
    child = _segment_motion(child_points, None, min_points, "child_points")
    if child.n_frames != parent.n_frames:
        raise ValueError(f"child_points: expected {parent.n_frames} frames like parent_points, "
                         f"got {child.n_frames}")
    return fit_joint(parent, child, frames=frames, max_centre_sd=max_centre_sd,
                     noise_floor=noise_floor)
