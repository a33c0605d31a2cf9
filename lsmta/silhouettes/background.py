"""The person's silhouette from a background model learnt on frames without the person.

Why a background model and not an OpenCV subtractor (MOG2, KNN): the cameras of the
LSMTA rig stand still, the studio is static and can be filmed empty before the person
walks in, so the per-pixel median of the empty frames is the background and their robust
spread (1.4826 x the median absolute deviation) is the image noise of each pixel. An
adaptive subtractor learns the background while the person is in view and slowly absorbs
whoever stands still; it answers a harder question than the one this rig asks.

A pixel is foreground when ``|I - median| > max(k * spread, min_difference)``; the
silhouette is the largest connected foreground region, closed and with its holes filled
(the person's clothing can match the wall's grey value in places).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validate import as_array, as_int, as_scalar, freeze


@dataclass(frozen=True, eq=False)
class BackgroundModel:
    """Per-pixel background of one camera.

    Attributes
    ----------
    median : (H, W) array
        Grey value of the empty scene.
    spread : (H, W) array
        Robust standard deviation of the empty frames (grey levels).
    """

    median: np.ndarray
    spread: np.ndarray

    def __post_init__(self):
        freeze(self, ("median", "spread"))

    def difference(self, image) -> np.ndarray:
        """``|image - median| / spread`` ``(H, W)``: the foreground evidence in noise units
        (spread floored at 0.5 grey levels)."""
        image = as_array(image, "image", shape=self.median.shape)
        return np.abs(image - self.median) / np.maximum(self.spread, 0.5)


@dataclass(frozen=True)
class SilhouetteParams:
    """Settings of :func:`silhouettes`.

    Attributes
    ----------
    k_sigma : float
        Threshold in units of each pixel's background spread.
    min_difference : float
        Threshold floor in grey levels.
    closing : int
        Radius (pixels) of the morphological closing of the foreground (0: none).
    """

    k_sigma: float = 4.0
    min_difference: float = 6.0
    closing: int = 2

    def __post_init__(self):
        as_scalar(self.k_sigma, "k_sigma", positive=True)
        as_scalar(self.min_difference, "min_difference", nonnegative=True)
        as_int(self.closing, "closing", minimum=0, unit="pixels")


def learn_background(frames) -> BackgroundModel:
    """The background of one camera from ``frames (T, H, W)`` of the empty scene (T >= 3).

    Returns a :class:`BackgroundModel`: the per-pixel median and ``1.4826 * MAD``.
    """
    frames = as_array(frames, "frames", shape=(None, None, None))
    if len(frames) < 3:
        raise ValueError(f"frames: expected at least 3 frames of the empty scene, got "
                         f"{len(frames)}")
    med = np.median(frames, axis=0)
    mad = np.median(np.abs(frames - med), axis=0)
    return BackgroundModel(median=med, spread=1.4826 * mad)


def silhouettes(images, background: BackgroundModel, *,
                params: SilhouetteParams | None = None) -> np.ndarray:
    """Silhouette masks ``(T, H, W)`` bool of ``images (T, H, W)`` against ``background``.

    Each mask is the largest connected foreground region (empty when nothing differs),
    closed with a disc of radius ``params.closing`` and with its holes filled.
    """
    images = as_array(images, "images", shape=(None,) + background.median.shape)
    params = SilhouetteParams() if params is None else params
    if not isinstance(params, SilhouetteParams):
        raise TypeError(f"params: expected SilhouetteParams, got {type(params).__name__}")
    thr = np.maximum(params.k_sigma * background.spread, params.min_difference)
    return largest_region(np.abs(images - background.median) > thr, closing=params.closing)


def largest_region(foreground, *, closing: int = 0) -> np.ndarray:
    """The largest connected region of each mask of ``foreground (T, H, W)`` bool, after a
    closing with a disc of radius ``closing`` (pixels), with its holes filled."""
    fg = np.asarray(foreground, bool)
    if fg.ndim != 3:
        raise ValueError(f"foreground: expected (T, H, W) masks, got shape {fg.shape}")
    r = int(closing)
    disc = None
    if r:
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        disc = xx * xx + yy * yy <= r * r
    out = np.zeros(fg.shape, bool)
    for t, m in enumerate(fg):
        if disc is not None:
            m = ndimage.binary_closing(m, structure=disc, border_value=0)
        lab, n = ndimage.label(m)
        if n == 0:
            continue
        sizes = np.bincount(lab.ravel())[1:]
        out[t] = ndimage.binary_fill_holes(lab == 1 + int(np.argmax(sizes)))
    return out
