"""Dense disparity of a rectified stereo pair: seeds, then geometrically constrained growth.

Beyond the paper, which works with a calibrated triplet: for a rectified pair the epipolar
lines are the image rows, and the constrained matcher (:mod:`lsmta.matching.mpgc`,
:class:`~lsmta.matching.mpgc.RectifiedPair`) estimates one disparity per node of a grid in
the left image. Three stages:

1. seeds: corners of the left image found along their row in the right image
   (:func:`~lsmta.matching.seeds.find_disparity_seeds`), unless the caller gives seeds;
2. growth: :func:`~lsmta.matching.grow.grow_matches` with the constraint, from the seeds
   over the grid;
3. seeds found again where the growth never came (automatic seeds only): corners in the
   regions more than ``reseed_gap`` nodes (city-block) from every measured node, then growth from
   them over the unmeasured nodes only, ``reseed_rounds`` times or until no new node is
   measured. A growth stops at a depth edge or a weak-texture band, so a region behind
   it is reached only from a seed of its own; measured nodes are never matched again;
4. the grid: disparities, their standard deviations and ``sigma0`` as ``(rows, cols)``
   arrays; matches outside ``disparity_range`` are dropped.

Started from SGBM instead (``seeds="sgbm"``, issue #33): OpenCV SGBM's disparity at every
node starts the growth's LSM there (:func:`~lsmta.matching.refine.refine_at_nodes`); a node
counts only where the adjustment converges and passes the growth's thresholds, SGBM's value
is never kept; then the growth continues from the accepted nodes that border the nodes still
open into them (``sgbm_fill``). Its own settings (``sgbm_grow``: ``grow`` with a texture floor of
:data:`SGBM_MIN_TEXTURE` grey levels; ``sgbm_fill="unmeasured"``) were chosen on Art and Teddy
by the rule of ``experiments/dense_sgbm_tuning.py``; Tsukuba is held out, Cones only partly
(the growth defaults it inherits were chosen on Cones; notebook 16). SGBM works on 8-bit
grey levels: give the images in 0–255. It is an
option, not the default: denser than the automatic seeds on all four pairs, still below
SGBM's density, its share > 1 px up to 0.16 points higher on two of them.

The defaults (:class:`DisparityParams`) were chosen on Middlebury "Cones" (notebook 16), then
the only real pair with ground truth in the project, so its numbers are not an independent
test of them; Teddy, Art and Tsukuba were added later and are held out (nothing was chosen
on them; notebook 16 reports them with these defaults):

* a 9 x 9 patch, retried at 5 x 5 (closer to depth edges);
* ``geometry="row-affine"``: between rectified images every patch row stays a row, so only
  the first row of ``A`` is free (4 unknowns with the radiometry instead of 6);
* inverse compositional iterations, at most 15: nodes that need more rarely converge to
  the right disparity (on Cones: 0.7 % of the matches more than 1 px off at 10
  iterations, 1.9 % at 15, 2.4 % at 20, for 74 %, 87 % and 88 % density);
* patches may reach over the image border (``partial``), so border nodes are matched;
* thresholds: ``sigma_xy`` up to 0.2 px, singular values of ``A`` in 0.5-2, shear up to 0.5;
* one round of new seeds in unreached regions (``reseed_rounds=1``, ``reseed_gap=2``): added
  for issue #33 item 3, set by rule (more than two nodes clear of the growth), not by scores;
  ``experiments/dense_misses.py`` shows where the remaining misses are, and
  ``experiments/dense_reject_census.py`` which of the growth's tests loses them;
* no slow nodes' attempt (``GrowParams.slow=False``). An option (issue #33 item 3): a node
  still moving after ``max_iter`` iterations is tried once more with a convergence limit of
  a tenth of ``max_sigma_xy`` and kept only as good a fit and as precise as the median
  accepted match; on Cones, Art and Teddy (its tuning pairs) it raised the density by 0.007
  at most, with the median and bad-1.0 verdicts unchanged, for 13-16 % more CPU time
  (``experiments/dense_real_pairs.py --slow``);
* no texture test by a rule (``precision_fill=False``). An option (issue #33 item 1): after
  the growths, the automatic seeds' nodes never tried whose patch could reach
  ``max_sigma_xy`` along the row with the residuals the adjustment measured on the pair
  (:func:`row_precision_nodes`, ``sigma0`` the median of the matches) are grown into from
  their measured neighbours, with no texture floor. Chosen with Cones, Art and Teddy as
  tuning pairs (no free constant), Tsukuba held out: density 0.866/0.757/0.547/0.629 ->
  0.871/0.816/0.588/0.632 (Cones/Teddy/Art/Tsukuba), bad 1.0 1.98/3.50/4.46/2.50 % ->
  1.97/3.29/4.25/2.49 %, no verdict changed, CPU time +3-22 %
  (``experiments/dense_real_pairs.py --precision-fill``). With it as the default,
  notebooks 03, 16 and 21 and tests/test_surfaces_rectified.py, test_capture_recording.py
  and test_surfaces_more_views.py passed (checked once, not committed). Not the default
  yet: it would make Art and Teddy tuning pairs of the automatic seeds, whose held-out
  split notebook 16 states and records; and the rule does not discount the gradient of
  the noise itself, so on a noisy flat background a patch of noise alone can pass it;
* no adaptive window (``wide_patch=None``). An option for real pairs:
  ``replace(DisparityParams().grow, wide_patch=WIDE_PATCH)`` (:data:`WIDE_PATCH`, 13 px,
  after Kanade & Okutomi 1994): a node whose 9 x 9 patch is below the texture floor but whose
  13 x 13 patch is not is matched with the wide patch, and a node rejected by a precision
  test is tried once more with it (not after non-convergence, a depth edge). Its size was
  chosen on Cones (``experiments/dense_adaptive_window.py``, its run committed as
  ``experiments/results/dense_adaptive_window.json``); on the held-out Teddy, Art and
  Tsukuba it raised the automatic seeds' density by 0.043, 0.041 and 0.013 with the median
  and bad-1.0 verdicts unchanged (``experiments/dense_real_pairs.py --wide-patch 13``
  against ``--wide-patch 0``; notebook 16); the SGBM start's changed by 0.004 at most. Not the
  default: these defaults are also the rectified surface stage's
  (:mod:`lsmta.systems.rectified`), and on a generated body before a flat background the
  wide window lends the silhouette's texture to background nodes beside it, which then
  match at the body's disparity (``tests/test_surfaces_rectified.py``: 5.6 % of the kept
  points off the body with it, the test allows 5 %).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from .._validate import as_int, as_scalar, check_patch
from .grow import GrowParams, GrowResult, NodeOutcome, _gradient_sums, grow_matches
from .lsm import LSMThresholds, _params
from .mpgc import RectifiedPair
from .refine import refine_at_nodes, sgbm_start
from .seeds import Seeds, find_disparity_seeds
from .spline import SplineImage, check_image


@dataclass(frozen=True)
class DisparityResult:
    """Disparities on a grid of the left image.

    Attributes
    ----------
    disparity : (rows, cols) array
        ``x_left - x_right`` in pixels at node ``(r, c)``, pixel ``(c * step, r * step)`` of
        the left image; NaN where nothing was matched.
    sigma : (rows, cols) array
        Standard deviation of the disparity from the adjustment, pixels.
    sigma0 : (rows, cols) array
        A-posteriori standard deviation of unit weight, grey levels.
    step : int
        Grid spacing, pixels.
    seeds : Seeds
        The seeds the growth started from.
    grown : GrowResult
        The growth from ``seeds`` (affine matrices, growth order, ...).
    regrown : tuple of (Seeds, GrowResult)
        The growths after ``grown``: from seeds found again in unreached regions, one per
        round; then, with ``precision_fill``, the fill's growth (one more); started from
        SGBM (``seeds="sgbm"``), the growth from the accepted nodes' front (``sgbm_fill``).
    """

    disparity: np.ndarray
    sigma: np.ndarray
    sigma0: np.ndarray
    step: int
    seeds: Seeds
    grown: GrowResult
    regrown: tuple = ()

    @property
    def density(self) -> float:
        """Share of the grid's nodes with a disparity."""
        return float(np.isfinite(self.disparity).mean())


