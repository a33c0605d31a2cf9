"""The matchers a user would pick instead of LSM, behind LSM's call signature.

Each function takes ``(template, search, template_xy, search_xy, patch=...)`` like
:func:`~lsmta.matching.lsm` and returns a :class:`PeerResult`, so that all methods are
compared on the same patches and the same starting positions:

- :func:`ecc` — OpenCV ``findTransformECC`` (enhanced correlation coefficient; affine or
  translation), called per point on the template patch and a search window;
- :func:`klt` — OpenCV ``calcOpticalFlowPyrLK`` (pyramidal Lucas-Kanade, translation),
  batched by OpenCV itself; needs 8-bit images;
- :func:`phase_correlation` — scikit-image ``phase_cross_correlation`` (translation, with
  up-sampled sub-pixel refinement), per point;
- :func:`ilk` — scikit-image ``optical_flow_ilk`` (iterative Lucas-Kanade, translation),
  per point on small windows, read at the window centre.

Template centres are rounded to whole pixels (the peers cut patches from the pixel grid).

Dense stereo peers: :func:`sgbm` (semi-global matching on a pair rectified from calibrated
cameras, triangulated), and for an already rectified pair :func:`stereo_sgbm` (with and
without its usual post-filters) and :func:`stereo_bm` (block matching).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
from skimage.registration import optical_flow_ilk, phase_cross_correlation

from .._validate import as_point_pairs, check_patch
from .spline import check_image


@dataclass(frozen=True)
class PeerResult:
    """``xy`` (N, 2) matched positions (NaN where the method failed); ``ok`` (N,) bool."""

    xy: np.ndarray
    ok: np.ndarray


def _prepare(template, search, template_xy, search_xy, patch, margin):
    patch = check_patch(patch)
    f = check_image(template, "template")
    g = check_image(search, "search")
    t, s = as_point_pairs(template_xy, search_xy, "template_xy", "search_xy")
    t = np.rint(t).astype(np.int64)
    h = patch // 2
    c = np.rint(s).astype(np.int64)
    r = h + margin

    def fits(xy, shape, reach):
        return ((xy[:, 0] >= reach) & (xy[:, 0] < shape[1] - reach)
                & (xy[:, 1] >= reach) & (xy[:, 1] < shape[0] - reach))

    usable = fits(t, f.shape, r) & fits(c, g.shape, r)
    return f, g, t, s, c, h, usable


def ecc(template, search, template_xy, search_xy, *, patch: int = 13, motion: str = "affine",
        margin: int = 6, max_iter: int = 50, eps: float = 1e-4,
        gauss_filt_size: int = 1) -> PeerResult:
    """OpenCV's enhanced correlation coefficient maximisation, per point.

    The template patch is aligned inside a search window of ``patch + 2 * margin`` pixels
    around the rounded start; ``motion`` is ``"affine"`` or ``"translation"``.
    ``gauss_filt_size`` is OpenCV's Gaussian pre-smoothing; we use 1 (none) because
    OpenCV's default of 5 triples the median error on 13 x 13 patches of fine texture
    (0.09 px instead of 0.03 px at noise 2, measured here).
    """
    kind = {"affine": cv2.MOTION_AFFINE, "translation": cv2.MOTION_TRANSLATION}
    if motion not in kind:
        raise ValueError(f"motion: expected 'affine' or 'translation', got {motion!r}")
    f, g, t, s, c, h, usable = _prepare(template, search, template_xy, search_xy, patch, margin)
    f32, g32 = f.astype(np.float32), g.astype(np.float32)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, max_iter, eps)
    xy = np.full((len(t), 2), np.nan)
    r = h + margin
    for i in np.flatnonzero(usable):
        T = f32[t[i, 1] - h:t[i, 1] + h + 1, t[i, 0] - h:t[i, 0] + h + 1]
        x0, y0 = c[i, 0] - r, c[i, 1] - r
        window = g32[y0:c[i, 1] + r + 1, x0:c[i, 0] + r + 1]
        W = np.array([[1, 0, s[i, 0] - h - x0], [0, 1, s[i, 1] - h - y0]], np.float32)
        try:
            _, W = cv2.findTransformECC(T, window, W, kind[motion], crit, None, gauss_filt_size)
        except cv2.error:
            continue
        xy[i] = W @ np.array([h, h, 1.0]) + (x0, y0)
    return PeerResult(xy, np.isfinite(xy).all(axis=1))


def klt(template, search, template_xy, search_xy, *, patch: int = 13, levels: int = 0,
        max_iter: int = 50, eps: float = 1e-3) -> PeerResult:
    """OpenCV's pyramidal Lucas-Kanade, all points in one call.

    Images are converted to 8 bits (rounded and clipped), as OpenCV requires; ``levels`` is
    the number of pyramid levels above the original (0: none).
    """
    f, g, t, s, c, h, usable = _prepare(template, search, template_xy, search_xy, patch, 1)
    f8 = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    g8 = np.clip(np.rint(g), 0, 255).astype(np.uint8)
    prev = t.astype(np.float32).reshape(-1, 1, 2)
    nxt = s.astype(np.float32).reshape(-1, 1, 2)
    out, st, _ = cv2.calcOpticalFlowPyrLK(
        f8, g8, prev, nxt.copy(), winSize=(patch, patch), maxLevel=levels,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, max_iter, eps),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    ok = (st[:, 0] == 1) & usable
    xy = np.where(ok[:, None], out[:, 0].astype(float), np.nan)
    return PeerResult(xy, ok)


def phase_correlation(template, search, template_xy, search_xy, *, patch: int = 13,
                      upsample: int = 100) -> PeerResult:
    """scikit-image's phase cross-correlation of the template patch with the search patch
    at the rounded start, refined by ``upsample``-fold matrix-multiply DFT up-sampling."""
    f, g, t, s, c, h, usable = _prepare(template, search, template_xy, search_xy, patch, 0)
    xy = np.full((len(t), 2), np.nan)
    for i in np.flatnonzero(usable):
        T = f[t[i, 1] - h:t[i, 1] + h + 1, t[i, 0] - h:t[i, 0] + h + 1]
        S = g[c[i, 1] - h:c[i, 1] + h + 1, c[i, 0] - h:c[i, 0] + h + 1]
        shift, _, _ = phase_cross_correlation(T, S, upsample_factor=upsample)
        xy[i] = c[i] - shift[::-1]
    return PeerResult(xy, np.isfinite(xy).all(axis=1))


def ilk(template, search, template_xy, search_xy, *, patch: int = 13, margin: int = 6,
        num_warp: int = 10) -> PeerResult:
    """scikit-image's iterative Lucas-Kanade optical flow on windows of
    ``patch + 2 * margin`` pixels, with ``radius = patch // 2``, read at the window centre."""
    f, g, t, s, c, h, usable = _prepare(template, search, template_xy, search_xy, patch, margin)
    xy = np.full((len(t), 2), np.nan)
    r = h + margin
    for i in np.flatnonzero(usable):
        T = f[t[i, 1] - r:t[i, 1] + r + 1, t[i, 0] - r:t[i, 0] + r + 1]
        S = g[c[i, 1] - r:c[i, 1] + r + 1, c[i, 0] - r:c[i, 0] + r + 1]
        v, u = optical_flow_ilk(T, S, radius=h, num_warp=num_warp)
        xy[i] = c[i] + (u[r, r], v[r, r])
    return PeerResult(xy, np.isfinite(xy).all(axis=1))


