"""Segments proposed from rigidity in a labelled clip, never from the recording to be
labelled.

Markers on one rigid body keep their distances; markers on two bodies joined by a joint
change theirs as the joint turns. Over a labelled clip, the *spread* of a pair (the
standard deviation of its distance over the frames that see both) measures this.
:func:`suggest_segments` groups markers whose pairs all spread less than a threshold
(complete linkage), or starts from groups the user knows (marker plates) and places only
the loose markers; links the groups into a tree along their steadiest cross pair (minimum
spanning tree; a joint keeps the distances of the markers near it); and proposes a marker as
shared by two linked groups when it is as steady against the other group as against its own.

The suggestion is only as good as the clip: in a clip in which two segments do not move
against each other they look like one rigid body.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial.distance import squareform

from .._validate import as_scalar
from .learning import LearnParams, check_clip, learn_link, mean_shape, segment_poses


@dataclass(frozen=True)
class SegmentSuggestion:
    """Segments and a tree proposed by :func:`suggest_segments`.

    Attributes
    ----------
    segments : dict
        segment name -> list of labels (at least 3; a label in two segments is shared by a
        parent and its child); pass to :meth:`MarkerModel.from_labelled_frames`.
    parents : dict
        segment name -> parent name, None for the root.
    spread : (M, M) array
        Standard deviation of each pair's distance over the clip, mm (inf where the pair is
        seen together in fewer than two frames).
    unplaced : list of str
        Markers seen too rarely to be placed (see ``min_seen``); leave them out of the
        model.
    max_spread : float
        The threshold the groups were formed with, mm (NaN when ``groups`` were given).
    """

    segments: dict
    parents: dict
    spread: np.ndarray
    unplaced: list
    max_spread: float


def pair_spread(points, *, min_frames: int = 2) -> np.ndarray:
    """(M, M) standard deviation of every pair's distance over the frames of ``points``
    (T, M, 3) that see both, mm; inf where fewer than ``min_frames`` do."""
    X = np.asarray(points, float)
    M = X.shape[1]
    out = np.empty((M, M))
    for i in range(M):                          # one row at a time: (T, M) at most
        d = np.linalg.norm(X[:, i:i + 1] - X, axis=2)
        n = np.isfinite(d).sum(axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[i] = np.where(n >= max(2, min_frames), np.nanstd(d, axis=0), np.inf)
    np.fill_diagonal(out, 0.0)
    return out


def _grouped(labels, S, groups, max_spread):
    """Lists of marker indices: the user's ``groups``, or complete-linkage clusters."""
    index = {k: i for i, k in enumerate(labels)}
    if groups is None:
        finite = np.where(np.isfinite(S), S, 1e12)
        Z = linkage(squareform(finite, checks=False), "complete")
        cl = fcluster(Z, max_spread, "distance")
        out = [list(np.flatnonzero(cl == c)) for c in np.unique(cl)]
        return {f"group{k + 1}": m for k, m in enumerate(sorted(out, key=min))}
    if not isinstance(groups, dict):
        raise TypeError("groups: expected a dict name -> list of labels")
    seen = {}
    out = {}
    for name, labs in groups.items():
        unknown = [k for k in labs if k not in index]
        if unknown:
            raise ValueError(f"groups: group {name!r} has labels not in labels: {unknown}")
        twice = [k for k in labs if k in seen]
        if twice:
            raise ValueError(f"groups: labels {twice} are in more than one group")
        seen.update(dict.fromkeys(labs))
        out[name] = [index[k] for k in labs]
    return out