#: where the growth continues after LSM at SGBM's nodes (:attr:`DisparityParams.sgbm_fill`)
SGBM_FILLS = ("unmeasured", "sgbm-empty", "none")
#: the growth's defaults for a rectified pair (see the module docstring)
_GROW = GrowParams(step=4, patch=9, retry_patch=(5,), geometry="row-affine", method="inverse",
                   max_iter=15, partial=True)
#: the adaptive window's size (``GrowParams.wide_patch``, an option, px), chosen on Cones by the
#: rule of experiments/dense_adaptive_window.py
WIDE_PATCH = 13
#: the texture floor of the growth started from SGBM (grey levels), chosen on the tuning pairs
#: Art and Teddy by the rule of experiments/dense_sgbm_tuning.py
SGBM_MIN_TEXTURE = 1.0


@dataclass(frozen=True)
class DisparityParams:
    """Settings of :func:`measure_disparity`. Built by keyword; every field is checked here,
    and the error names it.

    Attributes
    ----------
    grow : GrowParams
        The constrained growth (:func:`~lsmta.matching.grow.grow_matches`). Default: step 4,
        patch 9, retry patch 5, ``geometry="row-affine"``, ``method="inverse"``,
        ``max_iter=15``, ``partial=True``, no adaptive window (see the module docstring);
        vary it with ``dataclasses.replace(DisparityParams().grow, max_iter=10)``. Its
        ``thresholds`` default here (None) to ``max_displacement = step``,
        ``max_sigma_xy = 0.2``, ``scale_range = (0.5, 2)``, ``max_shear = 0.5``.
    n_seeds : int
        Seeds to look for (:func:`~lsmta.matching.seeds.find_disparity_seeds`), in each
        round.
    reseed_rounds : int
        Rounds of new seeds in regions the growth never reached (0: none; automatic seeds
        only).
    reseed_gap : int
        A node is unreached more than this many nodes (city-block distance) from every
        measured node.
    sgbm_grow : GrowParams, optional
        The growth's settings when started from SGBM (``seeds="sgbm"``), at ``grow``'s step.
        None (default): ``grow`` with ``min_texture`` :data:`SGBM_MIN_TEXTURE` (chosen on Art
        and Teddy, ``experiments/dense_sgbm_tuning.py``; the rest of ``grow``'s defaults
        were chosen on Cones).
    sgbm_fill : {"unmeasured", "sgbm-empty", "none"}
        Started from SGBM, where the growth continues from the accepted nodes: into every
        node still without a disparity, only into the nodes where SGBM had none, or nowhere.
    precision_fill : bool
        Automatic seeds, after the growths (issue #33 item 1, a texture test by a rule): the
        nodes never tried (below the texture floor ``min_texture``, or never reached) that
        could reach the accepted precision along the row are grown into from the measured
        nodes beside them, with no texture floor (:func:`row_precision_nodes`: ``sigma0 /
        sqrt(sum g_x^2) <= max_sigma_xy`` over the patch, ``sigma0`` the median of the
        matches of the growths before, the adjustment's own measure of the pair's noise and
        model error). Ignored, with a warning, when ``seeds`` are given or ``"sgbm"``.
        False (default): off.
    """

    grow: GrowParams = _GROW
    n_seeds: int = 30
    reseed_rounds: int = 1
    reseed_gap: int = 2
    sgbm_grow: GrowParams | None = None
    sgbm_fill: str = "unmeasured"
    precision_fill: bool = False

    def __post_init__(self):
        if not isinstance(self.grow, GrowParams):
            raise TypeError(f"grow: expected a GrowParams, got {type(self.grow).__name__}")
        object.__setattr__(self, "n_seeds", as_int(self.n_seeds, "n_seeds"))
        object.__setattr__(self, "reseed_rounds", as_int(self.reseed_rounds, "reseed_rounds",
                                                         minimum=0))
        object.__setattr__(self, "reseed_gap", as_int(self.reseed_gap, "reseed_gap"))
        if self.sgbm_grow is not None and not isinstance(self.sgbm_grow, GrowParams):
            raise TypeError(f"sgbm_grow: expected a GrowParams or None, got "
                            f"{type(self.sgbm_grow).__name__}")
        if self.sgbm_grow is not None and self.sgbm_grow.step != self.grow.step:
            raise ValueError(f"sgbm_grow: expected grow's step ({self.grow.step} px; the maps are "
                             f"scored on one grid), got step {self.sgbm_grow.step}")
        if not isinstance(self.sgbm_fill, str) or self.sgbm_fill not in SGBM_FILLS:
            raise ValueError(f"sgbm_fill: expected one of {SGBM_FILLS}, got {self.sgbm_fill!r}")
        if not isinstance(self.precision_fill, (bool, np.bool_)):
            raise ValueError(f"precision_fill: expected True or False, got "
                             f"{self.precision_fill!r}")
        object.__setattr__(self, "precision_fill", bool(self.precision_fill))

    def grow_params(self, *, sgbm: bool = False) -> GrowParams:
        """``grow`` (``sgbm_grow`` with ``sgbm`` if given) with its thresholds: given, or the
        defaults above at its ``step``."""
        g = self.grow
        if sgbm:
            g = (self.sgbm_grow if self.sgbm_grow is not None
                 else replace(g, min_texture=SGBM_MIN_TEXTURE))
        if g.thresholds is not None:
            return g
        return replace(g, thresholds=LSMThresholds(
            max_displacement=float(g.step), max_sigma_xy=0.2, scale_range=(0.5, 2.0),
            max_shear=0.5))


