"""A marker model's definition checked against its labels: segments, members, tree.

The user writes a model as two dicts, segment -> labels and segment -> parent;
:func:`definition` turns them into the arrays both ways of building a
:class:`~lsmta.sapm.MarkerModel` use (one clear frame, :mod:`lsmta.sapm.model`; a labelled
clip, :mod:`lsmta.sapm.learning`), with an error naming what is wrong.
"""

from __future__ import annotations

import numpy as np


def definition(labels: tuple, segments: dict, parents: dict, *, labels_name: str = "labels"):
    """Segment names, member index arrays and the (S,) parent array of a model definition,
    checked against ``labels``."""
    if not isinstance(segments, dict) or not segments:
        raise TypeError("segments: expected a non-empty dict segment -> list of labels")
    if not isinstance(parents, dict):
        raise TypeError("parents: expected a dict segment -> parent segment or None")
    index = {k: i for i, k in enumerate(labels)}
    names = tuple(segments)
    seg_index = {s: i for i, s in enumerate(names)}
    if set(parents) != set(names):
        missing = sorted(set(names) - set(parents))
        extra = sorted(set(parents) - set(names))
        raise ValueError(f"parents: expected one entry per segment; missing {missing}, "
                         f"unknown {extra}")
    parent = np.full(len(names), -1)
    for s, p in parents.items():
        if p is None:
            continue
        if p not in seg_index:
            raise ValueError(f"parents: segment {s!r} has unknown parent {p!r}")
        if p == s:
            raise ValueError(f"parents: segment {s!r} is its own parent")
        parent[seg_index[s]] = seg_index[p]
    members = []
    for s in names:
        labs = list(segments[s])
        if len(set(labs)) != len(labs):
            raise ValueError(f"segments: segment {s!r} lists a label twice: {labs}")
        unknown = [k for k in labs if k not in index]
        if unknown:
            raise ValueError(f"segments: segment {s!r} has labels not in {labels_name}: "
                             f"{unknown}")
        if len(labs) < 3:
            raise ValueError(f"segments: segment {s!r} has {len(labs)} markers; SAPM fits "
                             f"a rigid motion per segment and needs at least 3")
        members.append(np.array([index[k] for k in labs]))
    unused = sorted(set(labels) - {labels[i] for m in members for i in m})
    if unused:
        raise ValueError(f"segments: labels in no segment: {unused}")
    _check_tree(names, parent)
    return names, members, parent


def _check_tree(names, parent) -> None:
    """One root, and every chain reaches it."""
    roots = np.flatnonzero(parent < 0)
    if len(roots) != 1:
        raise ValueError(f"parents: expected exactly one root segment (parent None), got "
                         f"{[names[i] for i in roots]}")
    for s in range(len(names)):
        seen, p = {s}, parent[s]
        while p >= 0:
            if p in seen:
                raise ValueError(f"parents: segments {sorted(names[i] for i in seen)} form "
                                 f"a cycle; expected a tree")
            seen.add(p)
            p = parent[p]
