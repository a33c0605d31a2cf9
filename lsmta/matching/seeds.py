"""Automatic seed points: correlation along epipolar lines, checked in every image.

Two finders: :func:`find_seeds` for calibrated cameras (any number, with distortion) and
:func:`find_disparity_seeds` for a rectified pair, where the epipolar lines are the rows
and OpenCV's ``matchTemplate`` correlates a whole row segment at once.


Candidate points are well-textured corners of the template (OpenCV's Shi-Tomasi
``goodFeaturesToTrack``). For each candidate, the viewing ray of the template camera is
sampled at depths evenly spaced in inverse depth over ``depth_range``; each sample is
projected into every search image (through their distortion, so the "epipolar line" is
the true curve) and the template patch is compared there by normalised cross-correlation.
The depth that maximises the *mean* correlation over all search images wins; requiring
all images to agree at one depth is what removes most false seeds. The best-scoring
candidates become seeds; :func:`~lsmta.matching.grow.grow_matches` refines them by LSM.

The search patch is the template's square patch (``warp="identity"``), or sampled through
the map from the template to the search image that a surface at the sample's depth facing
both cameras alike induces (``warp="predicted"``: the cameras' roll about their axes and
the scale from their distances and focal lengths; :func:`predicted_maps`). A camera mounted
on its side sees the template's patch turned by 90°, where the square patch correlates with
nothing. ``warp="auto"`` predicts the map for a search camera whose map at the working
point (the template's principal ray at the middle inverse depth) turns by more than
``AUTO_TURN_DEG`` or scales by more than ``AUTO_SCALE``, and keeps the square patch for the
others. The seeds carry the map they were found with (``Seeds.A``) for LSM's start.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_array, as_scalar, check_patch
from ..camera import Camera
from .spline import SplineImage, check_image

#: ``warp="auto"``: a search image whose predicted map at the working point turns by more
#: than this (degrees) or scales by more than ``AUTO_SCALE`` (or less than its inverse) is
#: searched through the predicted map. Beyond them the square patch's corners land
#: ``(patch - 1) * sqrt(2) * sin(turn / 2)`` or ``(patch - 1) / sqrt(2) * (scale - 1)`` px
#: off (about 3 px at the thresholds for a 9 px patch), past the grain of a texture of a
#: couple of pixels, so its correlation, and LSM's pull-in that starts from it, are lost
#: (tests/test_seed_warp.py: a 9 px patch holds at 20 deg and scale 1.25, not at 45 deg or
#: scale 2; a finer texture is lost earlier).
AUTO_TURN_DEG = 30.0
AUTO_SCALE = 1.5
WARPS = ("identity", "predicted", "auto")


@dataclass(frozen=True)
class Seeds:
    """Automatically found seeds.

    Attributes
    ----------
    xy : (K, S, 2) array
        Seed positions in all K images (the template row holds the corners).
    score : (S,) array
        Mean normalised cross-correlation over the search images at the chosen depth.
    depth : (S,) array
        Chosen distance along the template camera's ray, mm (NaN for a rectified pair).
    disparity : (S,) array or None
        For a rectified pair (:func:`find_disparity_seeds`): ``x_left - x_right``, pixels.
    A : (K, S, 2, 2) array or None
        The map from the template's patch to each image's that the seed was found with
        (identity for the template and where the square patch was used); None: identity.
    """

    xy: np.ndarray
    score: np.ndarray
    depth: np.ndarray
    disparity: np.ndarray | None = None
    A: np.ndarray | None = None


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation of patches along the last axis."""
    a = a - a.mean(axis=-1, keepdims=True)
    b = b - b.mean(axis=-1, keepdims=True)
    den = np.sqrt((a * a).sum(axis=-1) * (b * b).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (a * b).sum(axis=-1) / den, -1.0)


