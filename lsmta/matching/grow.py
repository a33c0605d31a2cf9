"""Dense matching by region growing from seed points (D'Apuzzo 1998; LSMTA paper, Section 2.2).

The template's area is split into the Voronoi cells of the seeds. Starting from each seed,
the matcher steps to neighbouring nodes of a regular grid (spacing ``step`` pixels),
horizontally first and then vertically, and runs least squares matching there, starting
from the neighbour's solution: the approximation is the neighbour's match moved by its
affine matrix, ``search = parent_search + A_parent (node - parent_node)``, and the start
of ``A`` is ``A_parent``. A match is kept when it passes the quality thresholds; otherwise
it is tried once more with a bigger patch. Growth stays inside each seed's cell; when no
cell can grow any more, holes are closed by growing into the remaining nodes from every
side, across cell borders.

Batched: each growth step sends the whole front (all candidate nodes of all cells) through
one :func:`~lsmta.matching.lsm` call, so the number of calls grows with the width of the
region in grid steps, not with the number of points. What a step costs besides LSM is kept
small (issue #33 item 4): for a rectified pair the step calls the solver without building
:func:`~lsmta.matching.mpgc.mpgc`'s result (``mpgc._rectified_once``, the same matches), the
front's candidates are found by a compiled pass, and the texture test reads box filters.

Choices where the paper is vague: the retry changes the patch size only (a smaller step
would leave the grid); a node may be tried up to ``max_attempts`` times from different
neighbours; nodes whose patch does not fit or whose template patch has no texture are
never tried.

Geometrically constrained growth (beyond the paper; ``constraint=``): every node is matched
by :func:`~lsmta.matching.mpgc.mpgc`, one parameter ``t`` along the epipolar curve instead of
a free 2-D shift — a disparity for a rectified pair, a depth for calibrated cameras.
:func:`grow_joint` grows into several search images at once, each node matched in all of
them jointly (Gruen & Baltsavias 1988).

The settings are a :class:`GrowParams`. The driver reads as its stages: turn the settings
into the LSM settings of every attempt (``_Options``), lay out the node grid (``_grid``),
match the seeds and their first nodes (``_start_from_seeds``), grow inside the cells and then
across them (``_grow``), and freeze the result (``_results``); the state of the nodes lives in
``_State`` and every matching attempt goes through ``_Matcher``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import numba as nb
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .._validate import as_array, as_int, check_patch
from .lsm import (
    THRESHOLD_TESTS,
    LSMParams,
    LSMThresholds,
    Status,
    _check_model,
    _Model,
    _params,
    _positive,
    _template_weights,
    lsm,
)
from .mpgc import RectifiedPair, _check_constraint, _rectified_once, mpgc
from .spline import SplineImage

HORIZONTAL = ((1, 0), (-1, 0))
VERTICAL = ((0, 1), (0, -1))
#: the reach of the last phase (``reach=True``): diagonal neighbours and nodes two steps away
FAR = ((1, 1), (-1, 1), (1, -1), (-1, -1), (2, 0), (-2, 0), (0, 2), (0, -2))
METHODS = ("patch", "retry", "robust", "shifted", "wide", "slow")
#: the slow nodes' convergence limit as a share of ``max_sigma_xy`` (:class:`GrowParams` ``slow``)
SLOW_TOL_SHARE = 0.1
#: the fewest accepted matches whose medians may set the slow nodes' limits (:func:`slow_limit`):
#: the median of n values scatters by about 1.25 s / sqrt(n) (s their spread), from 25 on by a
#: quarter of the spread at most, so a few matches of one small growth do not set the limits
SLOW_MIN_MATCHES = 25


class AttemptOutcome(enum.IntEnum):
    """What became of one LSM attempt (:attr:`GrowResult.attempt_census`,
    :attr:`GrowResult.node_failure`): accepted, rejected by the first threshold it fails
    (:data:`~lsmta.matching.lsm.THRESHOLD_TESTS`, in that order), or not converged (the other
    :class:`~lsmta.matching.lsm.Status` codes)."""

    ACCEPTED = 0
    SIGMA0 = 1
    SIGMA_XY = 2
    DISPLACEMENT = 3
    SCALE = 4
    SHEAR = 5
    WEIGHT_SHARE = 6
    MAX_ITERATIONS = 7
    DIVERGED = 8
    OUTSIDE = 9
    SINGULAR = 10


class NodeOutcome(enum.IntEnum):
    """What became of a grid node (:attr:`GrowResult.node_census`,
    :attr:`GrowResult.node_outcome`)."""

    OUTSIDE = 0
    MASKED = 1
    NO_TEXTURE = 2
    MATCHED = 3
    GIVEN_UP = 4
    FAILED_OPEN = 5
    NEVER_REACHED = 6


#: the census keys of :class:`AttemptOutcome`, in its order (lower-case member names)
ATTEMPT_OUTCOMES = tuple(o.name.lower() for o in AttemptOutcome)
#: the census keys of :class:`NodeOutcome`, in its order (lower-case member names)
NODE_OUTCOMES = tuple(o.name.lower() for o in NodeOutcome)
#: the first attempt's failures that the adaptive window (``wide_patch``) retries: too little
#: signal for the precision, not a model that does not fit (non-convergence, shape)
IMPRECISE = (AttemptOutcome.SIGMA0, AttemptOutcome.SIGMA_XY)


@dataclass(frozen=True)
class GrowResult:
    """Matches grown from seeds.

    Attributes
    ----------
    template_xy : (N, 2) array
        Matched grid nodes in the template (pixels).
    search_xy : (N, 2) array
        Their matches in the search image (pixels).
    A : (N, 2, 2) array
        Affine matrices of the matches.
    sigma0 : (N,) array
        A-posteriori standard deviation of unit weight (grey levels).
    sigma_xy : (N, 2) array
        Standard deviations of ``search_xy`` (pixels).
    seed : (N,) int array
        The seed whose Voronoi cell holds the node.
    wave : (N,) int array
        Growth step in which the node was matched (0: the seeds' own nodes); the phase of
        hole closing continues the count.
    hole_closing : (N,) bool array
        Matched while closing holes (across cell borders).
    seeds_matched : (S,) bool array
        Which seeds LSM could match (the others are reported, not grown from).
    n_lsm : int
        Number of points sent to LSM in all (attempts, including retries).
    grid_shape : (int, int)
        Rows and columns of the node grid; node ``(r, c)`` lies at ``(c * step, r * step)``.
    node_index : (N, 2) int array
        Grid row and column of each match.
    method : (N,) str array
        Which attempt matched the node: ``"patch"`` (the main patch), ``"retry"`` (a retry
        patch size), ``"robust"``, ``"shifted"``, ``"wide"`` (the adaptive window,
        :class:`GrowParams` ``wide_patch``) or ``"slow"`` (:class:`GrowParams` ``slow``).
    t : (N,) array
        With a ``constraint``: the node's parameter along the epipolar curve (disparity in
        px, or inverse depth in 1/m); NaN without one.
    sigma_t : (N,) array
        Its standard deviation from the joint adjustment (NaN without a constraint).
    attempt_census : dict
        Every LSM attempt of the growth (seeds, retries and shifted windows included) by
        outcome, :data:`ATTEMPT_OUTCOMES` -> count; the counts add up to ``n_lsm``.
    node_census : dict
        Every grid node by outcome, :data:`NODE_OUTCOMES` -> count (adding up to the grid's
        nodes): the patch does not fit the image, outside ``mask``, below ``min_texture``,
        matched, given up after ``max_attempts``, tried and failed fewer times, never
        reached from a matched neighbour.
    node_outcome : (rows, cols) int8 array
        Every grid node's outcome, a :class:`NodeOutcome` value (the census per node).
    node_failure : (rows, cols) int8 array
        For nodes tried and not matched: why the first attempt (the main patch; the wide
        patch at nodes textured in it only, ``wide_patch``) failed at the node's last try,
        an :class:`AttemptOutcome` value (the first threshold test failed, or the
        non-convergence status); -1 elsewhere.
    """

    template_xy: np.ndarray
    search_xy: np.ndarray
    A: np.ndarray
    sigma0: np.ndarray
    sigma_xy: np.ndarray
    seed: np.ndarray
    wave: np.ndarray
    hole_closing: np.ndarray
    seeds_matched: np.ndarray
    n_lsm: int
    grid_shape: tuple
    node_index: np.ndarray
    method: np.ndarray
    t: np.ndarray = field(default=None)
    sigma_t: np.ndarray = field(default=None)
    attempt_census: dict = field(default=None)
    node_census: dict = field(default=None)
    node_outcome: np.ndarray = field(default=None)
    node_failure: np.ndarray = field(default=None)

    def __post_init__(self):
        for name in ("t", "sigma_t"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(len(self.template_xy), np.nan))
        for name in ("attempt_census", "node_census"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, {})

    def __len__(self) -> int:
        return len(self.template_xy)


def voronoi_cells(seeds_xy: np.ndarray, nodes_xy: np.ndarray) -> np.ndarray:
    """Index of the nearest seed for every node (the seeds' Voronoi cells)."""
    return cKDTree(seeds_xy).query(nodes_xy)[1]


@dataclass(frozen=True)
class GrowParams:
    """Settings of :func:`grow_matches` and :func:`grow_joint`: the node grid, the attempts
    at a node and their LSM model. Built by keyword; every field is checked here, and the
    error names it.

    Attributes
    ----------
    step : int
        Grid spacing in pixels.
    patch : int
        LSM patch size (odd, >= 5).
    retry_patch : int or tuple of int, optional
        Patch sizes of further attempts at a failed node, in order (default
        ``patch + 6``). A smaller patch can match closer to an occlusion border. Kept as a
        tuple.
    thresholds : LSMThresholds, optional
        Quality indicators a match must pass (default :class:`LSMThresholds` with
        ``max_displacement = step``; :meth:`lsm_thresholds`).
    geometry, radiometry : str
        LSM model (see :func:`~lsmta.matching.lsm`).
    max_attempts : int
        How often a node may be tried from different neighbours.
    min_texture : float
        Nodes whose template patch's grey-value standard deviation is below this are skipped
        (unless ``noise`` is given).
    noise : float, optional
        The images' noise, grey levels (e.g. :func:`~lsmta.noise.temporal_noise`). Given, it
        replaces the ``min_texture`` test by the precision rule: a node is tried only if
        its template patch (the largest patch size tried) could reach the accepted precision
        ``thresholds.max_sigma_xy`` with residuals no larger than the two images' noise,
        ``sqrt(2) noise / sqrt(lambda_min) <= max_sigma_xy``, where ``lambda_min`` is the
        smaller eigenvalue of the patch's gradient tensor ``sum(grad f grad f^T)``
        (grey levels² / px²). LSM's shift precision is ``sigma0 / sqrt(lambda)`` at best
        (the shift alone; the shape's parameters only add to it), and ``sigma0`` holds
        both images' noise, so a node failing the rule fails ``max_sigma_xy`` whatever it
        matches (up to the scatter of the estimated ``sigma0``): the rule skips only such
        nodes, at any contrast and noise level, where a fixed ``min_texture`` skips
        low-contrast patches of a quiet camera that would match and tries edges of a noisy
        one that cannot.
    close_holes : bool
        After growing inside the cells, grow into the remaining nodes from every side.
    shift : int
        If positive, a node that failed every patch size is tried once more with the
        ``patch`` window moved by ``shift`` pixels in each of the 8 grid directions, so
        that the window can lie on one side of an occlusion border; the node's match is
        then the shifted match carried back by its affine matrix,
        ``search = search_shifted - A (shift offset)``, from the passing window with the
        smallest ``sigma0``. 0 (default) turns this off.
    robust : float, optional
        If given, a node that failed every patch size is tried once more by robust LSM
        (Tukey cut-off ``robust`` grey levels, see :func:`~lsmta.matching.lsm`), which
        lets the pixels across an occlusion border drop out; before the shifted windows.
    robust_patch : int, optional
        Patch size of the robust attempt (default ``patch``).
    method : {"forward", "inverse"}
        LSM's iterations (see :func:`~lsmta.matching.lsm`).
    support : float, optional
        Adaptive support weights in every LSM (see :func:`~lsmta.matching.lsm`).
    partial : bool
        Let patches reach over the image borders (see :func:`~lsmta.matching.lsm`), so that
        nodes next to the border are tried too.
    max_iter : int, optional
        LSM's iteration limit (default: :class:`~lsmta.matching.lsm.LSMParams`'s). Nodes
        that need many iterations rarely pass the thresholds; a lower limit saves their time.
    tol : float
        LSM's convergence limit, pixels (see :func:`~lsmta.matching.lsm`).
    reach : bool
        After closing holes, grow once more from diagonal neighbours and from nodes two
        steps away, into open nodes that no direct neighbour could reach (all of theirs
        failed).
    wide_patch : int, optional
        Side of the adaptive window's square patch, pixels: odd and larger than ``patch``.
        Adaptive window (after Kanade & Okutomi 1994: a larger window where the signal is too
        weak for the precision, not where the model fails): a node whose ``patch`` fails the
        texture test (``min_texture``, or the precision rule with ``noise``) but whose
        ``wide_patch`` passes it is matched with ``wide_patch`` alone; a node whose main
        patch was rejected by a precision test (``sigma0`` or ``sigma_xy``,
        :data:`IMPRECISE`) and that no retry matched is tried once more with it. Same
        thresholds; nodes that did not converge are not widened (a depth edge, where a
        wider window would straddle more of it). None (default): off.
    slow : bool
        Slow nodes (issue #33 item 3; ``experiments/dense_reject_census.py``: of the nodes
        SGBM measures and the growth does not, the largest class for the SGBM start on Cones,
        Art and Teddy, for the automatic seeds on Cones only; on Art never reached, on Teddy
        below the texture floor come first): a node whose main patch was still moving after
        ``max_iter`` iterations (``MAX_ITERATIONS``) and that no retry matched is tried once
        more with the main patch and a convergence limit set by the accepted precision,
        ``tol = SLOW_TOL_SHARE * max_sigma_xy`` (an update of a tenth of the precision a
        match may have does not change whether it is accepted), and accepted only if it fits
        and is as precise as a typical match: ``sigma0`` and ``sigma_xy`` at most the
        medians (:func:`slow_limit`; the adjustment's own measure of the pair's noise, model
        error and texture; that a slow node straddles a depth edge and so fits worse was
        not measured) of the matches accepted so far by the main, retry and robust
        attempts of this call only (:func:`grow_matches`; each of
        :func:`~lsmta.matching.measure_disparity`'s reseed rounds, its precision fill and
        the SGBM start's growth from the front is a call of its own, with its own matches,
        possibly few; :func:`~lsmta.matching.refine.refine_at_nodes`: all its main and
        retry matches). No slow node is tried before :data:`SLOW_MIN_MATCHES` matches are
        accepted. False (default): off.
    stall : int, optional
        LSM's early stop, iterations (:class:`~lsmta.matching.lsm.LSMParams` ``stall``): from
        iteration ``stall`` on, an attempt whose update has not halved over the last three
        iterations stops as ``MAX_ITERATIONS``, in every LSM of the growth (its seeds'
        too). None (default): off; ``experiments/dense_real_pairs.py`` ``--stall`` measures it
        (7: about a fifth less LSM work on Cones, but a region lost there).
    """

    step: int = 4
    patch: int = 13
    retry_patch: int | tuple | None = None
    thresholds: LSMThresholds | None = None
    geometry: str = "affine"
    radiometry: str = "linear"
    max_attempts: int = 3
    min_texture: float = 2.0
    noise: float | None = None
    close_holes: bool = True
    shift: int = 0
    robust: float | None = None
    robust_patch: int | None = None
    method: str = "forward"
    support: float | None = None
    partial: bool = False
    max_iter: int | None = None
    tol: float = 1e-4
    reach: bool = False
    wide_patch: int | None = None
    slow: bool = False
    stall: int | None = None

    def __post_init__(self):
        _check_model(self)
        if self.retry_patch is not None:
            object.__setattr__(self, "retry_patch", tuple(
                check_patch(p, "retry_patch") for p in np.atleast_1d(self.retry_patch)))
        if self.robust_patch is not None:
            object.__setattr__(self, "robust_patch",
                               check_patch(self.robust_patch, "robust_patch"))
        if self.wide_patch is not None:
            object.__setattr__(self, "wide_patch", check_patch(self.wide_patch, "wide_patch"))
            if self.wide_patch <= self.patch:
                raise ValueError(f"wide_patch: expected an odd integer > patch, i.e. > "
                                 f"{self.patch} pixels, got {self.wide_patch}")
        object.__setattr__(self, "step", as_int(self.step, "step", unit="pixels"))
        object.__setattr__(self, "shift", as_int(self.shift, "shift", minimum=0,
                                                 unit="pixels"))
        object.__setattr__(self, "max_attempts", as_int(self.max_attempts, "max_attempts"))
        if isinstance(self.min_texture, bool) or not (_positive(self.min_texture)
                                                      or self.min_texture == 0):
            raise ValueError(f"min_texture: expected a grey-value spread >= 0, "
                             f"got {self.min_texture!r}")
        if self.noise is not None and not _positive(self.noise):
            raise ValueError(f"noise: expected the images' noise in grey levels (> 0) or "
                             f"None, got {self.noise!r}")
        for name in ("close_holes", "reach", "slow"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name}: expected True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        if not _positive(self.tol):
            raise ValueError(f"tol: expected a positive convergence limit in pixels, "
                             f"got {self.tol!r}")
        if self.thresholds is not None and not isinstance(self.thresholds, LSMThresholds):
            raise TypeError(f"thresholds: expected an LSMThresholds or None, got "
                            f"{type(self.thresholds).__name__}")

    def lsm_thresholds(self) -> LSMThresholds:
        """The thresholds a match must pass: ``thresholds``, or by default
        :class:`LSMThresholds` with ``max_displacement = step``."""
        if self.thresholds is not None:
            return self.thresholds
        return LSMThresholds(max_displacement=float(self.step))


def grow_matches(template, search, seeds_template, seeds_search, *, mask=None,
                 template_mask=None, constraint=None, seeds_A=None,
                 params: GrowParams | None = None) -> GrowResult:
    """Grow dense matches between two images from a few seed correspondences.

    Parameters
    ----------
    template, search : (H, W) arrays
        Grey images (any real dtype).
    seeds_template : (S, 2) array
        Seed positions in the template (pixels).
    seeds_search : (S, 2) array
        Approximate seed positions in the search image; refined by LSM first.
    mask : (H, W) bool array, optional
        Where in the template to grow (default: everywhere the patch fits).
    template_mask : (H, W) bool array, optional
        Template pixels on the object: every LSM ignores the others (see
        :func:`~lsmta.matching.lsm`), so a patch next to the silhouette rests on the
        object alone (a patch with less than ``thresholds.min_weight_share`` of object
        pixels is rejected). Unlike ``mask``, it does not say where to grow.
    constraint : RectifiedPair or CameraGeometry, optional
        Match every node under the epipolar condition (:func:`~lsmta.matching.mpgc.mpgc`):
        one disparity or depth per node instead of a free shift. The geometry must have
        one search image.
    seeds_A : (S, 2, 2) array, optional
        The seeds' starting affine maps from the template's patch to the search image's
        (e.g. :attr:`~lsmta.matching.Seeds.A`; default: identity).
    params : GrowParams, optional
        The grid, the attempts and their LSM model (default :class:`GrowParams`).

    Returns
    -------
    GrowResult
    """
    p = _params(params, GrowParams)
    seeds_t = as_array(seeds_template, "seeds_template", shape=(None, 2))
    seeds_s = as_array(seeds_search, "seeds_search", shape=(None, 2))
    if len(seeds_t) != len(seeds_s):
        raise ValueError(f"seeds_search: expected {len(seeds_t)} seeds like seeds_template, "
                         f"got {len(seeds_s)}")
    if constraint is not None:
        _check_constraint(constraint)
        if constraint.n_search != 1:
            raise ValueError(f"constraint: expected a geometry with one search image, got "
                             f"{constraint.n_search} (use grow_joint)")
    A0 = None if seeds_A is None else as_array(seeds_A, "seeds_A",
                                                shape=(len(seeds_t), 2, 2))[:, None]
    return _grow_driver(template, [search], seeds_t, seeds_s[:, None], _options(p, constraint),
                        mask=mask, template_mask=template_mask, seeds_A=A0)[0]


def grow_joint(template, searches, seeds_template, seeds_search, constraint, *, mask=None,
               template_mask=None, seeds_A=None,
               params: GrowParams | None = None) -> list[GrowResult]:
    """Grow dense matches into K search images at once, every node matched jointly in all
    of them under the epipolar condition (:func:`~lsmta.matching.mpgc.mpgc`).

    Parameters
    ----------
    template : (H, W) array
    searches : sequence of K (H, W) arrays
    seeds_template : (S, 2) array
    seeds_search : (K, S, 2) array
        Approximate seed positions in every search image.
    constraint : RectifiedPair or CameraGeometry
        With ``constraint.n_search == K``.
    mask, template_mask
        As in :func:`grow_matches`.
    seeds_A : (K, S, 2, 2) array, optional
        The seeds' starting affine maps into every search image (default: identity).
    params : GrowParams, optional
        As in :func:`grow_matches`.

    Returns
    -------
    list of K GrowResult
        One per search image, over the same nodes (each with the shared ``t``).
    """
    _check_constraint(constraint)
    p = _params(params, GrowParams)
    searches = list(searches)
    K = constraint.n_search
    if len(searches) != K:
        raise ValueError(f"searches: expected {K} search images for this constraint, "
                         f"got {len(searches)}")
    seeds_t = as_array(seeds_template, "seeds_template", shape=(None, 2))
    seeds_s = as_array(seeds_search, "seeds_search", shape=(K, len(seeds_t), 2))
    A0 = None if seeds_A is None else as_array(seeds_A, "seeds_A",
                                                shape=(K, len(seeds_t), 2, 2)).transpose(1, 0, 2, 3)
    return _grow_driver(template, searches, seeds_t, seeds_s.transpose(1, 0, 2),
                        _options(p, constraint), mask=mask, template_mask=template_mask,
                        seeds_A=A0)


@dataclass(frozen=True)
class _Options:
    """The settings of one growth, with the LSM settings of every attempt."""

    step: int
    patch: int                     # the main patch (also the texture test's window)
    largest_patch: int             # of the main, retry and robust patches (usable nodes)
    partial: bool
    offsets: np.ndarray            # (8, 2) shifted-window offsets, or empty
    thresholds: LSMThresholds
    max_attempts: int
    min_texture: float
    noise: float | None
    close_holes: bool
    reach: bool
    seed: LSMParams                # the seeds: the largest patch size, no thresholds
    attempts: tuple                # ((LSMParams, label), ...): patch, retries, robust
    shifted: LSMParams             # the shifted windows
    constraint: object
    wide: LSMParams | None = None  # the adaptive window (``wide_patch``), or None
    slow: LSMParams | None = None  # the slow nodes' attempt (``slow``), or None


def _options(p: GrowParams, constraint) -> _Options:
    retry_patches = (p.patch + 6,) if p.retry_patch is None else p.retry_patch
    robust_patch = p.patch if p.robust_patch is None else p.robust_patch
    offsets = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                        if dx or dy], dtype=float) * p.shift if p.shift else np.zeros((0, 2))
    thresholds = p.lsm_thresholds()
    model = LSMParams(patch=p.patch, geometry=p.geometry, radiometry=p.radiometry,
                      method=p.method, support=p.support, partial=p.partial,
                      max_iter=p.max_iter, tol=p.tol, stall=p.stall)
    attempts = [(replace(model, thresholds=thresholds), "patch")]
    attempts += [(replace(model, patch=size, thresholds=thresholds), "retry")
                 for size in retry_patches]
    if p.robust is not None:
        attempts.append((replace(model, patch=robust_patch, robust=p.robust,
                                 thresholds=thresholds), "robust"))
    return _Options(step=p.step, patch=p.patch,
                    largest_patch=max((p.patch, robust_patch) + retry_patches),
                    partial=p.partial, offsets=offsets, thresholds=thresholds,
                    max_attempts=p.max_attempts, min_texture=p.min_texture, noise=p.noise,
                    close_holes=p.close_holes, reach=p.reach,
                    seed=replace(model, patch=max((p.patch,) + retry_patches)),
                    attempts=tuple(attempts), shifted=replace(model, thresholds=thresholds),
                    constraint=constraint,
                    wide=None if p.wide_patch is None else replace(
                        model, patch=p.wide_patch, thresholds=thresholds),
                    slow=slow_params(replace(model, thresholds=thresholds)) if p.slow else None)


