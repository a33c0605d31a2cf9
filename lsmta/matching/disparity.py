"""Dense disparity of a rectified stereo pair: seeds, then geometrically constrained growth.

Beyond the paper, which works with a calibrated triplet: for a rectified pair the epipolar
lines are the image rows, and the constrained matcher (:mod:`lsmta.matching.mpgc`,
:class:`~lsmta.matching.mpgc.RectifiedPair`) estimates one disparity per node of a grid in
the left image. Three stages:

1. seeds: corners of the left image found along their row in the right image
   (:func:`~lsmta.matching.seeds.find_disparity_seeds`), unless the caller gives seeds;
2. growth: :func:`~lsmta.matching.grow.grow_matches` with the constraint, from the seeds
   over the grid;
3. the grid: disparities, their standard deviations and ``sigma0`` as ``(rows, cols)``
   arrays; matches outside ``disparity_range`` are dropped.

The defaults were chosen on Middlebury "Cones" (notebook 16), the only real pair with
ground truth in the project, so its numbers are not an independent test of them:

* a 9 x 9 patch, retried at 5 x 5 (closer to depth edges);
* ``geometry="row-affine"``: between rectified images every patch row stays a row, so only
  the first row of ``A`` is free (4 unknowns with the radiometry instead of 6);
* inverse compositional iterations, at most 15: nodes that need more rarely converge to
  the right disparity (on Cones: 0.7 % of the matches more than 1 px off at 10
  iterations, 1.9 % at 15, 2.4 % at 20, for 74 %, 87 % and 88 % density);
* patches may reach over the image border (``partial``), so border nodes are matched;
* thresholds: ``sigma_xy`` up to 0.2 px, singular values of ``A`` in 0.5-2, shear up to 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .grow import GrowResult, grow_matches
from .lsm import LSMThresholds
from .mpgc import RectifiedPair
from .seeds import Seeds, find_disparity_seeds
from .spline import check_image


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
        The growth itself (affine matrices, growth order, ...).
    """

    disparity: np.ndarray
    sigma: np.ndarray
    sigma0: np.ndarray
    step: int
    seeds: Seeds
    grown: GrowResult

    @property
    def density(self) -> float:
        """Share of the grid's nodes with a disparity."""
        return float(np.isfinite(self.disparity).mean())


def measure_disparity(left, right, *, disparity_range, step: int = 4, patch: int = 9,
                      retry_patch=(5,), geometry: str = "row-affine", method: str = "inverse",
                      max_iter: int = 15, partial: bool = True,
                      thresholds: LSMThresholds | None = None, n_seeds: int = 30,
                      seeds: Seeds | None = None, **grow_options) -> DisparityResult:
    """Dense disparities of a rectified pair by constrained region growing.

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair, grey; a left pixel ``(x, y)`` appears at ``(x - d, y)``.
    disparity_range : (int, int)
        Smallest and largest disparity, pixels: where the seeds are searched, and matches
        outside it are dropped.
    step, patch, retry_patch, geometry, method, max_iter, partial
        The growth (:func:`~lsmta.matching.grow.grow_matches`); see the module docstring.
    thresholds : LSMThresholds, optional
        Default: ``max_displacement = step``, ``max_sigma_xy = 0.2``, ``scale_range =
        (0.5, 2)``, ``max_shear = 0.5``.
    n_seeds : int
        Seeds to look for (:func:`~lsmta.matching.seeds.find_disparity_seeds`).
    seeds : Seeds, optional
        Seeds to start from instead (``xy`` (2, S, 2): left and right positions).
    **grow_options
        Further options of :func:`~lsmta.matching.grow.grow_matches` (``robust``,
        ``support``, ``reach``, ...).

    Returns
    -------
    DisparityResult
    """
    f = check_image(left, "left")
    g = check_image(right, "right")
    if g.shape != f.shape:
        raise ValueError(f"right: expected the shape of left {f.shape}, got {g.shape}")
    lo, hi = (float(d) for d in disparity_range)
    if not 0 <= lo < hi:
        raise ValueError(f"disparity_range: expected 0 <= smallest < largest (pixels), got "
                         f"{disparity_range}")
    if seeds is None:
        seeds = find_disparity_seeds(f, g, disparity_range=disparity_range, n_seeds=n_seeds)
    if seeds.xy.shape[1] == 0:
        raise ValueError("seeds: none found; give seeds or widen disparity_range")
    if thresholds is None:
        thresholds = LSMThresholds(max_displacement=float(step), max_sigma_xy=0.2,
                                   scale_range=(0.5, 2.0), max_shear=0.5)
    grown = grow_matches(f, g, seeds.xy[0], seeds.xy[1], step=step, patch=patch,
                         retry_patch=retry_patch, geometry=geometry, method=method,
                         max_iter=max_iter, partial=partial, thresholds=thresholds,
                         constraint=RectifiedPair(), **grow_options)
    grid = [np.full(grown.grid_shape, np.nan) for _ in range(3)]
    keep = (grown.t >= lo) & (grown.t <= hi)
    r, c = grown.node_index[keep].T
    for out, values in zip(grid, (grown.t, grown.sigma_t, grown.sigma0)):
        out[r, c] = values[keep]
    return DisparityResult(disparity=grid[0], sigma=grid[1], sigma0=grid[2], step=step,
                           seeds=seeds, grown=grown)
