"""Segment-based articulated point matching (SAPM; Holstein & Li 2002, Section 3).

Labels an unlabelled 3-D marker pose from one frame with a :class:`~lsmta.sapm.MarkerModel`:

* **local matching** (3.1): for a segment, candidate tables (CTs) from the pivot-distance
  criterion (Eq. 4), low-count tables discarded and the rest tried biggest first; partial
  matches by SVD rigid fits that pass the matching-quality test (Eq. 2), found by
  worst-pair replacement for segments of many points and by nearest–furthest-to-pivot
  triples for small ones; then closest-neighbour completion over every unidentified point
  (Eq. 5) and the matching-size test (Eq. 3);
* **global hierarchical search** (3.2): depth first from the root segment; a child uses its
  parent's identified joint marker as its only pivot, or, where that marker is missing (or
  the marker set has no shared joints), the *virtual joint* carried by the parent's
  transform as a gate on its pivots; a segment whose children fail is re-matched with its
  next candidate (confirmation of ambiguous segments, backward correction of parents);
  segments on broken chains are searched from scratch last.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

from .._validate import as_int, as_points, as_rng, as_scalar
from ..rigid import apply_rigid
from ._kernels import complete_match, fit_error, triple_fits
from .candidates import segment_candidates
from .configuration import (
    complete_partial,
    configure,
    label_margins,
    labelled_points,
    pair_scores,
)
from .model import MarkerModel
from .relax import relax_markers, relax_segments


@dataclass(frozen=True)
class SAPMParams:
    """Parameters of the search.

    Attributes
    ----------
    eps : float
        Tolerable segmental distortion ε of Eq. 2, a fraction of the segment's mean marker
        distance (paper, humans: 0.10–0.15).
    beta : float
        Matching-size fraction β of Eq. 3: a segment needs more than β·M_s matched markers
        (paper, humans: 0.8–0.9).
    coarse_min_points : int
        Segments with at least this many markers use worst-pair replacement; smaller ones
        the nearest–furthest-to-pivot search (paper: 6).
    max_alternatives : int
        How many whole matches of one segment are tried when its children fail.
    max_tables : int
        At most this many candidate tables per pivot are tried (best first).
    rank_root : bool
        Our option, not the paper's: try the root segment's whole matches from all of a
        pivot's tables in order of their fit error ē, instead of in the order the tables
        give them (biggest table first). Slower. It helps on distorted poses of the
        code-built model; it can hurt where segments look alike and fit each other well,
        as clusters on similar plates do (notebook 08).
    joint_test : bool
        Our option for the depth-first search: a child's match must also carry the joint
        to within its tolerance plus 2 ε_s l̄_s of where the parent's motion carries it
        (the paper only gates the child's pivot by its distance from that joint).
    search : {"depth_first", "tree"}
        "depth_first": the paper's global search (Section 3.2). "tree": ours: every
        segment's matches first (:mod:`lsmta.sapm.candidates`), then the best
        configuration of the whole tree by dynamic programming
        (:mod:`lsmta.sapm.configuration`). It needs a smaller β where markers go missing:
        a match is only accepted together with its linked segments.
    max_candidates : int
        Tree search: most matches kept per segment (per instance).
    link_penalty : float
        Tree search: what a link whose joint gap exceeds its limit costs, in markers
        (``inf``: such links are never accepted). A finite cost lets two well-matched
        segments stand together when the joint learned from a still clip was wrong.
    relax : tuple of float
        Tree search, ours: factors (> 1, increasing) on ε_s with which what the search left
        unlabelled is searched again among the free points, next to segments already
        found (:mod:`lsmta.sapm.relax`): tolerances that grow where the training clip
        ends. Empty: no second search.
    abstain : float
        Tree search, ours: a label whose margin (how much worse the best answer gets if it
        must change, about one unit per marker; ``Identification.confidence``) is below
        this is withdrawn: the point is left unlabelled rather than risk a wrong label.
        0: never abstain (and the margins, which take one more configuration per
        segment, are not computed: ``Identification.confidence`` is NaN).
    score_floor : float
        Tree search, ours: the least scale of a match's score, mm: a matched marker scores
        ``1 - (r / max(ε_s l̄_s, score_floor))²``, so that a segment whose learned ε_s is
        tiny (a plate in a clip) does not lose its matches for a millimetre.
    """

    eps: float = 0.10
    beta: float = 0.80
    coarse_min_points: int = 6
    max_alternatives: int = 3
    max_tables: int = 30
    rank_root: bool = False
    joint_test: bool = False
    search: str = "depth_first"
    max_candidates: int = 100
    link_penalty: float = 3.0
    relax: tuple = ()
    abstain: float = 0.0
    score_floor: float = 10.0

    @classmethod
    def generalising(cls, *, relax=(1.5, 2.0), abstain: float = 0.1) -> SAPMParams:
        """Our settings for labelling frames beyond a training clip: the tree search with
        β = 0.5, the second search at 1.5 and 2 ε_s, abstention below a margin of 0.1.
        Chosen on the tennis serve and the static wheelchair recording (notebook 18),
        reported on the others."""
        return cls(search="tree", beta=0.5, relax=relax, abstain=abstain)

    def __post_init__(self):
        eps, beta = as_scalar(self.eps, "eps"), as_scalar(self.beta, "beta")
        if not 0 < eps < 1:
            raise ValueError(f"eps: expected a fraction in (0, 1) (paper: 0.10-0.15), got {eps}")
        if not 0 <= beta < 1:
            raise ValueError(f"beta: expected a fraction in [0, 1) (paper: 0.8-0.9), got {beta}")
        if self.search not in ("depth_first", "tree"):
            raise ValueError(f"search: expected 'depth_first' or 'tree', got {self.search!r}")
        for name in ("coarse_min_points", "max_alternatives", "max_tables", "max_candidates"):
            object.__setattr__(self, name, as_int(getattr(self, name), name))
        object.__setattr__(self, "eps", eps)
        object.__setattr__(self, "beta", beta)
        try:
            penalty = float(self.link_penalty)
        except (TypeError, ValueError):
            raise TypeError(f"link_penalty: expected a number >= 0 or inf, got "
                            f"{self.link_penalty!r}") from None
        if not penalty >= 0:
            raise ValueError(f"link_penalty: expected a cost >= 0 or inf, got {penalty}")
        object.__setattr__(self, "link_penalty", penalty)
        try:
            relax = tuple(float(f) for f in self.relax)
        except (TypeError, ValueError):
            raise TypeError(f"relax: expected a sequence of factors > 1, got "
                            f"{self.relax!r}") from None
        if any(not f > 1 for f in relax) or list(relax) != sorted(relax):
            raise ValueError(f"relax: expected increasing factors > 1, got {relax}")
        object.__setattr__(self, "relax", relax)
        object.__setattr__(self, "abstain", as_scalar(self.abstain, "abstain",
                                                      nonnegative=True))
        object.__setattr__(self, "score_floor", as_scalar(self.score_floor, "score_floor",
                                                          nonnegative=True))


@dataclass(frozen=True)
class Identification:
    """The result of :func:`identify`.

    Attributes
    ----------
    labels : (N,) int array
        Index into ``model.labels`` for every observed point; -1 for points left
        unidentified (extra points, points of segments not found, dropped NaN rows).
    found : (S,) bool array
        Which segments were identified.
    rotation, translation : (S, 3, 3) and (S, 3) arrays
        Rigid transform of each found segment, model -> observed (NaN where not found).
    mean_error : (S,) array
        ē_s of Eq. 2 (mean distance over l̄_s) of each found segment, NaN where not found.
    matched : (S,) int array
        Markers matched per segment.
    dropped : (D,) int array
        Rows of ``observed`` that held NaN and were left out.
    tables, fits, backtracks : int
        Search effort: candidate tables tried, rigid fits computed, and segment matches
        undone because the segment's children failed. The tree search reports the whole
        matches it found, 0, and the rounds it took to settle clashes beyond the first.
    seconds : float
        Wall time of the search.
    confidence : (N,) array
        Tree search: each label's margin, in the score's units (about one per marker): how
        much worse the best answer gets if the label must change (another point, or none).
        NaN where unlabelled, and everywhere for the depth-first search.
    abstained : (N,) bool array
        Points whose label was withdrawn for a margin below ``SAPMParams.abstain`` (they
        are -1 in ``labels``).
    """

    labels: np.ndarray
    found: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    mean_error: np.ndarray
    matched: np.ndarray
    dropped: np.ndarray
    tables: int
    fits: int
    backtracks: int
    seconds: float
    confidence: np.ndarray | None = None
    abstained: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.labels)
        if self.confidence is None:
            object.__setattr__(self, "confidence", np.full(n, np.nan))
        if self.abstained is None:
            object.__setattr__(self, "abstained", np.zeros(n, bool))

    @property
    def n_identified(self) -> int:
        return int((self.labels >= 0).sum())


class _State:
    """What is identified so far; cheap to copy for backtracking."""

    def __init__(self, n_obs: int, model: MarkerModel):
        S = model.n_segments
        self.obs_of = np.full(model.n_points, -1)          # model marker -> observed point
        self.label_of = np.full(n_obs, -1)                 # observed point -> model marker
        self.found = np.zeros(S, bool)
        self.R = np.full((S, 3, 3), np.nan)
        self.t = np.full((S, 3), np.nan)
        self.err = np.full(S, np.nan)

    def copy(self) -> _State:
        new = object.__new__(_State)
        new.__dict__ = {k: v.copy() for k, v in self.__dict__.items()}
        return new

    def restore(self, other: _State) -> None:
        for k, v in other.__dict__.items():
            self.__dict__[k] = v.copy()

    @property
    def free(self) -> np.ndarray:
        return self.label_of < 0


@dataclass
class _Effort:
    tables: int = 0
    fits: int = 0
    backtracks: int = 0


@dataclass(frozen=True)
class _Match:
    members: np.ndarray   # (m,) model markers of the segment
    obs: np.ndarray       # (m,) observed index per member, -1 = lost
    R: np.ndarray
    t: np.ndarray
    err: float


class _Search:
    """One identification: the observed points, the model and the search state."""

    def __init__(self, model: MarkerModel, Q: np.ndarray, params: SAPMParams,
                 rng: np.random.Generator | None):
        self.model, self.Q, self.p = model, Q, params
        self.D = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
        self.state = _State(len(Q), model)
        self.effort = _Effort()
        self.rng = rng
        self.eps = model.segment_eps(params.eps)         # ε_s: learned, else the params'

    # ------------------------------------------------------------------ local matching
    def _fit(self, model_idx, obs_idx, s):
        self.effort.fits += 1
        return fit_error(self.model.points[model_idx], self.Q[obs_idx],
                         self.model.mean_length[s])

    def _whole(self, s, R, t, fixed: dict, gate) -> _Match | None:
        """Closest-neighbour completion (Eq. 5) from a partial match's motion, then the
        quality (Eq. 2) and size (Eq. 3) tests. ``fixed``: member marker -> observed point
        already known (an identified joint); ``gate``: the parent's virtual joint (V, J,
        tol) or None."""
        m = self.model.members[s]
        eps, lbar = self.eps[s], self.model.mean_length[s]
        reach = 2.0 * lbar * eps
        allowed = self.state.free.copy()
        allowed[list(fixed.values())] = True
        cand = np.flatnonzero(allowed)
        pinned = [(j, fixed[mi]) for j, mi in enumerate(m.tolist()) if mi in fixed]
        pin_j = np.array([j for j, _ in pinned], dtype=np.int64)
        pin_q = np.array([q for _, q in pinned], dtype=np.int64)
        passed, obs, R, t, err, fits = complete_match(
            self.model.points[m], self.Q, cand, R, t, reach, pin_j, pin_q, lbar, eps,
            self.p.beta)
        self.effort.fits += fits
        if not passed:
            return None
        if gate is not None and self.p.joint_test:      # our option: the joint must fit too
            V, J, tol = gate
            if np.linalg.norm(R @ J + t - V) > tol + 2.0 * eps * lbar:
                return None
        return _Match(members=m, obs=obs, R=R, t=t, err=float(err))

    def _tables(self, s, l, pivots, gate, fixed):
        """Candidate tables of segment ``s`` for pivot member ``l`` (local index) and
        assumed pivot matches ``pivots`` (observed indices), best first. A member in
        ``fixed`` (a joint marker the parent identified) has its known point as its only
        candidate.

        Yields (pivot observed index, columns), columns a list of (member local index,
        candidates sorted best first) in the pivotal sequence (non-decreasing model
        distance from the pivot); a table's columns are sorted only when it is asked for."""
        m = self.model.members[s]
        P = self.model.points[m]
        eps2 = 2.0 * self.eps[s]
        others = np.array([i for i in range(len(m)) if i != l])
        dm = np.linalg.norm(P[others] - P[l], axis=-1)
        order = np.argsort(dm, kind="stable")
        others, dm = others[order], dm[order]
        known = np.array([fixed.get(int(m[i]), -1) for i in others])
        free = np.flatnonzero(self.state.free)
        free = np.union1d(free, known[known >= 0])
        if len(pivots) == 0 or len(free) == 0:
            return
        ratio = np.abs(dm[None, :, None] - self.D[np.ix_(pivots, free)][:, None, :])
        ratio /= dm[None, :, None]
        ok = (ratio < eps2) & (free[None, None, :] != np.asarray(pivots)[:, None, None])
        # a known joint marker is its own only candidate, and nobody else's
        ok &= np.where(known[:, None] >= 0, free[None, :] == known[:, None],
                       ~np.isin(free, known)[None, :])[None]
        if gate is not None:                  # candidates must be within reach of the joint
            V, J, tol = gate
            reach = np.linalg.norm(P[others] - J, axis=-1)
            dist = np.linalg.norm(self.Q[free] - V, axis=-1)
            ok &= np.abs(dist[None, None, :] - reach[None, :, None]) <= (
                eps2 * reach[None, :, None] + tol)
        counts = ok.any(axis=2).sum(axis=1)
        if len(pivots) > 1:                   # discard low-count tables (economy)
            need = max(2, math.floor(self.p.beta * len(m)) - 1)
            keep = np.flatnonzero(counts >= need)
        else:
            keep = np.flatnonzero(counts >= 2)
        best = np.where(ok, ratio, np.inf).min(axis=2)
        score = np.where(np.isfinite(best), best, 0).sum(axis=1)
        keep = keep[np.lexsort((score[keep], -counts[keep]))][: self.p.max_tables]
        for k in keep:
            cols = []
            for c, i in enumerate(others):
                js = np.flatnonzero(ok[k, c])
                if len(js):
                    cols.append((int(i), free[js[np.argsort(ratio[k, c, js])]]))
            yield int(pivots[k]), cols

    def _coarse(self, s, l, k, cols, fixed, gate):
        """Worst-pair replacement on one CT; yields whole matches."""
        m = self.model.members[s]
        ptr = [0] * len(cols)
        limit = sum(len(c) for _, c in cols) + len(cols)

        def pick():
            used, sel = {k}, []
            for c, (i, cand) in enumerate(cols):
                while ptr[c] < len(cand) and cand[ptr[c]] in used:
                    ptr[c] += 1
                if ptr[c] < len(cand):
                    used.add(int(cand[ptr[c]]))
                    sel.append((c, i, int(cand[ptr[c]])))
            return sel

        for _ in range(limit):
            sel = pick()
            if len(sel) + 1 < 3:
                return
            idx_m = np.array([l] + [i for _, i, _ in sel])
            idx_q = np.array([k] + [q for _, _, q in sel])
            R, t, resid, err = self._fit(m[idx_m], idx_q, s)
            if err < self.eps[s]:             # a partial match: complete it (Eq. 5)
                match = self._whole(s, R, t, fixed, gate)
                if match is not None:
                    yield match
            worst = int(np.argmax(resid[1:]))
            ptr[sel[worst][0]] += 1

    def _near_far(self, s, l, k, cols, fixed, gate):
        """Triples (pivot, a near neighbour, a far neighbour); yields whole matches."""
        m = self.model.members[s]
        P = self.model.points[m]
        eps2 = 2.0 * self.eps[s]
        n = len(cols)
        pairs = [(a, b) for a in range(min(2, n)) for b in range(n - 1, max(n - 3, -1), -1)
                 if a < b]
        lbar = self.model.mean_length[s]
        for a, b in pairs:
            (ia, ca), (ib, cb) = cols[a], cols[b]
            dab = np.linalg.norm(P[ia] - P[ib])
            # the pairs (qa, qb) that pass the distance test, in the order of the two
            # candidate lists, and the ē of every triple's fit, in one compiled call
            qa, qb = np.repeat(ca[:6], len(cb[:6])), np.tile(cb[:6], len(ca[:6]))
            use = (qa != qb) & ~(np.abs(self.D[qa, qb] - dab) >= eps2 * dab)
            qa, qb = qa[use], qb[use]
            if len(qa) == 0:
                continue
            Rs, ts, errs = triple_fits(self.model.points[m[[l, ia, ib]]], self.Q, k, qa, qb,
                                       lbar)
            done = 0                         # fits counted as if computed one at a time
            for h in np.flatnonzero(errs < self.eps[s]).tolist():
                self.effort.fits += h + 1 - done
                done = h + 1
                match = self._whole(s, Rs[h], ts[h], fixed, gate)
                if match is not None:
                    yield match
            self.effort.fits += len(errs) - done

    def segment_matches(self, s, via):
        """Whole matches of segment ``s`` (a generator, best first), searched from the
        joint with search-tree parent ``via`` (-1: from scratch)."""
        model = self.model
        m = model.members[s]
        gate, fixed, pivot_order, shared = None, {}, None, ()
        if via >= 0:
            J, shared, tol = model.link(s, via)
            fixed = {int(j): int(self.state.obs_of[j]) for j in shared
                     if self.state.obs_of[j] >= 0}
            if fixed:                                       # identified joint markers
                first = next(iter(fixed))
                pivot_order = [(int(np.flatnonzero(m == first)[0]), [fixed[first]])]
            else:                                           # virtual joint
                st = self.state
                gate = (apply_rigid(st.R[via], st.t[via], J[None])[0], J, tol)
        if pivot_order is None:
            local = [i for i in range(len(m)) if m[i] not in shared]
            if gate is not None:
                local.sort(key=lambda i: np.linalg.norm(model.points[m[i]] - gate[1]))
            elif self.rng is not None:
                local = list(self.rng.permutation(local))
            n_piv = max(1, math.floor((1 - self.p.beta) * len(m)) + 1)
            free = np.flatnonzero(self.state.free)
            pivot_order = [(i, free) for i in local[:n_piv]]
        methods = [self._near_far]
        if len(m) >= self.p.coarse_min_points:
            methods.insert(0, self._coarse)
        rank = self.p.rank_root and s == model.search_root and via < 0
        seen = set()
        for l, pivots in pivot_order:
            if gate is not None:
                V, J, tol = gate
                reach = np.linalg.norm(model.points[m[l]] - J)
                d = np.linalg.norm(self.Q[pivots] - V, axis=-1)
                pivots = pivots[np.abs(d - reach) <= 2 * self.eps[s] * reach + tol]
            primary = self._table_matches(s, l, pivots, gate, fixed, methods, first_only=rank)
            if rank:        # our option: every table's first match, best fitting first
                primary = sorted(primary, key=lambda x: x.err)
            for match in primary:
                # asked for more only when the children failed: before the next match,
                # the same one less a marker (which may be a child's)
                for alt in itertools.chain([match], self._leave_one_out(s, match, fixed)):
                    key = tuple(alt.obs)
                    if key not in seen:
                        seen.add(key)
                        yield alt

    def _table_matches(self, s, l, pivots, gate, fixed, methods, first_only=False):
        """Whole matches from each candidate table of pivot ``l``, table by table (only the
        first of each with ``first_only``)."""
        for k, cols in self._tables(s, l, np.asarray(pivots, int), gate, fixed):
            self.effort.tables += 1
            for method in methods:           # near-far triples where replacement fails
                hit = False
                for match in method(s, l, k, cols, fixed, gate):
                    hit = True
                    yield match
                    if first_only:
                        break
                if hit:
                    break

    def _leave_one_out(self, s, match, fixed):
        """Valid matches with one marker of ``match`` let go, worst fitting first."""
        m, obs = match.members, match.obs
        ok = np.flatnonzero(obs >= 0)
        if len(ok) - 1 <= max(2, self.p.beta * len(m)):
            return
        _, _, resid, _ = self._fit(m[ok], obs[ok], s)
        for j in ok[np.argsort(-resid)]:
            if m[j] in fixed:
                continue
            new = obs.copy()
            new[j] = -1
            keep = new >= 0
            R, t, _, err = self._fit(m[keep], new[keep], s)
            if err < self.eps[s]:
                yield _Match(members=m, obs=new, R=R, t=t, err=float(err))

    # ------------------------------------------------------------------ global search
    def _assign(self, s, match: _Match) -> None:
        st = self.state
        for mi, q in zip(match.members, match.obs):
            if q >= 0:
                st.obs_of[mi] = q
                st.label_of[q] = mi
        st.found[s] = True
        st.R[s], st.t[s], st.err[s] = match.R, match.t, match.err

    def solve(self, s, via) -> bool:
        """Identify ``s`` and, depth first, its unfound children in the search tree."""
        children = [c for c in self.model.neighbours[s] if c != via]
        start = self.state.copy()
        best, best_score, tried = None, -1, 0
        for match in self.segment_matches(s, via):
            self._assign(s, match)
            complete = True
            for c in children:
                if not self.state.found[c]:
                    complete &= self.solve(c, s)
            score = int((self.state.label_of >= 0).sum())
            if score > best_score:
                best, best_score = self.state.copy(), score
            tried += 1
            if complete or tried >= self.p.max_alternatives:
                break
            self.effort.backtracks += 1
            self.state.restore(start)
        if best is None:
            return False
        self.state.restore(best)
        return True

    def run(self) -> None:
        model = self.model
        self.solve(model.search_root, -1)
        # broken chains last: first the segments whose parent was not found, then any
        # still unfound, searched from scratch among the points left
        for last_pass in (False, True):
            for s in model.tree_order(model.search_root):
                via = model.search_parent[s]
                if not self.state.found[s] and (last_pass or via < 0
                                                or not self.state.found[via]):
                    self.solve(s, -1)