def slow_params(model: LSMParams) -> LSMParams:
    """The slow nodes' attempt (:class:`GrowParams` ``slow``) of the main patch's ``model``.

    Parameters
    ----------
    model : LSMParams
        The main patch's LSM settings, with thresholds.

    Returns
    -------
    LSMParams
        ``model`` with the convergence limit ``tol = SLOW_TOL_SHARE * max_sigma_xy`` (px);
        the ``sigma0`` and ``sigma_xy`` limits are set per call (:func:`slow_limit`).
    """
    if model.thresholds is None:
        raise ValueError("model: expected LSMParams with thresholds (their max_sigma_xy sets "
                         "the slow nodes' convergence limit)")
    return replace(model, tol=SLOW_TOL_SHARE * model.thresholds.max_sigma_xy)


def slow_limit(slow: LSMParams, accepted_sigma0, accepted_sigma_xy) -> LSMParams | None:
    """``slow`` with its ``max_sigma0`` and ``max_sigma_xy`` lowered to the medians of the
    matches accepted so far (NaN ignored), or None if fewer than :data:`SLOW_MIN_MATCHES`
    are: a slow node must fit and be as precise as a typical match.

    Parameters
    ----------
    slow : LSMParams
        The slow nodes' attempt (:func:`slow_params`).
    accepted_sigma0 : (n,) array
        ``sigma0`` of the accepted matches, grey levels.
    accepted_sigma_xy : (n,) array
        Their position's standard deviation (the larger coordinate's), px.

    Returns
    -------
    LSMParams or None
    """
    s0 = np.asarray(accepted_sigma0, float).ravel()
    sxy = np.asarray(accepted_sigma_xy, float).ravel()
    if s0.shape != sxy.shape:
        raise ValueError(f"accepted_sigma_xy: expected one value per match of accepted_sigma0 "
                         f"({s0.size}), got {sxy.size}")
    keep = np.isfinite(s0) & np.isfinite(sxy)
    if keep.sum() < SLOW_MIN_MATCHES:
        return None
    th = slow.thresholds
    return replace(slow, thresholds=replace(
        th, max_sigma0=min(th.max_sigma0, float(np.median(s0[keep]))),
        max_sigma_xy=min(th.max_sigma_xy, float(np.median(sxy[keep])))))


