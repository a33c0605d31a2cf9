"""Camera rigs of the synthetic world.

World frame: X to the right as seen from the rig, Y away from the rig into the volume,
Z up, millimetres; the floor is Z = 0 and the centre of the capture volume is near the
origin.
"""

from __future__ import annotations

import cv2
import numpy as np

from .._validate import as_int, as_rng, as_scalar, as_vector
from ..camera import Camera

# Our assumption (the paper gives no optics): a 1/2" CCD of the late 1990s, 768 x 576 pixels
# of about 8.4 um, behind an 8 mm lens.
TRIPLET_PIXEL_SIZE_MM = 0.0084
TRIPLET_PRINCIPAL_DISTANCE_MM = 8.0


def _perturbed(cam: Camera, rng: np.random.Generator | None, *, pose_mm: float,
               pose_deg: float, pp_px: float, distortion_rel: float) -> Camera:
    """A copy of ``cam`` whose pose, principal point and distortion vary a little."""
    if rng is None:
        return cam
    # distortion varies relative to its design value, so a zero coefficient stays zero
    angles = np.radians(rng.normal(0, pose_deg, 3))
    dR, _ = cv2.Rodrigues(angles)
    changes = {
        "R": dR @ cam.R,
        "C": cam.C + rng.normal(0, pose_mm, 3),
        "cx": cam.cx + rng.normal(0, pp_px),
        "cy": cam.cy + rng.normal(0, pp_px),
    }
    for key in ("k1", "k2", "k3", "p1", "p2", "b1", "b2"):
        value = getattr(cam, key)
        changes[key] = value * (1 + rng.normal(0, distortion_rel))
    return cam.replace(**changes)


def triplet_rig(*, rng: np.random.Generator | int | None = None, distance: float = 4500.0,
                baseline: float = 1200.0, camera_height: float = 1100.0,
                target_height: float = 950.0, width: int = 768,
                height_px: int = 576) -> list[Camera]:
    """The three-camera linear arrangement of the LSMTA paper (left, centre, right).

    Three convergent cameras on a line parallel to X, neighbours ``baseline`` mm apart, at
    ``Y = -distance`` and ``Z = camera_height``, all aimed at ``(0, 0, target_height)``.
    Images are ``width x height_px`` pixels (768 x 576 as in the paper) with a principal
    distance of 8 mm at 8.4 um pixels (about 952 px) and realistic lens distortion (about
    7 px of barrel distortion in the corners).

    Parameters
    ----------
    rng : numpy.random.Generator, int or None
        If given, every camera's pose (standard deviations 20 mm and 0.5 degrees per axis),
        principal point (3 px) and distortion (10 % of each nonzero coefficient) are
        perturbed from the nominal design, as in a real, hand-built rig. ``None`` gives the
        nominal rig.
    distance, baseline, camera_height, target_height : float
        Geometry in mm.

    Returns
    -------
    list of three :class:`~lsmta.camera.Camera`, named "left", "centre", "right".
    """
    if rng is not None:
        rng = as_rng(rng)
    distance = as_scalar(distance, "distance", positive=True)
    baseline = as_scalar(baseline, "baseline", positive=True)
    camera_height = as_scalar(camera_height, "camera_height")
    target_height = as_scalar(target_height, "target_height")
    f = TRIPLET_PRINCIPAL_DISTANCE_MM / TRIPLET_PIXEL_SIZE_MM
    lens = {
        "left": dict(k1=-0.085, k2=0.11, k3=-0.02, p1=2.0e-4, p2=-1.5e-4, b1=1.5e-4, b2=0.0),
        "centre": dict(k1=-0.080, k2=0.10, k3=-0.02, p1=-1.0e-4, p2=1.2e-4, b1=-1.0e-4, b2=0.0),
        "right": dict(k1=-0.090, k2=0.12, k3=-0.02, p1=1.0e-4, p2=2.0e-4, b1=0.8e-4, b2=0.0),
    }
    cams = []
    for name, x in zip(("left", "centre", "right"), (-baseline, 0.0, baseline)):
        cam = Camera.look_at([x, -distance, camera_height], [0.0, 0.0, target_height], f=f,
                             width=width, height=height_px, pixel_size=TRIPLET_PIXEL_SIZE_MM,
                             name=name).replace(**lens[name])
        cams.append(_perturbed(cam, rng, pose_mm=20.0, pose_deg=0.5, pp_px=3.0,
                               distortion_rel=0.1))
    return cams


def ring_rig(*, n: int = 8, rng: np.random.Generator | int | None = None, radius: float = 5000.0,
             camera_height: float = 2800.0, target=(0.0, 0.0, 1000.0), f: float = 600.0,
             width: int = 640, height_px: int = 480, k1: float = -0.05) -> list[Camera]:
    """``n`` cameras evenly spaced on a ceiling ring, all looking at ``target``.

    The generic n-camera rig: a room of radius ``radius`` mm with cameras at
    ``camera_height`` mm,
    as in wide-area tracking systems. With ``rng``, poses and lenses are perturbed as in
    :func:`triplet_rig`.

    Returns
    -------
    list of ``n`` :class:`~lsmta.camera.Camera`, named "cam00", "cam01", ...
    """
    as_int(n, "n", minimum=2, unit="cameras")
    if rng is not None:
        rng = as_rng(rng)
    target = as_vector(target, "target", 3)
    radius = as_scalar(radius, "radius", positive=True)
    cams = []
    for i, a in enumerate(np.linspace(0, 2 * np.pi, int(n), endpoint=False)):
        eye = [radius * np.sin(a), -radius * np.cos(a), camera_height]
        cam = Camera.look_at(eye, target, f=f, width=width, height=height_px,
                             name=f"cam{i:02d}").replace(k1=k1, k2=0.5 * abs(k1))
        cams.append(_perturbed(cam, rng, pose_mm=20.0, pose_deg=0.5, pp_px=3.0,
                               distortion_rel=0.1))
    return cams


