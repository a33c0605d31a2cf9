"""A view pair's surface measured on the rectified pair: disparities by constrained LSM growth.

The views of a wide pair (tens of degrees apart) differ by a large perspective change, and
LSM between the unrectified images often does not converge. Rectified, every epipolar line
is an image row and a surface patch changes much less between the views; the disparity
growth (:func:`~lsmta.matching.measure_disparity`, one unknown per node besides the
row-affine shape) then measures it. The rectification is built here from the two cameras
(no OpenCV ``stereoRectify``, so that a rectified pixel maps back to the original pixel
exactly through :meth:`~lsmta.camera.Camera.project`, distortion included):

* both rectified cameras sit at the original centres, with the same rotation: x along the
  baseline (from the left camera to the right one: the one whose image x grows towards
  the other is left, so images stay upright), z the mean of the two optical axes made
  orthogonal to x, y = z x x;
* the principal distance is the mean of the two cameras'; the rectified images are the
  original height, wide enough to hold the searched depths of both views; the working
  point (where the optical axes meet) sits at the centre row, and its disparity is set so
  that the searched depths (``depth_range`` times the working point's depth) give
  disparities from ``margin`` px up;
* matches are mapped back to both cameras' original pixels and intersected
  (:func:`~lsmta.triangulation.triangulate`).

A rectified match lies on its epipolar line by construction, so its two-view reprojection
residual is ~0 whether the disparity is right or wrong; its precision is the disparity's
standard deviation. On a generated wide pair the points lie on the true surface
(``tests/test_surfaces_rectified.py``); on the Pose2Sim demo the growth stalls (plain
LSM started at SGBM's disparities rarely converges; ``experiments/surface_rectified_demo.py``).

``start="sgbm"`` (:func:`~lsmta.matching.refine.sgbm_start`,
:func:`~lsmta.matching.refine_disparities`) instead starts the growth's
LSM, constrained to the row, at every textured node where OpenCV's SGBM has a disparity, with
no growth; a node counts only where the adjustment converges and passes the thresholds. On
the generated pair its points lie on the true surface too; on the demo's frame 0 at full
size it keeps 606 and 589 points on the system's subject mask when written (shift-only LSM,
``experiments/surface_rectified_demo.py --system-only``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..camera import Camera
from ..matching import (
    DisparityParams,
    DisparityResult,
    SurfaceResult,
    measure_disparity,
    refine_disparities,
    sgbm_start,
)
from ..triangulation import Intersection, triangulate


class NoSeedsError(ValueError):
    """No seed was found on a rectified pair."""


@dataclass(frozen=True)
class Rectification:
    """A rectified view pair (see the module docstring).

    Attributes
    ----------
    left, right : int
        Which input camera (0 or 1) is the left and the right view.
    R : (3, 3) array
        Rotation from world to both rectified cameras.
    f : float
        Rectified principal distance, px.
    cx : (2,) array
        Rectified principal points' x (left, right), px; ``cy`` their common y.
    cy : float
    size : (int, int)
        Rectified image (width, height), px.
    disparity_range : (int, int)
        Disparities of the searched depths, px.
    maps : tuple of 2 (H, W, 2) float32 arrays
        Original pixel of every rectified pixel, left and right (for ``cv2.remap``).
    """

    left: int
    right: int
    R: np.ndarray
    f: float
    cx: np.ndarray
    cy: float
    size: tuple
    disparity_range: tuple
    maps: tuple = field(repr=False)


def _rays(rect: Rectification, xy, view: int) -> np.ndarray:
    """World directions ``(N, 3)`` of rectified pixels ``xy`` ``(N, 2)`` of ``view``."""
    xy = np.asarray(xy, float)
    d = np.stack([(xy[:, 0] - rect.cx[view]) / rect.f, (xy[:, 1] - rect.cy) / rect.f,
                  np.ones(len(xy))], axis=1)
    return d @ rect.R


def rectify_pair(cam_a: Camera, cam_b: Camera, *, working_point, depth_range=(0.6, 1.6),
                 margin: float = 8.0) -> Rectification:
    """Rectify the pair ``cam_a``, ``cam_b`` (see the module docstring).

    Parameters
    ----------
    cam_a, cam_b : Camera
        The two calibrated cameras (same image size).
    working_point : (3,) array
        A world point both cameras see (mm), e.g. where their optical axes meet; it is put
        at the centre row.
    depth_range : (float, float)
        The searched depths as multiples of the left camera's distance to ``working_point``.
    margin : float
        Smallest disparity of the searched depths, px.

    Returns
    -------
    Rectification
    """
    if (cam_a.width, cam_a.height) != (cam_b.width, cam_b.height):
        raise ValueError(f"cam_b: expected the size of cam_a {cam_a.image_size}, got "
                         f"{cam_b.image_size}")
    W0 = np.asarray(working_point, float).reshape(3)
    cams = (cam_a, cam_b)
    base = cam_b.C - cam_a.C
    left = 0 if np.asarray(cam_a.R)[0] @ base > 0 else 1
    x = (cams[1 - left].C - cams[left].C) / np.linalg.norm(base)
    z = np.asarray(cam_a.R)[2] + np.asarray(cam_b.R)[2]
    z = z - (z @ x) * x
    z /= np.linalg.norm(z)
    R = np.stack([x, np.cross(z, x), z])
    f = 0.5 * (cam_a.f + cam_b.f)
    w, h = cam_a.width, cam_a.height
    p = [(W0 - cams[k].C) @ R.T for k in (left, 1 - left)]          # rectified camera coords
    cy = h / 2 - f * p[0][1] / p[0][2]
    lo_hi = [f * np.linalg.norm(base) / (s * p[0][2]) for s in depth_range[::-1]]
    # x_left = f X/Z + cx_l, x_right = f (X - B)/Z + cx_r: disparity f B / Z + cx_l - cx_r
    span = lo_hi[1] - lo_hi[0]
    dw = margin + f * np.linalg.norm(base) / p[0][2] - lo_hi[0]   # the working point's
    width = int(np.ceil(w + dw))                                    # the canvas holds both
    cx_l = width / 2 + dw / 2 - f * p[0][0] / p[0][2]
    cx_r = width / 2 - dw / 2 - f * p[1][0] / p[1][2]
    rect = Rectification(left=left, right=1 - left, R=R, f=f, cx=np.array([cx_l, cx_r]), cy=cy,
                         size=(width, h), disparity_range=(int(np.floor(margin)),
                                                           int(np.ceil(margin + span))),
                         maps=())
    grid = np.stack(np.meshgrid(np.arange(width, dtype=float), np.arange(h, dtype=float)),
                    -1).reshape(-1, 2)
    maps = []
    for view, k in enumerate((left, 1 - left)):
        X = cams[k].C + _rays(rect, grid, view)
        xy = cams[k].project(X, behind="nan")
        xy[~cams[k].in_lens(X)] = np.nan          # past the lens model's fold: another ray's pixel
        maps.append(np.nan_to_num(xy, nan=-1.0).reshape(h, width, 2).astype(np.float32))
    return Rectification(**{**rect.__dict__, "maps": tuple(maps)})


def warp(rect: Rectification, image_a, image_b) -> tuple:
    """The rectified ``(left, right)`` images (float, bilinear) of the original pair."""
    images = (np.asarray(image_a, np.float32), np.asarray(image_b, np.float32))
    return tuple(cv2.remap(images[k], m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(float)
                 for k, m in zip((rect.left, rect.right), rect.maps))


def to_original(rect: Rectification, cam_a: Camera, cam_b: Camera, xy_left, xy_right):
    """Original pixels ``(2, N, 2)`` (``cam_a``'s row first) of rectified matches
    ``xy_left``, ``xy_right`` ``(N, 2)``; NaN where a ray points behind its camera."""
    cams = (cam_a, cam_b)
    out = np.full((2, len(xy_left), 2), np.nan)
    for view, (k, xy) in enumerate(zip((rect.left, rect.right), (xy_left, xy_right))):
        out[k] = cams[k].project(cams[k].C + _rays(rect, xy, view), behind="nan")
    return out


@dataclass(frozen=True)
class RectifiedSurface:
    """A pair's surface from its rectified images.

    Attributes
    ----------
    rectification : Rectification
    disparity : DisparityResult
        On the rectified left image.
    xy : (2, N, 2) array
        The matches in the original images (the input cameras' order), px.
    intersection : Intersection
        Their forward intersection (with reprojection errors).
    """

    rectification: Rectification
    disparity: DisparityResult
    xy: np.ndarray
    intersection: Intersection


def measure_rectified_pair(image_a, image_b, cam_a: Camera, cam_b: Camera, *, working_point,
                           masks=None, depth_range=(0.6, 1.6), start: str = "grow",
                           params: DisparityParams | None = None) -> RectifiedSurface:
    """Measure a pair's surface on its rectified images (module docstring).

    Parameters
    ----------
    image_a, image_b : (H, W) arrays
        Grey images of ``cam_a`` and ``cam_b``.
    cam_a, cam_b : Camera
    working_point : (3,) array
        World point (mm) both cameras see, see :func:`rectify_pair`.
    masks : pair of (H, W) bool arrays, optional
        Where to grow, in ``cam_a``'s and ``cam_b``'s original images (the left view's is
        warped to the rectified left image and used).
    depth_range : (float, float)
        Searched depths, multiples of the working distance.
    start : {"grow", "sgbm"}
        ``"grow"``: seeds and the disparity growth (:func:`~lsmta.matching.measure_disparity`);
        ``"sgbm"``: LSM at every node where OpenCV's SGBM has a disparity, started there
        (:func:`~lsmta.matching.refine.sgbm_start`,
        :func:`~lsmta.matching.refine_disparities`; no growth).
    params : DisparityParams, optional

    Returns
    -------
    RectifiedSurface
    """
    if start not in ("grow", "sgbm"):
        raise ValueError(f"start: expected 'grow' or 'sgbm', got {start!r}")
    rect = rectify_pair(cam_a, cam_b, working_point=working_point, depth_range=depth_range)
    left, right = warp(rect, image_a, image_b)
    # grow only where the left view's rectified pixels come from its image, a patch inside
    # the zero-filled border (its step edges would give false matches)
    mm = rect.maps[rect.left]
    inside = ((mm[..., 0] >= 0) & (mm[..., 0] <= cam_a.width - 1)
              & (mm[..., 1] >= 0) & (mm[..., 1] <= cam_a.height - 1))
    grow = (DisparityParams() if params is None else params).grow
    half = grow.patch // 2
    rect_mask = cv2.erode(inside.astype(np.uint8), np.ones((2 * half + 1,) * 2, np.uint8),
                          borderValue=0).astype(bool)
    if masks is not None:
        m = np.asarray(masks[rect.left], bool)
        if m.shape != (cam_a.height, cam_a.width):
            raise ValueError(f"masks: expected two masks of shape "
                             f"{(cam_a.height, cam_a.width)}, got {m.shape}")
        rect_mask &= cv2.remap(m.astype(np.uint8), mm[..., 0], mm[..., 1],
                               cv2.INTER_NEAREST).astype(bool)
    if start == "sgbm":
        start = sgbm_start(left, right, disparity_range=rect.disparity_range, step=grow.step)
        res = refine_disparities(left, right, start, disparity_range=rect.disparity_range,
                                 mask=rect_mask, params=params)
    else:
        res = _grown(left, right, rect, rect_mask, params)
    r, c = np.nonzero(np.isfinite(res.disparity))
    xl = np.stack([c * res.step, r * res.step], axis=1).astype(float)
    xr = xl - np.stack([res.disparity[r, c], np.zeros(len(r))], axis=1)
    xy = to_original(rect, cam_a, cam_b, xl, xr)
    return RectifiedSurface(rectification=rect, disparity=res, xy=xy,
                            intersection=triangulate([cam_a, cam_b], xy))


def _grown(left, right, rect: Rectification, rect_mask, params) -> DisparityResult:
    """The disparity growth on the rectified pair (:func:`measure_rectified_pair`)."""
    try:
        res = measure_disparity(left, right, disparity_range=rect.disparity_range,
                                mask=rect_mask, params=params)
    except ValueError as err:
        if str(err).startswith("seeds: none"):
            raise NoSeedsError("seeds: none found on the rectified pair (no corner of the "
                               "left view found along its row in the right one)") from err
        raise
    return res


def surface_result(surface: RectifiedSurface, *, template: int = 0) -> SurfaceResult:
    """A :class:`~lsmta.matching.SurfaceResult` of a rectified pair's surface, so that the
    surface stage returns one type: ``grown`` holds the disparity growth (seeds' regrowths
    left out), ``xy`` the original pixels with the ``template`` camera's as
    ``template_xy``; ``sigma_xy`` holds the disparity's standard deviation (rectified px)
    in x of the non-template row. No neighbourhood filter is run (every match counts as
    passing it); ``points`` are the intersected ones."""
    xy = surface.xy
    n = xy.shape[1]
    disp = surface.disparity
    r, c = np.nonzero(np.isfinite(disp.disparity))
    sigma = np.zeros((2, n, 2))
    sigma[1 - template, :, 0] = disp.sigma[r, c]
    inter = surface.intersection
    return SurfaceResult(grown=[disp.grown], template_xy=xy[template], xy=xy, sigma_xy=sigma,
                         neighbourhood_ok=np.ones(n, bool), rematched=np.zeros(n, bool),
                         intersection=inter, cloud=None, points=inter.points[inter.valid],
                         points_xy=xy[:, inter.valid])
