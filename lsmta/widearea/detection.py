"""LED feature detection in camera images (Davis 2002, §3.3).

* **Thresholds.** Per pixel, the maximum background intensity seen over a set of frames
  without LEDs, plus an additive offset, and never below a minimum
  (:func:`background_threshold`). When many pixels exceed their thresholds at once, the
  lighting has changed and the thresholds are recomputed (:func:`needs_new_threshold`).
* **Invalid regions.** A boolean mask of pixels never to report (monitors, lamps).
* **Features.** Pixels above threshold are grouped into 8-connected components (OpenCV's
  ``connectedComponents`` for a whole frame, ``scipy.ndimage.label`` in the small crops of
  the sub-sampled search); each component's centroid is weighted by its intensity above
  the background.
* **Sub-sampled search.** Instead of every pixel, test one pixel per ``k x k`` block on a
  grid jittered anew every frame, plus every pixel of a window around each predicted
  position; a hit on the grid is grown in a small neighbourhood to find its whole spot
  (:func:`detect` with ``mode="subsampled"``). The pixels tested are counted so the saving
  can be measured (:func:`search_mask` draws them, Fig. 32).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from .._validate import as_rng, as_scalar

_STRUCTURE_2D = np.ones((3, 3), bool)     # 8-connected


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
    grow : int
        Half-size of the neighbourhood searched around a grid hit.
    min_area : int
        Smallest component reported, pixels.
    max_area : int
        Largest component reported (bigger blobs are not LEDs), pixels.
    """

    k: int = 5
    window: int = 40
    grow: int = 5
    min_area: int = 1
    max_area: int = 400

    def __post_init__(self):
        for key in ("k", "window", "grow", "min_area", "max_area"):
            v = getattr(self, key)
            if int(v) != v or v < 1:
                raise ValueError(f"{key}: expected a positive integer, got {v}")


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
    f = _frames(frames).astype(float)
    offset = as_scalar(offset, "offset", nonnegative=True)
    minimum = as_scalar(minimum, "minimum")
    if exclude is not None:
        ex = np.asarray(exclude, bool)
        if ex.shape != f.shape:
            raise ValueError(f"exclude: expected shape {f.shape}, got {ex.shape}")
        f = np.where(ex, -np.inf, f)
    bg = f.max(axis=0)
    bg = np.where(np.isfinite(bg), bg, minimum - offset)
    return Threshold(background=bg, threshold=np.maximum(bg + offset, minimum))


def needs_new_threshold(frame, threshold: Threshold, fraction: float = 0.01) -> bool:
    """True when more than ``fraction`` of the pixels exceed their thresholds (a lighting
    change, not LEDs)."""
    f = _frames(frame, "frame")
    if f.shape[1:] != threshold.threshold.shape:
        raise ValueError("frame: expected the image size of the threshold")
    return bool((f > threshold.threshold).mean() > as_scalar(fraction, "fraction"))


