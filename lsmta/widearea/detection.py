"""LED feature detection in camera images (Davis 2002, §3.3).

* **Thresholds.** Per pixel, the maximum background intensity seen over a set of frames
  without LEDs, plus an additive offset, and never below a minimum
  (:func:`background_threshold`). When many pixels exceed their thresholds at once, the
  lighting has changed and the thresholds are recomputed (:func:`needs_new_threshold`)
  from the next frames, with small bright spots (LEDs) replaced by the local background
  (:func:`relearn_threshold`, SciPy's grey opening). Instead of a fixed offset and floor,
  the offset can come from the images: ``k`` times the image noise measured in the empty
  room's frames (:func:`noise_threshold`, :func:`lsmta.noise.temporal_noise`), so that an
  LED only a little brighter than a dark background is found.
* **Invalid regions.** A boolean mask of pixels never to report (monitors, lamps).
* **Features.** Pixels above threshold are grouped into 8-connected components (OpenCV's
  ``connectedComponents``, once per frame on the image of the pixels found); each
  component's centroid is weighted by its intensity above the background (``bincount``
  over those pixels only).
* **Sub-sampled search.** Instead of every pixel, test one pixel per ``k x k`` block on a
  grid jittered anew every frame (or every pixel of one row in ``k``:
  ``DetectionParams(grid="rows")``), plus every pixel of a window around each predicted
  position; a hit starts a flood fill over the pixels over threshold, so its whole spot is
  found (:func:`detect` with ``mode="subsampled"``; the compiled loop of
  :mod:`lsmta.widearea._kernels`, one frame at a time through
  :func:`lsmta.widearea.search_frame` when a tracker's predictions place the windows).
  The pixels tested are counted so the saving can be measured (:func:`search_mask` draws
  the grid and windows, Fig. 32).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from .._validate import as_int, as_rng, as_scalar
from ..noise import temporal_noise
from ._kernels import search_kernel

GRIDS = ("points", "rows")     # the sub-sampled search's grids (DetectionParams.grid)


@dataclass(frozen=True)
class Threshold:
    """Per-pixel detection thresholds.

    Attributes
    ----------
    background : (H, W) array
        Maximum background intensity per pixel.
    threshold : (H, W) array
        ``max(background + offset, minimum)``.
    """

    background: np.ndarray
    threshold: np.ndarray


@dataclass(frozen=True)
class DetectionParams:
    """Settings of the detector (intensities in grey levels, sizes in pixels).

    Attributes
    ----------
    k : int
        Sub-sampling: one tested pixel per ``k x k`` block (thesis: 5).
    window : int
        Side of the fully searched window around a predicted position (thesis: 40).
    min_area : int
        Smallest component reported, pixels.
    max_area : int
        Largest component reported (bigger blobs are not LEDs), pixels.
    grid : {"points", "rows"}
        The sub-sampled search's grid: ``"points"``, one pixel per ``k x k`` block (thesis,
        Fig. 32); ``"rows"``, every pixel of one row in ``k``. The compiled search compares
        each grid row whole anyway (one contiguous pass), so ``"rows"`` costs about the same
        time, and a spot ``h`` rows tall is hit with probability ``min(h / k, 1)`` per frame
        instead of about ``area / k**2``.
    """

    k: int = 5
    window: int = 40
    min_area: int = 1
    max_area: int = 400
    grid: str = "points"

    def __post_init__(self):
        for key in ("k", "window", "min_area", "max_area"):
            as_int(getattr(self, key), key)
        if self.grid not in GRIDS:
            raise ValueError(f"grid: expected one of {GRIDS}, got {self.grid!r}")

    @property
    def column_step(self) -> int:
        """Columns between the grid's pixels in a grid row (``k``, or 1 for ``"rows"``)."""
        return 1 if self.grid == "rows" else self.k


@dataclass(frozen=True)
class Detections:
    """Features found in ``T`` frames.

    Attributes
    ----------
    start : (T + 1,) int array
        Frame ``t`` holds features ``start[t]:start[t + 1]``.
    xy : (M, 2) array
        Intensity centroids in pixels.
    area : (M,) int array
        Pixels per feature.
    tested : (T,) int array
        Pixels compared with their threshold in each frame.
    """

    start: np.ndarray
    xy: np.ndarray
    area: np.ndarray
    tested: np.ndarray

    def centroids(self, t: int) -> np.ndarray:
        """The ``(n, 2)`` centroids of frame ``t``."""
        return self.xy[self.start[t]:self.start[t + 1]]