def checked_params(model, params) -> SAPMParams:
    """``params`` (default ``SAPMParams()``) after checking it and ``model``."""
    if not isinstance(model, MarkerModel):
        raise TypeError(f"model: expected a MarkerModel, got {type(model).__name__}")
    params = SAPMParams() if params is None else params
    if not isinstance(params, SAPMParams):
        raise TypeError(f"params: expected an SAPMParams, got {type(params).__name__}")
    return params


def identify(model: MarkerModel, observed, *, params: SAPMParams | None = None,
             rng: np.random.Generator | int | None = None) -> Identification:
    """Label an unlabelled 3-D marker pose with SAPM.

    Parameters
    ----------
    model : MarkerModel
        The subject's articulated marker model.
    observed : (N, 3) array_like
        Observed points in any order, mm; may include extra points and miss markers.
        Rows holding NaN are dropped and reported in ``Identification.dropped``. Not
        modified.
    params : SAPMParams, optional
        ε (Eq. 2), β (Eq. 3), the search (the paper's depth-first one or our tree search)
        and its limits.
    rng : numpy.random.Generator, int or None
        Randomises the choice of pivots for segments searched from scratch (the paper's
        "arbitrary" pivot); ``None`` takes them in model order.

    Returns
    -------
    Identification
    """
    params = checked_params(model, params)
    Q = as_points(observed, "observed", allow_nan=True)
    if rng is not None:
        rng = as_rng(rng)
    bad = np.isnan(Q).any(axis=1)
    keep = np.flatnonzero(~bad)
    if len(keep) < 3:
        raise ValueError(f"observed: expected at least 3 points without NaN, got {len(keep)}")
    t0 = time.perf_counter()
    if params.search == "tree":
        return _tree_identify(model, Q, keep, bad, params, t0)
    search = _Search(model, Q[keep], params, rng)
    search.run()
    st = search.state
    labels = np.full(len(Q), -1)
    labels[keep] = st.label_of
    matched = np.array([(st.obs_of[m] >= 0).sum() if st.found[s] else 0
                        for s, m in enumerate(model.members)])
    return Identification(labels=labels, found=st.found.copy(), rotation=st.R,
                          translation=st.t, mean_error=st.err, matched=matched,
                          dropped=np.flatnonzero(bad), tables=search.effort.tables,
                          fits=search.effort.fits, backtracks=search.effort.backtracks,
                          seconds=time.perf_counter() - t0)


