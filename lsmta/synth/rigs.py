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
