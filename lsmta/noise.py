"""Image noise measured in the images themselves.

In a video, most pixels see something that does not move between two frames (the
backdrop, the floor, the still parts of a body), so the difference of two consecutive
frames there is noise alone, with standard deviation ``sigma sqrt(2)``, and its median
absolute value estimates it (``1.4826 MAD`` for a Gaussian). Pixels at the sensor's limits
(0 or 255 in 8-bit images), and then those within four first-estimate sigmas of them, are
left out: clipping removes part of their noise. Moving
pixels would still pull the median up (a tenth of the image moving raises it by about
10 %), so they are found and left out first: where the mean absolute difference over a
7 x 7 window is more than twice the first estimate's median absolute difference (noise
alone stays below 1.5 times it), the window sees motion.

8-bit differences are integers, so their median can only take integer values (a step of
about 1 grey level in ``sigma``). We take the median of the *grouped* data instead: each
integer ``k`` stands for the interval ``[k - 1/2, k + 1/2)`` (``[0, 1/2)`` for 0) and the
median is interpolated inside the interval where the cumulative count passes one half.
The estimate is the noise of the delivered images, rounding included (``sqrt(sigma² +
1/12)`` for Gaussian noise ``sigma`` before rounding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._validate import as_int

# 1 / Phi^-1(3/4): a Gaussian's standard deviation from its median absolute value
MAD_TO_SIGMA = 1.482602218505602


@dataclass(frozen=True)
class NoiseEstimate:
    """Image noise from consecutive frames.

    Attributes
    ----------
    sigma : float
        Standard deviation of the noise of one image, grey levels.
    per_camera : (K,) array
        The same for each camera.
    n_pixels : int
        Pixel differences used (both values inside the sensor's range, no motion near).
    """

    sigma: float
    per_camera: np.ndarray
    n_pixels: int


def _grouped_median(a: np.ndarray) -> float:
    """Median of non-negative integers, each standing for ``[k - 1/2, k + 1/2)``."""
    counts = np.bincount(a)
    half = a.size / 2.0
    cum = np.cumsum(counts)
    k = int(np.searchsorted(cum, half, side="right"))
    below = cum[k - 1] if k else 0
    lo, width = (0.0, 0.5) if k == 0 else (k - 0.5, 1.0)
    return lo + (half - below) / counts[k] * width


def temporal_noise(videos, *, max_frames: int = 12) -> NoiseEstimate:
    """Image noise of K cameras' videos from differences of consecutive frames.

    Parameters
    ----------
    videos : (K, T, H, W) or (T, H, W) array
        Grey frames (T >= 2); uint8 or float.
    max_frames : int
        Use at most this many evenly spread pairs of consecutive frames per camera.

    Returns
    -------
    NoiseEstimate
    """
    v = np.asarray(videos)
    if v.ndim == 3:
        v = v[None]
    if v.ndim != 4 or v.shape[1] < 2:
        raise ValueError(f"videos: expected (K, T, H, W) or (T, H, W) frames with T >= 2, got "
                         f"shape {v.shape}")
    if not (np.issubdtype(v.dtype, np.integer) or np.issubdtype(v.dtype, np.floating)):
        raise TypeError(f"videos: expected grey values (integer or float), got {v.dtype}")
    as_int(max_frames, "max_frames")
    integer = np.issubdtype(v.dtype, np.integer)
    if not integer and not np.isfinite(v).all():
        raise ValueError("videos: expected finite grey values")
    lo, hi = (np.iinfo(v.dtype).min, np.iinfo(v.dtype).max) if integer else (-np.inf, np.inf)
    T = v.shape[1]
    pairs = np.unique(np.linspace(0, T - 2, min(int(max_frames), T - 1)).round().astype(int))
    median = (lambda d: _grouped_median(d.astype(np.int64))) if integer else np.median
    per, total = [], 0
    for cam in v:
        a, b = cam[pairs].astype(np.float64), cam[pairs + 1].astype(np.float64)
        inside = (a > lo) & (a < hi) & (b > lo) & (b < hi)
        d = np.abs(b - a)
        if inside.sum() < 100:
            raise ValueError(f"videos: only {inside.sum()} pixel pairs inside the sensor's "
                             "range; too few to measure the noise")
        first = median(d[inside])
        # near a limit the noise is partly clipped: keep 4 first-estimate sigmas away
        margin = 4 * MAD_TO_SIGMA * first / np.sqrt(2.0)
        inside &= (np.minimum(a, b) >= lo + margin) & (np.maximum(a, b) <= hi - margin)
        local = ndimage.uniform_filter(np.where(inside, d, 0.0), size=(1, 7, 7))
        share = ndimage.uniform_filter(inside.astype(float), size=(1, 7, 7))
        still = inside & (local <= 2.0 * max(first, 0.5) * np.maximum(share, 1e-9))
        use = still if still.sum() >= 100 else inside
        total += int(use.sum())
        per.append(MAD_TO_SIGMA * median(d[use]) / np.sqrt(2.0))
    per = np.asarray(per)
    return NoiseEstimate(sigma=float(np.median(per)), per_camera=per, n_pixels=int(total))
