"""The sub-sampled, windowed LED search of one frame (Davis 2002, §3.3, Fig. 32), compiled.

Per frame: every pixel of a ``window`` x ``window`` square around each predicted position,
and a grid jittered anew every frame (``params.grid``: one pixel per ``k`` x ``k`` block, or
every pixel of one row in ``k``), is compared with its threshold. A pixel over its
threshold starts a flood fill (8-connected, over the pixels over threshold), so each LED
spot that has at least one tested pixel is found whole: its intensity-weighted centroid
and its area are exactly those of the full search (:func:`lsmta.widearea.detect` with
``mode="full"``; OpenCV's connected components), up to the order of the floating-point
sums. Pixels are tested once each and counted: the count is the grid's, the windows' and
the flood fills' pixels, not the pixels read (a grid row is first compared whole in one
contiguous pass, which is not counted for the point grid; the row grid tests those pixels,
so it finds a new spot ``h`` rows tall with probability ``min(h / k, 1)`` per frame,
instead of about ``area / k**2``, for about the same time).

The loop over windows, grid and flood fill is compiled (:mod:`lsmta.widearea._kernels`)
and called once per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_rng
from ._kernels import search_kernel
from .detection import DetectionParams, Threshold, _test_threshold, _valid_mask


@dataclass(frozen=True, eq=False)
class SearchSetup:
    """One camera's thresholds prepared for :func:`search_frame` (built once, used for
    every frame; see :func:`search_setup`).

    Attributes
    ----------
    threshold : (H, W) array
        The value every pixel is compared with (``inf`` / out of range at invalid
        pixels; integer for integer images).
    background : (H, W) float array
        The background the centroid weights are measured from.
    params : DetectionParams
    dtype : numpy dtype
        The frames' dtype the threshold was prepared for.
    """

    threshold: np.ndarray
    background: np.ndarray
    params: DetectionParams
    dtype: np.dtype


@dataclass(frozen=True)
class FrameFeatures:
    """Features found in one frame.

    Attributes
    ----------
    xy : (n, 2) array
        Intensity centroids, px.
    area : (n,) int array
        Pixels per feature.
    tested : int
        Pixels the search decides on (grid, windows, flood fills; each once), not the pixels
        read: the contiguous pass that first compares each grid row whole is not counted.
    """

    xy: np.ndarray
    area: np.ndarray
    tested: int


def search_setup(threshold: Threshold, *, invalid=None, dtype=np.uint8,
                 params: DetectionParams | None = None) -> SearchSetup:
    """Prepare one camera's thresholds for :func:`search_frame`.

    Parameters
    ----------
    threshold : Threshold
    invalid : (H, W) bool array, optional
        Pixels never reported.
    dtype : numpy dtype
        The dtype of the frames that will be searched (uint8 for 8-bit video).
    params : DetectionParams, optional
    """
    if not isinstance(threshold, Threshold):
        raise TypeError("threshold: expected an lsmta.widearea.Threshold")
    H, W = threshold.threshold.shape
    valid = _valid_mask(invalid, (H, W))
    dtype = np.dtype(dtype)
    if not (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)):
        raise TypeError(f"dtype: expected a real numeric image dtype, got {dtype}")
    p = DetectionParams() if params is None else params
    if not isinstance(p, DetectionParams):
        raise TypeError("params: expected an lsmta.widearea.DetectionParams")
    # writable arrays of its own (numba's dispatcher types read-only arrays slowly); no
    # function writes into them
    thr = np.array(_test_threshold(threshold, valid, dtype), order="C")
    bg = np.array(threshold.background, float, order="C")
    return SearchSetup(threshold=thr, background=bg, params=p, dtype=dtype)


def search_frame(frame, setup: SearchSetup, *, windows=None, half_sizes=None,
                 rng: np.random.Generator | int | None = None, full: bool = False,
                 jitter=None) -> FrameFeatures:
    """Search one frame: windows around ``windows`` plus the jittered grid (see the module).

    Parameters
    ----------
    frame : (H, W) array
        Grey image of the dtype ``setup`` was prepared for.
    setup : SearchSetup
    windows : (n, 2) array, optional
        Predicted positions (x, y), px; non-finite rows are ignored.
    half_sizes : (n,) array, optional
        Half the side of each window, px (rounded up; finite and at least 1 where the
        position is finite): for example the tracker's gate plus
        the spot's radius (:meth:`lsmta.widearea.ImagePrediction.windows`). Default: half
        of ``params.window`` (the thesis's 40 x 40) for every window.
    rng : numpy.random.Generator, int or None
        Draws the grid's jitter (row, column offsets in ``[0, k)``).
    full : bool
        Test every pixel (the same compiled loop with ``k = 1``), for comparison.
    jitter : (int, int), optional
        The grid's offsets, instead of drawing them (with ``params.grid == "rows"`` the
        column offset is not used).

    Returns
    -------
    FrameFeatures
    """
    if not isinstance(setup, SearchSetup):
        raise TypeError("setup: expected a SearchSetup (see search_setup)")
    img = np.ascontiguousarray(frame)
    if img.shape != setup.threshold.shape:
        raise ValueError(f"frame: expected an image of shape {setup.threshold.shape}, got "
                         f"{img.shape}")
    if img.dtype != setup.dtype:
        raise TypeError(f"frame: expected dtype {setup.dtype} (as prepared), got {img.dtype}")
    p = setup.params
    k = 1 if full else p.k
    if jitter is None:
        jr, jc = (0, 0) if k == 1 else (int(u * k) for u in as_rng(rng).random(2))
    else:
        jr, jc = jitter
        if not (0 <= jr < k and 0 <= jc < k):
            raise ValueError(f"jitter: expected two offsets in [0, {k}), got {jitter}")
    centres = np.zeros((0, 2)) if windows is None else np.ascontiguousarray(windows, float)
    if centres.ndim != 2 or centres.shape[1] != 2:
        raise ValueError(f"windows: expected an (n, 2) array of positions, got shape "
                         f"{centres.shape}")
    if half_sizes is None:                 # windows narrower than 2 px: none
        centres = centres if p.window >= 2 else np.zeros((0, 2))
        half = np.full(len(centres), float(p.window // 2))
    else:
        half = np.asarray(half_sizes, float)          # >= 1: checked by the kernel
        if half.shape != (len(centres),):
            raise ValueError(f"half_sizes: expected {len(centres)} sizes (px), got shape "
                             f"{half.shape}")
    kc = 1 if full else p.column_step          # "rows": every pixel of a grid row
    xy, area, tested = search_kernel(img, setup.threshold, setup.background, centres,
                                     half, k, kc, int(jr), int(jc), p.min_area, p.max_area)
    return FrameFeatures(xy=xy, area=area, tested=int(tested))