def find_seeds(images, cameras, *, template: int = 1, n_seeds: int = 12, patch: int = 11,
               depth_range=(1500.0, 4000.0), n_depths: int = 400, min_score: float = 0.8,
               mask=None, min_distance: int = 25, warp: str = "identity") -> Seeds:
    """Find seed correspondences in K >= 2 calibrated images without a user.

    Parameters
    ----------
    images : sequence of K (H, W) arrays
    cameras : sequence of K Camera
    template : int
        Index of the template image.
    n_seeds : int
        How many seeds to return at most (best scores first).
    patch : int
        Odd correlation patch size.
    depth_range : (float, float)
        Nearest and farthest distance along the template rays to search, mm.
    n_depths : int
        Samples along each ray (evenly in inverse depth).
    min_score : float
        Seeds whose mean correlation is lower are dropped.
    mask : (H, W) bool array, optional
        Where in the template to look for corners.
    min_distance : int
        Smallest distance between two candidate corners, pixels.
    warp : {"identity", "predicted", "auto"}
        The search patch: the template's square patch, or sampled through the predicted
        map (module docstring).

    Corners where the template camera's lens model cannot be inverted (a fitted distortion
    that folds over inside the frame) have no ray and are passed over.
    """
    images = [check_image(im, f"images[{k}]") for k, im in enumerate(images)]
    cameras = list(cameras)
    K = len(images)
    if K < 2 or len(cameras) != K or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras: expected one lsmta.camera.Camera per image, at least 2")
    patch = check_patch(patch)
    near, far = (float(d) for d in depth_range)
    if not 0 < near < far:
        raise ValueError(f"depth_range: expected 0 < near < far (mm), got {depth_range}")
    if warp not in WARPS:
        raise ValueError(f"warp: expected one of {list(WARPS)}, got {warp!r}")
    h = patch // 2
    f = images[template]
    corners = _corners(f, n_seeds=n_seeds, min_distance=min_distance, mask=mask, patch=patch)
    empty = Seeds(xy=np.zeros((K, 0, 2)), score=np.zeros(0), depth=np.zeros(0),
                  A=np.zeros((K, 0, 2, 2)))
    if corners is None:
        return empty
    t_xy = corners[:, 0].astype(float)
    spline_t = SplineImage(f)
    t_xy = t_xy[spline_t.inside(t_xy, margin=h)]
    t_xy = t_xy[cameras[template].invertible(t_xy)] if len(t_xy) else t_xy   # no ray there
    if len(t_xy) == 0:
        return empty
    # distance along the ray whose camera depth goes evenly in inverse depth
    inv = np.linspace(1.0 / near, 1.0 / far, n_depths)
    warped = warped_images(cameras, template, 2.0 / (1.0 / near + 1.0 / far), warp=warp)
    score, projected, maps = _ray_scores(images, cameras, template, spline_t, t_xy, inv, h,
                                         warped)
    return _best_seeds(score, projected, maps, t_xy, inv, K, template, n_seeds=n_seeds,
                       min_score=min_score)


def camera_depth(camera: Camera, X) -> np.ndarray:
    """Depth (mm) of points ``X`` ``(..., 3)`` (mm) along ``camera``'s optical axis: shape
    ``(...)``, negative behind it."""
    return (np.asarray(X, float) - camera.C) @ np.asarray(camera.R)[2]


