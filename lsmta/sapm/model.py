"""The articulated marker model of SAPM (Holstein & Li 2002, Section 2).

Labelled points with model coordinates, grouped into segments; the segments form a tree.
Where a parent and a child share markers (joint markers: one, or a pair such as two wrist
markers) those labels belong to both. Where they share none, as with cluster marker sets,
the joint is estimated from the model frame (the midpoint of the closest pair of markers
across the two segments) and carries a tolerance, so that a child can still be searched
near its parent. A model comes from one clear frame, as in the paper, or is learned from a
labelled clip (:meth:`MarkerModel.from_labelled_frames`, :mod:`lsmta.sapm.learning`), which
also gives every segment its own tolerance ε_s and finds the joints from the motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from itertools import combinations

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from .._validate import as_array
from .definition import definition
from .learning import learn_model


@dataclass(frozen=True, eq=False)
class MarkerModel:
    """A segment-based articulated model of labelled markers.

    Attributes
    ----------
    labels : tuple of str, length M
        Marker labels; ``points[i]`` is the model position of ``labels[i]``.
    points : (M, 3) array
        Model coordinates, mm (read-only).
    segments : tuple of str, length S
        Segment names.
    members : tuple of S int arrays
        Indices into ``labels`` of each segment's markers; a joint marker is a member of
        both its segments.
    parent : (S,) int array
        Index of each segment's parent, -1 for the root of the given tree.
    joint : (S, 3) array
        Model position of the joint between each segment and its parent, mm (NaN for the
        root): the shared markers' centroid, or the estimate described above.
    shared : tuple of S int arrays
        Indices into ``labels`` of the markers each segment shares with its parent (joint
        markers; empty where they share none, and for the root).
    joint_tolerance : (S,) array
        How far, mm, the estimated joint may be from the true centre of rotation: 0 for
        shared markers, else the distance between the closest pair the estimate came from
        (or, for a model learned from a clip, the joint's learned spread).
    joint_prior : (S,) array
        For a joint without shared markers, the share of the one-frame estimate left in it
        where the clip fixes it least: 1 for a model from one frame, near 0 where the clip
        turned the link enough to find its centre; 0 for shared markers and the root.
    eps : (S,) array
        Each segment's own tolerable distortion ε_s of Eq. 2 (a fraction of its l̄_s),
        learned from a clip (:meth:`from_labelled_frames`); NaN where the search's
        ``SAPMParams.eps`` applies (a model from one frame).
    """

    labels: tuple
    points: np.ndarray
    segments: tuple
    members: tuple
    parent: np.ndarray
    joint: np.ndarray
    shared: tuple
    joint_tolerance: np.ndarray
    joint_prior: np.ndarray
    eps: np.ndarray

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_labelled_frame(cls, points_by_label: dict, segments: dict, parents: dict,
                            *, joints: dict | None = None) -> MarkerModel:
        """Build a model from one clear frame, as the paper does.

        Parameters
        ----------
        points_by_label : dict
            label -> (3,) model position, mm.
        segments : dict
            segment name -> list of labels (at least 3). A label in two segments must be
            a joint marker of a parent and its child.
        parents : dict
            segment name -> parent segment name, or None for the root (exactly one).
        joints : dict, optional
            segment name -> (3,) joint position with its parent, mm, for links without a
            shared marker (overrides the closest-pair estimate, tolerance 0).

        Returns
        -------
        MarkerModel
        """
        if not isinstance(points_by_label, dict) or not points_by_label:
            raise TypeError("points_by_label: expected a non-empty dict label -> (3,) position")
        labels = tuple(points_by_label)
        points = np.stack([as_array(points_by_label[k], f"points_by_label[{k!r}]", shape=(3,))
                           for k in labels])
        names, members, parent = definition(labels, segments, parents,
                                            labels_name="points_by_label")
        joints = {} if joints is None else dict(joints)
        unknown = sorted(set(joints) - set(names))
        if unknown:
            raise ValueError(f"joints: unknown segments {unknown}")
        return cls._build(labels, points, names, members, parent, joints)

    @classmethod
    def from_labelled_frames(cls, labels, points, segments: dict, parents: dict, *,
                             params=None) -> MarkerModel:
        """Learn a model from a labelled clip, as a user has from a range-of-motion trial.

        Learns each segment's mean shape, its rigidity tolerance ε_s (from the spread of
        Eq. 2's ē_s over the clip) and the joints of links without shared markers (the
        point fixed in both segments over the clip) with their tolerances; see
        :mod:`lsmta.sapm.learning`. A link may share several markers (two wrist markers,
        a medial/lateral pair).

        Parameters
        ----------
        labels : sequence of str, length M
            Marker names, one per column of ``points``.
        points : (T, M, 3) array_like
            The labelled clip, mm; NaN for a gap (a marker with any NaN coordinate is
            missing in that frame). Not modified.
        segments : dict
            segment name -> list of labels (at least 3); a label in two segments must be
            shared by a parent and its child. :func:`suggest_segments` proposes one.
        parents : dict
            segment name -> parent segment name, or None for the root (exactly one).
        params : LearnParams, optional
            Margins and floors of the learned tolerances.

        Returns
        -------
        MarkerModel
            With ``eps`` (ε_s) learned; ``points`` is the clip's mean pose.
        """
        return learn_model(cls, labels, points, segments, parents, params=params)

    @classmethod
    def _build(cls, labels, points, names, members, parent, joints, *, tolerances=None,
               priors=None, eps=None):
        """The model from checked parts. ``joints``: segment name -> joint position for
        links without shared markers (``tolerances``: name -> its tolerance, default 0;
        ``priors``: name -> the share of the one-frame estimate left in it, default 0 for a
        given joint); ``eps``: (S,) learned ε_s (default NaN: the search's ε)."""
        S = len(names)
        owner = {}
        for s, m in enumerate(members):
            for i in m:
                owner.setdefault(int(i), []).append(s)
        for i, segs in owner.items():
            if len(segs) == 1:
                continue
            a, b = segs[0], segs[-1]
            if len(segs) > 2 or not (parent[a] == b or parent[b] == a):
                raise ValueError(f"segments: label {labels[i]!r} is in segments "
                                 f"{[names[s] for s in segs]}; a shared label must join one "
                                 f"parent and its child")
        joint = np.full((S, 3), np.nan)
        shared = [np.zeros(0, int) for _ in range(S)]
        tol = np.zeros(S)
        prior = np.zeros(S)
        tolerances = {} if tolerances is None else tolerances
        priors = {} if priors is None else priors
        for s in range(S):
            p = parent[s]
            if p < 0:
                continue
            shared[s] = np.intersect1d(members[s], members[p])
            if len(shared[s]):
                joint[s] = points[shared[s]].mean(axis=0)
            elif names[s] in joints:
                joint[s] = as_array(joints[names[s]], f"joints[{names[s]!r}]", shape=(3,))
                tol[s] = tolerances.get(names[s], 0.0)
                prior[s] = priors.get(names[s], 0.0)
            else:
                a, b = points[members[s]], points[members[p]]
                d = np.linalg.norm(a[:, None] - b[None], axis=-1)
                i, j = np.unravel_index(np.argmin(d), d.shape)
                joint[s] = 0.5 * (a[i] + b[j])
                tol[s] = d[i, j]
                prior[s] = 1.0
        eps = np.full(S, np.nan) if eps is None else np.asarray(eps, float).copy()
        for arr in (points, parent, joint, tol, prior, eps, *shared):
            arr.setflags(write=False)
        return cls(labels=tuple(labels), points=points, segments=tuple(names),
                   members=tuple(np.asarray(m) for m in members), parent=parent, joint=joint,
                   shared=tuple(shared), joint_tolerance=tol, joint_prior=prior, eps=eps)

    # ------------------------------------------------------------------ derived structure
    @property
    def n_points(self) -> int:
        return len(self.labels)

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @cached_property
    def mean_length(self) -> np.ndarray:
        """(S,) average distance between a segment's markers, mm (the paper's l̄_s)."""
        out = np.empty(self.n_segments)
        for s, m in enumerate(self.members):
            p = self.points[m]
            d = np.linalg.norm(p[:, None] - p[None], axis=-1)
            out[s] = d[np.triu_indices(len(m), 1)].mean()
        return out

    @cached_property
    def base_triples(self) -> tuple:
        """Per segment, the triples of its markers (local indices) the tree search starts
        its matches from: the largest triangle and, for four or more markers, the largest
        triangle without each of its corners (so one missing marker is survived)."""
        out = []
        for m in self.members:
            p = self.points[m]
            tri = list(combinations(range(len(m)), 3))
            area = [np.linalg.norm(np.cross(p[b] - p[a], p[c] - p[a])) for a, b, c in tri]
            order = np.argsort(-np.asarray(area), kind="stable")
            best = tri[order[0]]
            picks = [best] + ([next(tri[k] for k in order if corner not in tri[k])
                               for corner in best] if len(m) >= 4 else [])
            out.append(tuple(dict.fromkeys(picks)))
        return tuple(out)

    @cached_property
    def point_segment(self) -> np.ndarray:
        """(M,) the segment that owns each marker (for a joint marker, the parent)."""
        out = np.full(self.n_points, -1)
        for s in self.tree_order(self.root_of_tree):
            for i in self.members[s]:
                if out[i] < 0:
                    out[i] = s
        return out

    @property
    def root_of_tree(self) -> int:
        return int(np.flatnonzero(self.parent < 0)[0])

    @cached_property
    def neighbours(self) -> tuple:
        """Linked segments of each segment (parent and children), as tuples."""
        out = [[] for _ in range(self.n_segments)]
        for s, p in enumerate(self.parent):
            if p >= 0:
                out[s].append(int(p))
                out[p].append(s)
        return tuple(tuple(n) for n in out)

    @cached_property
    def search_root(self) -> int:
        """Where SAPM starts: the segment with the most markers plus links (ties: the
        tree's root, then the first listed)."""
        score = [len(m) + len(n) for m, n in zip(self.members, self.neighbours)]
        best = max(score)
        if score[self.root_of_tree] == best:
            return self.root_of_tree
        return int(score.index(best))

    def tree_order(self, start: int) -> list[int]:
        """Segments depth first from ``start`` over the undirected tree."""
        order, stack, seen = [], [start], {start}
        while stack:
            s = stack.pop()
            order.append(s)
            for n in reversed(self.neighbours[s]):
                if n not in seen:
                    seen.add(n)
                    stack.append(n)
        return order

    @cached_property
    def search_parent(self) -> np.ndarray:
        """(S,) parent of each segment in the tree re-rooted at :attr:`search_root`."""
        out = np.full(self.n_segments, -1)
        for s in self.tree_order(self.search_root):
            for n in self.neighbours[s]:
                if n != out[s] and n != self.search_root and out[n] < 0:
                    out[n] = s
        return out

    @property
    def joint_label(self) -> np.ndarray:
        """(S,) the first marker each segment shares with its parent, -1 where none."""
        return np.array([m[0] if len(m) else -1 for m in self.shared])

    def link(self, a: int, b: int):
        """Joint between linked segments ``a`` and ``b``: (position (3,), shared markers
        (int array, may be empty), tolerance mm)."""
        child = a if self.parent[a] == b else b
        if self.parent[child] not in (a, b) or a == b:
            raise ValueError(f"segments {self.segments[a]!r} and {self.segments[b]!r} are "
                             f"not linked")
        return self.joint[child], self.shared[child], float(self.joint_tolerance[child])

    def segment_eps(self, default: float) -> np.ndarray:
        """(S,) ε_s of each segment: the learned one, else ``default``."""
        return np.where(np.isfinite(self.eps), self.eps, default)

    def label_index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise KeyError(f"label: {label!r} is not in the model") from None

    def segment_index(self, name: str) -> int:
        try:
            return self.segments.index(name)
        except ValueError:
            raise KeyError(f"segment: {name!r} is not in the model") from None

    def edges(self) -> list[tuple[int, int]]:
        """Stick links for drawing: every pair of markers within a segment that are
        neighbours in the segment's minimum spanning tree."""
        out = []
        for m in self.members:
            p = self.points[m]
            d = np.linalg.norm(p[:, None] - p[None], axis=-1)
            mst = minimum_spanning_tree(d).tocoo()
            out += [(int(m[i]), int(m[j])) for i, j in zip(mst.row, mst.col)]
        return out

    def __repr__(self) -> str:
        return (f"MarkerModel({self.n_points} markers, {self.n_segments} segments, "
                f"search root {self.segments[self.search_root]!r})")
