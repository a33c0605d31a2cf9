"""A marker model learned from a labelled clip: mean shapes, rigidity and joints.

A user who labels a short range-of-motion trial has far more than the paper's one clear
frame. From the clip (T, M, 3), with NaN gaps, :func:`learn_model` learns

* each segment's **mean shape**: generalised Procrustes over the frames in which at least
  three of its markers are seen (a marker's position is the mean of its aligned positions
  over the frames that see it);
* the **model pose**: the root's shape, and down the tree each child carried by the mean
  relative motion parent -> child over the clip (chordal mean of the rotations), placed so
  that its joint with the parent coincides in both (*assembled at the joint*); a marker
  shared by two segments sits at the mean of its two placements;
* each segment's **rigidity tolerance**: Eq. 2's ē_s(t) of every training frame against the
  model's shape, ``ε_s = clip(margin · max_t ē_s(t), floor, eps_ceiling)``; the floor is
  ``eps_min`` if every link of the segment turned by at least ``turned`` degrees in the clip
  (the clip shows the deformation the joints cause), else ``eps_floor``;
* the **joints** of links without shared markers: the point fixed in both segments over the
  clip (SCoRE, as :func:`lsmta.body.joints.functional_joint`), pulled towards the one-frame
  estimate (the midpoint of the closest pair across the link, ``d0`` apart) with the weight
  of every frame turning the link by ``joint_rotation``, so that a clip in which the link
  hardly turns keeps the one-frame estimate. ``joint_prior`` is the share of that estimate
  left where the clip fixes the joint least but one (a hinge leaves the centre free along
  its axis); the tolerance is ``max(margin · max_t gap(t), 2 · joint_prior · d0)``, gap the
  distance between the joint's two images (one carried by each segment).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .._validate import as_array, as_int, as_scalar
from .definition import definition


@dataclass(frozen=True)
class LearnParams:
    """How a model is learned from a labelled clip.

    Attributes
    ----------
    margin : float
        Factor on the largest spread seen in the clip (ē_s for ε_s, the joint's gap for its
        tolerance): the test recording will deform segments further than a short clip.
    eps_floor : float
        Smallest ε_s, a fraction of l̄_s (default 0.10, the lower of the paper's values for
        real humans): the prior for a clip in which a segment hardly deforms (a standing
        subject).
    eps_min : float
        Smallest ε_s of a segment whose every link turned by at least ``turned`` degrees in
        the clip: its deformation is then seen in the clip, and only measurement noise
        needs the extra room.
    turned : float
        Turn of a link, degrees, beyond which the clip counts as showing the deformation
        it causes in the two segments it joins.
    eps_ceiling : float
        Largest ε_s: beyond it Eq. 2 no longer tells right from wrong matches.
    joint_rotation : float
        Relative rotation, degrees, at which one frame of the clip weighs as much as the
        one-frame joint estimate (see the module docstring).
    n_iter : int
        Procrustes passes for the mean shapes.
    """

    margin: float = 1.5
    eps_floor: float = 0.10
    eps_min: float = 0.02
    turned: float = 30.0
    eps_ceiling: float = 0.30
    joint_rotation: float = 10.0
    n_iter: int = 4

    def __post_init__(self):
        for name in ("margin", "eps_floor", "eps_min", "turned", "eps_ceiling", "joint_rotation"):
            object.__setattr__(self, name, as_scalar(getattr(self, name), name, positive=True))
        if self.margin < 1:
            raise ValueError(f"margin: expected a factor >= 1, got {self.margin}")
        if not self.eps_min <= self.eps_floor <= self.eps_ceiling < 1:
            raise ValueError(f"eps_min, eps_floor, eps_ceiling: expected 0 < eps_min <= eps_floor "
                             f"<= eps_ceiling < 1, got {self.eps_min}, {self.eps_floor} and "
                             f"{self.eps_ceiling}")
        object.__setattr__(self, "n_iter", as_int(self.n_iter, "n_iter"))


# ---------------------------------------------------------------------- checks
def check_clip(labels, points) -> tuple[tuple, np.ndarray]:
    """Labels (tuple of M str) and points (T, M, 3) float64 of a labelled clip, checked."""
    if isinstance(labels, str) or not all(isinstance(k, str) for k in labels):
        raise TypeError("labels: expected a sequence of marker names (str)")
    labels = tuple(labels)
    X = as_array(points, "points", shape=(None, None, 3), allow_nan=True)
    if len(labels) != X.shape[1]:
        raise ValueError(f"labels: expected {X.shape[1]} names, one per marker of points "
                         f"(T, M, 3), got {len(labels)}")
    twice = sorted({k for k in labels if labels.count(k) > 1})
    if twice:
        raise ValueError(f"labels: names occur more than once: {twice}")
    if X.shape[0] < 1:
        raise ValueError("points: expected at least one frame")
    never = [k for k, seen in zip(labels, np.isfinite(X).all(axis=2).any(axis=0)) if not seen]
    if never:
        what = "every marker is" if len(never) == len(labels) else f"markers {never} are"
        raise ValueError(f"points: {what} missing (NaN) in every frame; drop them or give "
                         f"frames that see them")
    X = X.copy()
    X[np.isnan(X).any(axis=2)] = np.nan
    return labels, X


# ---------------------------------------------------------------------- rigid fits with gaps
def weighted_fit(P, Q, w):
    """Rigid motions carrying ``P`` (T, n, 3) onto ``Q`` (T, n, 3) with weights ``w``
    (T, n) (0 for a gap; NaN in zero-weight rows is ignored). Rows with fewer than three
    weighted points get NaN. Returns R (T, 3, 3), t (T, 3)."""
    w = np.asarray(w, float)
    P = np.where(w[..., None] > 0, P, 0.0)
    Q = np.where(w[..., None] > 0, Q, 0.0)
    W = w.sum(axis=1)
    ok = (w > 0).sum(axis=1) >= 3
    Ws = np.where(ok, W, 1.0)[:, None]
    pc = np.einsum("tn,tnk->tk", w, P) / Ws
    qc = np.einsum("tn,tnk->tk", w, Q) / Ws
    H = np.einsum("tn,tni,tnj->tij", w, P - pc[:, None], Q - qc[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    D = np.zeros((len(w), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)
    t = qc - np.einsum("tij,tj->ti", R, pc)
    R[~ok], t[~ok] = np.nan, np.nan
    return R, t


def _carry(R, t, P):
    """P (n, 3) or (T, n, 3) carried by (T, 3, 3), (T, 3)."""
    return np.einsum("tij,...nj->tni", R, P) + t[:, None]


def segment_poses(shape, X):
    """Poses (T, 3, 3), (T, 3) carrying a segment's ``shape`` (m, 3) onto its markers
    ``X`` (T, m, 3) with NaN gaps (NaN where fewer than 3 are seen), and the residual
    distances (T, m) (NaN for gaps)."""
    seen = np.isfinite(X).all(axis=2)
    R, t = weighted_fit(np.broadcast_to(shape, X.shape), X, seen.astype(float))
    resid = np.linalg.norm(_carry(R, t, shape) - X, axis=2)
    return R, t, resid


def mean_shape(X, n_iter: int, name: str):
    """Generalised Procrustes mean (m, 3) of a segment's markers ``X`` (T, m, 3) with gaps,
    in the coordinates of its most complete frame."""
    seen = np.isfinite(X).all(axis=2)
    usable = seen.sum(axis=1) >= 3
    if not usable.any():
        raise ValueError(f"points: segment {name!r} never has 3 of its markers seen in one "
                         f"frame; its shape cannot be learned")
    lonely = np.flatnonzero(~(seen & usable[:, None]).any(axis=0))
    if lonely.size:
        raise ValueError(f"points: in segment {name!r}, marker(s) at position {lonely.tolist()} "
                         f"are never seen with two other markers of the segment")
    f0 = int(np.argmax(seen.sum(axis=1)))
    shape = np.where(seen[f0][:, None], X[f0], np.nan)
    for _ in range(n_iter + 1):
        have = np.isfinite(shape).all(axis=1)
        w = (seen & have[None]).astype(float) * usable[:, None]
        R, t = weighted_fit(np.broadcast_to(np.nan_to_num(shape), X.shape), X, w)
        ok = np.isfinite(t).all(axis=1)
        # frames carried back into the shape's coordinates
        back = np.einsum("tji,tnj->tni", R[ok], X[ok] - t[ok][:, None])
        s_ok = seen[ok]
        count = s_ok.sum(axis=0)
        new = np.where(s_ok[..., None], back, 0.0).sum(axis=0) / np.maximum(count, 1)[:, None]
        new[count == 0] = np.nan
        shape = np.where(np.isfinite(new), new, shape)
    return shape


def chordal_mean(R):
    """The rotation closest (Frobenius) to the mean of rotations ``R`` (n, 3, 3)."""
    U, _, Vt = np.linalg.svd(np.mean(R, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


# ---------------------------------------------------------------------- the model
class Link(NamedTuple):
    """A learned link: the mean relative motion child -> parent shape coordinates
    (``R``, ``t``), assembled at the ``joint`` (parent's shape coordinates, mm) with its
    ``tolerance`` (mm); ``gap`` is the RMS distance between the joint's two images over
    the clip, ``closest`` the distance of the closest pair across the link (mm),
    ``turn`` the largest angle by which the link turned away from its mean (degrees) and
    ``prior`` the share of the one-frame estimate left in the joint where the clip fixes it
    least (0: fixed by the clip's motion, 1: the one-frame estimate)."""

    R: np.ndarray
    t: np.ndarray
    joint: np.ndarray
    tolerance: float
    gap: float
    closest: float
    turn: float
    prior: float


def learn_link(shape_p, pose_p, shape_c, pose_c, shared_p, shared_c, params: LearnParams) -> Link:
    """The link between a parent and a child segment, from their shapes (m, 3) and their
    poses over the clip ((T, 3, 3), (T, 3), NaN where unseen). With shared markers
    (``shared_p``, ``shared_c``: their rows in the two shapes) the joint is their centroid
    and its tolerance 0; else it is learned as in the module docstring."""
    (Rp, tp), (Rc, tc) = pose_p, pose_c
    both = np.isfinite(tp).all(axis=1) & np.isfinite(tc).all(axis=1)
    Rp, tp, Rc, tc = Rp[both], tp[both], Rc[both], tc[both]
    rel_R = np.einsum("tji,tjk->tik", Rp, Rc)                     # child -> parent
    R = chordal_mean(rel_R)
    cos = (np.einsum("ij,tij->t", R, rel_R) - 1) / 2
    turn = float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max())
    if len(shared_p):
        cp, cc = shape_p[shared_p], shape_c[shared_c]
        return Link(R=R, t=(cp - cc @ R.T).mean(axis=0), joint=cp.mean(axis=0), tolerance=0.0,
                    gap=0.0, closest=0.0, turn=turn, prior=0.0)
    t0 = np.einsum("tji,tj->ti", Rp, tc - tp).mean(axis=0)
    # the one-frame estimate on the mean relative placement: the closest pair's midpoint
    placed = shape_c @ R.T + t0
    d = np.linalg.norm(placed[:, None] - shape_p[None], axis=-1)
    i, k = np.unravel_index(np.argmin(d), d.shape)
    j0, tol0 = 0.5 * (placed[i] + shape_p[k]), d[i, k]
    prior = np.concatenate([j0, R.T @ (j0 - t0)])
    # SCoRE: Rp cp + tp = Rc cc + tc in every frame, pulled towards the prior
    A = np.concatenate([Rp, -Rc], axis=2)                            # (n, 3, 6)
    b = tc - tp
    lam = len(A) * 4 * np.sin(np.radians(params.joint_rotation) / 2) ** 2
    N = np.einsum("tji,tjk->ik", A, A)
    c = np.linalg.solve(N + lam * np.eye(6), np.einsum("tji,tj->i", A, b) + lam * prior)
    gap = np.linalg.norm(np.einsum("tij,j->ti", A, c) - b, axis=1)
    # share of the prior left in the worst direction but one (a hinge leaves the centre
    # free along its axis, which does not matter while the joint turns about that axis)
    kept = lam / (lam + np.linalg.eigvalsh(N)[1])
    return Link(R=R, t=c[:3] - R @ c[3:], joint=c[:3],
                tolerance=max(params.margin * gap.max(), 2 * kept * tol0),
                gap=float(np.sqrt(np.mean(gap ** 2))), closest=float(tol0), turn=turn,
                prior=float(kept))


def _model_pose(X, members, parent, order, names, params: LearnParams):
    """Mean shapes placed down the tree, assembled at the joints: the model points (M, 3),
    the joints of links without shared markers (name -> (3,)), their tolerances and the
    share of the one-frame prior left in them, and the least any of a segment's links
    turned (S,) degrees."""
    shapes = [mean_shape(X[:, m], params.n_iter, names[s]) for s, m in enumerate(members)]
    poses = [segment_poses(shapes[s], X[:, m])[:2] for s, m in enumerate(members)]
    place = {order[0]: (np.eye(3), np.zeros(3))}
    joints, tolerances, priors = {}, {}, {}
    turn = np.full(len(members), np.inf)
    for c in order[1:]:
        p = parent[c]
        if not (np.isfinite(poses[p][1]).all(axis=1) & np.isfinite(poses[c][1]).all(axis=1)).any():
            raise ValueError(f"points: segments {names[p]!r} and {names[c]!r} (a link of "
                             f"parents) are never both seen (3 markers each) in one frame")
        common = np.intersect1d(members[p], members[c])
        rows_p, rows_c = (np.array([int(np.flatnonzero(m == i)[0]) for i in common], int)
                          for m in (members[p], members[c]))
        link = learn_link(shapes[p], poses[p], shapes[c], poses[c], rows_p, rows_c, params)
        Rp, tp = place[p]
        place[c] = (Rp @ link.R, Rp @ link.t + tp)
        turn[[p, c]] = np.minimum(turn[[p, c]], link.turn)
        if not len(common):
            joints[names[c]], tolerances[names[c]] = Rp @ link.joint + tp, link.tolerance
            priors[names[c]] = link.prior
    M = X.shape[1]
    total, count = np.zeros((M, 3)), np.zeros(M)
    for s, m in enumerate(members):
        Rs, ts = place[s]
        np.add.at(total, m, shapes[s] @ Rs.T + ts)
        np.add.at(count, m, 1)
    return total / count[:, None], joints, tolerances, priors, turn


def learn_model(cls, labels, points, segments, parents, *, params=None):
    """The body of :meth:`MarkerModel.from_labelled_frames` (see the module docstring);
    ``cls`` is the model class, whose ``_build`` makes the model."""
    params = LearnParams() if params is None else params
    if not isinstance(params, LearnParams):
        raise TypeError(f"params: expected a LearnParams, got {type(params).__name__}")
    labels, X = check_clip(labels, points)
    names, members, parent = definition(labels, segments, parents)
    order = _tree_order(parent, int(np.flatnonzero(parent < 0)[0]))
    P, joints, tolerances, priors, turn = _model_pose(X, members, parent, order, names, params)
    lbar = cls._build(labels, P, names, members, parent, joints).mean_length
    eps = np.empty(len(names))
    for s, m in enumerate(members):
        resid = segment_poses(P[m], X[:, m])[2]
        seen = np.isfinite(resid)
        ebar = np.where(seen, resid, 0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1)
        floor = params.eps_min if turn[s] >= params.turned else params.eps_floor
        eps[s] = np.clip(params.margin * ebar.max() / lbar[s], floor, params.eps_ceiling)
    return cls._build(labels, P, names, members, parent, joints, tolerances=tolerances,
                      priors=priors, eps=eps)


def _tree_order(parent, root):
    order, stack = [], [root]
    while stack:
        s = stack.pop()
        order.append(s)
        stack.extend(int(c) for c in np.flatnonzero(parent == s))
    return order