@dataclass(frozen=True)
class StereoPoints:
    """3-D points from a rectified stereo matcher.

    ``points`` (N, 3) world mm; ``xy_first`` (N, 2) their pixels in the first (original,
    unrectified) image; ``seconds`` the matcher's run time (rectification included).
    """

    points: np.ndarray
    xy_first: np.ndarray
    seconds: float


def sgbm(first, second, cam_first, cam_second, *, depth_range=(1800.0, 3500.0),
         block_size: int = 5, uniqueness: int = 10, filters: bool = False) -> StereoPoints:
    """OpenCV semi-global matching on a rectified pair, triangulated to world points.

    ``first`` must be the left image of the pair (the second camera lies to its right).
    OpenCV rectifies both images (``stereoRectify`` with the cameras' own distortion),
    ``StereoSGBM`` computes disparities over the range that ``depth_range`` (mm from the
    first camera) implies, and ``reprojectImageTo3D`` turns them into points, which are
    mapped back to the world frame and to the first image's original pixels (exact,
    sub-pixel: the projection of each point). With ``filters`` OpenCV's usual post-filters
    are on, as in :func:`stereo_sgbm`: the speckle filter (window 100, range 2) and the
    left-right check (``disp12MaxDiff = 1``).
    """
    f_img = check_image(first, "first")
    s_img = check_image(second, "second")
    if f_img.shape != s_img.shape:
        raise ValueError("second: expected the size of first")
    t0 = time.perf_counter()
    K1, d1, _, _ = cam_first.to_opencv()
    K2, d2, _, _ = cam_second.to_opencv()
    R = np.asarray(cam_second.R) @ np.asarray(cam_first.R).T
    T = np.asarray(cam_second.R) @ (cam_first.C - cam_second.C)
    size = (cam_first.width, cam_first.height)
    # alpha=1 keeps every pixel: with convergent cameras alpha=0 zooms in threefold
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, d1, K2, d2, size, R, T.reshape(3, 1),
                                                alpha=1)
    maps = [cv2.initUndistortRectifyMap(K, d, Rr, P, size, cv2.CV_32FC1)
            for K, d, Rr, P in ((K1, d1, R1, P1), (K2, d2, R2, P2))]
    rect = [cv2.remap(np.clip(img, 0, 255).astype(np.uint8), mx, my, cv2.INTER_LINEAR)
            for img, (mx, my) in zip((f_img, s_img), maps)]
    fb = abs(P2[0, 3])                                    # focal length x baseline
    shift = P1[0, 2] - P2[0, 2]                           # principal points may differ
    d_lo, d_hi = fb / depth_range[1] + shift, fb / depth_range[0] + shift
    num = int(np.ceil((d_hi - d_lo) / 16.0)) * 16
    matcher = cv2.StereoSGBM_create(minDisparity=int(np.floor(d_lo)), numDisparities=num,
                                    blockSize=block_size, P1=8 * block_size**2,
                                    P2=32 * block_size**2, uniquenessRatio=uniqueness,
                                    disp12MaxDiff=1 if filters else -1,
                                    speckleWindowSize=100 if filters else 0,
                                    speckleRange=2 if filters else 0,
                                    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    disp = matcher.compute(rect[0], rect[1]).astype(np.float32) / 16.0
    valid = disp > matcher.getMinDisparity()
    xyz = cv2.reprojectImageTo3D(disp, Q)[valid]          # first rectified camera frame
    cam1 = xyz @ R1                                        # R1^T x, as rows
    world = cam1 @ np.asarray(cam_first.R) + cam_first.C
    seconds = time.perf_counter() - t0
    xy = cam_first.project(world, behind="nan")
    keep = np.isfinite(xy).all(axis=1)
    return StereoPoints(points=world[keep], xy_first=xy[keep], seconds=seconds)


@dataclass(frozen=True)
class DisparityMap:
    """A rectified matcher's disparity of every left pixel (``x_left - x_right``, NaN where
    it gives none) and its run time in seconds."""

    disparity: np.ndarray
    seconds: float


def _as_uint8(image, name: str) -> np.ndarray:
    img = check_image(image, name)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


_SGBM_MODES = {"hh": cv2.STEREO_SGBM_MODE_HH, "sgbm": cv2.STEREO_SGBM_MODE_SGBM}


def sgbm_hh_bytes(shape, num_disparities: int, *, min_disparity: int = 0) -> int:
    """Memory of OpenCV SGBM's full 8-path mode on images of ``shape = (H, W)``, bytes: its
    cost and path-sum volumes, two 16-bit values per disparity ``D`` and pixel of the columns
    it matches (``4 H (W - min - D) D``, OpenCV's ``calcSGBM``)."""
    h, w = (int(v) for v in shape)
    d = int(num_disparities)
    return 4 * h * max(w - int(min_disparity) - d, 0) * d


def stereo_sgbm(left, right, *, num_disparities: int = 64, min_disparity: int = 0,
                block_size: int = 5, uniqueness: int = 5, filters: bool = True,
                speckle_window: int = 100, speckle_range: int = 2,
                mode: str = "hh") -> DisparityMap:
    """OpenCV's semi-global matching on a rectified pair, run as a user would.

    ``P1 = 8 block_size²``, ``P2 = 32 block_size²`` (OpenCV's recommendation for grey
    images), full 8-path mode (``mode="hh"``, ``MODE_HH``: about
    :func:`sgbm_hh_bytes` of memory) or OpenCV's default single-pass 5-path mode
    (``mode="sgbm"``, ``MODE_SGBM``: a few image rows of costs). With ``filters`` the usual
    post-filters are on: OpenCV's speckle filter (regions under ``speckle_window`` pixels
    whose disparity varies by more than ``speckle_range`` are removed) and its left-right
    check (``disp12MaxDiff = 1``); without, both are off. Images are rounded to 8 bits.
    """
    f8, g8 = _as_uint8(left, "left"), _as_uint8(right, "right")
    if f8.shape != g8.shape:
        raise ValueError(f"right: expected the shape of left {f8.shape}, got {g8.shape}")
    if mode not in _SGBM_MODES:
        raise ValueError(f"mode: expected one of {tuple(_SGBM_MODES)}, got {mode!r}")
    matcher = cv2.StereoSGBM_create(
        minDisparity=min_disparity, numDisparities=num_disparities, blockSize=block_size,
        P1=8 * block_size**2, P2=32 * block_size**2, uniquenessRatio=uniqueness,
        disp12MaxDiff=1 if filters else -1, speckleWindowSize=speckle_window if filters else 0,
        speckleRange=speckle_range if filters else 0, mode=_SGBM_MODES[mode])
    t0 = time.perf_counter()
    raw = matcher.compute(f8, g8)
    seconds = time.perf_counter() - t0
    disparity = raw.astype(float) / 16.0
    return DisparityMap(np.where(raw >= 16 * min_disparity, disparity, np.nan), seconds)


def stereo_bm(left, right, *, num_disparities: int = 64, block_size: int = 15) -> DisparityMap:
    """OpenCV's block matching on a rectified pair with its default filters (prefilter,
    texture threshold, uniqueness 15); images rounded to 8 bits."""
    f8, g8 = _as_uint8(left, "left"), _as_uint8(right, "right")
    if f8.shape != g8.shape:
        raise ValueError(f"right: expected the shape of left {f8.shape}, got {g8.shape}")
    matcher = cv2.StereoBM_create(numDisparities=num_disparities, blockSize=block_size)
    t0 = time.perf_counter()
    raw = matcher.compute(f8, g8)
    seconds = time.perf_counter() - t0
    return DisparityMap(np.where(raw >= 0, raw.astype(float) / 16.0, np.nan), seconds)