def search_mask(shape, k: int, jitter, windows=None, window: int = 40) -> np.ndarray:
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
        searched fully.
    window : int
    """
    H, W = shape
    m = np.zeros((H, W), bool)
    m[int(jitter[0])::k, int(jitter[1])::k] = True
    if windows is not None:
        for x, y in np.asarray(windows, float).reshape(-1, 2):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            r0, c0 = int(round(y)) - window // 2, int(round(x)) - window // 2
            m[max(r0, 0):max(r0 + window, 0), max(c0, 0):max(c0 + window, 0)] = True
    return m


def _components(weights, mask, params, offset_rc=(0, 0)):
    """Centroids (x, y) and areas of the 8-connected components of a 2-D ``mask``."""
    lab, n = ndimage.label(mask, structure=_STRUCTURE_2D)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64), lab
    idx = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(weights), lab, idx).astype(np.int64)
    com = np.array(ndimage.center_of_mass(weights + 1e-9 * mask, lab, idx)).reshape(-1, 2)
    xy = com[:, ::-1] + np.array([offset_rc[1], offset_rc[0]])
    return xy, area, lab


def detect(frames, threshold: Threshold, params: DetectionParams | None = None, *,
           invalid=None, mode: str = "full", predicted=None,
           rng: np.random.Generator | None = None) -> Detections:
    """Find LED features in a batch of frames.

    Parameters
    ----------
    frames : (T, H, W) array
        Grey images.
    threshold : Threshold
    params : DetectionParams, optional
    invalid : (H, W) bool array, optional
        Pixels never reported (masked regions).
    mode : {"full", "subsampled"}
        Test every pixel, or the jittered grid plus windows around ``predicted``.
    predicted : sequence of T arrays (n_t, 2), or "previous", optional
        Predicted positions (x, y) per frame, for the windows of the sub-sampled search;
        ``"previous"`` uses the features found in the previous frame (the thesis's simplest
        prediction).
    rng : numpy.random.Generator
        Jitter of the grid (required for ``"subsampled"``).

    Returns
    -------
    Detections
    """
    f = _frames(frames)
    T, H, W = f.shape
    p = DetectionParams() if params is None else params
    if not isinstance(threshold, Threshold) or threshold.threshold.shape != (H, W):
        raise ValueError("threshold: expected a Threshold of the frames' image size")
    valid = np.ones((H, W), bool)
    if invalid is not None:
        inv = np.asarray(invalid)
        if inv.shape != (H, W) or inv.dtype != bool:
            raise ValueError(f"invalid: expected a boolean mask of shape {(H, W)}")
        valid = ~inv
    if mode not in ("full", "subsampled"):
        raise ValueError(f"mode: expected 'full' or 'subsampled', got {mode!r}")
    thr, bg = threshold.threshold, threshold.background
    if mode == "full":
        xy_all, area_all, start = [], [], [0]
        ramp_x, ramp_y = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
        for t in range(T):
            mask = ((f[t] > thr) & valid).astype(np.uint8)
            n, lab = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
            if n > 1:
                lab = lab.ravel()
                w = np.clip(f[t] - bg, 0, None).ravel() + 1e-9
                sw = np.bincount(lab, w, n)[1:]
                sx = np.bincount(lab, w * ramp_x.ravel(), n)[1:]
                sy = np.bincount(lab, w * ramp_y.ravel(), n)[1:]
                area = np.bincount(lab, None, n)[1:].astype(np.int64)
                xy = np.stack([sx / sw, sy / sw], axis=1)
                ok = (area >= p.min_area) & (area <= p.max_area)
                xy, area = xy[ok], area[ok]
            else:
                xy, area = np.zeros((0, 2)), np.zeros(0, np.int64)
            xy_all.append(xy)
            area_all.append(area)
            start.append(start[-1] + len(xy))
        return Detections(start=np.asarray(start, np.int64), xy=np.concatenate(xy_all),
                          area=np.concatenate(area_all).astype(np.int64),
                          tested=np.full(T, H * W, np.int64))
    rng = as_rng(rng)
    previous = isinstance(predicted, str) and predicted == "previous"
    if isinstance(predicted, str) and not previous:
        raise ValueError(f"predicted: expected position arrays or 'previous', got {predicted!r}")
    if predicted is not None and not previous and len(predicted) != T:
        raise ValueError(f"predicted: expected one array of positions per frame ({T})")
    xy_all, area_all, start, tested = [], [], [0], []
    k, g = p.k, p.grow
    for t in range(T):
        img = f[t]
        jr, jc = rng.integers(0, k, 2)
        rows = np.arange(jr, H, k)
        cols = np.arange(jc, W, k)
        n_test = len(rows) * len(cols)
        hit = (img[np.ix_(rows, cols)] > thr[np.ix_(rows, cols)]) & valid[np.ix_(rows, cols)]
        boxes = [(int(rows[i]) - g, int(cols[j]) - g, 2 * g + 1)
                 for i, j in zip(*np.nonzero(hit))]
        centres = (xy_all[-1] if previous and xy_all else np.zeros((0, 2))) if previous else (
            None if predicted is None else predicted[t])
        if centres is not None:
            for x, y in np.asarray(centres, float).reshape(-1, 2):
                if np.isfinite(x) and np.isfinite(y):
                    boxes.append((int(round(y)) - p.window // 2, int(round(x)) - p.window // 2,
                                  p.window))
        seen = np.zeros((H, W), bool)
        found_xy, found_area = [], []
        for r0, c0, size in boxes:
            r0c, c0c = max(r0, 0), max(c0, 0)
            r1, c1 = min(r0 + size, H), min(c0 + size, W)
            if r1 <= r0c or c1 <= c0c:
                continue
            n_test += int((~seen[r0c:r1, c0c:c1]).sum())
            seen[r0c:r1, c0c:c1] = True
            crop = img[r0c:r1, c0c:c1].astype(float)
            m = (crop > thr[r0c:r1, c0c:c1]) & valid[r0c:r1, c0c:c1]
            if not m.any():
                continue
            xy, area, _ = _components(np.clip(crop - bg[r0c:r1, c0c:c1], 0, None), m, p,
                                      (r0c, c0c))
            found_xy.append(xy)
            found_area.append(area)
        if found_xy:
            xy = np.concatenate(found_xy)
            area = np.concatenate(found_area)
            # one spot reached from several grid hits or windows: keep the largest view of it
            order = np.argsort(-area, kind="stable")
            xy, area = xy[order], area[order]
            d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
            dup = np.triu(d < 2.0, k=1).any(axis=0)
            xy, area = xy[~dup], area[~dup]
            ok = (area >= p.min_area) & (area <= p.max_area)
            xy, area = xy[ok], area[ok]
        else:
            xy, area = np.zeros((0, 2)), np.zeros(0, np.int64)
        xy_all.append(xy)
        area_all.append(area)
        start.append(start[-1] + len(xy))
        tested.append(n_test)
    return Detections(start=np.asarray(start, np.int64),
                      xy=np.concatenate(xy_all) if xy_all else np.zeros((0, 2)),
                      area=np.concatenate(area_all).astype(np.int64) if area_all
                      else np.zeros(0, np.int64),
                      tested=np.asarray(tested, np.int64))
