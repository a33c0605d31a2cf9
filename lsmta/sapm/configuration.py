"""The best configuration of segment matches over the model's tree (our global search).

The paper's global search (Section 3.2) goes depth first and accepts a segment's first
match that passes Eq. 2, undoing it only when its children fail. Where segments look alike
(clusters on identical plates, short triangles along a limb) the first match is often a
wrong one. Here every segment's matches are found first (:mod:`lsmta.sapm.candidates`)
and the configuration is chosen over the whole tree at once, by max-sum dynamic programming
(exact on a tree):

* a segment's match scores ``1 - (r / τ)²`` per marker it labels (``r`` the marker's
  residual, ``τ = max(ε_s l̄_s, floor)``; :attr:`Candidates.scores`); leaving a segment
  out scores 0;
* two linked segments are compatible when their matches use different points (except the
  markers they share, which must be the same points) and when the joint carried by the
  parent's motion and the joint carried by the child's lie within the joint's tolerance plus
  2 ε l̄ of each segment; a compatible pair costs half its joint gap over that limit.

Points claimed by two segments that are not linked are settled afterwards: the weaker match
is dropped and the tree is solved again. Each label's margin (:func:`label_margins`) is the
score lost by the best configuration that labels one segment's points otherwise.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .candidates import Candidates, segment_candidates
from .model import MarkerModel


@nb.njit(cache=True)
def _pair_kernel(op, oc, sp, sc, a, b, limit, penalty):
    """(Kp, Kc) scores from the matches' points: ``op``, ``oc`` the parent's and child's
    points of their own (not shared) markers, ``sp``, ``sc`` the points of the shared
    markers in the same order (-1: none), ``a``, ``b`` the joint carried by each."""
    Kp, Kc = len(op), len(oc)
    out = np.empty((Kp, Kc))
    for i in range(Kp):
        for j in range(Kc):
            bad = False
            for x in range(sp.shape[1]):                    # shared: the same points
                if sp[i, x] >= 0 and sc[j, x] >= 0 and sp[i, x] != sc[j, x]:
                    bad = True
            for u in range(op.shape[1] + sp.shape[1]):       # no point used twice
                q = op[i, u] if u < op.shape[1] else sp[i, u - op.shape[1]]
                if q < 0 or bad:
                    continue
                for v in range(oc.shape[1] + sc.shape[1]):
                    r = oc[j, v] if v < oc.shape[1] else sc[j, v - oc.shape[1]]
                    if r == q and (u < op.shape[1] or v < oc.shape[1]
                                   or u - op.shape[1] != v - oc.shape[1]):
                        bad = True
                        break
            if bad:
                out[i, j] = -np.inf
                continue
            gap = np.sqrt((a[i, 0] - b[j, 0]) ** 2 + (a[i, 1] - b[j, 1]) ** 2
                          + (a[i, 2] - b[j, 2]) ** 2)
            out[i, j] = -penalty if gap > limit else -0.5 * gap / limit
    return out


def _pair(model: MarkerModel, p: int, c: int, cp: Candidates, cc: Candidates, eps,
          penalty: float):
    """(Kp, Kc) pair scores of parent ``p`` and child ``c`` (-inf: incompatible, their
    matches use a point twice or disagree on a shared marker; a joint gap beyond its limit
    costs ``penalty``)."""
    J, shared, tol = model.link(p, c)
    mp, mc = model.members[p], model.members[c]
    jp = np.array([int(np.flatnonzero(mp == j)[0]) for j in shared], int)
    jc = np.array([int(np.flatnonzero(mc == j)[0]) for j in shared], int)
    limit = tol + 2 * eps[p] * model.mean_length[p] + 2 * eps[c] * model.mean_length[c]
    a = np.einsum("kij,j->ki", cp.R, J) + cp.t
    b = np.einsum("kij,j->ki", cc.R, J) + cc.t
    return _pair_kernel(np.ascontiguousarray(np.delete(cp.obs, jp, axis=1)),
                        np.ascontiguousarray(np.delete(cc.obs, jc, axis=1)),
                        np.ascontiguousarray(cp.obs[:, jp]), np.ascontiguousarray(cc.obs[:, jc]),
                        a, b, float(limit), float(penalty))


def pair_scores(model: MarkerModel, cands: list, eps, *, penalty: float) -> dict:
    """Pair scores of every link, {(parent, child): (Kp, Kc)}."""
    return {(int(p), c): _pair(model, int(p), c, cands[p], cands[c], eps, penalty)
            for c, p in enumerate(model.parent) if p >= 0}


def _score(c, eps, s):
    """(K,) the tree's score of segment ``s``'s matches (:attr:`Candidates.scores`)."""
    return c.scores


def _unary(cands, eps, allowed):
    """Per segment the (K + 1,) scores of its candidates, the last for "left out"."""
    out = []
    for s, c in enumerate(cands):
        u = np.append(_score(c, eps, s), 0.0)             # last entry: segment left out
        if allowed is not None:
            u[:-1][~allowed[s]] = -np.inf
        out.append(u)
    return out


def _padded(pairs, s, c, ks, kc):
    phi = np.zeros((ks, kc))
    phi[:-1, :-1] = pairs[s, c]
    return phi


def best_configuration(model: MarkerModel, cands: list, eps, pairs: dict, *,
                       allowed=None) -> np.ndarray:
    """(S,) chosen candidate of each segment (-1: left out), maximising the tree's score
    (``pairs`` from :func:`pair_scores`). ``allowed``: per segment a (K,) bool mask of
    usable candidates."""
    S = model.n_segments
    unary = _unary(cands, eps, allowed)
    root = model.root_of_tree
    order = model.tree_order(root)
    below = [u.copy() for u in unary]                    # subtree score per choice
    pick = {}
    for s in reversed(order):                            # children before parents
        for c in np.flatnonzero(model.parent == s):
            total = _padded(pairs, s, c, len(below[s]), len(below[c])) + below[c][None]
            pick[c] = total.argmax(axis=1)
            below[s] = below[s] + total.max(axis=1)
    choice = np.full(S, -1)
    choice[root] = int(np.argmax(below[root]))
    for s in order:
        for c in np.flatnonzero(model.parent == s):
            choice[c] = pick[c][choice[s]]
    return np.where(choice == np.array([len(c) for c in cands]), -1, choice)


def configuration_score(model: MarkerModel, cands: list, eps, pairs: dict, choice) -> float:
    """The tree's score of a configuration ``choice`` (S,) (-1: left out)."""
    total = 0.0
    for s, k in enumerate(choice):
        if k >= 0:
            total += float(_score(cands[s], eps, s)[k])
    for c, p in enumerate(model.parent):
        if p >= 0 and choice[p] >= 0 and choice[c] >= 0:
            total += float(pairs[int(p), c][choice[p], choice[c]])
    return total


