"""Which end of the reference bar is which, consistently in every camera.

:func:`~lsmta.calibration.track_targets` labels a bar's two targets in each camera on its
own: left to right at the start, then by continuity. When a target leaves the image and
comes back, or when the bar turns end-on, one camera's labels can swap while another's do
not; a swapped frame pairs target A in one camera with target B in the other, and the
bundle adjustment then fits a wrong bar. The two ends look alike, so only geometry can
tell them apart.

For each bar position and each way of swapping the labels in some of the cameras (``2^K``
combinations; swapping in every camera is the same combination, so the first camera that
sees the bar keeps its labels), both targets are intersected with approximate cameras and
scored by their reprojection errors and by how far their distance is from the bar's length
(the swap that fits the epipolar geometry but not the length - a bar lying along the
epipolar lines - is caught by the length). The best combination wins; where the best and
the second best are closer than ``margin``, the frame keeps its labels.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..triangulation import triangulate


@dataclass(frozen=True)
class BarLabels:
    """Consistent bar labels.

    Attributes
    ----------
    xy : (K, T, 2, 2) array
        The targets' image positions with A and B consistent across cameras, px.
    swapped : (K, T) bool array
        Frames whose two labels were exchanged in that camera.
    cost : (T,) array
        Score of the chosen combination: mean squared reprojection error (px²) plus the
        squared length deviation in units of ``length_tolerance`` (NaN where fewer than two
        cameras see the bar).
    ambiguous : (T,) bool array
        Frames where another combination scored within ``margin`` of the best (kept as
        labelled).
    """

    xy: np.ndarray
    swapped: np.ndarray
    cost: np.ndarray
    ambiguous: np.ndarray

    @property
    def n_swapped(self) -> int:
        return int(self.swapped.sum())


def consistent_bar_labels(cameras, xy, length: float, *, length_tolerance: float = 0.02,
                          margin: float = 1.0) -> BarLabels:
    """Make the two ends of a bar carry the same labels in every camera.

    Parameters
    ----------
    cameras : sequence of K Camera
        Approximate cameras (e.g. from
        :func:`~lsmta.calibration.relative_orientation_start`), scaled to the bar.
    xy : (K, T, 2, 2) array
        Image positions of targets A and B at T bar positions, px; NaN where not seen.
    length : float
        The bar's length, mm.
    length_tolerance : float
        Relative length deviation that costs as much as one square pixel of mean
        reprojection error (approximate cameras are a few per cent off in scale).
    margin : float
        Frames whose best and second-best combinations differ by less than this are kept
        as labelled.

    Returns
    -------
    BarLabels
        The input is not modified.
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    K = len(cameras)
    xy = as_array(xy, "xy", shape=(K, None, 2, 2), allow_nan=True)
    length = as_scalar(length, "length", positive=True)
    tol = as_scalar(length_tolerance, "length_tolerance", positive=True)
    margin = as_scalar(margin, "margin", nonnegative=True)
    T = xy.shape[1]
    combos = np.array(list(itertools.product((False, True), repeat=K)))     # (C, K)
    C = len(combos)
    # candidate observations (K, C, T, 2 targets, 2)
    flipped = xy[:, :, ::-1]
    cand = np.where(combos.T[:, :, None, None, None], flipped[:, None], xy[:, None])
    inter = triangulate(cameras, cand.reshape(K, -1, 2), min_angle_deg=0.0)
    err = inter.reprojection_error.reshape(K, C, T, 2)
    X = inter.points.reshape(C, T, 2, 3)
    # a combination in which no target has two rays cannot be scored
    n_err = np.isfinite(err).sum(axis=(0, 3))
    reproj = np.where(n_err > 0, np.nansum(err**2, axis=(0, 3)) / np.maximum(n_err, 1),
                      np.inf)
    dev = (np.linalg.norm(X[:, :, 0] - X[:, :, 1], axis=2) - length) / (tol * length)
    cost = reproj + np.where(np.isfinite(dev), dev**2, 0.0)              # (C, T)
    seen = np.isfinite(xy).all(axis=3).any(axis=2)                       # (K, T)
    usable = (seen.sum(axis=0) >= 2) & np.isfinite(cost.min(axis=0))
    best = np.argmin(cost, axis=0)
    # swapping in every camera, or in a camera that does not see the bar, gives the same
    # combination: compare combinations in a canonical form in which the first camera to
    # see the bar keeps its labels
    ref = np.argmax(seen, axis=0)
    canon = (combos[:, :, None] ^ combos[:, ref][:, None, :]) & seen[None]  # (C, K, T)
    choice = canon[best, :, np.arange(T)].T                              # (K, T)
    differs = (canon != choice[None]).any(axis=1)                        # (C, T)
    runner_up = np.where(differs, cost, np.inf).min(axis=0)
    with np.errstate(invalid="ignore"):
        gap = runner_up - cost[best, np.arange(T)]
    ambiguous = usable & (gap < margin)
    swap = choice & (usable & ~ambiguous)[None, :] & seen
    out = np.where(swap[:, :, None, None], flipped, xy)
    chosen = np.where(usable, cost[best, np.arange(T)], np.nan)
    return BarLabels(xy=out, swapped=swap, cost=chosen, ambiguous=ambiguous)
