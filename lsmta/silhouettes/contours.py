"""Closed contours of silhouettes, tracked with snakes (D'Apuzzo et al. 2000, Fig. 16).

A snake (Kass et al. 1988) is a closed polygon that moves to minimise an internal energy
(``alpha`` stretching, ``beta`` bending) plus an external one (``-w_edge |grad I|`` of the
smoothed image); scikit-image's ``active_contour`` solves it. Its capture range is a few
smoothing lengths, so a contour that moved further between frames is lost. The paper
predicts each frame's start contour from the 3-D trajectories of the surrounding points:
projected into the camera, their image displacements from frame ``t - 1`` to ``t`` move
each contour vertex by their Gaussian-weighted mean (weights
``exp(-|c - p|^2 / (2 sigma^2))`` of the distance from the vertex to each point ``p``).
Without trajectories the start is the previous contour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from skimage.measure import find_contours
from skimage.segmentation import active_contour

from .._validate import as_array, as_int, as_scalar, freeze


@dataclass(frozen=True)
class SnakeParams:
    """Settings of :func:`fit_snake` and :func:`track_contours`.

    Attributes
    ----------
    smoothing : float
        Gaussian smoothing of the evidence image before the snake (pixels).
    alpha, beta, gamma, w_line, w_edge, max_px_move, max_num_iter, convergence
        ``active_contour``'s arguments (scikit-image's meaning).
    prediction_sigma : float
        Reach of the trajectory prediction: Gaussian weight's standard deviation (pixels).
    """

    smoothing: float = 1.5
    alpha: float = 0.01
    beta: float = 0.1
    gamma: float = 0.1
    w_line: float = 0.0
    w_edge: float = 1.0
    max_px_move: float = 0.5
    max_num_iter: int = 200
    convergence: float = 0.1
    prediction_sigma: float = 15.0

    def __post_init__(self):
        for name in ("smoothing", "gamma", "max_px_move", "prediction_sigma", "convergence"):
            as_scalar(getattr(self, name), name, positive=True)
        for name in ("alpha", "beta"):
            as_scalar(getattr(self, name), name, nonnegative=True)
        for name in ("w_line", "w_edge"):
            as_scalar(getattr(self, name), name)
        as_int(self.max_num_iter, "max_num_iter")


@dataclass(frozen=True, eq=False)
class ContourTracks:
    """Contours tracked over ``T`` frames.

    Attributes
    ----------
    contours : (T, n, 2) array
        The snake of each frame, pixels ``(x, y)``.
    starts : (T, n, 2) array
        Each frame's start contour (predicted or the previous contour).
    n_predictors : (T,) int array
        Trajectories that predicted the start (0: no prediction).
    """

    contours: np.ndarray
    starts: np.ndarray
    n_predictors: np.ndarray

    def __post_init__(self):
        freeze(self, ("contours", "starts", "n_predictors"))


def _resample(closed_xy: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced along the closed polygon ``closed_xy (m, 2)``."""
    loop = np.vstack([closed_xy, closed_xy[:1]])
    seg = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    at = np.linspace(0.0, s[-1], n, endpoint=False)
    return np.stack([np.interp(at, s, loop[:, 0]), np.interp(at, s, loop[:, 1])], axis=1)


def _contour(value, name: str) -> np.ndarray:
    c = as_array(value, name, shape=(None, 2))
    if len(c) < 8:
        raise ValueError(f"{name}: expected a closed contour of at least 8 points, got {len(c)}")
    return c


def mask_contour(mask, *, n_points: int = 200) -> np.ndarray:
    """The outline ``(n_points, 2)`` (x, y pixels) of the largest region of ``mask (H, W)``.

    The 0.5 level of the mask (scikit-image's ``find_contours``) of the longest closed
    outline, resampled to equal spacing.
    """
    m = np.asarray(mask)
    if m.ndim != 2 or m.dtype != bool:
        raise ValueError(f"mask: expected a 2-D bool array, got {m.dtype} of shape {m.shape}")
    as_int(n_points, "n_points", minimum=8)
    if not m.any():
        raise ValueError("mask: is empty; there is no outline")
    lines = find_contours(np.pad(m, 1).astype(float), 0.5)
    rc = max(lines, key=len) - 1.0
    return _resample(rc[:-1, ::-1], int(n_points))