def measure_disparity(left, right, *, disparity_range, seeds: Seeds | str | None = None,
                      mask=None, template_mask=None,
                      params: DisparityParams | None = None) -> DisparityResult:
    """Dense disparities of a rectified pair by constrained region growing.

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair, grey; a left pixel ``(x, y)`` appears at ``(x - d, y)``.
    disparity_range : (int, int)
        Smallest and largest disparity, pixels: where the seeds are searched, and matches
        outside it are dropped.
    seeds : Seeds or "sgbm", optional
        Seeds to start from instead (``xy`` (2, S, 2): left and right positions); or
        ``"sgbm"``: LSM at every node where OpenCV's SGBM has a disparity, started there
        (:func:`~lsmta.matching.refine.refine_at_nodes`, settings ``params.sgbm_grow``),
        then growth from the accepted nodes (``params.sgbm_fill``); a node counts only
        where the adjustment accepts it, SGBM's value is never kept.
    mask, template_mask : (H, W) bool arrays, optional
        Where in the left image to grow, and its pixels on the object (see
        :func:`~lsmta.matching.grow.grow_matches`).
    params : DisparityParams, optional
        The growth and the number of seeds (default :class:`DisparityParams`).

    Returns
    -------
    DisparityResult
    """
    p = _params(params, DisparityParams)
    f = check_image(left, "left")
    g = check_image(right, "right")
    if g.shape != f.shape:
        raise ValueError(f"right: expected the shape of left {f.shape}, got {g.shape}")
    lo, hi = (float(d) for d in disparity_range)
    if not 0 <= lo < hi:
        raise ValueError(f"disparity_range: expected 0 <= smallest < largest (pixels), got "
                         f"{disparity_range}")
    if p.precision_fill and seeds is not None:
        warnings.warn("precision_fill: ignored (automatic seeds only), seeds were given",
                      stacklevel=2)
    if isinstance(seeds, str) and seeds == "sgbm":
        return _from_sgbm(f, g, (lo, hi), mask, template_mask, p)
    if not (seeds is None or isinstance(seeds, Seeds)):
        raise ValueError(f"seeds: expected None, a Seeds or 'sgbm', got {seeds!r}")
    automatic = seeds is None
    if automatic:
        seeds = find_disparity_seeds(f, g, disparity_range=disparity_range, n_seeds=p.n_seeds)
    if seeds.xy.shape[1] == 0:
        raise ValueError("seeds: none found; give seeds or widen disparity_range")
    grow = p.grow_params()
    fs, gs = SplineImage(f, "left"), SplineImage(g, "right")     # prefiltered once
    grown = grow_matches(fs, gs, seeds.xy[0], seeds.xy[1], mask=mask, template_mask=template_mask,
                         constraint=RectifiedPair(), params=grow)
    grid = [np.full(grown.grid_shape, np.nan) for _ in range(3)]
    _put(grid, grown, lo, hi)
    regrown = []
    for _ in range(p.reseed_rounds if automatic else 0):
        unmeasured = _pixels(~np.isfinite(grid[0]), grow.step, f.shape, mask)
        unreached = _pixels(~ndimage.binary_dilation(np.isfinite(grid[0]),
                                                     iterations=p.reseed_gap),
                            grow.step, f.shape, mask)
        more = find_disparity_seeds(f, g, disparity_range=disparity_range, n_seeds=p.n_seeds,
                                    mask=unreached)
        if more.xy.shape[1] == 0:
            break
        again = grow_matches(fs, gs, more.xy[0], more.xy[1], mask=unmeasured,
                             template_mask=template_mask, constraint=RectifiedPair(),
                             params=grow)
        regrown.append((more, again))
        if not _put(grid, again, lo, hi):
            break
    if automatic and p.precision_fill:
        regrown += _precision_fill(f, g, grid, [grown] + [a for _, a in regrown], (lo, hi),
                                   mask, template_mask, grow)
    return DisparityResult(disparity=grid[0], sigma=grid[1], sigma0=grid[2], step=grow.step,
                           seeds=seeds, grown=grown, regrown=tuple(regrown))


