"""Pan-tilt camera models: the simple model (eq. 1) and the general model (eq. 2).

Davis (2002), Section 4.2. A pan-tilt head turns a rigid camera (optics and image plane)
about two axes. The *simple* model assumes both axes pass through the projection centre and
are aligned with the image (pan about the image's y axis, tilt about its x axis); the
*general* model lets each axis be an arbitrary line in space, with a direction and a point.

Conventions
-----------
Angles
    Pan and tilt are in **degrees**, as the Sony EVI-D30 of the thesis takes them. Every
    function that takes angles checks them against the head's mechanical range
    (``pan_limits``, ``tilt_limits``), so values in other units (motor counts, tenths of a
    degree) are refused with a message naming the argument. Radians passed where degrees are
    expected look like small angles; :func:`lsmta.pantilt.calibrate` refuses settings that
    all lie within ±π/2 while not all zero (no calibration can use such a small range).
Home pose
    At ``pan = tilt = 0`` the camera is :attr:`PanTiltCamera.camera` (a
    :class:`~lsmta.camera.Camera`: intrinsics, distortion and the home pose ``R, C``).
Axes
    Given in world coordinates at the home setting. Positive pan turns the view to the right
    of the image, positive tilt turns it up; for the simple model the pan axis is the
    camera's +y axis (down the image) and the tilt axis its +x axis (right), both through
    the projection centre. The pan joint carries the tilt joint (the tilt axis turns with
    pan, as in the EVI-D30), so the camera-to-world motion at ``(pan, tilt)`` is
    ``M = M_pan(pan) ∘ M_tilt(tilt)`` with ``M_axis(θ): X ↦ q + R(d, θ) (X - q)``. The thesis
    writes eq. 2 with the product in the other order; for the settings it calibrates with
    (pan at tilt 0, tilt at pan 0) the two orders agree, and ours is the mechanism's.
    The sense of each axis is part of the convention: a general model's pan axis must point
    along the camera's +y (a positive component, > 0.1) and its tilt axis along +x, else
    :class:`PanTiltCamera` raises ``ValueError`` (a reversed axis turns the head the other
    way, and :func:`lsmta.pantilt.params_from_model` could not represent it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_points, as_vector
from ..camera import Camera

#: Mechanical range of the Sony EVI-D30 in degrees (its data sheet: pan ±100°, tilt ±25°).
EVI_D30_PAN_LIMITS = (-100.0, 100.0)
EVI_D30_TILT_LIMITS = (-25.0, 25.0)


def axis_rotations(direction, angles_deg) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` by ``angles_deg`` (N,) about the unit vector ``direction``.

    Right-handed (Rodrigues): a positive angle turns counter-clockwise when seen from the tip
    of ``direction``.
    """
    d = np.asarray(direction, dtype=float)
    a = np.radians(np.asarray(angles_deg, dtype=float))
    K = np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    s = np.sin(a)[:, None, None]
    c = np.cos(a)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def check_angles(angles, name: str, limits: tuple[float, float]) -> np.ndarray:
    """Angles in degrees as a float64 array (any shape) inside ``limits``; a new array."""
    a = as_array(angles, name)
    lo, hi = limits
    bad = (a < lo - 1e-9) | (a > hi + 1e-9)
    if bad.any():
        worst = a[bad].flat[0]
        raise ValueError(
            f"{name}: expected angles in degrees within the head's range [{lo:g}, {hi:g}], got "
            f"{worst:g} ({np.count_nonzero(bad)} value(s) outside); angles are in degrees, not "
            "radians or motor units")
    return a