def predict_contour(contour, before, after, *, sigma: float = 15.0) -> np.ndarray:
    """Move ``contour (n, 2)`` by the image motion of nearby trajectories.

    Parameters
    ----------
    contour : (n, 2) array
        Contour in frame ``t - 1`` (pixels).
    before, after : (N, 2) arrays
        The trajectories' projections in frames ``t - 1`` and ``t`` (NaN where missing).
    sigma : float
        Gaussian reach of a trajectory (pixels); beyond it the nearest ones dominate.

    Returns
    -------
    (n, 2) array
        The predicted contour in frame ``t`` (``contour`` itself when no trajectory has
        both positions).
    """
    contour = _contour(contour, "contour")
    before = as_array(before, "before", shape=(None, 2), allow_nan=True)
    after = as_array(after, "after", shape=before.shape, allow_nan=True)
    sigma = as_scalar(sigma, "sigma", positive=True)
    ok = np.isfinite(before).all(axis=1) & np.isfinite(after).all(axis=1)
    if not ok.any():
        return contour.copy()
    p, d = before[ok], after[ok] - before[ok]
    d2 = ((contour[:, None, :] - p[None]) ** 2).sum(axis=2)           # (n, N)
    w = np.exp(-(d2 - d2.min(axis=1, keepdims=True)) / (2 * sigma * sigma))
    return contour + (w @ d) / w.sum(axis=1, keepdims=True)


def fit_snake(image, start, *, params: SnakeParams | None = None) -> np.ndarray:
    """A snake on ``image (H, W)`` (evidence: e.g. a silhouette mask as floats) from the
    closed contour ``start (n, 2)`` (x, y pixels); returns the contour ``(n, 2)``,
    resampled to equal spacing."""
    image = as_array(image, "image", shape=(None, None))
    start = _contour(start, "start")
    params = SnakeParams() if params is None else params
    if not isinstance(params, SnakeParams):
        raise TypeError(f"params: expected SnakeParams, got {type(params).__name__}")
    smooth = ndimage.gaussian_filter(image, params.smoothing)
    span = np.ptp(smooth)
    smooth = (smooth - smooth.min()) / span if span > 0 else smooth
    rc = active_contour(smooth, start[:, ::-1], alpha=params.alpha, beta=params.beta,
                        w_line=params.w_line, w_edge=params.w_edge, gamma=params.gamma,
                        max_px_move=params.max_px_move, max_num_iter=int(params.max_num_iter),
                        convergence=params.convergence, boundary_condition="periodic")
    return _resample(rc[:, ::-1], len(start))


def track_contours(images, first, *, tracks=None,
                   params: SnakeParams | None = None) -> ContourTracks:
    """Snakes over ``images (T, H, W)`` from the contour ``first (n, 2)`` of frame 0.

    Parameters
    ----------
    images : (T, H, W) array
        Evidence images (silhouette masks as floats, or background differences).
    first : (n, 2) array
        Start contour of frame 0 (pixels), e.g. :func:`mask_contour` of its silhouette.
    tracks : (T, N, 2) array, optional
        Projected 3-D trajectories of points near the contour (NaN where missing); each
        frame's start is predicted from them (:func:`predict_contour`). Without them the
        start is the previous frame's contour.
    params : SnakeParams

    Returns
    -------
    ContourTracks
    """
    images = as_array(images, "images", shape=(None, None, None))
    first = _contour(first, "first")
    if tracks is not None:
        tracks = as_array(tracks, "tracks", shape=(len(images), None, 2), allow_nan=True)
    params = SnakeParams() if params is None else params
    if not isinstance(params, SnakeParams):
        raise TypeError(f"params: expected SnakeParams, got {type(params).__name__}")
    T, n = len(images), len(first)
    contours, starts = np.empty((T, n, 2)), np.empty((T, n, 2))
    used = np.zeros(T, np.int64)
    starts[0] = first
    contours[0] = fit_snake(images[0], first, params=params)
    for t in range(1, T):
        start = contours[t - 1]
        if tracks is not None:
            start = predict_contour(start, tracks[t - 1], tracks[t],
                                    sigma=params.prediction_sigma)
            used[t] = int((np.isfinite(tracks[t - 1]).all(1)
                           & np.isfinite(tracks[t]).all(1)).sum())
        starts[t] = start
        contours[t] = fit_snake(images[t], start, params=params)
    return ContourTracks(contours=contours, starts=starts, n_predictors=used)