def _frames(frames, name="frames") -> np.ndarray:
    arr = np.asarray(frames)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"{name}: expected grey images of shape (T, H, W) or (H, W), "
                         f"got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise TypeError(f"{name}: expected a real numeric image, got dtype {arr.dtype}")
    return arr


def background_threshold(frames, offset: float, minimum: float, *, exclude=None) -> Threshold:
    """Thresholds from frames of the background.

    Parameters
    ----------
    frames : (T, H, W) array
        Frames without LEDs (or with ``exclude`` masking them).
    offset : float
        Added to the per-pixel maximum, grey levels.
    minimum : float
        No threshold below this, grey levels.
    exclude : (T, H, W) bool array, optional
        Pixels to leave out of the maximum (e.g. features found in those frames).
    """
    f = _frames(frames)
    offset = as_scalar(offset, "offset", nonnegative=True)
    minimum = as_scalar(minimum, "minimum")
    bg = _background_max(f, exclude)
    bg = np.where(np.isfinite(bg), bg, minimum - offset)
    return Threshold(background=bg, threshold=np.maximum(bg + offset, minimum))


def _background_max(f, exclude) -> np.ndarray:
    """Per-pixel maximum of the frames ``f`` over those not ``exclude``d (-inf if none)."""
    g = f.astype(float)
    if exclude is not None:
        ex = np.asarray(exclude, bool)
        if ex.shape != f.shape:
            raise ValueError(f"exclude: expected shape {f.shape}, got {ex.shape}")
        g = np.where(ex, -np.inf, g)
    return g.max(axis=0)


def noise_threshold(frames, *, sigmas: float = 5.0, exclude=None) -> Threshold:
    """Thresholds from frames of the background, with the offset measured in them.

    ``threshold = max over the frames + sigmas * sigma`` per pixel, where ``sigma`` is the
    image noise of the frames (:func:`lsmta.noise.temporal_noise`, from differences of
    consecutive frames) and there is no floor: a pixel over a dark background needs only
    a few noise levels more than the background ever showed, so a dim LED is found, while
    with ``sigmas`` 4 to 5 a pixel of noise alone rarely passes (the maximum of the
    frames is already about two sigmas above the mean).

    Parameters
    ----------
    frames : (T, H, W) array
        Frames of the empty room, T >= 2.
    sigmas : float
        The offset in units of the measured noise (> 0).
    exclude : (T, H, W) bool array, optional
        As in :func:`background_threshold`.

    Returns
    -------
    Threshold
    """
    f = _frames(frames)
    sigmas = as_scalar(sigmas, "sigmas", positive=True)
    if len(f) < 2:
        raise ValueError(f"frames: expected at least 2 frames to measure the noise, got {len(f)}")
    offset = sigmas * temporal_noise(f).sigma
    bg = _background_max(f, exclude)
    # a pixel excluded in every frame: the brightest background seen anywhere
    bg = np.where(np.isfinite(bg), bg, float(np.max(f)))
    return Threshold(background=bg, threshold=bg + offset)


def needs_new_threshold(frame, threshold: Threshold, *, fraction: float = 0.01) -> bool:
    """True when more than ``fraction`` of the pixels exceed their thresholds (a lighting
    change, not LEDs)."""
    f = _frames(frame, "frame")
    if f.shape[1:] != threshold.threshold.shape:
        raise ValueError("frame: expected the image size of the threshold")
    return bool((f > threshold.threshold).mean() > as_scalar(fraction, "fraction"))


def relearn_threshold(frames, offset: float, minimum: float, *, spot_px: int = 7,
                      spot_level: float = 20.0, grow_px: int = 2) -> Threshold:
    """Thresholds relearnt from frames that may contain LEDs (after a lighting change).

    In each frame, small bright spots are replaced by the local background before the
    maximum is taken, so that an LED in view does not become part of the background: a grey
    opening (``scipy.ndimage.grey_opening``, ``spot_px`` x ``spot_px``) removes spots
    narrower than ``spot_px``; pixels more than ``spot_level`` above the opened image, grown
    by ``grow_px`` pixels, take the opened value. Larger bright areas (a lamp) are kept.

    Parameters
    ----------
    frames : (T, H, W) or (H, W) array
        Frames taken after the change, grey levels.
    offset, minimum : float
        As in :func:`background_threshold`, grey levels.
    spot_px : int
        Width of the opening, px (odd, >= 3).
    spot_level : float
        How far above the opened image a pixel must be to count as a spot, grey levels.
    grow_px : int
        Dilation of the spots, px.

    Returns
    -------
    Threshold
    """
    f = _frames(frames).astype(float)
    spot_level = as_scalar(spot_level, "spot_level", nonnegative=True)
    spot_px = as_int(spot_px, "spot_px", minimum=3, unit="pixels")
    grow_px = as_int(grow_px, "grow_px", minimum=0, unit="pixels")
    opened = np.stack([ndimage.grey_opening(x, size=(spot_px,) * 2) for x in f])
    spot = f - opened > spot_level
    if grow_px:
        spot = np.stack([ndimage.binary_dilation(m, iterations=grow_px) for m in spot])
    return background_threshold(np.where(spot, opened, f), offset, minimum)