def label_margins(model: MarkerModel, cands: list, eps, pairs: dict, choice, allowed,
                  n: int) -> np.ndarray:
    """(n,) each labelled point's margin, in the score's units (about one per marker): the
    score of the chosen configuration less that of the best configuration (clashes settled
    as in :func:`configure`) in which a segment's points are labelled otherwise, taken over
    the alternatives that change the point's label (another marker) or give its marker
    another point; ``inf`` where no alternative does, NaN for points left unlabelled.
    Leaving a point unlabelled is not an alternative that counts: it is never wrong."""
    chosen = labelled_points(model, cands, choice, n)
    point_of = np.full(model.n_points, -1)
    point_of[chosen[chosen >= 0]] = np.flatnonzero(chosen >= 0)
    best = configuration_score(model, cands, eps, pairs, choice)
    out = np.where(chosen >= 0, np.inf, np.nan)
    users = np.zeros((n, model.n_segments), bool)      # segments with a match on a point
    for s, c in enumerate(cands):
        if len(c):
            q = c.obs[c.obs >= 0]
            users[q, s] = True
    for s, k in enumerate(choice):
        if k < 0:
            continue
        obs = cands[s].obs
        mine = obs[k]
        same = ((obs == mine[None]) | (obs < 0)).all(axis=1)   # nothing of s relabelled
        rivals = users[mine[mine >= 0]].any(axis=0)
        rivals[s] = False
        if same.all() and not rivals.any():            # no match could label s otherwise
            continue
        mask = [a.copy() for a in allowed]
        mask[s] &= ~same
        alt, _ = configure(model, cands, eps, pairs, allowed=mask)
        lab = labelled_points(model, cands, alt, n)
        moved = np.zeros(n, bool)
        moved |= (lab >= 0) & (chosen >= 0) & (lab != chosen)
        alt_point = np.full(model.n_points, -1)
        alt_point[lab[lab >= 0]] = np.flatnonzero(lab >= 0)
        elsewhere = (alt_point >= 0) & (point_of >= 0) & (alt_point != point_of)
        moved[point_of[elsewhere]] = True
        if moved.any():
            margin = best - configuration_score(model, cands, eps, pairs, alt)
            out[moved] = np.minimum(out[moved], margin)
    return out


def _clashes(model: MarkerModel, cands, choice):
    """Pairs of segments (a, b) whose chosen matches claim the same point, not being a
    marker they share."""
    owner = {}
    out = set()
    for s, k in enumerate(choice):
        if k < 0:
            continue
        for mi, q in zip(model.members[s], cands[s].obs[k]):
            if q < 0:
                continue
            for t, mj in owner.get(int(q), []):
                if mj != mi:
                    out.add((t, s))
            owner.setdefault(int(q), []).append((s, int(mi)))
    return sorted(out)