def refine_disparities(left, right, start, *, disparity_range, mask=None, template_mask=None,
                       params: DisparityParams | None = None) -> DisparityResult:
    """LSM of a rectified pair at every node with a starting disparity (e.g. SGBM's,
    :func:`~lsmta.matching.refine.sgbm_start`), no growth: a node not started is not measured
    (:func:`~lsmta.matching.refine.refine_at_nodes` with ``params.grow_params()``).

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair.
    start : (rows, cols) array
        Starting disparities at the nodes ``(c * step, r * step)``, px (NaN: not tried).
    disparity_range : (float, float)
        Matches outside it are dropped, px.
    mask, template_mask : (H, W) bool arrays, optional
        Nodes to try (read at the node's pixel); left pixels on the object.
    params : DisparityParams, optional

    Returns
    -------
    DisparityResult
        ``seeds`` holds the started nodes (``disparity`` their start), ``grown`` the accepted
        ones.
    """
    grow = _params(params, DisparityParams).grow_params()
    lo, hi = (float(d) for d in disparity_range)
    seeds, refined = refine_at_nodes(left, right, start, disparity_range=(lo, hi), grow=grow,
                                     mask=mask, template_mask=template_mask)
    grid = [np.full(refined.grid_shape, np.nan) for _ in range(3)]
    _put(grid, refined, lo, hi)
    return DisparityResult(disparity=grid[0], sigma=grid[1], sigma0=grid[2], step=grow.step,
                           seeds=seeds, grown=refined)