def predicted_maps(cameras, template: int, X) -> dict:
    """The local map from the template's pixels to each search image's at points ``X`` on a
    surface facing both cameras alike (its normal halves the angle between the two rays):
    the cameras' roll about their axes and the scale from their distances and focal
    lengths, the foreshortening shared evenly between the two views.

    Parameters
    ----------
    cameras : sequence of K >= 2 Camera
    template : int
        Index into ``cameras`` of the template camera: the maps take a step of one of its
        pixels to the search images.
    X : (..., 3) array
        Finite points in front of the template camera, mm (one template pixel spans
        ``camera_depth(cameras[template], X) / f`` there).

    Returns
    -------
    dict of int -> (..., 2, 2) array
        Per search image ``k``: columns = the image of a one-pixel step along the template's
        x and y; NaN where a point or its steps fall behind camera ``k``.
    """
    cameras = list(cameras)
    if len(cameras) < 2 or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a sequence of at least 2 Camera")
    if isinstance(template, bool) or not isinstance(template, int | np.integer) \
            or not 0 <= template < len(cameras):
        raise ValueError(f"template: expected an index into the {len(cameras)} cameras, got "
                         f"{template!r}")
    X = as_array(X, "X")
    if X.ndim < 1 or X.shape[-1] != 3:
        raise ValueError(f"X: expected an array of shape (..., 3), got shape {X.shape}")
    t = cameras[template]
    depth = camera_depth(t, X)
    if not (depth > 0).all():
        raise ValueError("X: expected points in front of the template camera (depth > 0)")
    step = (depth / t.f)[..., None]
    to_t = t.C - X
    to_t = to_t / np.linalg.norm(to_t, axis=-1, keepdims=True)
    shape = X.shape[:-1] + (2,)
    out = {}
    for k, cam in enumerate(cameras):
        if k == template:
            continue
        n = to_t + (cam.C - X) / np.linalg.norm(cam.C - X, axis=-1, keepdims=True)
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        at = cam.project(X.reshape(-1, 3), behind="nan").reshape(shape)
        cols = []
        for i in (0, 1):
            e = step * t.R[i]                       # a template pixel, square to its axis
            along = (e * n).sum(-1, keepdims=True) / (to_t * n).sum(-1, keepdims=True)
            on_plane = X + e - along * to_t         # slid along the ray onto the plane
            cols.append(cam.project(on_plane.reshape(-1, 3), behind="nan").reshape(shape)
                        - at)
        out[k] = np.stack(cols, axis=-1)
    return out


def warped_images(cameras, template: int, depth: float, *, warp: str = "auto") -> set:
    """The search images matched through the predicted map (:func:`predicted_maps`):
    none (``"identity"``), all (``"predicted"``), or (``"auto"``) those whose map at the
    template's principal ray at ``depth`` (mm) turns by more than ``AUTO_TURN_DEG`` or
    scales by more than ``AUTO_SCALE`` (module docstring)."""
    if warp not in WARPS:
        raise ValueError(f"warp: expected one of {list(WARPS)}, got {warp!r}")
    if warp == "identity":
        return set()
    others = {k for k in range(len(cameras)) if k != template}
    if warp == "predicted":
        return others
    t = cameras[template]
    X = t.C + as_scalar(depth, "depth", positive=True) * np.asarray(t.R)[2]
    chosen = set()
    for k, A in predicted_maps(cameras, template, X).items():
        if not np.isfinite(A).all():
            continue
        turn = np.degrees(abs(np.arctan2(A[1, 0] - A[0, 1], A[0, 0] + A[1, 1])))
        scale = np.sqrt(abs(np.linalg.det(A)))
        if turn > AUTO_TURN_DEG or not 1 / AUTO_SCALE <= scale <= AUTO_SCALE:
            chosen.add(k)
    return chosen


def _corners(f, *, n_seeds: int, min_distance, mask, patch: int):
    """Shi-Tomasi corners ``(C, 1, 2)`` of the grey image ``f`` (scaled to 8 bits), at most
    ``4 n_seeds``, inside ``mask``; None if there are none."""
    f8 = np.clip(np.rint(255 * (f - f.min()) / max(np.ptp(f), 1e-9)), 0, 255).astype(np.uint8)
    m8 = None if mask is None else np.asarray(mask, dtype=np.uint8)
    return cv2.goodFeaturesToTrack(f8, maxCorners=4 * n_seeds, qualityLevel=0.05,
                                   minDistance=min_distance, mask=m8, blockSize=patch)