def configure(model: MarkerModel, cands: list, eps, pairs: dict, *, allowed=None,
              max_rounds: int = 8, with_allowed: bool = False):
    """The best configuration without clashes: (S,) chosen candidate per segment (-1: left
    out) and the number of rounds it took (and, ``with_allowed``, the candidates still
    allowed at the end, per segment a (K,) bool mask)."""
    allowed = [np.ones(len(c), bool) for c in cands] if allowed is None else \
        [a.copy() for a in allowed]
    for rounds in range(1, max_rounds + 1):
        choice = best_configuration(model, cands, eps, pairs, allowed=allowed)
        clashes = _clashes(model, cands, choice)
        if not clashes:
            return (choice, rounds, allowed) if with_allowed else (choice, rounds)
        for a, b in clashes:                             # drop the weaker of the two
            ua = _score(cands[a], eps, a)[choice[a]]
            ub = _score(cands[b], eps, b)[choice[b]]
            s = a if ua < ub else b
            allowed[s][choice[s]] = False
    choice = best_configuration(model, cands, eps, pairs, allowed=allowed)
    for _, b in _clashes(model, cands, choice):          # still clashing: leave one out
        choice[b] = -1
    return (choice, max_rounds, allowed) if with_allowed else (choice, max_rounds)


def tree_search(model: MarkerModel, Q, eps, *, beta: float, limit: int, free=None,
                penalty: float = np.inf, floor: float = 0.0):
    """Label the observed points ``Q`` (N, 3) (no NaN) with one instance of ``model``.

    Returns (labels (N,) model marker or -1, chosen candidates (S,), the candidates, rounds).
    """
    D = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
    cands = [segment_candidates(model, s, Q, D, eps=eps[s], beta=beta, limit=limit, free=free,
                                floor=floor) for s in range(model.n_segments)]
    pairs = pair_scores(model, cands, eps, penalty=penalty)
    choice, rounds = configure(model, cands, eps, pairs)
    return labelled_points(model, cands, choice, len(Q)), choice, cands, rounds


def labelled_points(model: MarkerModel, cands: list, choice, n: int) -> np.ndarray:
    """(n,) model marker of each observed point under the chosen candidates, -1 elsewhere."""
    labels = np.full(n, -1)
    for s, k in enumerate(choice):
        if k >= 0:
            o = cands[s].obs[k]
            labels[o[o >= 0]] = model.members[s][o >= 0]
    return labels


def complete_partial(model: MarkerModel, Q, eps, cands: list, choice, labels, *,
                     beta: float):
    """Our last step: a segment left out, one of whose markers is missing, is matched on
    the two markers it has and the joint with a found neighbour (the neighbour's motion
    carries the joint): pairs of free points at the model's distance from each other and
    from the joint, fitted rigidly with the joint as a third point (Eq. 2 on the pair,
    the joint within its limit). Only joints the training clip fixed (``joint_prior`` at
    most 0.5) are used; a match is accepted only where exactly one assignment passes, and
    only where two markers are more than ``beta`` of the segment (a 3-marker segment at the
    tree search's β of 0.5). Returns the updated labels (n,) and {segment:
    (R, t, err, matched)} of the segments completed."""
    labels = labels.copy()
    out = {}
    for s in range(model.n_segments):
        m = model.members[s]
        if choice[s] >= 0 or not 2 > beta * len(m):
            continue
        for f in model.neighbours[s]:
            J, shared, tol = model.link(s, f)
            child = s if model.parent[s] == f else f
            if choice[f] < 0 or len(shared) or model.joint_prior[child] > 0.5:
                continue
            c = cands[f]
            V = c.R[choice[f]] @ J + c.t[choice[f]]
            found = _pair_with_joint(model, s, Q, labels < 0, V, J,
                                     tol + 2 * eps[s] * model.mean_length[s], eps[s])
            if found is not None:
                (a, i), (b, j), R, t, err = found
                labels[[i, j]] = m[[a, b]]
                out[s] = (R, t, err, 2)
                break
    return labels, out


def _pair_with_joint(model, s, Q, free, V, J, limit, eps):
    """The unique (marker, point) pair assignment of segment ``s`` around the joint image
    ``V``, or None."""
    m = model.members[s]
    P = model.points[m]
    lbar = model.mean_length[s]
    idx = np.flatnonzero(free)
    if len(idx) < 2:
        return None
    reach = np.linalg.norm(P - J, axis=1)
    dist = np.linalg.norm(Q[idx] - V, axis=1)
    near = np.abs(dist[None] - reach[:, None]) <= limit                  # (m, n)
    D = np.linalg.norm(Q[idx][:, None] - Q[idx][None], axis=-1)
    hits = []
    for a in range(len(m)):
        for b in range(a + 1, len(m)):
            dab = np.linalg.norm(P[a] - P[b])
            ii, jj = np.nonzero(near[a][:, None] & near[b][None]
                                & (np.abs(D - dab) < 2 * eps * dab))
            for i, j in zip(ii, jj):
                src = np.stack([P[a], P[b], J])
                dst = np.stack([Q[idx[i]], Q[idx[j]], V])
                R, t = _rigid3(src, dst)
                r = np.linalg.norm(src @ R.T + t - dst, axis=1)
                if r[:2].mean() < eps * lbar and r[2] <= limit:
                    hits.append(((a, idx[i]), (b, idx[j]), R, t, float(r[:2].mean() / lbar)))
    points = {frozenset((h[0][1], h[1][1])) for h in hits}
    return hits[0] if len(points) == 1 and len({(h[0], h[1]) for h in hits}) == 1 else None


def _rigid3(src, dst):
    """Least-squares rigid motion of three points (Kabsch)."""
    ps, pd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - ps).T @ (dst - pd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, pd - R @ ps
