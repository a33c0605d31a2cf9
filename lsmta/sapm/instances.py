"""Several instances of one marker model in one cloud (two players wearing the same marker
set).

How instances are separated: by the tree, not by space. Every segment's matches are found
once among all the points (:mod:`lsmta.sapm.candidates`); the best configuration of the
whole tree (:mod:`lsmta.sapm.configuration`) is the first instance; the matches that use
any of its points are then ruled out and the best configuration of what is left is the
next instance, and so on. A configuration holds together only through its joints (shared
markers, and joint gaps within their learned tolerances), so one instance cannot take
segments of two people unless they stand closer than those tolerances. The search stops
after ``n_instances``, or when the next configuration labels fewer than ``min_share`` of
the model's markers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .._validate import as_int, as_points, as_scalar
from .candidates import segment_candidates
from .configuration import configure, labelled_points, pair_scores
from .identify import SAPMParams, checked_params
from .model import MarkerModel


@dataclass(frozen=True)
class Instances:
    """The result of :func:`identify_instances`.

    Attributes
    ----------
    labels : (N,) int array
        Model marker of every observed point, -1 where unidentified (and for NaN rows).
    instance : (N,) int array
        Which instance (0, 1, ... in the order found, best first) each point belongs to,
        -1 where unidentified.
    found : (I, S) bool array
        Segments found per instance.
    dropped : (D,) int array
        Rows of ``observed`` that held NaN and were left out.
    seconds : float
        Wall time.
    """

    labels: np.ndarray
    instance: np.ndarray
    found: np.ndarray
    dropped: np.ndarray
    seconds: float

    @property
    def n_instances(self) -> int:
        return len(self.found)


def identify_instances(model: MarkerModel, observed, *, n_instances: int | None = None,
                       min_share: float = 0.5, params: SAPMParams | None = None) -> Instances:
    """Label a cloud holding several instances of ``model`` (see the module docstring).

    Parameters
    ----------
    model : MarkerModel
    observed : (N, 3) array_like
        Observed points in any order, mm (NaN rows are dropped). Not modified.
    n_instances : int, optional
        How many instances to look for; default: as many as are found.
    min_share : float
        An instance must label at least this share of the model's markers, in (0, 1].
    params : SAPMParams, optional
        ε (where the model has no learned ε_s), β, ``max_candidates`` (per instance) and
        ``link_penalty`` of the tree search.

    Returns
    -------
    Instances
    """
    params = checked_params(model, params)
    min_share = as_scalar(min_share, "min_share", positive=True)
    if min_share > 1:
        raise ValueError(f"min_share: expected a share in (0, 1], got {min_share}")
    n_instances = as_int(n_instances, "n_instances", allow_none=True)
    Q = as_points(observed, "observed", allow_nan=True)
    bad = np.isnan(Q).any(axis=1)
    keep = np.flatnonzero(~bad)
    t0 = time.perf_counter()
    Qk = Q[keep]
    most = n_instances or max(1, len(Qk) // max(1, int(np.ceil(min_share * model.n_points))))
    eps = model.segment_eps(params.eps)
    D = np.linalg.norm(Qk[:, None] - Qk[None], axis=-1)
    cands = [segment_candidates(model, s, Qk, D, eps=eps[s], beta=params.beta,
                                limit=params.max_candidates * most, floor=params.score_floor)
             for s in range(model.n_segments)]
    pairs = pair_scores(model, cands, eps, penalty=params.link_penalty)
    used = np.zeros(len(Qk), bool)
    labels = np.full(len(Qk), -1)
    instance = np.full(len(Qk), -1)
    found = []
    while len(found) < most:
        allowed = [~(used[np.maximum(c.obs, 0)] & (c.obs >= 0)).any(axis=1) for c in cands]
        choice, _ = configure(model, cands, eps, pairs, allowed=allowed)
        lab = labelled_points(model, cands, choice, len(Qk))
        if (lab >= 0).sum() < min_share * model.n_points:
            break
        labels[lab >= 0] = lab[lab >= 0]
        instance[lab >= 0] = len(found)
        used |= lab >= 0
        found.append(choice >= 0)
    out_labels = np.full(len(Q), -1)
    out_instance = np.full(len(Q), -1)
    out_labels[keep], out_instance[keep] = labels, instance
    return Instances(labels=out_labels, instance=out_instance,
                     found=np.array(found, bool).reshape(-1, model.n_segments),
                     dropped=np.flatnonzero(bad), seconds=time.perf_counter() - t0)
