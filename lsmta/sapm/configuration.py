"""The best configuration of segment matches over the model's tree (our global search).

The paper's global search (Section 3.2) goes depth first and accepts a segment's first
match that passes Eq. 2, undoing it only when its children fail. Where segments look alike
(clusters on identical plates, short triangles along a limb) the first match is often a
wrong one. Here every segment's matches are found first (:mod:`lsmta.sapm.candidates`)
and the configuration is chosen over the whole tree at once, by max-sum dynamic programming
(exact on a tree):

* a segment scores the markers its match labels, less its ē_s / ε_s (a tie-breaker in
  [0, 1)); leaving a segment out scores 0;
* two linked segments are compatible when their matches use different points (except the
  markers they share, which must be the same points) and when the joint carried by the
  parent's motion and the joint carried by the child's lie within the joint's tolerance plus
  2 ε l̄ of each segment; a compatible pair costs half its joint gap over that limit.

Points claimed by two segments that are not linked are settled afterwards: the weaker match
is dropped and the tree is solved again.
"""

from __future__ import annotations

import numpy as np

from .candidates import Candidates, segment_candidates
from .model import MarkerModel


def _usage(obs, n: int) -> np.ndarray:
    """(K, W) uint64 bit sets: which of the n observed points each match (K, m) uses."""
    U = np.zeros((len(obs), (n + 63) // 64), np.uint64)
    k, i = np.nonzero(obs >= 0)
    q = obs[k, i]
    np.bitwise_or.at(U, (k, q // 64), np.left_shift(np.uint64(1), (q % 64).astype(np.uint64)))
    return U


def _overlap(A, B) -> np.ndarray:
    """(Ka, Kb) bool: bit sets of A (Ka, W) and B (Kb, W) that share a bit."""
    return (np.bitwise_and(A[:, None], B[None]) != 0).any(axis=2)


def _pair(model: MarkerModel, p: int, c: int, cp: Candidates, cc: Candidates, eps,
          penalty: float, n: int):
    """(Kp, Kc) pair scores of parent ``p`` and child ``c`` (-inf: incompatible; a joint
    gap beyond its limit costs ``penalty``); ``n`` observed points."""
    J, shared, tol = model.link(p, c)
    mp, mc = model.members[p], model.members[c]
    jp = np.array([int(np.flatnonzero(mp == j)[0]) for j in shared], int)
    jc = np.array([int(np.flatnonzero(mc == j)[0]) for j in shared], int)
    limit = tol + 2 * eps[p] * model.mean_length[p] + 2 * eps[c] * model.mean_length[c]
    a = np.einsum("kij,j->ki", cp.R, J) + cp.t
    b = np.einsum("kij,j->ki", cc.R, J) + cc.t
    gap = np.linalg.norm(a[:, None] - b[None], axis=-1)
    score = np.where(gap > limit, -penalty, -0.5 * gap / limit)
    Up = _usage(np.delete(cp.obs, jp, axis=1), n)
    Uc = _usage(np.delete(cc.obs, jc, axis=1), n)
    Sp, Sc = _usage(cp.obs[:, jp], n), _usage(cc.obs[:, jc], n)
    # no point used by both, and a shared marker's point is no other marker of the other
    bad = _overlap(Up, Uc) | _overlap(Sp, Uc) | _overlap(Up, Sc)
    for x, y in zip(jp, jc):                               # shared markers: the same points
        a_, b_ = cp.obs[:, x][:, None], cc.obs[:, y][None]
        bad |= (a_ >= 0) & (b_ >= 0) & (a_ != b_)
    return np.where(bad, -np.inf, score)


def pair_scores(model: MarkerModel, cands: list, eps, *, penalty: float, n: int) -> dict:
    """Pair scores of every link, {(parent, child): (Kp, Kc)}."""
    return {(int(p), c): _pair(model, int(p), c, cands[p], cands[c], eps, penalty, n)
            for c, p in enumerate(model.parent) if p >= 0}


def best_configuration(model: MarkerModel, cands: list, eps, pairs: dict, *,
                       allowed=None) -> np.ndarray:
    """(S,) chosen candidate of each segment (-1: left out), maximising the tree's score
    (``pairs`` from :func:`pair_scores`). ``allowed``: per segment a (K,) bool mask of
    usable candidates."""
    S = model.n_segments
    unary = []
    for s, c in enumerate(cands):
        u = np.append(c.n - c.err / eps[s], 0.0)          # last entry: segment left out
        if allowed is not None:
            u[:-1][~allowed[s]] = -np.inf
        unary.append(u)
    root = model.root_of_tree
    order = model.tree_order(root)
    below = [u.copy() for u in unary]                    # subtree score per choice
    pick = {}
    for s in reversed(order):                            # children before parents
        for c in np.flatnonzero(model.parent == s):
            phi = np.zeros((len(below[s]), len(below[c])))
            phi[:-1, :-1] = pairs[s, c]
            total = phi + below[c][None]
            pick[c] = total.argmax(axis=1)
            below[s] = below[s] + total.max(axis=1)
    choice = np.full(S, -1)
    choice[root] = int(np.argmax(below[root]))
    for s in order:
        for c in np.flatnonzero(model.parent == s):
            choice[c] = pick[c][choice[s]]
    return np.where(choice == np.array([len(c) for c in cands]), -1, choice)


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
              max_rounds: int = 8):
    """The best configuration without clashes: (S,) chosen candidate per segment (-1: left
    out) and the number of rounds it took."""
    allowed = [np.ones(len(c), bool) for c in cands] if allowed is None else \
        [a.copy() for a in allowed]
    for rounds in range(1, max_rounds + 1):
        choice = best_configuration(model, cands, eps, pairs, allowed=allowed)
        clashes = _clashes(model, cands, choice)
        if not clashes:
            return choice, rounds
        for a, b in clashes:                             # drop the weaker of the two
            ua = cands[a].n[choice[a]] - cands[a].err[choice[a]] / eps[a]
            ub = cands[b].n[choice[b]] - cands[b].err[choice[b]] / eps[b]
            s = a if ua < ub else b
            allowed[s][choice[s]] = False
    choice = best_configuration(model, cands, eps, pairs, allowed=allowed)
    for _, b in _clashes(model, cands, choice):          # still clashing: leave one out
        choice[b] = -1
    return choice, max_rounds


def tree_search(model: MarkerModel, Q, eps, *, beta: float, limit: int, free=None,
                penalty: float = np.inf):
    """Label the observed points ``Q`` (N, 3) (no NaN) with one instance of ``model``.

    Returns (labels (N,) model marker or -1, chosen candidates (S,), the candidates, rounds).
    """
    D = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
    cands = [segment_candidates(model, s, Q, D, eps=eps[s], beta=beta, limit=limit, free=free)
             for s in range(model.n_segments)]
    pairs = pair_scores(model, cands, eps, penalty=penalty, n=len(Q))
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