def suggest_segments(labels, points, *, groups: dict | None = None,
                     parents: dict | None = None, max_spread: float = 3.0,
                     min_seen: float = 0.25) -> SegmentSuggestion:
    """Propose SAPM segments and their tree from rigidity in a labelled clip.

    Parameters
    ----------
    labels : sequence of str, length M
    points : (T, M, 3) array_like
        The labelled training clip, mm, NaN for gaps. Not modified.
    groups : dict, optional
        name -> labels the user knows to be rigid (a cluster plate); markers in none of
        them (loose markers) are placed by the clip. Without it, markers are grouped by
        complete linkage: every pair of a group spreads less than ``max_spread``.
    parents : dict, optional
        name -> parent name (None for the root) of the groups, if the user knows the tree;
        by default it is proposed from the clip.
    max_spread : float
        Threshold of the grouping, mm (standard deviation of a pair's distance over the
        clip). Also the most a loose marker may spread against a second, linked group to
        be proposed as shared with it.
    min_seen : float
        A pair's spread counts only if both markers are seen together in at least this
        fraction of the frames (a marker seen in two frames looks rigid with everything).

    Returns
    -------
    SegmentSuggestion
        Groups of fewer than three markers are dissolved; their markers, like loose ones,
        join the group they spread least against (mean over its markers), or are listed
        in ``unplaced`` when no spread against any group counts.
    """
    labels, X = check_clip(labels, points)
    max_spread = as_scalar(max_spread, "max_spread", positive=True)
    min_seen = as_scalar(min_seen, "min_seen", nonnegative=True)
    if min_seen > 1:
        raise ValueError(f"min_seen: expected a fraction in [0, 1], got {min_seen}")
    S = pair_spread(X, min_frames=int(np.ceil(min_seen * len(X))))
    members = {k: list(m) for k, m in _grouped(labels, S, groups, max_spread).items()
               if len(m) >= 3}
    if not members:
        raise ValueError("points: no group of 3 or more markers is rigid in this clip; give "
                         "groups, or a larger max_spread")
    names = list(members)
    if parents is None:
        parents = _tree(X, [np.array(members[k]) for k in names], names)
    elif set(parents) != set(names):
        raise ValueError(f"parents: expected one entry per group of 3 or more markers "
                         f"{sorted(names)}, got {sorted(parents)}")
    loose = sorted(set(range(len(labels))) - {i for m in members.values() for i in m})
    unplaced, home = [], {}
    for i in loose:
        mean = np.array([S[i, members[k]].mean() for k in names])
        if np.isfinite(mean).any():
            home[i] = names[int(np.argmin(mean))]
        else:
            unplaced.append(labels[i])
    segments = {k: list(m) for k, m in members.items()}
    for i, k in home.items():
        segments[k].append(i)
    for i, k in home.items():                      # a loose marker steady with a neighbour
        for other in [parents[k]] + [c for c, p in parents.items() if p == k]:
            if other is not None and S[i, members[other]].max() < max_spread:
                segments[other].append(i)
                break
    return SegmentSuggestion(
        segments={k: [labels[i] for i in sorted(m)] for k, m in segments.items()},
        parents=dict(parents), spread=S, unplaced=unplaced,
        max_spread=float("nan") if groups is not None else max_spread)


def _tree(X, members, names) -> dict:
    """Parents of the groups: the minimum spanning tree of link costs, rooted at the
    biggest group. A link's cost is how badly the two groups share a fixed point over the
    clip (the RMS gap of their learned joint, mm) plus a tenth of the distance between
    their closest markers (which decides where the clip shows no motion)."""
    params = LearnParams()
    shapes = [mean_shape(X[:, m], params.n_iter, n) for m, n in zip(members, names)]
    poses = [segment_poses(sh, X[:, m])[:2] for sh, m in zip(shapes, members)]
    G = len(members)
    cost = np.full((G, G), np.inf)
    none = np.zeros(0, int)
    for a in range(G):
        for b in range(a + 1, G):
            if (np.isfinite(poses[a][1]).all(axis=1) & np.isfinite(poses[b][1]).all(axis=1)).any():
                link = learn_link(shapes[a], poses[a], shapes[b], poses[b], none, none, params)
                cost[a, b] = cost[b, a] = link.gap + 0.1 * link.closest
    tree = minimum_spanning_tree(np.where(np.isfinite(cost), cost, 1e12) + 1e-9).toarray()
    adj = (tree + tree.T) > 0
    root = max(range(G), key=lambda g: (len(members[g]), adj[g].sum(), -g))
    parents, order = {names[root]: None}, [root]
    for g in order:
        for h in np.flatnonzero(adj[g]):
            if names[h] not in parents:
                parents[names[h]] = names[g]
                order.append(int(h))
    return parents