@dataclass(frozen=True)
class _Grid:
    """The node grid: node ``(r, c)`` at ``(c * step, r * step)``; which nodes can be tried;
    the seed cell of every node."""

    nodes: np.ndarray      # (rows, cols, 2)
    usable: np.ndarray     # (rows, cols) bool
    cell: np.ndarray       # (rows, cols) int
    why: np.ndarray        # (rows, cols) int8: NodeOutcome of unusable nodes, -1
    wide: np.ndarray       # (rows, cols) bool: usable through the wide patch alone
    wide_fits: np.ndarray  # (rows, cols) bool: usable, and the wide patch may be tried there

    @property
    def shape(self) -> tuple:
        return self.usable.shape


def _grid(f_img: SplineImage, opts: _Options, mask, seeds_t) -> _Grid:
    H, W = f_img.shape
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (H, W) or mask.dtype != bool:
            raise ValueError(f"mask: expected a boolean array of shape {(H, W)}, got "
                             f"{mask.dtype} {mask.shape}")
    step = opts.step
    rows, cols = (H - 1) // step + 1, (W - 1) // step + 1
    gr, gc = np.mgrid[0:rows, 0:cols]
    nodes = np.stack([gc * step, gr * step], axis=-1).astype(float)
    usable = f_img.inside(nodes, margin=0 if opts.partial else opts.largest_patch // 2)
    why = np.where(usable, -1, NodeOutcome.OUTSIDE).astype(np.int8)
    if mask is not None:
        why[usable & ~mask[gr * step, gc * step]] = NodeOutcome.MASKED
        usable &= mask[gr * step, gc * step]
    flat = nodes.reshape(-1, 2)
    textured = _textured(f_img, opts, usable, gr * step, gc * step, opts.largest_patch
                         if opts.noise is not None else opts.patch)
    wide, fits = np.zeros_like(usable), np.zeros_like(usable)
    if opts.wide is not None:
        n = opts.wide.patch
        fits = usable & (opts.partial | f_img.inside(nodes, margin=n // 2))
        wide = fits & ~textured & _textured(f_img, opts, fits & ~textured, gr * step,
                                            gc * step, n)
    why[usable & ~textured & ~wide] = NodeOutcome.NO_TEXTURE
    usable &= textured | wide
    return _Grid(nodes=nodes, usable=usable,
                 cell=voronoi_cells(seeds_t, flat).reshape(rows, cols), why=why, wide=wide,
                 wide_fits=fits & usable)


def _textured(f_img: SplineImage, opts: _Options, usable, rows, cols, size: int):
    """The texture test over ``size`` x ``size`` patches: the precision rule with ``noise``,
    else the ``min_texture`` spread (False where not ``usable``)."""
    if opts.noise is not None:
        return _precise_enough(f_img.image, opts, rows, cols, size) & usable
    flat = np.stack([cols, rows], axis=-1).reshape(-1, 2).astype(float)
    return _spread(f_img, opts, usable, flat, usable.shape, size)


def _precise_enough(image, opts: _Options, rows, cols, n: int) -> np.ndarray:
    """The precision rule (:class:`GrowParams` ``noise``) at the nodes ``(rows, cols)``:
    ``sqrt(2) noise / sqrt(lambda_min) <= max_sigma_xy`` over ``n`` x ``n`` patches."""
    a, b, c = (s[rows, cols] for s in _gradient_sums(image, n))
    lam = (a + c) / 2 - np.sqrt(((a - c) / 2) ** 2 + b * b)
    need = (np.sqrt(2.0) * opts.noise / opts.thresholds.max_sigma_xy) ** 2
    return lam >= need


def _gradient_sums(image, n: int, *, row_only: bool = False) -> tuple:
    """Sums over every pixel's ``n`` x ``n`` window (the border repeated) of ``g_x^2``,
    ``g_x g_y`` and ``g_y^2`` (``row_only``: ``g_x^2`` alone), the gradient by central
    differences (``np.gradient``); (H, W) arrays, grey levels² / px². Shared by the precision
    rule (:func:`_precise_enough`) and :func:`~lsmta.matching.disparity.row_precision_nodes`."""
    f = np.asarray(image, float)
    if row_only:
        gx = np.gradient(f, axis=1)
        products = (gx * gx,)
    else:
        gy, gx = np.gradient(f)
        products = (gx * gx, gx * gy, gy * gy)
    return tuple(ndimage.uniform_filter(a, n, mode="nearest") * n * n for a in products)


def _spread(f_img: SplineImage, opts: _Options, usable, flat, shape, size: int) -> np.ndarray:
    """The ``min_texture`` test: the grey-value spread of each usable node's ``size`` x
    ``size`` patch (the part inside the image).

    Decided by the patches' moments from box filters where the variance is further than
    ``1e-9 max f^2`` from the limit (the filters' running sums err by about ``1e-16 max f^2``
    per pixel of a line, far inside that margin); the patches within the margin and those
    over the border by :func:`_patch_spread`, the reference (a pass over each patch's
    pixels), so the test's outcome is the reference's."""
    H, W = f_img.shape
    ok = np.full(len(flat), 0.0 >= opts.min_texture)      # (the nodes not usable: spread 0)
    idx = np.flatnonzero(usable.ravel())
    if idx.size == 0:
        return ok.reshape(shape)
    hp = size // 2
    x, y = flat[idx, 0].astype(np.intp), flat[idx, 1].astype(np.intp)
    interior = (x >= hp) & (x <= W - 1 - hp) & (y >= hp) & (y <= H - 1 - hp)
    exact = ~interior
    if interior.any():
        f = f_img.image
        mean = ndimage.uniform_filter(f, size)
        var = ndimage.uniform_filter(f * f, size) - mean * mean
        var = var[y[interior], x[interior]]
        limit = float(opts.min_texture) ** 2
        margin = 1e-9 * float(np.max(f * f)) + 1e-12
        sure = np.abs(var - limit) > margin
        ok[idx[interior][sure]] = var[sure] >= limit
        exact[np.flatnonzero(interior)[~sure]] = True
    if exact.any():
        ok[idx[exact]] = _patch_spread(f_img.image, x[exact], y[exact], hp,
                                       masked=not interior.all()) >= opts.min_texture
    return ok.reshape(shape)


def _patch_spread(image, x, y, hp: int, *, masked: bool) -> np.ndarray:
    """The grey-value standard deviation of the ``2 hp + 1`` square patches at pixels
    ``(x, y)`` over their pixels inside ``image`` (``masked``; else all inside)."""
    H, W = image.shape
    yy, xx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
    ix = x[:, None] + xx.ravel()
    iy = y[:, None] + yy.ravel()
    if not masked:
        return image[iy, ix].std(axis=1)
    inside = (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
    v = image[np.clip(iy, 0, H - 1), np.clip(ix, 0, W - 1)]
    n = inside.sum(axis=1)
    mean = (v * inside).sum(axis=1) / n
    return np.sqrt((inside * (v - mean[:, None]) ** 2).sum(axis=1) / n)


@dataclass
class _State:
    """Per-node state of the growth (``K`` search images)."""

    state: np.ndarray          # (rows, cols) int8: 0 open, 1 matched, 2 given up
    attempts: np.ndarray       # (rows, cols)
    xy: np.ndarray             # (rows, cols, K, 2)
    A: np.ndarray              # (rows, cols, K, 2, 2)
    sigma0: np.ndarray         # (rows, cols)
    sigma_xy: np.ndarray       # (rows, cols, K, 2)
    t: np.ndarray              # (rows, cols)
    sigma_t: np.ndarray        # (rows, cols)
    wave: np.ndarray           # (rows, cols)
    holes: np.ndarray          # (rows, cols) bool
    method: np.ndarray         # (rows, cols) index into METHODS
    failure: np.ndarray        # (rows, cols) int8: AttemptOutcome, -1
    n_lsm: int = 0
    census: dict = field(default_factory=dict)

    @classmethod
    def initial(cls, shape, K: int) -> _State:
        rows, cols = shape
        return cls(state=np.zeros(shape, dtype=np.int8), attempts=np.zeros(shape, np.int16),
                   xy=np.full((rows, cols, K, 2), np.nan),
                   A=np.full((rows, cols, K, 2, 2), np.nan), sigma0=np.full(shape, np.nan),
                   sigma_xy=np.full((rows, cols, K, 2), np.nan), t=np.full(shape, np.nan),
                   sigma_t=np.full(shape, np.nan), wave=np.full(shape, -1),
                   holes=np.zeros(shape, dtype=bool), method=np.zeros(shape, dtype=np.int8),
                   failure=np.full(shape, -1, dtype=np.int8))

    def store(self, rc, m: _Matches, wave: int, hole: bool, max_attempts: int) -> None:
        """Keep the accepted matches; count an attempt at the others (given up after
        ``max_attempts``)."""
        r, c = rc[:, 0], rc[:, 1]
        g = np.flatnonzero(m.ok)
        rg, cg = r[g], c[g]
        self.state[rg, cg] = 1
        self.xy[rg, cg], self.A[rg, cg] = m.xy[g], m.A[g]
        self.sigma0[rg, cg], self.sigma_xy[rg, cg] = m.sigma0[g], m.sigma_xy[g]
        self.t[rg, cg], self.sigma_t[rg, cg] = m.t[g], m.sigma_t[g]
        self.wave[rg, cg], self.holes[rg, cg], self.method[rg, cg] = wave, hole, m.how[g]
        b = np.flatnonzero(~m.ok)
        self.failure[r[b], c[b]] = m.failure[b]
        self.attempts[r[b], c[b]] += 1
        self.state[r[b], c[b]] = np.where(self.attempts[r[b], c[b]] >= max_attempts, 2, 0)


@dataclass
class _Matches:
    """Matches of m nodes in K search images (NaN where not ``ok``)."""

    ok: np.ndarray             # (m,)
    xy: np.ndarray             # (m, K, 2)
    A: np.ndarray              # (m, K, 2, 2)
    sigma0: np.ndarray         # (m,)
    sigma_xy: np.ndarray       # (m, K, 2)
    t: np.ndarray              # (m,)
    sigma_t: np.ndarray        # (m,)
    how: np.ndarray            # (m,) index into METHODS
    failure: np.ndarray = None  # (m,) AttemptOutcome of the main patch (of the wide patch
    #                             at nodes textured in the wide patch only), -1 untried

    @classmethod
    def none(cls, m: int, K: int) -> _Matches:
        return cls(ok=np.zeros(m, dtype=bool), xy=np.full((m, K, 2), np.nan),
                   A=np.full((m, K, 2, 2), np.nan), sigma0=np.full(m, np.nan),
                   sigma_xy=np.full((m, K, 2), np.nan), t=np.full(m, np.nan),
                   sigma_t=np.full(m, np.nan), how=np.zeros(m, dtype=np.int8),
                   failure=np.full(m, -1, dtype=np.int8))

    def take(self, idx) -> _Matches:
        """The rows ``idx``."""
        return _Matches(**{name: None if v is None else v[idx]
                           for name, v in vars(self).items()})

    def adopt(self, again, res: _Matches, label: str) -> None:
        """Take the converged ``res`` rows for the nodes ``again``."""
        good = res.ok
        take = again[good]
        self.ok[take] = True
        self.how[take] = METHODS.index(label)
        for name in ("xy", "A", "sigma0", "sigma_xy", "t", "sigma_t"):
            getattr(self, name)[take] = getattr(res, name)[good]


class _Matcher:
    """Every matching attempt of the growth: LSM into one search image, or constrained
    matching into all of them (:func:`~lsmta.matching.mpgc.mpgc`)."""

    def __init__(self, f_img, g_imgs, opts: _Options, template_mask):
        self.f_img, self.g_imgs, self.opts = f_img, g_imgs, opts
        self.template_mask = template_mask
        self.K = len(g_imgs)
        self.n_lsm = 0
        self.census = dict.fromkeys(ATTEMPT_OUTCOMES, 0)
        self.accepted = []   # (sigma0, sigma_xy) of the accepted matches (``slow_limit``)
        self.pending = []    # the slow nodes' tries (template xy, approximation, A) to come
        self.models = {}     # LSMParams -> _Model (the rectified pair's lean path)
        self.weights = None  # _template_weights, once

    def once(self, t_xy, approx, A0, params: LSMParams) -> _Matches:
        """One attempt at m template points from approximations ``approx`` (m, K, 2) and
        starting affinities ``A0`` (m, K, 2, 2); ``ok`` means converged and accepted."""
        self.n_lsm += len(t_xy)
        con = self.opts.constraint
        if con is None:
            res = lsm(self.f_img, self.g_imgs[0], t_xy, approx[:, 0], initial_A=A0[:, 0],
                      template_mask=self.template_mask, params=params)
            code = _tally(self.census, res.status, params.thresholds, [res])
            nan = np.full(len(t_xy), np.nan)
            return _Matches(ok=res.status == Status.CONVERGED, xy=res.xy[:, None],
                            A=res.A[:, None], sigma0=res.sigma0,
                            sigma_xy=res.sigma_xy[:, None], t=nan, sigma_t=nan.copy(),
                            how=np.zeros(len(t_xy), dtype=np.int8), failure=code)
        t0 = con.parameter(t_xy, approx)
        if isinstance(con, RectifiedPair):
            return self._rectified(t_xy, t0, A0, params)
        res = mpgc(self.f_img, self.g_imgs, t_xy, t0, con, initial_A=A0,
                   template_mask=self.template_mask, params=params)
        code = _tally(self.census, res.status, params.thresholds,
                      [res.image(k) for k in range(self.K)])
        return _Matches(ok=res.status == Status.CONVERGED, xy=res.xy.transpose(1, 0, 2),
                        A=res.A.transpose(1, 0, 2, 3), sigma0=res.sigma0,
                        sigma_xy=res.sigma_xy.transpose(1, 0, 2), t=res.t, sigma_t=res.sigma_t,
                        how=np.zeros(len(t_xy), dtype=np.int8), failure=code)

    def _rectified(self, t_xy, t0, A0, params: LSMParams) -> _Matches:
        """:meth:`once` for a rectified pair: :func:`~lsmta.matching.mpgc.mpgc`'s
        computation without its result object (:func:`~lsmta.matching.mpgc._rectified_once`;
        the same matches, tested against mpgc)."""
        if params not in self.models:
            self.models[params] = _Model.of(params)
        if self.weights is None:
            self.weights = _template_weights(self.template_mask, self.f_img)
        status, c, A, t, sigma_t, sigma0, sigma_xy, fails = _rectified_once(
            self.f_img, self.g_imgs[0], t_xy, t0, A0, self.weights, self.models[params],
            params.thresholds, self.opts.constraint)
        code = _tally(self.census, status, params.thresholds, fails=fails)
        return _Matches(ok=status == Status.CONVERGED.value, xy=c, A=A, sigma0=sigma0,
                        sigma_xy=sigma_xy, t=t, sigma_t=sigma_t,
                        how=np.zeros(len(t_xy), dtype=np.int8), failure=code)

    def match(self, t_xy, approx, A0, wide=None, wide_fits=None) -> _Matches:
        """The attempts in turn: the patch, the retry patch sizes, the robust attempt, the
        wide patch (:func:`wide_window_nodes`, only where ``wide_fits``) and the shifted
        windows; each only for the nodes still unmatched (the slow nodes' attempt comes
        later, :meth:`slow`). The nodes ``wide`` ((m,) bool,
        textured in the wide patch only) get the wide patch alone."""
        o = self.opts
        out = _Matches.none(len(t_xy), self.K)
        wide = np.zeros(len(t_xy), bool) if wide is None else np.asarray(wide, bool)
        wide_fits = wide if wide_fits is None else wide_fits
        for i, (params, label) in enumerate(o.attempts):
            again = np.flatnonzero(~out.ok & ~wide)
            if again.size == 0:
                break
            res = self.once(t_xy[again], approx[again], A0[again], params)
            if i == 0:
                out.failure[again] = res.failure
            out.adopt(again, res, label)
            if o.slow is not None:
                self.accepted.append((res.sigma0[res.ok],
                                      np.nanmax(res.sigma_xy[res.ok], axis=(1, 2))))
        if o.slow is not None:    # tried later, all at once (:meth:`slow`)
            slow = np.flatnonzero(~out.ok & ~wide
                                  & (out.failure == AttemptOutcome.MAX_ITERATIONS))
            self.pending.append((t_xy[slow], approx[slow], A0[slow]))
        if o.wide is not None:
            again = np.flatnonzero(wide_window_nodes(out.failure, matched=out.ok,
                                                     wide_only=wide, fits=wide_fits))
            if again.size:
                res = self.once(t_xy[again], approx[again], A0[again], o.wide)
                first = wide[again]
                out.failure[again[first]] = res.failure[first]
                out.adopt(again, res, "wide")
        again = np.flatnonzero(~out.ok & ~wide)
        if len(o.offsets) and again.size:
            out.adopt(again, self._shifted(t_xy[again], approx[again], A0[again]), "shifted")
        return out

    def slow(self, keep) -> tuple:
        """The slow nodes' attempt (:class:`GrowParams` ``slow``) at the tries collected since
        the last call (a node tried from several neighbours is in it once for each) whose
        template points pass ``keep`` ((n, 2) -> (n,) bool), its limits from the matches
        accepted so far (:func:`slow_limit`): those points (n, 2) and their matches (None if
        there was nothing to try)."""
        tries = [np.concatenate(a) for a in zip(*self.pending)] if self.pending else None
        self.pending = []
        if tries is not None:
            sel = keep(tries[0])
            tries = [a[sel] for a in tries]
        params = None if tries is None or len(tries[0]) == 0 else slow_limit(
            self.opts.slow, *(np.concatenate(a) for a in zip(*self.accepted)))
        if params is None:
            return np.zeros((0, 2)), None
        res = self.once(*tries, params)
        res.how[:] = METHODS.index("slow")
        return tries[0], res

    def _shifted(self, t_xy, approx, A0) -> _Matches:
        """Every node in every shifted window, in one call; a node's match is its best
        passing window's (smallest sigma0) carried back by that window's affine matrices."""
        o = self.opts
        n_a, n_o = len(t_xy), len(o.offsets)
        off = np.tile(o.offsets, (n_a, 1))                                    # (n_a n_o, 2)
        A0r = np.repeat(A0, n_o, axis=0)                                      # (.., K, 2, 2)
        res = self.once(np.repeat(t_xy, n_o, axis=0) + off,
                        np.repeat(approx, n_o, axis=0) + np.einsum("nkij,nj->nki", A0r, off),
                        A0r, o.shifted)
        passed = res.ok.reshape(n_a, n_o)
        best = np.argmin(np.where(passed, res.sigma0.reshape(n_a, n_o), np.inf), axis=1)
        pick = np.arange(n_a) * n_o + best
        back = res.xy - np.einsum("nkij,nj->nki", res.A, off)
        out = _Matches(ok=res.ok[pick], xy=back[pick], A=res.A[pick], sigma0=res.sigma0[pick],
                       sigma_xy=res.sigma_xy[pick], t=res.t[pick], sigma_t=res.sigma_t[pick],
                       how=res.how[pick])
        if o.constraint is not None and out.ok.any():
            # the node's own parameter: its carried-back positions on its own curve
            out.t[out.ok] = o.constraint.parameter(t_xy[out.ok], out.xy[out.ok])
        return out


def _grow_driver(template, searches, seeds_t, seeds_s, opts: _Options, *, mask,
                 template_mask, seeds_A=None) -> list[GrowResult]:
    """Lay out the grid, start from the seeds, grow, freeze."""
    f_img = template if isinstance(template, SplineImage) else SplineImage(template, "template")
    g_imgs = [g if isinstance(g, SplineImage) else SplineImage(g, "search") for g in searches]
    if len(seeds_t) == 0:
        raise ValueError("seeds_template: expected at least one seed")
    grid = _grid(f_img, opts, mask, seeds_t)
    state = _State.initial(grid.shape, len(g_imgs))
    matcher = _Matcher(f_img, g_imgs, opts, template_mask)
    seeds_ok = _start_from_seeds(state, grid, matcher, seeds_t, seeds_s, opts, seeds_A)
    _grow(state, grid, matcher, opts)
    state.n_lsm = matcher.n_lsm
    state.census = matcher.census
    return _results(state, grid, seeds_ok)


def wide_window_nodes(first_failure, *, matched, wide_only, fits) -> np.ndarray:
    """The nodes the adaptive window (:class:`GrowParams` ``wide_patch``) tries, after the main
    patch and its retries (and the robust attempt): those textured in the wide patch only, and
    those whose main patch was rejected by a precision test (:data:`IMPRECISE`) and that no
    later attempt matched; in both
    cases only where the wide patch may be tried (``fits``). The growth and
    :func:`~lsmta.matching.refine.refine_at_nodes` share this rule.

    Parameters
    ----------
    first_failure : (m,) int array
        The main patch's :class:`AttemptOutcome` at each node (-1: not tried).
    matched, wide_only, fits : (m,) bool arrays
        Matched by an earlier attempt; textured in the wide patch but not in the main one;
        the wide patch may be tried there (inside the image, or ``partial`` patches).

    Returns
    -------
    (m,) bool array
    """
    return (np.asarray(fits, bool) & ~np.asarray(matched, bool)
            & (np.asarray(wide_only, bool) | np.isin(first_failure, IMPRECISE)))


def attempt_outcomes(status, thresholds, views) -> np.ndarray:
    """Every point's :class:`AttemptOutcome` after one LSM attempt (int8): accepted, the first
    threshold test it fails in any search image, or its non-convergence status.

    Parameters
    ----------
    status : (m,) int array
        :class:`~lsmta.matching.lsm.Status` of each point.
    thresholds : LSMThresholds
        The attempt's thresholds.
    views : list of LSMResult
        The attempt's result in each search image (``thresholds.failures`` of each).

    Returns
    -------
    (m,) int8 array
    """
    return _tally(dict.fromkeys(ATTEMPT_OUTCOMES, 0), status, thresholds, views)


#: the non-convergence statuses and their outcomes (:func:`_tally`), as plain ints
_NOT_CONVERGED = tuple((name, int(Status[name.upper()]), int(AttemptOutcome[name.upper()]))
                       for name in ("max_iterations", "diverged", "outside", "singular"))
_REJECTED_BY = tuple((name, i, int(AttemptOutcome[name.upper()]))
                     for i, name in enumerate(THRESHOLD_TESTS))


def _tally(census: dict, status, thresholds, views=(), *, fails=None) -> np.ndarray:
    """Count one attempt's outcomes into ``census`` (:data:`ATTEMPT_OUTCOMES`): a rejected
    match under the first test it fails in any search image (``thresholds.failures`` of
    ``views``, or ``fails``: one image's, (len(THRESHOLD_TESTS), n) bool). Returns every
    point's outcome, an :class:`AttemptOutcome` value (int8)."""
    status = np.asarray(status)
    code = np.zeros(len(status), dtype=np.int8)
    census["accepted"] += int((status == Status.CONVERGED.value).sum())
    for name, st, outcome in _NOT_CONVERGED:
        hit = status == st
        census[name] += int(hit.sum())
        code[hit] = outcome
    rejected = status == Status.REJECTED.value
    if not rejected.any():
        return code
    if fails is None:
        fails = np.array([[f[name] for name in THRESHOLD_TESTS]
                          for f in (thresholds.failures(v) for v in views)]).any(axis=0)
    left = rejected.copy()
    for name, i, outcome in _REJECTED_BY:
        hit = left & fails[i]
        census[name] += int(hit.sum())
        code[hit] = outcome
        left &= ~hit
    census["sigma0"] += int(left.sum())    # rejected by the joint rule only (mpgc)
    code[left] = AttemptOutcome.SIGMA0
    return code


def _start_from_seeds(state: _State, grid: _Grid, matcher: _Matcher, seeds_t, seeds_s,
                      opts: _Options, seeds_A=None) -> np.ndarray:
    """LSM at every seed (the largest patch, no thresholds; from ``seeds_A`` (S, K, 2, 2),
    default identity), then at the nearest usable node of each matched seed's cell,
    starting from the seed's solution; returns which seeds matched."""
    A0 = np.broadcast_to(np.eye(2), seeds_s.shape + (2,)) if seeds_A is None else seeds_A
    seed = matcher.once(seeds_t, seeds_s, A0, opts.seed)
    start_nodes, start_approx, start_A = [], [], []
    for k, rc in _nearest_open_nodes(grid, state, seeds_t, seed.ok):
        start_nodes.append(rc)
        offset = grid.nodes[rc[0], rc[1]] - seeds_t[k]
        start_approx.append(seed.xy[k] + seed.A[k] @ offset)
        start_A.append(seed.A[k])
    if start_nodes:
        rc = np.array(start_nodes)
        state.store(rc, matcher.match(grid.nodes[rc[:, 0], rc[:, 1]], np.array(start_approx),
                                      np.array(start_A), grid.wide[rc[:, 0], rc[:, 1]],
                                      grid.wide_fits[rc[:, 0], rc[:, 1]]),
                    0, False, opts.max_attempts)
    return seed.ok


def _nearest_open_nodes(grid: _Grid, state: _State, seeds_t, ok) -> list:
    """``(k, (row, col))`` for every seed ``k`` with ``ok[k]``, in order, whose cell has a
    usable open node: the nearest such node to the seed (ties: the first in row-major order).
    One pass over the grid for all seeds (a pass per seed cost 40 ms at 1800 seeds)."""
    cand = np.argwhere(grid.usable & (state.state == 0))          # row-major order
    k = grid.cell[cand[:, 0], cand[:, 1]]
    keep = np.asarray(ok, bool)[k]
    cand, k = cand[keep], k[keep]
    if k.size == 0:
        return []
    d = np.linalg.norm(grid.nodes[cand[:, 0], cand[:, 1]] - seeds_t[k], axis=1)
    pick = np.lexsort((np.arange(len(k)), d, k))                  # by seed, distance, order
    first = pick[np.r_[True, k[pick][1:] != k[pick][:-1]]]
    return [(int(k[i]), cand[i]) for i in first]


def _grow(state: _State, grid: _Grid, matcher: _Matcher, opts: _Options) -> None:
    """Growth inside the cells, then (``close_holes``) across them, then (``reach``) from
    further neighbours: each step matches the whole front, from the neighbours' solutions
    (horizontally and then vertically in the first two phases)."""
    phases = [(False, (HORIZONTAL, VERTICAL))]
    if opts.close_holes:
        phases.append((True, (HORIZONTAL, VERTICAL)))
    if opts.reach:
        phases.append((True, (HORIZONTAL + VERTICAL + FAR,)))
    w = 1
    for across, steps in phases:
        frontier = state.state == 1
        while frontier.any():
            grown = np.zeros_like(frontier)
            for directions in steps:
                cand, parent = _candidates(frontier | grown, state.state, grid.usable,
                                           grid.cell, directions, same_cell=not across)
                if cand.size == 0:
                    continue
                pr, pc = parent[:, 0], parent[:, 1]
                offset = grid.nodes[cand[:, 0], cand[:, 1]] - grid.nodes[pr, pc]
                A_par = state.A[pr, pc]
                approx = state.xy[pr, pc] + np.einsum("nkij,nj->nki", A_par, offset)
                m = matcher.match(grid.nodes[cand[:, 0], cand[:, 1]], approx, A_par,
                                  grid.wide[cand[:, 0], cand[:, 1]],
                                  grid.wide_fits[cand[:, 0], cand[:, 1]])
                state.store(cand, m, w, across, opts.max_attempts)
                grown[cand[m.ok, 0], cand[m.ok, 1]] = True
            frontier = grown
            w += 1
            if not frontier.any() and matcher.pending:
                # the slow nodes at the end of the front, in one call; growth goes on from them
                frontier = _slow_nodes(state, grid, matcher, w, across)


def _slow_nodes(state: _State, grid: _Grid, matcher: _Matcher, wave: int,
                across: bool) -> np.ndarray:
    """The slow nodes' attempt (:meth:`_Matcher.slow`) at the nodes still unmatched; a node
    tried from several neighbours takes its passing try with the smallest ``sigma0``.
    Returns the matched nodes as a (rows, cols) mask. A failure is not counted as a try."""
    grown = np.zeros(grid.shape, bool)

    def node(xy):                           # grid row and column of template points
        return np.rint(xy[:, ::-1] / matcher.opts.step).astype(int)

    t_xy, m = matcher.slow(lambda xy: state.state[tuple(node(xy).T)] != 1)
    if m is None:
        return grown
    rc = node(t_xy)
    flat = rc[:, 0] * grid.shape[1] + rc[:, 1]
    ok = np.flatnonzero(m.ok)
    ok = ok[np.lexsort((m.sigma0[ok], flat[ok]))]             # by node, then by sigma0
    ok = ok[np.r_[True, flat[ok][1:] != flat[ok][:-1]]] if ok.size else ok   # each node's best
    state.store(rc[ok], m.take(ok), wave, across, matcher.opts.max_attempts)  # all accepted
    grown[rc[ok, 0], rc[ok, 1]] = True
    return grown


def _node_outcome(state: _State, grid: _Grid) -> np.ndarray:
    """Every grid node's outcome, a :class:`NodeOutcome` value (int8 grid)."""
    u, st = grid.usable, state.state
    out = grid.why.copy()
    for outcome, sel in ((NodeOutcome.MATCHED, st == 1), (NodeOutcome.GIVEN_UP, st == 2),
                         (NodeOutcome.FAILED_OPEN, (st == 0) & (state.attempts > 0)),
                         (NodeOutcome.NEVER_REACHED, (st == 0) & (state.attempts == 0))):
        out[u & sel] = outcome
    return out


def _node_census(outcome: np.ndarray) -> dict:
    """Every grid node by outcome (:data:`NODE_OUTCOMES`) -> count."""
    return {name: int((outcome == i).sum()) for i, name in enumerate(NODE_OUTCOMES)}


def _results(state: _State, grid: _Grid, seeds_ok) -> list[GrowResult]:
    r, c = np.nonzero(state.state == 1)
    outcome = _node_outcome(state, grid)
    common = dict(template_xy=grid.nodes[r, c], sigma0=state.sigma0[r, c], seed=grid.cell[r, c],
                  wave=state.wave[r, c], hole_closing=state.holes[r, c],
                  seeds_matched=seeds_ok, n_lsm=state.n_lsm, grid_shape=grid.shape,
                  node_index=np.stack([r, c], axis=1),
                  method=np.array(METHODS)[state.method[r, c]], t=state.t[r, c],
                  sigma_t=state.sigma_t[r, c], attempt_census=dict(state.census),
                  node_census=_node_census(outcome), node_outcome=outcome,
                  node_failure=np.where(state.state == 1, -1, state.failure).astype(np.int8))
    return [GrowResult(search_xy=state.xy[r, c, k], A=state.A[r, c, k],
                       sigma_xy=state.sigma_xy[r, c, k], **common)
            for k in range(state.xy.shape[2])]


def _candidates(frontier, state, usable, cell, directions, *, same_cell):
    """Open usable neighbours of frontier nodes in the given directions, one parent each:
    the candidates in row-major order, each with the first parent found (directions in
    order, frontier nodes in row-major order). Compiled (:func:`_candidates_kernel`)."""
    cand, par = _candidates_kernel(np.ascontiguousarray(frontier, bool),
                                   np.ascontiguousarray(state), np.ascontiguousarray(usable),
                                   np.ascontiguousarray(cell),
                                   np.array(directions, np.int64).reshape(-1, 2), same_cell)
    return cand, par


@nb.njit(cache=True)
def _candidates_kernel(frontier, state, usable, cell, directions, same_cell):
    rows, cols = state.shape
    parent = np.full(rows * cols, -1, np.int64)
    n = 0
    for d in range(directions.shape[0]):
        dc, dr = directions[d, 0], directions[d, 1]
        for r in range(rows):
            for c in range(cols):
                if not frontier[r, c]:
                    continue
                nr, nc = r + dr, c + dc
                if nr < 0 or nr >= rows or nc < 0 or nc >= cols:
                    continue
                if not usable[nr, nc] or state[nr, nc] != 0:
                    continue
                if same_cell and cell[nr, nc] != cell[r, c]:
                    continue
                k = nr * cols + nc
                if parent[k] < 0:
                    parent[k] = r * cols + c
                    n += 1
    cand = np.empty((n, 2), np.int64)
    par = np.empty((n, 2), np.int64)
    j = 0
    for k in range(rows * cols):
        if parent[k] >= 0:
            cand[j, 0], cand[j, 1] = k // cols, k % cols
            par[j, 0], par[j, 1] = parent[k] // cols, parent[k] % cols
            j += 1
    return cand, par
