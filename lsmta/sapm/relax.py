"""Tolerances that grow where the training clip ends, with abstention (ours, beyond the
paper).

A model learned from a short clip knows the segments' deformation only as far as the clip
shows it: a clip of a player standing teaches nothing about the shoulder markers with the
arm overhead. The tree search (:mod:`lsmta.sapm.configuration`) runs at the learned ε_s;
what it leaves unlabelled is then searched again among the points nobody took, with the
tolerances widened step by step (``SAPMParams.relax``: factors on ε_s), and only next to
segments already found:

* **segments left out**: their whole matches among the free points (and the joint markers
  their found neighbours identified, which must keep their points), at ``f · ε_s``; a match
  must join a found neighbour (its joint within its limit at the widened tolerances) and
  scores as in the tree search, ``n - ē/ε + Σ links``;
* **markers left out of found segments**: each takes the free point nearest to where its
  segment's motion carries it, within ``f · 2 ε_s l̄_s``, scoring ``1 - d / gate``.

Every label gets a **margin** in the score's units (about one per marker): how much worse
the best answer gets if the label must change (another point, or none). A label whose margin
is below ``SAPMParams.abstain`` is withdrawn: where two labellings are about equally good
the point is left unlabelled rather than risk a wrong label.
"""

from __future__ import annotations

import numpy as np

from .candidates import segment_candidates
from .model import MarkerModel


def _link_terms(model: MarkerModel, s, R, t, found, eps, lbar):
    """(K,) sum of the joint terms of candidates (R (K, 3, 3), t (K, 3)) of segment ``s``
    with its found neighbours (``found``: segment -> (R, t)), -inf where a joint gap is
    beyond its limit; and whether any found neighbour exists."""
    total = np.zeros(len(R))
    linked = False
    for f in model.neighbours[s]:
        if f not in found:
            continue
        linked = True
        J, _, tol = model.link(s, f)
        Rf, tf = found[f]
        limit = tol + 2 * eps[s] * lbar[s] + 2 * eps[f] * lbar[f]
        gap = np.linalg.norm(np.einsum("kij,j->ki", R, J) + t - (Rf @ J + tf), axis=1)
        total += np.where(gap > limit, -np.inf, -0.5 * gap / limit)
    return total, linked


def relax_segments(model: MarkerModel, Q, D, eps, labels, margins, found, *, factor: float,
                   beta: float, limit: int, floor: float = 0.0, ceiling: float = 0.45):
    """One widening step for the segments left out. ``labels`` (N,) model marker per point
    (-1 free), ``margins`` (N,) and ``found`` (segment -> (R, t)) are updated in place.
    Returns the segments added."""
    lbar = model.mean_length
    loose = np.minimum(factor * np.asarray(eps, float), ceiling)
    added = []
    point_of = {int(m): int(q) for q, m in enumerate(labels) if m >= 0}
    for s in model.tree_order(model.root_of_tree):
        if s in found or not any(f in found for f in model.neighbours[s]):
            continue
        m = model.members[s]
        known = {j: point_of[int(mi)] for j, mi in enumerate(m) if int(mi) in point_of}
        free = labels < 0
        free[list(known.values())] = True
        c = segment_candidates(model, s, Q, D, eps=loose[s], beta=beta, limit=limit, free=free,
                               floor=floor)
        if not len(c):
            continue
        ok = np.ones(len(c), bool)
        for j, q in known.items():               # a known marker keeps its point or none
            ok &= (c.obs[:, j] == q) | (c.obs[:, j] < 0)
        taken = np.array(list(known.values()), int)
        for j in range(len(m)):                  # nobody else takes a known point
            if j not in known and len(taken):
                ok &= ~np.isin(c.obs[:, j], taken)
        links, linked = _link_terms(model, s, c.R, c.t, found, loose, lbar)
        if not linked:
            continue
        new = np.array([(c.obs[k][[j for j in range(len(m)) if j not in known]] >= 0).sum()
                        for k in range(len(c))])
        score = np.where(ok & (new > 0), c.scores + links, -np.inf)
        if not np.isfinite(score).any():
            continue
        k = int(np.argmax(score))
        for j, mi in enumerate(m):
            q = int(c.obs[k, j])
            if q < 0 or j in known:
                continue
            # alternatives: the marker on another point, or the point as another marker
            other = ((c.obs[:, j] >= 0) & (c.obs[:, j] != q)) | (
                (c.obs == q).any(axis=1) & (c.obs[:, j] != q))
            margin = score[k] - (score[other].max() if other.any() else -np.inf)
            labels[q] = mi
            margins[q] = margin
        found[s] = (c.R[k], c.t[k])
        added.append(s)
    return added


def relax_markers(model: MarkerModel, Q, eps, labels, margins, found, *, factor: float):
    """One widening step for markers of found segments left unlabelled: each takes the
    nearest free point within ``factor · 2 ε_s l̄_s`` of its predicted position, if that
    point is no other such marker's nearest. Updates ``labels`` and ``margins`` in
    place."""
    lbar = model.mean_length
    labelled = set(int(v) for v in labels[labels >= 0])
    free = np.flatnonzero(labels < 0)
    if not len(free):
        return
    want = []
    for s, (R, t) in found.items():
        gate = factor * 2 * eps[s] * lbar[s]
        for mi in model.members[s]:
            if int(mi) in labelled:
                continue
            d = np.linalg.norm(Q[free] - (R @ model.points[mi] + t), axis=1)
            order = np.argsort(d)
            if d[order[0]] >= gate:
                continue
            second = d[order[1]] if len(order) > 1 else np.inf
            margin = (second - d[order[0]]) / gate
            want.append((int(free[order[0]]), int(mi), margin))
    by_marker = {}
    for q, mi, margin in want:                   # a joint marker: wanted by two segments
        by_marker.setdefault(mi, []).append((q, margin))
    by_point = {}
    for mi, w in by_marker.items():
        if len({q for q, _ in w}) == 1:
            by_point.setdefault(w[0][0], []).append((mi, min(x for _, x in w)))
    for q, w in by_point.items():
        if len(w) == 1:
            labels[q], margins[q] = w[0]