def search_mask(shape, k: int, jitter, *, windows=None, window: int = 40,
                grid: str = "points") -> np.ndarray:
    """Pixels the sub-sampled search tests in one frame, ``(H, W)`` bool.

    Parameters
    ----------
    shape : (int, int)
        Image height and width.
    k : int
        One pixel per ``k x k`` block.
    jitter : (int, int)
        Row and column offset of the grid in ``[0, k)``.
    windows : (n, 2) array, optional
        Predicted positions (x, y) in pixels; a ``window`` x ``window`` square around each is
        searched fully (rows and columns ``y - window // 2`` to ``y + window // 2 - 1``).
    window : int
    grid : {"points", "rows"}
        As :attr:`DetectionParams.grid` (``"rows"``: the column offset is not used).
    """
    H, W = shape
    if grid not in GRIDS:
        raise ValueError(f"grid: expected one of {GRIDS}, got {grid!r}")
    m = np.zeros((H, W), bool)
    if grid == "rows":
        m[int(jitter[0])::k] = True
    else:
        m[int(jitter[0])::k, int(jitter[1])::k] = True
    _add_windows(m, windows, window)
    return m


def _add_windows(m, centres, window: int) -> int:
    """Mark ``window`` x ``window`` squares around the finite ``centres`` (x, y) in the
    ``(H, W)`` bool image ``m`` (in place); returns how many were marked."""
    if centres is None:
        return 0
    H, W = m.shape
    c = np.asarray(centres, float).reshape(-1, 2)
    c = c[np.isfinite(c).all(axis=1)]
    half = window // 2
    for x, y in np.rint(c).astype(np.int64).tolist():   # a handful of windows per frame
        r0, c0 = y - half, x - half
        m[max(r0, 0):max(y + half, 0), max(c0, 0):max(x + half, 0)] = True
    return len(c)


def _features(img, bg, sel, H, W):
    """Centroids (x, y), weighted by intensity above ``bg``, and areas of the 8-connected
    components of the pixels ``sel`` (flat indices into an ``(H, W)`` image)."""
    r, c = np.divmod(sel, W)
    r0, c0 = r.min(), c.min()
    on = np.zeros((r.max() - r0 + 1, c.max() - c0 + 1), np.uint8)   # the pixels' bounding box
    on[r - r0, c - c0] = 1
    n, lab = cv2.connectedComponents(on, connectivity=8, ltype=cv2.CV_32S)
    lab = lab[r - r0, c - c0]
    w = np.clip(img.reshape(-1)[sel] - bg.reshape(-1)[sel], 0, None) + 1e-9
    sw = np.bincount(lab, w, n)[1:]
    xy = np.stack([np.bincount(lab, w * c, n)[1:] / sw,
                   np.bincount(lab, w * r, n)[1:] / sw], axis=1)
    return xy, np.bincount(lab, None, n)[1:].astype(np.int64)


def detect(frames, threshold: Threshold, *, params: DetectionParams | None = None,
           rng: np.random.Generator | int | None = None, invalid=None, mode: str = "full",
           predicted=None) -> Detections:
    """Find LED features in a batch of frames.

    Parameters
    ----------
    frames : (T, H, W) array
        Grey images.
    threshold : Threshold
    params : DetectionParams, optional
    rng : numpy.random.Generator, int or None
        Jitter of the grid (``"subsampled"`` only).
    invalid : (H, W) bool array, optional
        Pixels never reported (masked regions).
    mode : {"full", "subsampled"}
        Test every pixel, or the jittered grid plus windows around ``predicted``.
    predicted : sequence of T arrays (n_t, 2), or "previous", optional
        Predicted positions (x, y) per frame, for the windows of the sub-sampled search;
        ``"previous"`` uses the features found in the previous frame (the thesis's simplest
        prediction).

    Returns
    -------
    Detections
    """
    f = _frames(frames)
    T, H, W = f.shape
    p = DetectionParams() if params is None else params
    if not isinstance(threshold, Threshold) or threshold.threshold.shape != (H, W):
        raise ValueError("threshold: expected a Threshold of the frames' image size")
    valid = _valid_mask(invalid, (H, W))
    if mode not in ("full", "subsampled"):
        raise ValueError(f"mode: expected 'full' or 'subsampled', got {mode!r}")
    previous = isinstance(predicted, str) and predicted == "previous"
    if mode == "subsampled":
        if isinstance(predicted, str) and not previous:
            raise ValueError(f"predicted: expected position arrays or 'previous', "
                             f"got {predicted!r}")
        if predicted is not None and not previous and len(predicted) != T:
            raise ValueError(f"predicted: expected one array of positions per frame ({T})")
    found = _Found(frames=f, background=np.ascontiguousarray(threshold.background, float),
                   thr=np.ascontiguousarray(_test_threshold(threshold, valid, f.dtype)), p=p)
    if mode == "full":
        for t in range(T):
            found.keep(t, np.flatnonzero(found.frames[t] > found.thr), H * W)
    else:
        _search_subsampled(found, as_rng(rng), predicted, previous)
    return found.result()