def _from_sgbm(f, g, span, mask, template_mask, p: DisparityParams) -> DisparityResult:
    """``seeds="sgbm"``: LSM at SGBM's nodes, then growth from the accepted nodes that border
    the nodes left open (``p.sgbm_fill``) into them."""
    grow = p.grow_params(sgbm=True)
    start = sgbm_start(f, g, disparity_range=span, step=grow.step)
    res = refine_disparities(f, g, start, disparity_range=span, mask=mask,
                             template_mask=template_mask, params=replace(p, grow=grow))
    if p.sgbm_fill == "none":
        return res
    got = np.isfinite(res.disparity)
    open_ = ~got if p.sgbm_fill == "unmeasured" else ~got & ~np.isfinite(start)
    grid = [res.disparity.copy(), res.sigma.copy(), res.sigma0.copy()]
    regrown = _from_front(f, g, grid, open_, span, mask, template_mask, grow)
    if not regrown:
        return res
    return replace(res, disparity=grid[0], sigma=grid[1], sigma0=grid[2], regrown=regrown)


def _from_front(f, g, grid, open_, span, mask, template_mask, grow: GrowParams) -> tuple:
    """Growth from the measured nodes of ``grid`` (disparity, sigma, sigma0) that border the
    nodes ``open_`` into them (``grid`` updated); returns ``((seeds, growth),)``, or ``()``
    if no measured node borders them."""
    got = np.isfinite(grid[0])
    front = got & ndimage.binary_dilation(open_, structure=ndimage.generate_binary_structure(2, 1))
    if not front.any():
        return ()
    r, c = np.nonzero(front)
    xl = np.stack([c * grow.step, r * grow.step], axis=1).astype(float)
    xr = xl - np.stack([grid[0][r, c], np.zeros(len(r))], axis=1)
    more = Seeds(xy=np.stack([xl, xr]), score=np.full(len(r), np.nan),
                 depth=np.full(len(r), np.nan), disparity=grid[0][r, c])
    again = grow_matches(f, g, xl, xr, mask=_pixels(open_, grow.step, f.shape, mask),
                         template_mask=template_mask, constraint=RectifiedPair(), params=grow)
    _put(grid, again, *span)
    return ((more, again),)


