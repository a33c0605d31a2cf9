"""Functional joint centres: where two rigid segments turn about each other.

Given the poses of two segments over T frames (e.g. from
:func:`~lsmta.tracking.segmentation.rigid_groups`), the joint is the point that is fixed
in both: a point ``c_p`` in the parent's frame and ``c_c`` in the child's frame that
coincide in every frame, ``R_p(t) c_p + t_p(t) = R_c(t) c_c + t_c(t)``. Stacked over the
frames this is a linear least-squares problem in the six unknowns (the symmetrical
centre-of-rotation estimation, SCoRE, of Ehrig et al. 2006, "A survey of formal methods
for determining the centre of rotation of ball joints", J. Biomech. 39). Its solution
needs rotation about two axes; about one axis (a hinge, or a shoulder that only abducts)
the centre may slide along it, and a weak prior (``prior_weight``) decides where: the
centre should lie on a segment's long axis (a bone runs through its joints), given as a
line in the parent's or the child's frame (:func:`segment_axis` finds it from the
segment's surface points), or near a given point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar


@dataclass(frozen=True)
class FunctionalJoint:
    """A joint between two rigidly moving segments.

    Attributes
    ----------
    parent_local, child_local : (3,) arrays
        The centre in the parent's and in the child's frame, mm.
    world : (T, 3) array
        The centre in the world per frame (the mean of its two images), mm; NaN where a
        pose is unknown.
    rms : float
        RMS distance between the centre's two images over the frames used, mm: how well
        the two segments share one fixed point.
    n_frames : int
        Frames in which both poses are known.
    condition : float
        Ratio of the smallest to the largest singular value of the design matrix (small:
        the centre is poorly fixed by the motion, e.g. a hinge).
    """

    parent_local: np.ndarray
    child_local: np.ndarray
    world: np.ndarray
    rms: float
    n_frames: int
    condition: float


@dataclass(frozen=True)
class SegmentAxis:
    """The long axis of a limb segment, in the segment's frame.

    Attributes
    ----------
    point : (3,) array
        A point on the axis (the centre of the fitted cross-section), mm.
    direction : (3,) unit array
    radius : float
        Radius of the fitted cross-section, mm.
    """

    point: np.ndarray
    direction: np.ndarray
    radius: float


def segment_axis(points, *, middle: float = 0.5) -> SegmentAxis:
    """Long axis of a limb segment from points on its (visible) surface.

    The direction is the points' principal direction; the axis passes through the centre
    of the circle fitted (algebraically, Kasa's method) to the points of the segment's
    middle part projected on the plane across it - so points seen from one side only still
    give the axis, not their centroid. Only the middle is used because a limb tapers
    towards its ends, where the cross-sections are smaller circles.

    Parameters
    ----------
    points : (N, 3) array
        Surface points in the segment's frame, mm.
    middle : float
        Share of the points, central along the axis, that the circle is fitted to.
    """
    P = as_array(points, "points", shape=(None, 3))
    middle = as_scalar(middle, "middle", positive=True)
    if middle > 1:
        raise ValueError(f"middle: expected a share in (0, 1], got {middle}")
    m = P.mean(axis=0)
    if len(P) < 5 or round(middle * len(P)) < 5:
        raise ValueError(f"points: expected at least 5 points in the segment's middle, got "
                         f"{len(P)} points in all")
    _, vecs = np.linalg.eigh(np.cov((P - m).T))
    u, e1, e2 = vecs[:, 2], vecs[:, 1], vecs[:, 0]
    along = (P - m) @ u
    lo, hi = np.quantile(along, [0.5 - middle / 2, 0.5 + middle / 2])
    mid = (along >= lo) & (along <= hi)
    x, y = (P[mid] - m) @ e1, (P[mid] - m) @ e2
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    D, E, F = np.linalg.lstsq(A, -(x * x + y * y), rcond=None)[0]
    cx, cy = -D / 2, -E / 2
    r = float(np.sqrt(max(cx * cx + cy * cy - F, 0.0)))
    return SegmentAxis(point=m + cx * e1 + cy * e2, direction=u, radius=r)


def functional_joint(parent_rotation, parent_translation, child_rotation, child_translation,
                     *, prior=None, parent_line: SegmentAxis | None = None,
                     child_line: SegmentAxis | None = None,
                     prior_weight: float = 0.05) -> FunctionalJoint:
    """The point fixed in two moving segments (SCoRE; see the module docstring).

    Parameters
    ----------
    parent_rotation, child_rotation : (T, 3, 3) arrays
        Segment frame -> world rotations (NaN where unknown).
    parent_translation, child_translation : (T, 3) arrays
        Segment frame -> world translations, mm (NaN where unknown).
    prior : (3,) array, optional
        A world point of the first common frame near which the centre is expected.
    parent_line, child_line : SegmentAxis, optional
        A line in the parent's (child's) frame on which the centre is expected: the
        segment's long axis.
    prior_weight : float
        Weight of each prior relative to one frame's equations. With no prior the
        minimum-norm solution is returned.

    Returns
    -------
    FunctionalJoint
    """
    Rp = as_array(parent_rotation, "parent_rotation", shape=(None, 3, 3), allow_nan=True)
    T = len(Rp)
    tp = as_array(parent_translation, "parent_translation", shape=(T, 3), allow_nan=True)
    Rc = as_array(child_rotation, "child_rotation", shape=(T, 3, 3), allow_nan=True)
    tc = as_array(child_translation, "child_translation", shape=(T, 3), allow_nan=True)
    w = as_scalar(prior_weight, "prior_weight", nonnegative=True)
    both = (np.isfinite(tp).all(axis=1) & np.isfinite(tc).all(axis=1)
            & np.isfinite(Rp).all(axis=(1, 2)) & np.isfinite(Rc).all(axis=(1, 2)))
    f = np.flatnonzero(both)
    if f.size < 3:
        raise ValueError(f"parent/child poses: the segments share {f.size} frame(s) with known "
                         "poses; a joint needs at least 3")
    A = np.concatenate([Rp[f], -Rc[f]], axis=2).reshape(-1, 6)
    b = (tc[f] - tp[f]).reshape(-1)
    s = np.linalg.svd(A, compute_uv=False)
    rows, rhs = [A], [b]
    if w > 0 and prior is not None:
        q = as_array(prior, "prior", shape=(3,))
        f0 = f[0]
        rows.append(np.sqrt(w) * np.eye(6))
        rhs.append(np.sqrt(w) * np.concatenate([Rp[f0].T @ (q - tp[f0]),
                                                Rc[f0].T @ (q - tc[f0])]))
    for line, cols, name in ((parent_line, slice(0, 3), "parent_line"),
                             (child_line, slice(3, 6), "child_line")):
        if w > 0 and line is not None:
            if not isinstance(line, SegmentAxis):
                raise TypeError(f"{name}: expected a SegmentAxis, got {type(line).__name__}")
            across = np.eye(3) - np.outer(line.direction, line.direction)  # distance to it
            block = np.zeros((3, 6))
            block[:, cols] = across
            rows.append(np.sqrt(w) * block)
            rhs.append(np.sqrt(w) * across @ line.point)
    A, b = np.vstack(rows), np.concatenate(rhs)
    c = np.linalg.lstsq(A, b, rcond=None)[0]
    cp, cc = c[:3], c[3:]
    a = np.einsum("tij,j->ti", Rp, cp) + tp
    d = np.einsum("tij,j->ti", Rc, cc) + tc
    gap = np.linalg.norm(a[f] - d[f], axis=1)
    return FunctionalJoint(parent_local=cp, child_local=cc, world=(a + d) / 2,
                           rms=float(np.sqrt(np.mean(gap**2))), n_frames=int(f.size),
                           condition=float(s[-1] / s[0]))
