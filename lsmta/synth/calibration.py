"""Calibration data of the synthetic world: a reference bar moved through the triplet
volume (LSMTA §2.1), its rendered target images, an LED path for the ceiling ring (Davis
§3.2), a long room whose cameras see only parts of an LED path that sweeps it (partial
overlap, Fig. 24), and a "tape-measured" poor initial guess of a rig.

The truth here (target positions, cameras) reaches the library only through the
evaluation harness (:mod:`lsmta.evaluation.calibration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_int, as_rng, as_scalar, as_vector
from ..camera import Camera
from .rigs import _perturbed


@dataclass(frozen=True)
class BarTrack:
    """Reference bar positions.

    Attributes
    ----------
    A, B : (T, 3) arrays
        The two targets at each of T positions, mm (A starts on the -X side).
    length : float
        True distance between the targets, mm.
    """

    A: np.ndarray
    B: np.ndarray
    length: float

    @property
    def points(self) -> np.ndarray:
        """``(T, 2, 3)`` targets A, B per position."""
        return np.stack([self.A, self.B], axis=1)


def _walk(rng, n, center, half_size, step):
    """A smooth random walk of ``n`` points in a box (reflected at the walls), mm."""
    center = np.asarray(center, float)
    half = np.asarray(half_size, float)
    p = center + rng.uniform(-0.5, 0.5, 3) * half
    v = rng.normal(0, 1, 3)
    v *= step / np.linalg.norm(v)
    out = np.empty((n, 3))
    for t in range(n):
        out[t] = p
        v = 0.85 * v + 0.5 * step * rng.normal(0, 1, 3) / np.sqrt(3)
        v *= step / np.linalg.norm(v)
        p = p + v
        for a in range(3):
            lo, hi = center[a] - half[a], center[a] + half[a]
            if p[a] < lo or p[a] > hi:
                v[a] = -v[a]
                p[a] = np.clip(p[a], lo, hi)
    return out


def bar_track(*, n: int = 150, rng: np.random.Generator | int | None = None, length: float = 800.0,
              center=(0.0, 0.0, 950.0), half_size=(1000.0, 700.0, 500.0), step: float = 150.0,
              max_azimuth_deg: float = 45.0, max_elevation_deg: float = 75.0) -> BarTrack:
    """A reference bar moved by hand through the triplet volume.

    The bar's midpoint follows a smooth random walk (``step`` mm per position) inside the
    box ``center +- half_size``; its direction turns smoothly (azimuth from +X towards +Y
    within ``+-max_azimuth_deg``, elevation within ``+-max_elevation_deg``) so it never
    points at the cameras (which look along +Y); it starts horizontal along +X.
    """
    rng = as_rng(rng)
    as_int(n, "n")
    length = as_scalar(length, "length", positive=True)
    mid = _walk(rng, int(n), as_vector(center, "center", 3), as_vector(half_size,
                                                                          "half_size", 3), step)
    az = np.zeros(n)
    el = np.zeros(n)
    va = ve = 0.0
    for t in range(1, n):
        va = 0.8 * va + rng.normal(0, 3.0)
        ve = 0.8 * ve + rng.normal(0, 4.0)
        az[t] = az[t - 1] + va
        el[t] = el[t - 1] + ve
        if abs(az[t]) > max_azimuth_deg:
            az[t] = np.sign(az[t]) * max_azimuth_deg
            va = -va
        if abs(el[t]) > max_elevation_deg:
            el[t] = np.sign(el[t]) * max_elevation_deg
            ve = -ve
    a, e = np.radians(az), np.radians(el)
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    return BarTrack(A=mid - 0.5 * length * d, B=mid + 0.5 * length * d, length=length)


def levelled_bar(*, n_places: int = 4, frames_per_place: int = 3,
                 rng: np.random.Generator | int | None = None, length: float = 400.0,
                 center=(0.0, 0.0, 950.0), half_size=(200.0, 150.0, 100.0),
                 tilt_deg: float = 0.2) -> BarTrack:
    """The reference bar stood upright on a stand and set vertical with a spirit level, at
    ``n_places`` places in the box ``center +- half_size`` (uniform), held still for
    ``frames_per_place`` frames at each: how a studio levels its world (the ground-plane
    step of motion-capture calibration). Each time it stands ``tilt_deg`` per horizontal
    axis (Gaussian) off the true vertical, the level's own error; target B is on top.

    Parameters
    ----------
    n_places : int
        Places the bar is stood at (>= 1).
    frames_per_place : int
        Frames it is held still for at each place (>= 1).
    rng : Generator, int or None
        Random places and tilts.
    length : float
        Distance between the two targets, mm.
    center : (3,) array_like
        Centre of the box the bar's midpoint is drawn in, mm.
    half_size : (3,) array_like
        The box's half sizes, mm.
    tilt_deg : float
        Standard deviation of the tilt about each horizontal axis, degrees (>= 0).

    Returns
    -------
    BarTrack
        ``A`` (bottom) and ``B`` (top) of shape ``(n_places * frames_per_place, 3)``, mm,
        the frames of one place consecutive and equal; ``length``.
    """
    rng = as_rng(rng)
    n_places = as_int(n_places, "n_places")
    frames_per_place = as_int(frames_per_place, "frames_per_place")
    length = as_scalar(length, "length", positive=True)
    tilt = np.radians(as_scalar(tilt_deg, "tilt_deg", nonnegative=True))
    center = as_vector(center, "center", 3)
    half = as_vector(half_size, "half_size", 3)
    mid = center + rng.uniform(-1.0, 1.0, (n_places, 3)) * half
    a, b = rng.normal(0.0, tilt, (2, n_places))            # about X, then about Y
    d = np.stack([np.sin(b) * np.cos(a), -np.sin(a), np.cos(a) * np.cos(b)], axis=1)
    mid, d = np.repeat(mid, frames_per_place, axis=0), np.repeat(d, frames_per_place, axis=0)
    return BarTrack(A=mid - 0.5 * length * d, B=mid + 0.5 * length * d, length=length)


def led_path(*, n: int = 300, rng: np.random.Generator | int | None = None,
             center=(0.0, 0.0, 1100.0), half_size=(2600.0, 2600.0, 800.0),
             step: float = 120.0) -> np.ndarray:
    """An LED carried through the room: ``(n, 3)`` positions, mm (smooth random walk)."""
    rng = as_rng(rng)
    as_int(n, "n")
    return _walk(rng, int(n), as_vector(center, "center", 3),
                 as_vector(half_size, "half_size", 3), step)


def sweep_path(*, n: int = 400, rng: np.random.Generator | int | None = None,
               center=(0.0, 0.0, 1100.0), half_size=(4300.0, 1800.0, 700.0),
               passes: float = 2.0, step: float = 150.0) -> np.ndarray:
    """An LED carried up and down a long room: ``(n, 3)`` positions, mm.

    Along X (the room's length) the LED goes from one end to the other and back,
    ``passes`` times in all (a triangle wave over 97 % of ``half_size[0]``); across the
    room and in height it wanders as :func:`led_path`'s smooth random walk inside the box
    ``center +- half_size``. So the path covers the whole working volume, as Davis's Fig. 24
    asks, also where no camera sees it all.
    """
    rng = as_rng(rng)
    as_int(n, "n", minimum=2)
    passes = as_scalar(passes, "passes", positive=True)
    center = as_vector(center, "center", 3)
    half = as_vector(half_size, "half_size", 3)
    out = _walk(rng, int(n), center, half, step)
    s = np.linspace(0.0, passes, int(n))
    out[:, 0] = center[0] + 0.97 * half[0] * (1 - 2 * np.abs(s % 2 - 1))
    return out


def long_room_rig(*, rng: np.random.Generator | int | None = None, n_per_side: int = 4,
                  length: float = 9000.0, width: float = 4000.0, camera_height: float = 2800.0,
                  f: float = 400.0, width_px: int = 640, height_px: int = 480,
                  k1: float = -0.05) -> list[Camera]:
    """Ceiling cameras along both long walls of a ``length`` x ``width`` mm room, each
    looking across and down at the far half of the room (1 m high): a camera sees a few
    metres of the room, so it shares parts of an LED path with its neighbours only
    (partial overlap, Davis §3.2: "cameras not all of which have overlapping working
    volumes"). Numbered around the room: 0 .. n-1 along the wall at -Y (towards +X), then
    back along the wall at +Y. With ``rng``, poses and lenses are perturbed as in
    :func:`lsmta.synth.rigs.triplet_rig` (20 mm, 0.5 degrees, 3 px, 10 %).
    """
    as_int(n_per_side, "n_per_side", minimum=2)
    if rng is not None:
        rng = as_rng(rng)
    length = as_scalar(length, "length", positive=True)
    width = as_scalar(width, "width", positive=True)
    xs = (np.arange(int(n_per_side)) + 0.5) * length / n_per_side - length / 2
    cams = []
    for side, row in ((-1.0, xs), (1.0, xs[::-1])):
        for x in row:
            cam = Camera.look_at((x, side * width / 2, camera_height),
                                 (x, -0.1 * side * width, 1000.0), f=f, width=width_px,
                                 height=height_px, name=f"cam{len(cams):02d}")
            cam = cam.replace(k1=k1, k2=0.5 * abs(k1))
            cams.append(_perturbed(cam, rng, pose_mm=20.0, pose_deg=0.5, pp_px=3.0,
                                   distortion_rel=0.1))
    return cams


def project_observations(cameras, points, *, rng: np.random.Generator | int | None = None,
                         sigma_px: float = 0.0) -> np.ndarray:
    """``(K, N, 2)`` projections of ``points`` ``(N, 3)`` into K cameras plus Gaussian
    noise of ``sigma_px`` per coordinate; NaN where outside the image or behind."""
    out = []
    for cam in cameras:
        p = cam.project(points, behind="nan")
        p[~cam.in_image(p)] = np.nan
        if sigma_px > 0:
            p = p + as_rng(rng).normal(0, sigma_px, p.shape)
        out.append(p)
    return np.stack(out)


def render_bar_images(camera: Camera, track: BarTrack, *,
                      rng: np.random.Generator | int | None = None, dot_sigma: float = 1.6,
                      amplitude: float = 180.0, background: float = 25.0,
                      noise: float = 2.0) -> np.ndarray:
    """``(T, H, W)`` uint8 images of the two retro-reflective bar targets in one camera.

    Each target is a Gaussian dot (``dot_sigma`` px, peak ``amplitude`` grey levels,
    sampled at the pixel centres) at its projection through the camera's full model
    (distortion included) on a dark uniform ``background`` with Gaussian ``noise`` (grey
    levels), rounded to 8 bits - the dots of
    :func:`lsmta.synth.marker_video.render_marker_video` without the skin texture, drawn
    only where they are (so a sequence renders in a fraction of the time).
    """
    rng = as_rng(rng)
    pts = track.points
    T = len(pts)
    H, W = camera.height, camera.width
    sigma = as_scalar(dot_sigma, "dot_sigma", positive=True)
    xy = camera.project(pts.reshape(-1, 3), behind="nan").reshape(T, 2, 2)
    r = int(np.ceil(4 * sigma))
    off = np.arange(-r, r + 1)
    images = np.empty((T, H, W), np.uint8)
    for t in range(T):
        img = rng.standard_normal((H, W), dtype=np.float32)
        img *= np.float32(noise)
        img += np.float32(background)
        for q in xy[t]:
            if not (np.isfinite(q).all() and camera.in_image(q[None])[0]):
                continue
            c = np.round(q).astype(int)
            xs, ys = c[0] + off, c[1] + off
            mx, my = (xs >= 0) & (xs < W), (ys >= 0) & (ys < H)
            gx = np.exp(-((xs[mx] - q[0]) ** 2) / (2 * sigma**2))
            gy = np.exp(-((ys[my] - q[1]) ** 2) / (2 * sigma**2))
            img[np.ix_(ys[my], xs[mx])] += (amplitude * np.outer(gy, gx)).astype(np.float32)
        np.clip(np.round(img), 0, 255, out=img)
        images[t] = img
    return images


def poor_guess(cameras, *, rng: np.random.Generator | int | None = None, pose_mm: float = 150.0,
               pose_deg: float = 3.0, f_rel: float = 0.05) -> list[Camera]:
    """A tape-measured rig: every camera's centre off by ``pose_mm`` (per axis, Gaussian),
    its attitude by ``pose_deg`` per axis, its principal distance by ``f_rel`` (relative),
    the principal point at the image centre and no lens distortion."""
    rng = as_rng(rng)
    out = []
    for cam in cameras:
        dR, _ = cv2.Rodrigues(np.radians(rng.normal(0, pose_deg, 3)))
        out.append(cam.replace(R=dR @ cam.R, C=cam.C + rng.normal(0, pose_mm, 3),
                               f=cam.f * (1 + rng.normal(0, f_rel)),
                               cx=(cam.width - 1) / 2, cy=(cam.height - 1) / 2, k1=0.0, k2=0.0,
                               k3=0.0, p1=0.0, p2=0.0, b1=0.0, b2=0.0))
    return out


@dataclass(frozen=True, eq=False)
class BarFootage:
    """A session's calibration footage (:func:`bar_footage`).

    Attributes
    ----------
    bar, heldout : BarTrack
        The bar waved for the calibration, and the positions held out as check points.
    bar_videos, heldout_videos : (K, T, H, W) uint8 arrays
        Their videos in each camera.
    nominal : list of K Camera
        The tape-measured rig (:func:`poor_guess`).
    level : BarTrack or None
        The bar stood upright with a spirit level (None without ``level_places``).
    level_videos : (K, T, H, W) uint8 array or None
    """

    bar: BarTrack
    heldout: BarTrack
    bar_videos: np.ndarray
    heldout_videos: np.ndarray
    nominal: list
    level: BarTrack | None
    level_videos: np.ndarray | None


def bar_footage(cameras, *, length: float, center, half_size, n, noise: float, tape,
                level_places: int, step: float = 150.0,
                level_half_size=(200.0, 150.0, 100.0), level_tilt_deg: float = 0.2,
                rng: np.random.Generator | int | None = None) -> BarFootage:
    """The footage a studio calibrates from, rendered in ``cameras``: a bar of ``length`` mm
    waved ``n[0]`` times through the box ``center`` +- ``half_size`` (mm, moves of about
    ``step`` mm), ``n[1]`` more positions in 0.8 of that box as check points, the
    tape-measured rig (``tape`` = (mm per axis, degrees per axis, relative focal length
    error), :func:`poor_guess`), and with ``level_places`` > 0 the bar stood upright with
    a spirit level (``level_half_size`` box, ``level_tilt_deg`` off vertical), drawn last
    so the rest does not depend on it. Every draw comes from ``rng`` in that order (pass
    the session's generator to continue its stream); images get Gaussian noise of ``noise``
    grey levels."""
    rng = as_rng(rng)
    n_bar, n_heldout = n
    tape_mm, tape_deg, lens_rel = tape
    bar = bar_track(n=n_bar, rng=rng, length=length, center=center, half_size=half_size,
                    step=step)
    held = bar_track(n=n_heldout, rng=rng, length=length, center=center,
                     half_size=0.8 * np.asarray(half_size), step=step)
    bar_videos = np.stack([render_bar_images(c, bar, rng=rng, noise=noise) for c in cameras])
    held_videos = np.stack([render_bar_images(c, held, rng=rng, noise=noise) for c in cameras])
    nominal = poor_guess(cameras, rng=rng, pose_mm=tape_mm, pose_deg=tape_deg, f_rel=lens_rel)
    level, level_videos = None, None
    if level_places:
        level = levelled_bar(n_places=level_places, rng=rng, length=length, center=center,
                             half_size=level_half_size, tilt_deg=level_tilt_deg)
        level_videos = np.stack([render_bar_images(c, level, rng=rng, noise=noise)
                                 for c in cameras])
    return BarFootage(bar=bar, heldout=held, bar_videos=bar_videos, heldout_videos=held_videos,
                      nominal=nominal, level=level, level_videos=level_videos)