def _precision_fill(f, g, grid, growths, span, mask, template_mask, grow: GrowParams) -> list:
    """:attr:`DisparityParams.precision_fill`: growth from the measured nodes into the nodes
    no growth of ``growths`` tried that pass :func:`row_precision_nodes` (``sigma0`` the
    median of the measured nodes'), with no texture floor; ``grid`` updated."""
    got = np.isfinite(grid[0])
    if not got.any():
        return []
    tried = np.zeros_like(got)
    for one in growths:
        tried |= np.isin(one.node_outcome, (NodeOutcome.MATCHED, NodeOutcome.GIVEN_UP,
                                            NodeOutcome.FAILED_OPEN))
    precise = row_precision_nodes(f, patch=grow.patch, step=grow.step,
                                  sigma0=float(np.median(grid[2][got])),
                                  max_sigma=grow.lsm_thresholds().max_sigma_xy)
    return list(_from_front(f, g, grid, ~got & ~tried & precise, span, mask, template_mask,
                            replace(grow, min_texture=0.0, noise=None)))


def row_precision_nodes(image, *, patch: int, step: int, sigma0: float,
                        max_sigma: float) -> np.ndarray:
    """Grid nodes whose patch could be matched along the row (a rectified pair's disparity)
    to ``max_sigma`` with residuals of ``sigma0``: ``sigma0 / sqrt(sum g_x^2) <= max_sigma``,
    the sum over the ``patch`` x ``patch`` window (the image's border repeated), ``g_x`` the
    row derivative (central differences). LSM's disparity precision is at best
    ``sigma0 / sqrt(sum g_x^2)`` (the shift alone; the shape and radiometry only add to it).

    Parameters
    ----------
    image : (H, W) array
        The left image, grey levels.
    patch : int
        Odd window side, px (>= 5).
    step : int
        Grid spacing, px; node ``(r, c)`` at pixel ``(c * step, r * step)``.
    sigma0 : float
        Residual standard deviation expected of a match, grey levels (> 0).
    max_sigma : float
        Precision a match must reach, px (> 0).

    Returns
    -------
    ((H - 1) // step + 1, (W - 1) // step + 1) bool array
    """
    f = check_image(image, "image")
    patch = check_patch(patch)
    step = as_int(step, "step", unit="pixels")
    sigma0 = as_scalar(sigma0, "sigma0", positive=True)
    max_sigma = as_scalar(max_sigma, "max_sigma", positive=True)
    energy, = _gradient_sums(f, patch, row_only=True)
    return energy[::step, ::step] * max_sigma**2 >= sigma0**2


def _put(grid, grown: GrowResult, lo: float, hi: float) -> int:
    """Write ``grown``'s matches inside ``[lo, hi]`` into the empty nodes of ``grid``
    (disparity, sigma, sigma0); returns how many were written."""
    keep = (grown.t >= lo) & (grown.t <= hi)
    r, c = grown.node_index[keep].T
    new = ~np.isfinite(grid[0][r, c])
    for out, values in zip(grid, (grown.t, grown.sigma_t, grown.sigma0)):
        out[r[new], c[new]] = values[keep][new]
    return int(new.sum())


def _pixels(nodes, step: int, shape, mask) -> np.ndarray:
    """The pixel mask ``shape`` of the grid ``nodes`` (each node's ``step x step`` block, the
    node at its top-left corner, as the growth reads ``mask`` at the node's pixel), within
    ``mask`` if given."""
    px = np.repeat(np.repeat(nodes, step, axis=0), step, axis=1)[:shape[0], :shape[1]]
    px = np.pad(px, ((0, shape[0] - px.shape[0]), (0, shape[1] - px.shape[1])))
    return px if mask is None else px & np.asarray(mask, bool)