def _test_threshold(threshold: Threshold, valid, dtype) -> np.ndarray:
    """The threshold every pixel is compared with: ``inf`` at invalid pixels (so one
    comparison does both tests); for integer images floored into the images' integer
    range (``value > thr  <=>  value > floor(thr)``), so the comparison is in integers."""
    thr = np.where(valid, np.asarray(threshold.threshold, float), np.inf)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        thr = np.clip(np.floor(np.minimum(thr, info.max)), info.min - 1, info.max)
        # the images' own type when no threshold lies below their range (half the memory
        # of the next wider type: the sparse searches read it pixel by pixel)
        out = dtype if thr.min() >= info.min else (
            np.int16 if info.bits <= 8 else np.int32 if info.bits <= 16 else np.int64)
        thr = thr.astype(out)
    return thr


@dataclass
class _Found:
    """The frames, their test threshold, and the features found so far (frame by frame)."""

    frames: np.ndarray
    background: np.ndarray
    thr: np.ndarray
    p: DetectionParams
    xy: list = field(default_factory=list)
    area: list = field(default_factory=list)
    start: list = field(default_factory=lambda: [0])
    tested: list = field(default_factory=list)

    def keep(self, t: int, sel, tested: int) -> None:
        """Record frame ``t``: the features of the pixels ``sel`` (flat indices over
        threshold) within the area limits, and the number of pixels tested."""
        H, W = self.thr.shape
        if len(sel):
            xy, area = _features(self.frames[t], self.background, sel, H, W)
        else:
            xy, area = np.zeros((0, 2)), np.zeros(0, np.int64)
        self.add(xy, area, tested)

    def add(self, xy, area, tested: int) -> None:
        """Record the next frame's components within the area limits."""
        ok = (area >= self.p.min_area) & (area <= self.p.max_area)
        self.xy.append(xy[ok])
        self.area.append(area[ok])
        self.start.append(self.start[-1] + int(ok.sum()))
        self.tested.append(tested)

    def result(self) -> Detections:
        return Detections(start=np.asarray(self.start, np.int64),
                          xy=np.concatenate(self.xy) if self.xy else np.zeros((0, 2)),
                          area=np.concatenate(self.area).astype(np.int64) if self.area
                          else np.zeros(0, np.int64),
                          tested=np.asarray(self.tested, np.int64))


def _search_subsampled(found: _Found, rng, predicted, previous: bool) -> None:
    """The jittered grid plus windows around the predicted positions, frame by frame (the
    compiled search of :mod:`lsmta.widearea._kernels`)."""
    f, p = found.frames, found.p
    T = len(f)
    jit = rng.integers(0, p.k, (T, 2))     # "rows": the kernel ignores the column offset
    for t in range(T):
        centres = ((found.xy[-1] if found.xy else None) if previous
                   else None if predicted is None else predicted[t])
        c = (np.zeros((0, 2)) if centres is None or p.window < 2    # narrower than 2 px: none
             else np.asarray(centres, float).reshape(-1, 2))
        half = np.full(len(c), float(p.window // 2))
        xy, area, tested = search_kernel(np.ascontiguousarray(f[t]), found.thr,
                                         found.background, c, half, p.k, p.column_step,
                                         int(jit[t, 0]), int(jit[t, 1]), p.min_area,
                                         p.max_area)
        found.add(xy, area, int(tested))


def _valid_mask(invalid, shape) -> np.ndarray:
    """The pixels to report: the complement of the boolean mask ``invalid`` (or all)."""
    if invalid is None:
        return np.ones(shape, bool)
    inv = np.asarray(invalid)
    if inv.shape != tuple(shape) or inv.dtype != bool:
        raise ValueError(f"invalid: expected a boolean mask of shape {tuple(shape)}")
    return ~inv