@dataclass(frozen=True, eq=False)
class PanTiltCamera:
    """A camera on a pan-tilt head (see the module docstring for the conventions).

    Parameters
    ----------
    camera : Camera
        Intrinsics, distortion and the pose at the home setting ``pan = tilt = 0``.
    pan_axis, tilt_axis : (3,) array
        Unit directions of the two axes in world coordinates at home (normalised here). Their
        sense is fixed by the sign convention: the pan axis must have a positive component
        (> 0.1) along the home camera's +y axis and the tilt axis along its +x axis;
        otherwise ``ValueError``.
    pan_point, tilt_point : (3,) array
        A point on each axis, world coordinates in mm.
    kind : {"simple", "general"}
        Which model this is; a simple model's axes must be the camera's y and x axes through
        its projection centre (use :meth:`simple`).
    pan_limits, tilt_limits : (float, float)
        Mechanical range in degrees (defaults: the Sony EVI-D30's).
    """

    camera: Camera
    pan_axis: np.ndarray
    pan_point: np.ndarray
    tilt_axis: np.ndarray
    tilt_point: np.ndarray
    kind: str = "general"
    pan_limits: tuple[float, float] = EVI_D30_PAN_LIMITS
    tilt_limits: tuple[float, float] = EVI_D30_TILT_LIMITS

    def __post_init__(self):
        if not isinstance(self.camera, Camera):
            raise TypeError(f"camera: expected an lsmta.Camera, got {type(self.camera).__name__}")
        if self.kind not in ("simple", "general"):
            raise ValueError(f"kind: expected 'simple' or 'general', got {self.kind!r}")
        for key in ("pan_axis", "tilt_axis", "pan_point", "tilt_point"):
            v = as_vector(getattr(self, key), key, 3).copy()
            if key.endswith("axis"):
                n = np.linalg.norm(v)
                if n == 0:
                    raise ValueError(f"{key}: expected a nonzero direction")
                v /= n
            v.flags.writeable = False
            object.__setattr__(self, key, v)
        for key in ("pan_limits", "tilt_limits"):
            lo, hi = (float(x) for x in getattr(self, key))
            if not lo < hi:
                raise ValueError(f"{key}: expected (low, high) with low < high, got {(lo, hi)}")
            object.__setattr__(self, key, (lo, hi))
        if abs(float(np.dot(self.pan_axis, self.tilt_axis))) > 0.99:
            raise ValueError("tilt_axis: must not be (nearly) parallel to pan_axis")
        # Sign convention: positive pan turns the view right and positive tilt turns it up,
        # which fixes the sense of each axis (pan along the camera's +y, tilt along its +x,
        # give or take a misalignment). An axis pointing the other way would silently turn
        # the head the other way, and the calibration's parameters could not represent it.
        R_home = np.asarray(self.camera.R)
        for key, row, image_axis in (("pan_axis", 1, "+y (down the image)"),
                                     ("tilt_axis", 0, "+x (right in the image)")):
            along = float(getattr(self, key) @ R_home[row])
            if not along > 0.1:
                raise ValueError(
                    f"{key}: expected a direction within about 84° of the home camera's "
                    f"{image_axis} axis, so that positive {key[:-5]} turns the view "
                    f"{'right' if row == 1 else 'up'}; got a component of {along:.3f} along "
                    "it (for an axis pointing the other way, negate it and the angles)")
        if self.kind == "simple":
            R, C = np.asarray(self.camera.R), self.camera.C
            if (not np.allclose(self.pan_axis, R[1], atol=1e-9)
                    or not np.allclose(self.tilt_axis, R[0], atol=1e-9)
                    or not np.allclose(self.pan_point, C, atol=1e-6)
                    or not np.allclose(self.tilt_point, C, atol=1e-6)):
                raise ValueError("kind: a 'simple' model has its axes along the camera's y and x "
                                 "axes through its centre; use PanTiltCamera.simple(camera)")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def simple(cls, camera: Camera, *, pan_limits=EVI_D30_PAN_LIMITS,
               tilt_limits=EVI_D30_TILT_LIMITS) -> PanTiltCamera:
        """The simple model (eq. 1): both axes through the projection centre, along the
        camera's y (pan) and x (tilt) axes; the head's range in degrees."""
        R = np.asarray(camera.R)
        return cls(camera, R[1], camera.C, R[0], camera.C, kind="simple",
                   pan_limits=pan_limits, tilt_limits=tilt_limits)

    @classmethod
    def from_offsets(cls, camera: Camera, *, pan_axis_cam=(0.0, 1.0, 0.0),
                     pan_point_cam=(0.0, 0.0, 0.0), tilt_axis_cam=(1.0, 0.0, 0.0),
                     tilt_point_cam=(0.0, 0.0, 0.0), pan_limits=EVI_D30_PAN_LIMITS,
                     tilt_limits=EVI_D30_TILT_LIMITS) -> PanTiltCamera:
        """A general model with axes given in the *camera* frame at home.

        Directions and points (mm, relative to the projection centre) are in camera
        coordinates (x right, y down, z forward); the defaults give the ideal head.
        ``pan_limits``, ``tilt_limits``: the head's range, degrees.
        """
        R = np.asarray(camera.R)
        return cls(camera, as_vector(pan_axis_cam, "pan_axis_cam", 3) @ R,
                   camera.C + as_vector(pan_point_cam, "pan_point_cam", 3) @ R,
                   as_vector(tilt_axis_cam, "tilt_axis_cam", 3) @ R,
                   camera.C + as_vector(tilt_point_cam, "tilt_point_cam", 3) @ R,
                   kind="general", pan_limits=pan_limits, tilt_limits=tilt_limits)

    def replace(self, **changes) -> PanTiltCamera:
        """A copy with some fields changed (:func:`dataclasses.replace`: unknown names are
        refused, the new model is checked like any other)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ geometry
    def check(self, pan, tilt):
        """``pan, tilt`` as float64 arrays in degrees, checked against the head's range."""
        return (check_angles(pan, "pan", self.pan_limits),
                check_angles(tilt, "tilt", self.tilt_limits))

    def poses(self, pan, tilt):
        """World-to-camera rotations ``(S, 3, 3)`` and centres ``(S, 3)`` (mm) at settings
        ``pan, tilt`` (degrees, broadcast to shape ``(S,)``)."""
        pan, tilt = self.check(pan, tilt)
        pan, tilt = (np.atleast_1d(a).ravel() for a in np.broadcast_arrays(pan, tilt))
        return self._poses(pan, tilt)

    def _poses(self, pan, tilt):
        return pose_arrays(np.asarray(self.camera.R), self.camera.C, self.pan_axis,
                           self.pan_point, self.tilt_axis, self.tilt_point, pan, tilt)

    def camera_at(self, pan: float, tilt: float) -> Camera:
        """The :class:`~lsmta.camera.Camera` at one setting (degrees)."""
        R, C = self.poses(pan, tilt)
        if len(C) != 1:
            raise ValueError("pan, tilt: expected one setting (two numbers)")
        return self.camera.replace(R=R[0], C=C[0])

    def to_camera(self, X, pan, tilt) -> np.ndarray:
        """Camera coordinates ``(N, 3)`` (mm) of world points ``X`` ``(N, 3)`` seen at settings
        ``pan, tilt`` (degrees; scalars or ``(N,)``, one setting per point)."""
        X = as_points(X, "X")
        pan, tilt = self.check(pan, tilt)
        try:
            pan, tilt = (np.broadcast_to(a, (len(X),)) for a in (pan, tilt))
        except ValueError:
            raise ValueError(f"pan, tilt: expected scalars or arrays of shape ({len(X)},) like X, "
                             f"got shapes {np.shape(pan)} and {np.shape(tilt)}") from None
        R, C = self._poses(pan, tilt)
        return np.einsum("nij,nj->ni", R, X - C)

    def project(self, X, pan, tilt, *, behind: str = "raise") -> np.ndarray:
        """Pixel coordinates ``(N, 2)`` of world points ``X`` ``(N, 3)`` (mm) at settings
        ``pan, tilt``.

        Parameters
        ----------
        X : (N, 3) array
            World points in mm.
        pan, tilt : float or (N,) array
            Settings in degrees, one per point (scalars apply to all points). To see M points
            at S settings, repeat: ``np.repeat(pan, M)`` and ``np.tile(X, (S, 1))``.
        behind : {"raise", "nan"}
            Points on or behind the image plane: raise ``ValueError`` or give NaN.
        """
        if behind not in ("raise", "nan"):
            raise ValueError(f"behind: expected 'raise' or 'nan', got {behind!r}")
        Xc = self.to_camera(X, pan, tilt)
        return _image(self.camera, Xc, behind)

    def _project(self, X, pan, tilt):
        """:meth:`project` without argument checks (for inner loops): ``X`` (N, 3) and
        ``pan, tilt`` (N,) float arrays; NaN for points behind the camera."""
        R, C = self._poses(pan, tilt)
        return _image(self.camera, np.einsum("nij,nj->ni", R, X - C), "nan")

    def __repr__(self) -> str:
        return (f"PanTiltCamera({self.kind}, {self.camera!r}, pan axis "
                f"{np.round(self.pan_axis, 4).tolist()} through "
                f"{np.round(self.pan_point, 1).tolist()}, tilt axis "
                f"{np.round(self.tilt_axis, 4).tolist()} through "
                f"{np.round(self.tilt_point, 1).tolist()})")


