"""LSM of a rectified pair started at given disparities, e.g. OpenCV SGBM's, with no growth.

:func:`sgbm_start` reads OpenCV's semi-global matching (a well-kept peer,
:func:`~lsmta.matching.peers.stereo_sgbm`) at the nodes of the growth's grid;
:func:`refine_at_nodes` runs the growth's LSM model along the row
(:func:`~lsmta.matching.mpgc.mpgc` with :class:`~lsmta.matching.mpgc.RectifiedPair`) at every
node with a starting disparity: the patch, then the retry patches, each node counted only
where the adjustment converges and passes the growth's thresholds. The start only says where
to begin; SGBM's value is never kept. :func:`~lsmta.matching.measure_disparity` (``seeds=
"sgbm"``) and :func:`~lsmta.systems.rectified.measure_rectified_pair` (``start="sgbm"``) use
both.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage

from .grow import (
    AttemptOutcome,
    GrowParams,
    GrowResult,
    NodeOutcome,
    attempt_outcomes,
    slow_limit,
    slow_params,
    wide_window_nodes,
)
from .lsm import LSMParams, Status
from .mpgc import RectifiedPair, mpgc
from .peers import sgbm_hh_bytes, stereo_sgbm
from .seeds import Seeds
from .spline import SplineImage

#: memory allowed for SGBM's full 8-path mode in :func:`sgbm_start`, bytes (above it, the 5-path
#: single-pass mode): a full-size video pair with a wide disparity range needs 10 GB or more
SGBM_START_MAX_BYTES = 2**31


def sgbm_start(left, right, *, disparity_range, step: int = 4,
               max_bytes: float = SGBM_START_MAX_BYTES) -> np.ndarray:
    """OpenCV SGBM's disparities (filters on, block 5) at the grid nodes.

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair.
    disparity_range : (int, int)
        Smallest and largest disparity searched, pixels (SGBM's range is rounded out to a
        multiple of 16).
    step : int
        Grid spacing, pixels.
    max_bytes : float
        Memory allowed for SGBM's full 8-path mode (:func:`~lsmta.matching.peers.sgbm_hh_bytes`
        of the padded pair), bytes; a larger pair is matched in OpenCV's single-pass 5-path
        mode, whose memory does not grow with the image's height (a little less smooth:
        5 paths instead of 8). The Middlebury pairs stay far below the default.

    Returns
    -------
    (rows, cols) array
        SGBM's disparity at node ``(r, c)``, pixel ``(c * step, r * step)``; NaN where SGBM
        has none. SGBM leaves its first ``min + num`` columns empty: both images are padded
        on the left by as much so that the left image's border columns get a disparity too.
    """
    lo, hi = int(np.floor(disparity_range[0])), int(np.ceil(disparity_range[1]))
    num = int(np.ceil(max(hi - lo, 1) / 16) * 16)
    pad = lo + num
    if not max_bytes > 0:
        raise ValueError(f"max_bytes: expected a positive number of bytes, got {max_bytes!r}")
    h, w = np.shape(left)
    mode = "hh" if sgbm_hh_bytes((h, w + pad), num, min_disparity=lo) <= max_bytes else "sgbm"
    sg = stereo_sgbm(np.pad(left, ((0, 0), (pad, 0))), np.pad(right, ((0, 0), (pad, 0))),
                     min_disparity=lo, num_disparities=num, mode=mode)
    return sg.disparity[:, pad:][::step, ::step]


def refine_at_nodes(left, right, start, *, disparity_range, grow: GrowParams, mask=None,
                    template_mask=None) -> tuple:
    """LSM along the row at every node with a starting disparity; no growth.

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair.
    start : (rows, cols) array
        Starting disparities at the nodes ``(c * step, r * step)``, px (NaN: not tried).
    disparity_range : (float, float)
        Matches outside it are dropped, px.
    grow : GrowParams
        The LSM model, the patch and retry patches, ``min_texture`` (a node whose patch's
        grey-value spread is below it is not tried; here the window is padded with its
        nearest pixel at the image's border, where the growth takes the spread of the part
        inside), the slow nodes' attempt ``slow`` (the growth's rule: at the nodes whose
        patch was still moving after ``max_iter`` iterations and that no retry matched, its
        ``sigma0`` and ``sigma_xy`` limits the medians of the main and retry patches'
        matches, :func:`~lsmta.matching.grow.slow_limit`), the adaptive window
        ``wide_patch`` (the growth's rule,
        :func:`~lsmta.matching.grow.wide_window_nodes`: a node textured only in the wide
        patch is tried with it alone, and a node whose patch was rejected by a precision test
        and that no retry matched is tried once more with it; with ``partial`` False, only
        where the wide patch lies inside the image) and the thresholds
        (:meth:`~lsmta.matching.GrowParams.lsm_thresholds`).
    mask : (H, W) bool array, optional
        Nodes to try (read at the node's pixel).
    template_mask : (H, W) bool array, optional
        Left pixels on the object (see :func:`~lsmta.matching.lsm`).

    Returns
    -------
    (Seeds, GrowResult)
        The started nodes (``disparity`` their start) and the accepted ones (``wave`` 0,
        ``seed`` the started node's index, ``attempt_census`` by status; ``node_outcome``
        per node: matched, given up after every patch, ``NO_TEXTURE``, ``MASKED``, or
        ``NEVER_REACHED`` where ``start`` is NaN; ``node_failure`` the main patch's
        :class:`~lsmta.matching.grow.AttemptOutcome` at the nodes tried and not matched,
        the wide patch's at nodes textured in it only).
    """
    start = np.asarray(start, float)
    try_, outcome, wide_only, fits = _nodes_to_try(left, start, grow, mask)
    r, c = np.nonzero(try_)
    xy = np.stack([c * grow.step, r * grow.step], axis=1).astype(float)
    model = LSMParams(patch=grow.patch, geometry=grow.geometry, radiometry=grow.radiometry,
                      method=grow.method, support=grow.support, partial=grow.partial,
                      max_iter=grow.max_iter, tol=grow.tol, stall=grow.stall,
                      thresholds=grow.lsm_thresholds())
    got = {"t": np.full(len(r), np.nan), "sigma_t": np.full(len(r), np.nan),
           "sigma0": np.full(len(r), np.nan), "sigma_xy": np.full((len(r), 2), np.nan),
           "A": np.tile(np.eye(2), (len(r), 1, 1)), "method": np.full(len(r), "patch")}
    census: dict = {}
    wide = wide_only[r, c]
    todo = np.flatnonzero(~wide)
    first = np.full(len(r), -1, np.int8)
    retries = (grow.patch + 6,) if grow.retry_patch is None else grow.retry_patch
    run = (SplineImage(left, "left"), SplineImage(right, "right"), template_mask, xy,
           start[r, c], disparity_range, got, census)     # prefiltered once for every attempt
    for k, size in enumerate((grow.patch,) + tuple(retries)):
        if todo.size == 0:
            break
        # the main patch's outcomes always (a cheap pass over its results): node_failure
        ok, code = _attempt(*run, todo, replace(model, patch=size), "retry" if k else "patch",
                            outcomes=k == 0)
        if code is not None:
            first[todo] = code
        todo = todo[~ok]
    if grow.slow:
        _slow_attempt(run, model, first)
    if grow.wide_patch is not None:
        todo = np.flatnonzero(wide_window_nodes(first, matched=np.isfinite(got["t"]),
                                                wide_only=wide, fits=fits[r, c]))
        if todo.size:
            _, code = _attempt(*run, todo, replace(model, patch=grow.wide_patch), "wide",
                               outcomes=True)
            first[todo[wide[todo]]] = code[wide[todo]]
    return _refined(start, r, c, xy, got, census, outcome, first)


def _nodes_to_try(left, start, grow: GrowParams, mask) -> tuple:
    """:func:`refine_at_nodes`' nodes to try ((rows, cols) bool: started, in ``mask``,
    textured), every node's :class:`~lsmta.matching.grow.NodeOutcome` so far (``GIVEN_UP``
    at those to try until matched) and :func:`_wide_only`'s two masks; checks ``start``
    and ``mask`` against the image."""
    h, w = np.shape(left)
    grid = ((h - 1) // grow.step + 1, (w - 1) // grow.step + 1)
    if start.shape != grid:
        raise ValueError(f"start: expected the {grid} nodes of a {h} x {w} image at step "
                         f"{grow.step}, got shape {start.shape}")
    if mask is not None and np.shape(mask) != (h, w):
        raise ValueError(f"mask: expected the image's shape {(h, w)}, got {np.shape(mask)}")
    try_ = np.isfinite(start)
    outcome = np.where(try_, NodeOutcome.GIVEN_UP, NodeOutcome.NEVER_REACHED).astype(np.int8)
    if mask is not None:
        inside = np.asarray(mask, bool)[::grow.step, ::grow.step]
        outcome[try_ & ~inside] = NodeOutcome.MASKED
        try_ &= inside
    textured = _textured(left, grow.patch, grow.step, start.shape, grow.min_texture)
    wide_only, fits = _wide_only(left, grow, textured)
    outcome[try_ & ~(textured | wide_only)] = NodeOutcome.NO_TEXTURE
    return try_ & (textured | wide_only), outcome, wide_only, fits


def _attempt(left, right, template_mask, xy, t0, disparity_range, got: dict, census: dict,
             todo, model, label: str, outcomes: bool = False) -> tuple:
    """One LSM attempt along the row at the nodes ``todo``; the accepted ones (inside
    ``disparity_range``) go into ``got`` under ``label``. Returns which were accepted and,
    with ``outcomes``, every node's :class:`~lsmta.matching.grow.AttemptOutcome` (else
    None)."""
    res = mpgc(left, right, xy[todo], t0[todo], RectifiedPair(), params=model,
               template_mask=template_mask)
    st = np.asarray(res.status)
    for s_ in Status:
        census[s_.name.lower()] = census.get(s_.name.lower(), 0) + int((st == s_).sum())
    code = attempt_outcomes(st, model.thresholds, [res.image(0)]) if outcomes else None
    ok = (st == Status.CONVERGED) & (res.t >= disparity_range[0]) & \
        (res.t <= disparity_range[1])
    for name, value in (("t", res.t), ("sigma_t", res.sigma_t), ("sigma0", res.sigma0),
                        ("sigma_xy", res.sigma_xy[0]), ("A", res.A[0])):
        got[name][todo[ok]] = value[ok]
    got["method"][todo[ok]] = label
    return ok, code


def _slow_attempt(run: tuple, model, first) -> None:
    """:func:`refine_at_nodes`' slow nodes' attempt (:class:`~lsmta.matching.GrowParams`
    ``slow``) at the unmatched nodes whose main patch ended at ``MAX_ITERATIONS``
    (``first``), its limits the medians of the matches so far; ``run``: :func:`_attempt`'s
    first arguments (``got`` updated)."""
    got = run[6]
    matched = np.isfinite(got["t"])
    slow = slow_limit(slow_params(model), got["sigma0"][matched],
                      np.nanmax(got["sigma_xy"][matched], axis=1))
    todo = np.flatnonzero(~matched & (first == AttemptOutcome.MAX_ITERATIONS))
    if slow is not None and todo.size:
        _attempt(*run, todo, slow, "slow")


def _wide_only(left, grow: GrowParams, textured) -> tuple:
    """The nodes textured in the wide patch but not in the main one (``textured``), and where
    the wide patch may be tried (everywhere with ``partial``, else inside the image); both
    (rows, cols) bool, all False without ``wide_patch``."""
    if grow.wide_patch is None:
        return np.zeros_like(textured), np.zeros_like(textured)
    h, w = np.shape(left)
    gr, gc = np.indices(textured.shape) * grow.step
    half = grow.wide_patch // 2
    fits = grow.partial | ((gc >= half) & (gc <= w - 1 - half) & (gr >= half)
                           & (gr <= h - 1 - half))
    wide_only = fits & ~textured & _textured(left, grow.wide_patch, grow.step,
                                             textured.shape, grow.min_texture)
    return wide_only, fits


def _textured(image, patch: int, step: int, shape, min_texture: float) -> np.ndarray:
    """The grey-value spread of the ``patch`` x ``patch`` window at every node of the grid
    ``shape`` (spacing ``step``) is at least ``min_texture``."""
    f = np.asarray(image, float)
    mean = ndimage.uniform_filter(f, patch, mode="nearest")
    var = ndimage.uniform_filter(f * f, patch, mode="nearest") - mean * mean
    out = np.zeros(shape, bool)
    sub = np.sqrt(np.maximum(var, 0.0))[::step, ::step] >= min_texture
    out[:sub.shape[0], :sub.shape[1]] = sub[:shape[0], :shape[1]]
    return out


def _refined(start, r, c, xy, got: dict, census: dict, outcome, first) -> tuple:
    """:func:`refine_at_nodes`' seeds and matches from the started nodes and their LSM
    (``outcome``: the nodes' :class:`~lsmta.matching.grow.NodeOutcome` before LSM, ``first``
    the first attempt's outcome at the tried ones)."""
    ok = np.isfinite(got["t"])
    outcome = outcome.copy()
    outcome[r[ok], c[ok]] = NodeOutcome.MATCHED
    failure = np.full(start.shape, -1, np.int8)
    failure[r[~ok], c[~ok]] = first[~ok]
    shift = np.stack([start[r, c], np.zeros(len(r))], axis=1)
    seeds = Seeds(xy=np.stack([xy, xy - shift]), score=np.full(len(r), np.nan),
                  depth=np.full(len(r), np.nan), disparity=start[r, c])
    n = int(ok.sum())
    grown = GrowResult(
        template_xy=xy[ok], search_xy=xy[ok] - np.c_[got["t"][ok], np.zeros(n)],
        A=got["A"][ok], sigma0=got["sigma0"][ok], sigma_xy=got["sigma_xy"][ok],
        seed=np.flatnonzero(ok), wave=np.zeros(n, int), hole_closing=np.zeros(n, bool),
        seeds_matched=ok, n_lsm=int(sum(census.values())), grid_shape=start.shape,
        node_index=np.stack([r[ok], c[ok]], axis=1), method=got["method"][ok],
        t=got["t"][ok], sigma_t=got["sigma_t"][ok], attempt_census=census,
        node_census={"started": len(r), "matched": n, "failed": len(r) - n},
        node_outcome=outcome, node_failure=failure)
    return seeds, grown