def _ray_scores(images, cameras, template: int, spline_t: SplineImage, t_xy, inv, h: int,
                warped: set):
    """The mean correlation ``(C, D)`` over the search images of every candidate's template
    patch (half-width ``h``) at the inverse depths ``inv`` (D,) along its ray, the
    candidates' projections ``(C, D, 2)`` into each search image ``k`` (dict), and the
    maps ``(C, D, 2, 2)`` the patches were sampled through (dict; the images in ``warped``
    through the predicted map, the others square)."""
    K = len(images)
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    U = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(float)
    tpl = spline_t.patches(t_xy, U)                                   # (C, P)

    o, d = cameras[template].rays(t_xy)
    along = (1.0 / inv)[None, :] / (d @ cameras[template].R[2])[:, None]    # (C, D)
    X = o[:, None, :] + along[..., None] * d[:, None, :]                   # (C, D, 3)
    score = np.zeros(along.shape)
    projected, maps = {}, {}
    predicted = predicted_maps(cameras, template, X) if warped else {}
    for k, cam in enumerate(cameras):
        if k == template:
            continue
        xy = cam.project(X.reshape(-1, 3), behind="nan").reshape(X.shape[:2] + (2,))
        A = predicted[k] if k in warped else np.broadcast_to(np.eye(2), along.shape + (2, 2))
        spline = SplineImage(images[k])
        ok = np.isfinite(xy).all(axis=-1) & np.isfinite(A).all(axis=(-2, -1))
        reach = h * np.abs(np.nan_to_num(A)).sum(axis=-1).max(axis=-1)       # (C, D)
        ok &= spline.inside(np.nan_to_num(xy) - reach[..., None], margin=0.0)
        ok &= spline.inside(np.nan_to_num(xy) + reach[..., None], margin=0.0)
        at = np.where(ok[..., None], xy, 0.0)[:, :, None, :]
        offsets = (np.einsum("cdij,pj->cdpi", np.where(ok[..., None, None], A, 0.0), U)
                   if k in warped else U)
        vals = spline.sample(at + offsets, gradient=False)                    # (C, D, P)
        ncc = _ncc(tpl[:, None, :], vals)
        score += np.where(ok, ncc, -1.0)
        projected[k], maps[k] = xy, A
    score /= K - 1
    return score, projected, maps


def _best_seeds(score, projected, maps, t_xy, inv, K: int, template: int, *, n_seeds: int,
                min_score: float) -> Seeds:
    """Every candidate's best depth; the ``n_seeds`` best candidates reaching
    ``min_score`` as seeds."""
    best = score.argmax(axis=1)
    best_score = score[np.arange(len(best)), best]
    order = np.argsort(-best_score)
    order = order[best_score[order] >= min_score][:n_seeds]
    xy = np.zeros((K, len(order), 2))
    A = np.broadcast_to(np.eye(2), (K, len(order), 2, 2)).copy()
    xy[template] = t_xy[order]
    for k, p in projected.items():
        xy[k] = p[order, best[order]]
        A[k] = maps[k][order, best[order]]
    depth = 1.0 / inv[best[order]]
    return Seeds(xy=xy, score=best_score[order], depth=depth, A=A)