def pose_arrays(R0, C0, pan_axis, pan_point, tilt_axis, tilt_point, pan, tilt):
    """World-to-camera rotations ``(S, 3, 3)`` and centres ``(S, 3)`` at settings ``pan,
    tilt`` ``(S,)`` (degrees, unchecked) of a head with home pose ``R0, C0`` and the given
    unit axes and axis points (world coordinates). The arithmetic of
    :meth:`PanTiltCamera.poses`, on plain arrays for inner loops."""
    Rp = axis_rotations(pan_axis, pan)
    Rt = axis_rotations(tilt_axis, tilt)
    # M(X) = qp + Rp (qt + Rt (X - qt) - qp)
    Ct = tilt_point + (C0 - tilt_point) @ np.swapaxes(Rt, 1, 2)
    C = pan_point + np.einsum("sij,sj->si", Rp, Ct - pan_point)
    R = R0 @ np.swapaxes(Rt, 1, 2) @ np.swapaxes(Rp, 1, 2)
    return R, C


def _image(camera: Camera, Xc: np.ndarray, behind: str) -> np.ndarray:
    z = Xc[:, 2]
    front = z > 0
    if behind == "raise" and not front.all():
        raise ValueError(f"X: {np.count_nonzero(~front)} point(s) lie on or behind the image "
                         "plane at their settings (camera z <= 0)")
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = camera._to_pixel(camera._distort(Xc[:, 0] / z, Xc[:, 1] / z))
    xy[~front] = np.nan
    return xy
