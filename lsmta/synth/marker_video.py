"""Rendered marker video: painted facial markers as bright dots on skin-like texture.

Each image is what one camera sees in one frame: a smooth grey skin texture that moves
with the head (it is shifted with the projection of a chosen anchor point, e.g. the head
centre), and every *visible* marker drawn as a small Gaussian dot at its projected
(distorted) position. Optional motion blur on chosen frames (a line kernel along the
image motion of the anchor) and Gaussian image noise. The ground truth is the projected
positions of the drawn markers. Images are uint8, x right, y down, origin at the centre
of the top-left pixel (as :mod:`lsmta.camera`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_array, as_rng, as_scalar
from ..camera import Camera


@dataclass(frozen=True)
class MarkerVideo:
    """Rendered frames and their truth.

    Attributes
    ----------
    images : (T, H, W) uint8 array
    xy : (T, M, 2) array
        True image positions of the drawn markers, px; NaN where a marker is not drawn
        (not visible, behind the camera or outside the image).
    anchor_xy : (T, 2) array
        Image position of the texture anchor, px (the skin texture moves with it).
    blurred : (T,) bool array
        Frames rendered with motion blur.
    """

    images: np.ndarray
    xy: np.ndarray
    anchor_xy: np.ndarray
    blurred: np.ndarray


def skin_texture(shape, *, rng: np.random.Generator | int | None = None, scale: float = 4.0,
                 mean: float = 105.0, contrast: float = 6.0) -> np.ndarray:
    """A smooth random grey texture ``shape`` (rows, cols), float32: white noise blurred
    with a Gaussian of ``scale`` px, normalised to ``mean`` +- ``contrast`` (std)."""
    rng = as_rng(rng)
    noise = rng.normal(0.0, 1.0, tuple(int(s) for s in shape)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), scale) + 0.5 * cv2.GaussianBlur(noise, (0, 0),
                                                                          scale * 3)
    tex = (tex - tex.mean()) / tex.std()
    return (mean + contrast * tex).astype(np.float32)


def _line_kernel(dx: float, dy: float, length: float) -> np.ndarray:
    n = int(np.ceil(length)) | 1
    n = max(n, 3)
    k = np.zeros((n, n), np.float32)
    c = (n - 1) / 2
    d = np.array([dx, dy]) / max(np.hypot(dx, dy), 1e-12)
    for s in np.linspace(-length / 2, length / 2, 4 * n):
        x, y = c + s * d[0], c + s * d[1]
        k[int(round(y)), int(round(x))] += 1.0
    return k / k.sum()


def render_marker_video(cameras, points, visible, anchor, *,
                        rng: np.random.Generator | int | None = None, dot_sigma: float = 1.3,
                        dot_amplitude: float = 110.0, noise: float = 2.0, blur_frames=(),
                        blur_length: float = 9.0, texture=None) -> MarkerVideo:
    """Render one camera's view of markers over ``T`` frames.

    Parameters
    ----------
    cameras : sequence of T :class:`~lsmta.camera.Camera`
        The camera of each frame (a pan-tilt camera moves; pass rotated copies for camera
        shake). All must have the same image size.
    points : (T, M, 3) array
        Marker positions in the world, mm.
    visible : (T, M) bool array
        Markers drawn in each frame (e.g. :func:`lsmta.synth.face.visible`).
    anchor : (T, 3) array
        World point the skin texture moves with (e.g. the head position).
    rng : numpy.random.Generator, int or None
        Texture and image noise.
    dot_sigma, dot_amplitude : float
        Gaussian dot radius (px) and peak brightness added to the texture (grey levels).
    noise : float
        Standard deviation of the Gaussian image noise, grey levels.
    blur_frames : sequence of int
        Frames rendered with motion blur of ``blur_length`` px along the anchor's image
        motion (horizontal if it does not move).
    texture : (h, w) float array, optional
        Skin texture to use (default: :func:`skin_texture` twice the image size).
    """
    rng = as_rng(rng)
    cameras = list(cameras)
    pts = as_array(points, "points", shape=(len(cameras), None, 3), allow_nan=True)
    vis = np.asarray(visible, dtype=bool)
    if vis.shape != pts.shape[:2]:
        raise ValueError(f"visible: expected shape {pts.shape[:2]}, got {vis.shape}")
    anc = as_array(anchor, "anchor", shape=(len(cameras), 3))
    sigma = as_scalar(dot_sigma, "dot_sigma", positive=True)
    noise = as_scalar(noise, "noise", nonnegative=True)
    if not cameras:
        raise ValueError("cameras: expected at least one camera")
    W, H = cameras[0].width, cameras[0].height
    if any((c.width, c.height) != (W, H) for c in cameras):
        raise ValueError("cameras: expected one image size for all frames")
    T, M = pts.shape[:2]
    if texture is None:
        texture = skin_texture((2 * H, 2 * W), rng=rng)
    texture = np.asarray(texture, dtype=np.float32)
    blur = np.zeros(T, bool)
    blur[np.asarray(blur_frames, dtype=int)] = True
    xy, anchor_xy = _project_markers(cameras, pts, vis, anc)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    r = int(np.ceil(4 * sigma))
    off = np.arange(-r, r + 1)
    images = np.empty((T, H, W), np.uint8)
    tc = np.array([texture.shape[1] / 2, texture.shape[0] / 2], np.float32)
    for f in range(T):
        a = anchor_xy[f] if np.isfinite(anchor_xy[f]).all() else np.array([W / 2, H / 2])
        img = cv2.remap(texture, gx - np.float32(a[0] - tc[0]), gy - np.float32(a[1] - tc[1]),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        _add_dots(img, xy[f][np.isfinite(xy[f]).all(axis=1)], off, sigma, dot_amplitude)
        if blur[f]:
            prev, nxt = anchor_xy[max(f - 1, 0)], anchor_xy[min(f + 1, T - 1)]
            d = nxt - prev
            if not np.isfinite(d).all() or np.hypot(*d) < 1e-6:
                d = np.array([1.0, 0.0])
            img = cv2.filter2D(img, -1, _line_kernel(d[0], d[1], blur_length),
                               borderType=cv2.BORDER_REFLECT)
        if noise > 0:       # (in place: the same numbers as img + noise * z, fewer copies)
            z = rng.standard_normal(img.shape, dtype=np.float32)
            z *= np.float32(noise)
            img += z
        np.rint(img, out=img)
        images[f] = np.clip(img, 0, 255, out=img)
    return MarkerVideo(images=images, xy=xy, anchor_xy=anchor_xy, blurred=blur)


def _project_markers(cameras, pts, vis, anc):
    """True image positions ``(T, M, 2)`` of the drawn markers (NaN where not drawn: not
    visible, behind the camera or outside the image) and of the texture anchor ``(T, 2)``."""
    T, M = pts.shape[:2]
    xy = np.full((T, M, 2), np.nan)
    anchor_xy = np.full((T, 2), np.nan)
    for f, cam in enumerate(cameras):
        p = cam.project(pts[f], behind="nan")
        ok = vis[f] & np.isfinite(p).all(axis=1) & cam.in_image(p)
        xy[f, ok] = p[ok]
        anchor_xy[f] = cam.project(anc[f][None], behind="nan")[0]
    return xy, anchor_xy


def _add_dots(img, q, off, sigma: float, dot_amplitude: float) -> None:
    """Add a Gaussian dot (``sigma`` px, peak ``dot_amplitude``) at each position ``q``
    ``(n, 2)`` to the float32 image ``img`` ``(H, W)`` in place, over the window ``off``
    around its nearest pixel."""
    if not len(q):
        return
    H, W = img.shape
    c = np.round(q).astype(int)
    ix = c[:, 0, None, None] + off[None, None, :]           # (n, 1, k)
    iy = c[:, 1, None, None] + off[None, :, None]           # (n, k, 1)
    val = dot_amplitude * np.exp(-((ix - q[:, 0, None, None]) ** 2
                                   + (iy - q[:, 1, None, None]) ** 2) / (2 * sigma ** 2))
    ix, iy = np.broadcast_arrays(ix, iy)
    inside = (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
    np.add.at(img, (iy[inside], ix[inside]), val[inside].astype(np.float32))


def shaken(camera: Camera, deg: float, *, rng: np.random.Generator | int | None = None) -> Camera:
    """``camera`` rotated about its centre by a random small rotation (``deg`` per axis,
    Gaussian): pan-tilt jitter between frames."""
    rng = as_rng(rng)
    deg = as_scalar(deg, "deg", nonnegative=True)
    if deg == 0:
        return camera
    dR, _ = cv2.Rodrigues(np.radians(rng.normal(0.0, deg, 3)))
    return camera.replace(R=dR @ camera.R)