def find_disparity_seeds(left, right, *, disparity_range, n_seeds: int = 30, patch: int = 11,
                         min_score: float = 0.8, uniqueness: float = 0.05, mask=None,
                         min_distance: int = 15) -> Seeds:
    """Seeds for a rectified pair: corners of the left image, found in the right image on
    the same row by normalised cross-correlation.

    For each well-textured corner (Shi-Tomasi) the ``patch x patch`` window is correlated
    (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``) with the right image's row band over
    ``disparity_range``; the peak is refined to sub-pixel by a parabola. A corner is kept
    when its peak reaches ``min_score`` and beats every other peak of its row (more than
    two pixels away) by ``uniqueness`` — a repeated pattern gives two peaks and no seed —
    and when the right window, correlated back along the left row, finds the corner again
    within a pixel (left-right check: a corner that the right image does not see finds
    something else).

    Parameters
    ----------
    left, right : (H, W) arrays
        The rectified pair; a left pixel ``(x, y)`` appears at ``(x - d, y)`` on the right.
    disparity_range : (int, int)
        Smallest and largest disparity to search, pixels.
    n_seeds : int
        How many seeds to return at most (best scores first).
    patch : int
        Odd correlation window.
    min_score, uniqueness : float
        Smallest peak correlation, and its smallest lead over the row's second peak.
    mask : (H, W) bool array, optional
        Where in the left image to look for corners.
    min_distance : int
        Smallest distance between two corners, pixels.

    Returns
    -------
    Seeds
        ``xy`` (2, S, 2): left and right positions; ``disparity`` (S,); ``depth`` NaN.
    """
    f = check_image(left, "left")
    g = check_image(right, "right")
    if g.shape != f.shape:
        raise ValueError(f"right: expected the shape of left {f.shape}, got {g.shape}")
    patch = check_patch(patch)
    lo, hi = (int(d) for d in disparity_range)
    if not 0 <= lo < hi:
        raise ValueError(f"disparity_range: expected 0 <= smallest < largest (pixels), got "
                         f"{disparity_range}")
    h = patch // 2
    corners = _corners(f, n_seeds=n_seeds, min_distance=min_distance, mask=mask, patch=patch)
    empty = Seeds(xy=np.zeros((2, 0, 2)), score=np.zeros(0), depth=np.zeros(0),
                  disparity=np.zeros(0))
    if corners is None:
        return empty
    f32, g32 = f.astype(np.float32), g.astype(np.float32)
    found = []
    for x, y in np.rint(corners[:, 0]).astype(int):
        match = _row_match(f32, g32, x, y, h=h, lo=lo, hi=hi, min_score=min_score,
                           uniqueness=uniqueness)
        if match is not None:
            found.append(match)
    if not found:
        return empty
    found.sort(key=lambda s: -s[0])
    found = np.array(found[:n_seeds])
    xy = np.stack([found[:, 1:3], np.stack([found[:, 3], found[:, 2]], axis=1)])
    return Seeds(xy=xy, score=found[:, 0], depth=np.full(len(found), np.nan),
                 disparity=found[:, 1] - found[:, 3])


def _row_match(f32, g32, x, y, *, h: int, lo: int, hi: int, min_score: float,
               uniqueness: float):
    """The left corner ``(x, y)`` found along its row of the right image: ``(score, x, y,
    x_right)``, or None if its window does not fit, its peak is too low or not unique, or
    the left-right check fails."""
    H, W = f32.shape
    patch = 2 * h + 1
    if not (h <= y < H - h and x - lo + h < W and x - h >= 0):
        return None
    x0 = max(x - hi - h, 0)                          # the band's first column
    x1 = x - lo + h + 1
    if x1 - x0 < patch + 2:
        return None
    tpl = f32[y - h:y + h + 1, x - h:x + h + 1]
    ncc = cv2.matchTemplate(g32[y - h:y + h + 1, x0:x1], tpl, cv2.TM_CCOEFF_NORMED)[0]
    best = int(np.argmax(ncc))
    others = np.abs(np.arange(len(ncc)) - best) > 2
    second = ncc[others].max() if others.any() else -1.0
    if ncc[best] < min_score or ncc[best] - second < uniqueness:
        return None
    sub = 0.0
    if 0 < best < len(ncc) - 1:                      # parabola through the peak
        a, b, c = ncc[best - 1], ncc[best], ncc[best + 1]
        den = a - 2 * b + c
        sub = 0.5 * (a - c) / den if den < 0 else 0.0
    xr = x0 + h + best + sub
    # left-right check: the right window, correlated back along the left row, must
    # find the corner again (an occluded corner finds something else)
    xi = int(round(xr))
    if not h <= xi < W - h:
        return None
    b0 = max(xi + lo - h, 0)
    b1 = min(xi + hi + h + 1, W)
    back = cv2.matchTemplate(f32[y - h:y + h + 1, b0:b1],
                             g32[y - h:y + h + 1, xi - h:xi + h + 1], cv2.TM_CCOEFF_NORMED)[0]
    if abs(b0 + h + int(np.argmax(back)) - x) > 1:
        return None
    return ncc[best], x, y, xr