def _studio_heights(heights, rows: int) -> np.ndarray:
    """``(rows,)`` camera heights of :func:`studio_rig`, checked (None: the default)."""
    if heights is None:
        heights = {1: (1400.0,), 2: (800.0, 2000.0)}.get(rows, np.linspace(600.0, 2200.0, rows))
    try:
        heights = np.atleast_1d(np.asarray(heights, float))
    except (TypeError, ValueError):
        heights = np.array([np.nan])
    if heights.shape != (rows,) or not np.isfinite(heights).all():
        raise ValueError(f"heights: expected {rows} finite camera heights (one per row), mm, "
                         f"got {heights.tolist()}")
    return heights


def studio_rig(*, n: int = 8, rows: int = 2, rng: np.random.Generator | int | None = None,
               radius: float = 3500.0, heights=None, target=(0.0, 0.0, 950.0),
               azimuth_deg: float = 45.0, f: float = 750.0, width: int = 768,
               height_px: int = 576, k1: float = -0.05) -> list[Camera]:
    """An all-round body-scanning studio: ``n`` cameras on ``n / rows`` poles around the
    subject, ``rows`` cameras one above the other on each pole, all aimed at ``target``.

    Body-scanning studios stand their cameras on vertical poles (or columns) evenly round
    the person, several to a pole at different heights. We follow that with two rows by
    default: 8 cameras on 4 poles. The two cameras of a pole form a vertical stereo pair
    that converges by about 20 degrees (the papers' triplet converges by about 15 degrees
    between neighbours), so least squares matching between them sees a moderately
    foreshortened patch; the upper row sees the shoulders and the head from above and
    the lower one the legs from below. Cameras of neighbouring poles are about 90 degrees
    apart, too far for LSM, so each pole is one view group
    (:func:`lsmta.systems.views.view_groups`) and every side of the body is seen by at
    least one pole. With ``rows=1`` the cameras stand on one ring (neighbours
    ``360 / n`` degrees apart).

    The poles stand at ``azimuth_deg + k 360 / (n / rows)`` degrees, measured from -Y
    (the side of the triplet) towards +X; the default 45 puts them on the diagonals, so a
    person walking along X passes between poles, is never walking straight at a camera,
    and each side of the body is seen by two poles.

    Parameters
    ----------
    n : int
        Number of cameras (6 to 8 in the studios this models; any n >= 2 that ``rows``
        divides).
    rows : int
        Cameras per pole.
    rng : numpy.random.Generator, int or None
        If given, poses and lenses are perturbed as in :func:`triplet_rig`.
    radius : float
        Distance of the poles from the studio's axis (through ``target``), mm.
    heights : sequence of ``rows`` floats, optional
        Camera heights above the floor, mm, bottom row first. Default: 800 and 2000 for
        two rows (knee-to-hip and above the head), 1400 for one, else evenly from 600 to
        2200.
    target : (3,) floats
        The point every camera looks at, mm.
    azimuth_deg : float
        Angle of the first pole, degrees (see above).
    f : float
        Principal distance, px (750 px: about 4.7 mm per pixel at 3.5 m, the triplet's
        4.7 mm at 4.5 m).
    width, height_px : int
        Image size, px.
    k1 : float
        Radial distortion (``k2 = |k1| / 2``).

    Returns
    -------
    list of ``n`` :class:`~lsmta.camera.Camera`
        Pole by pole, bottom row first within a pole, named "p0r0", "p0r1", "p1r0", ...
    """
    n = as_int(n, "n", minimum=2, unit="cameras")
    rows = as_int(rows, "rows", minimum=1, unit="cameras per pole")
    if n % rows:
        raise ValueError(f"rows: expected a divisor of n={n} (cameras per pole), got {rows}")
    heights = _studio_heights(heights, rows)
    if rng is not None:
        rng = as_rng(rng)
    target = as_vector(target, "target", 3)
    radius = as_scalar(radius, "radius", positive=True)
    azimuth = np.radians(as_scalar(azimuth_deg, "azimuth_deg"))
    f = as_scalar(f, "f", positive=True)
    width = as_int(width, "width", minimum=2, unit="px")
    height_px = as_int(height_px, "height_px", minimum=2, unit="px")
    k1 = as_scalar(k1, "k1")
    cams = []
    for pole, a in enumerate(azimuth + np.linspace(0, 2 * np.pi, n // rows, endpoint=False)):
        for row, z in enumerate(heights):
            eye = [target[0] + radius * np.sin(a), target[1] - radius * np.cos(a), z]
            cam = Camera.look_at(eye, target, f=f, width=width, height=height_px,
                                 name=f"p{pole}r{row}").replace(k1=k1, k2=0.5 * abs(k1))
            cams.append(_perturbed(cam, rng, pose_mm=20.0, pose_deg=0.5, pp_px=3.0,
                                   distortion_rel=0.1))
    return cams