def _tree_identify(model, Q, keep, bad, params, t0) -> Identification:
    eps = model.segment_eps(params.eps)
    Qk = Q[keep]
    D = np.linalg.norm(Qk[:, None] - Qk[None], axis=-1)
    cands = [segment_candidates(model, s, Qk, D, eps=eps[s], beta=params.beta,
                                limit=params.max_candidates, floor=params.score_floor)
             for s in range(model.n_segments)]
    pairs = pair_scores(model, cands, eps, penalty=params.link_penalty)
    choice, rounds, allowed = configure(model, cands, eps, pairs, with_allowed=True)
    lab = labelled_points(model, cands, choice, len(Qk))
    if params.abstain > 0:
        margins = label_margins(model, cands, eps, pairs, choice, allowed, len(Qk))
    else:
        margins = np.where(lab >= 0, np.nan, np.nan)
    lab, partial = complete_partial(model, Qk, eps, cands, choice, lab, beta=params.beta)
    found = {s: (cands[s].R[k], cands[s].t[k]) for s, k in enumerate(choice) if k >= 0}
    for s, (Rs, ts, _, _) in partial.items():
        found[s] = (Rs, ts)
    if params.abstain > 0:                            # the unique completions of two markers
        margins[(lab >= 0) & np.isnan(margins)] = 1.0
    for f in params.relax:
        relax_segments(model, Qk, D, eps, lab, margins, found, factor=f, beta=params.beta,
                       limit=params.max_candidates, floor=params.score_floor)
        relax_markers(model, Qk, eps, lab, margins, found, factor=f)
    withdrawn = (lab >= 0) & (margins < params.abstain) if params.abstain > 0 else \
        np.zeros(len(lab), bool)
    lab = np.where(withdrawn, -1, lab)
    S = model.n_segments
    labels = np.full(len(Q), -1)
    labels[keep] = lab
    confidence = np.full(len(Q), np.nan)
    confidence[keep] = np.where(lab >= 0, margins, np.nan)
    abstained = np.zeros(len(Q), bool)
    abstained[keep] = withdrawn
    R, t, err = np.full((S, 3, 3), np.nan), np.full((S, 3), np.nan), np.full(S, np.nan)
    matched = np.zeros(S, int)
    for s, k in enumerate(choice):
        if k >= 0:
            R[s], t[s], err[s], matched[s] = cands[s].R[k], cands[s].t[k], cands[s].err[k], \
                cands[s].n[k]
    for s, (Rs, ts, es, ns) in partial.items():
        R[s], t[s], err[s], matched[s] = Rs, ts, es, ns
    for s, (Rs, ts) in found.items():
        if matched[s] == 0:
            R[s], t[s] = Rs, ts
    matched = np.array([int(np.isin(m, lab).sum()) if s in found else 0
                        for s, m in enumerate(model.members)])
    return Identification(labels=labels, found=matched > 0, rotation=R, translation=t,
                          mean_error=err, matched=matched, dropped=np.flatnonzero(bad),
                          tables=sum(len(c) for c in cands), fits=0, backtracks=rounds - 1,
                          seconds=time.perf_counter() - t0, confidence=confidence,
                          abstained=abstained)
