"""One camera: interior orientation, Brown distortion, affinity and shear, exterior orientation.

Conventions
-----------
World
    Right-handed, millimetres. The synthetic world uses Z up, with the floor at Z = 0.
Camera frame
    Origin at the projection centre ``C``; x to the right of the image, y down the image,
    z along the viewing direction (the OpenCV convention). A world point X has camera
    coordinates ``Xc = R @ (X - C)``: the rows of ``R`` are the camera axes written in
    world coordinates. A point is in front of the camera when ``Xc[2] > 0``.
Image
    Pixel coordinates ``(x, y)``: x to the right, y down, origin at the *centre* of the
    top-left pixel, so pixel ``(i, j)`` (row i, column j) covers ``[j-0.5, j+0.5] x
    [i-0.5, i+0.5]``. The same as OpenCV.
Interior orientation
    Principal distance ``f`` in pixels (square pixels; ``pixel_size`` in mm, if given,
    converts it to millimetres), principal point ``(cx, cy)`` in pixels.
Distortion (Brown, 1971)
    Applied in the forward direction to normalised coordinates ``x = Xc/Zc, y = Yc/Zc``
    (dimensionless), exactly as OpenCV's five-coefficient model::

        r2 = x² + y²
        xd = x (1 + k1 r2 + k2 r2² + k3 r2³) + 2 p1 x y + p2 (r2 + 2 x²)
        yd = y (1 + k1 r2 + k2 r2² + k3 r2³) + p1 (r2 + 2 y²) + 2 p2 x y

    Photogrammetric software often states K1, K2, K3 for image coordinates in mm and as
    corrections; with ours, ``K1_mm = k1 / c_mm²``, ``K2_mm = k2 / c_mm⁴``,
    ``K3_mm = k3 / c_mm⁶``, and the sign is that of a distortion, not a correction. The
    decentring pair follows OpenCV's order, which is swapped against Brown's: OpenCV's
    ``p2`` multiplies ``r2 + 2 x²``, Brown's P1 does.
Affinity and shear (B1, B2)
    ``u = cx + f ((1 + b1) xd + b2 yd)``, ``v = cy + f yd``: b1 scales x against y
    (non-square pixels, a clock mismatch of the frame grabber), b2 shears x by y.

Only ``b2 == 0`` cameras have an OpenCV counterpart (OpenCV's ``projectPoints`` ignores
skew): :meth:`Camera.to_opencv` refuses the others.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from ._validate import as_array, as_int, as_points, as_rotation, as_scalar, as_vector

DISTORTION_NAMES = ("k1", "k2", "k3", "p1", "p2", "b1", "b2")


#: largest error of distorting an undistorted point back, in normalised units: a point
#: beyond it lies where the distortion polynomial folds over
_INVERTED = 1e-10


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated frame camera (see the module docstring for the conventions).

    Parameters
    ----------
    f : float
        Principal distance in pixels.
    cx, cy : float
        Principal point in pixels.
    width, height : int
        Image size in pixels.
    R : (3, 3) array
        Rotation from world to camera coordinates.
    C : (3,) array
        Projection centre in world coordinates (mm).
    k1, k2, k3 : float
        Radial distortion (normalised coordinates).
    p1, p2 : float
        Decentring distortion (normalised coordinates).
    b1, b2 : float
        Affinity and shear.
    pixel_size : float, optional
        Pixel pitch in mm (only used to report the principal distance in mm).
    name : str
        A label for plots and messages.
    """

    f: float
    cx: float
    cy: float
    width: int
    height: int
    R: np.ndarray
    C: np.ndarray
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    b1: float = 0.0
    b2: float = 0.0
    pixel_size: float | None = None
    name: str = ""

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "f", as_scalar(self.f, "f", positive=True))
        for key in ("cx", "cy", *DISTORTION_NAMES):
            set_(self, key, as_scalar(getattr(self, key), key))
        if self.b1 <= -1:
            raise ValueError(f"b1: expected a number > -1 (x scale 1 + b1 > 0), got {self.b1}")
        for key in ("width", "height"):
            set_(self, key, as_int(getattr(self, key), key, unit="pixels"))
        if self.pixel_size is not None:
            set_(self, "pixel_size", as_scalar(self.pixel_size, "pixel_size", positive=True))
        R = as_rotation(self.R, "R").copy()
        C = as_vector(self.C, "C", 3).copy()
        R.flags.writeable = False
        C.flags.writeable = False
        set_(self, "R", R)
        set_(self, "C", C)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def look_at(cls, eye, target, *, f, width, height, up=(0.0, 0.0, 1.0), cx=None, cy=None,
                pixel_size: float | None = None, name: str = "") -> Camera:
        """A camera at ``eye`` (mm) whose optical axis points at ``target`` (mm), without
        distortion (add it with :meth:`replace`, e.g. ``.replace(k1=-0.1)``).

        ``up`` is the world direction that appears upwards in the image. ``cx, cy``
        default to the image centre; ``f``, ``width``, ``height``, ``pixel_size`` and
        ``name`` are :class:`Camera`'s.
        """
        eye = as_vector(eye, "eye", 3)
        target = as_vector(target, "target", 3)
        up = as_vector(up, "up", 3)
        z = target - eye
        if np.linalg.norm(z) == 0:
            raise ValueError("target: must differ from eye")
        z = z / np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:
            raise ValueError("up: must not be parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        cx = (width - 1) / 2 if cx is None else cx
        cy = (height - 1) / 2 if cy is None else cy
        return cls(f=f, cx=cx, cy=cy, width=width, height=height, R=np.stack([x, y, z]), C=eye,
                   pixel_size=pixel_size, name=name)

    @classmethod
    def from_opencv(cls, K, dist, rvec, tvec, image_size, *, pixel_size: float | None = None,
                    name: str = "") -> Camera:
        """A camera from OpenCV's ``(K, dist, rvec, tvec)`` and ``image_size = (width, height)``.

        ``dist`` holds ``(k1, k2, p1, p2[, k3[, ...]])``; coefficients beyond k3 (rational,
        thin-prism, tilt) must be zero because this model does not have them.
        ``pixel_size`` and ``name`` are :class:`Camera`'s.
        """
        K = as_array(K, "K", shape=(3, 3))
        if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise ValueError("K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError("K: expected positive focal lengths fx, fy")
        dist = as_array(dist, "dist").ravel()
        if dist.size not in (4, 5, 8, 12, 14):
            raise ValueError(f"dist: expected 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        if np.any(dist[5:] != 0):
            raise ValueError("dist: coefficients beyond k3 are not part of this camera model")
        d = np.zeros(5)
        d[: min(5, dist.size)] = dist[:5]
        rvec = as_array(rvec, "rvec").ravel()
        tvec = as_array(tvec, "tvec").ravel()
        if rvec.shape != (3,) or tvec.shape != (3,):
            raise ValueError("rvec, tvec: expected 3 numbers each")
        if len(image_size) != 2:
            raise ValueError("image_size: expected (width, height)")
        R, _ = cv2.Rodrigues(rvec)
        return cls(f=K[1, 1], cx=K[0, 2], cy=K[1, 2], width=image_size[0], height=image_size[1],
                   R=R, C=-R.T @ tvec, k1=d[0], k2=d[1], p1=d[2], p2=d[3], k3=d[4],
                   b1=K[0, 0] / K[1, 1] - 1.0, pixel_size=pixel_size, name=name)

    def to_opencv(self):
        """OpenCV's ``(K, dist, rvec, tvec)``; ``dist`` is ``(k1, k2, p1, p2, k3)``.

        Raises ``ValueError`` for a camera with shear (``b2 != 0``), which OpenCV cannot
        represent.
        """
        if self.b2 != 0:
            raise ValueError("b2: OpenCV's camera model has no shear; this camera has b2 != 0")
        K = np.array([[self.f * (1 + self.b1), 0, self.cx], [0, self.f, self.cy], [0, 0, 1.0]])
        dist = np.array([self.k1, self.k2, self.p1, self.p2, self.k3])
        rvec, _ = cv2.Rodrigues(np.asarray(self.R))
        tvec = -np.asarray(self.R) @ self.C
        return K, dist, rvec.ravel(), tvec

    def replace(self, **changes) -> Camera:
        """A copy with some fields changed (``dataclasses.replace``: any of the fields above,
        checked again as a new camera)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ properties
    @property
    def principal_distance_mm(self) -> float | None:
        """Principal distance in mm, if ``pixel_size`` is known."""
        return None if self.pixel_size is None else self.f * self.pixel_size

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.width, self.height

    @property
    def has_distortion(self) -> bool:
        return any(getattr(self, k) != 0 for k in DISTORTION_NAMES)

    # ------------------------------------------------------------------ geometry
    def to_camera(self, X) -> np.ndarray:
        """Camera coordinates ``(N, 3)`` (mm) of world points ``X`` ``(N, 3)`` (mm)."""
        X = as_points(X, "X")
        return (X - self.C) @ np.asarray(self.R).T

    def distort(self, xy_n) -> np.ndarray:
        """Apply lens distortion to normalised coordinates ``(N, 2)``."""
        xy_n = as_points(xy_n, "xy_n", 2)
        return self._distort(xy_n[:, 0], xy_n[:, 1])

    def _distort(self, x, y):
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_d, *, tol: float = 1e-14, max_iter: int = 30) -> np.ndarray:
        """Invert :meth:`distort` by Newton's method (vectorised over points).

        Parameters
        ----------
        xy_d : (N, 2) array
            Distorted normalised coordinates.

        Returns
        -------
        (N, 2) array
            Undistorted normalised coordinates; ``ValueError`` if the distortion cannot be
            inverted at some point (the model folds over, far outside a real lens's field).
        """
        xy_d = as_points(xy_d, "xy_d", 2)
        if not self.has_distortion:
            return xy_d.copy()
        xy, err = self._newton_undistort(xy_d, tol, max_iter)
        if not np.all(err < _INVERTED):
            bad = np.count_nonzero(~(err < _INVERTED))
            raise ValueError(
                f"xy_d: lens distortion cannot be inverted at {bad} "
                "point(s); they lie where the distortion polynomial folds over"
            )
        return xy

    def invertible(self, xy) -> np.ndarray:
        """``(N,)`` bool: the pixel positions ``xy`` ``(N, 2)`` lie where the lens model can be
        inverted (always, without distortion); :meth:`rays` raises for the others."""
        xy_d = self.pixel_to_normalized(xy)
        if not self.has_distortion:
            return np.isfinite(xy_d).all(axis=1)
        return self._newton_undistort(xy_d, 1e-14, 30)[1] < _INVERTED

    def _newton_undistort(self, xy_d, tol, max_iter):
        """Newton's iterations of :meth:`undistort`; returns the points and the error of
        distorting them back."""
        xd, yd = xy_d[:, 0], xy_d[:, 1]
        x, y = xd.copy(), yd.copy()                      # contiguous
        xd, yd = x.copy(), y.copy()
        coefficients = tuple(float(getattr(self, k)) for k in ("k1", "k2", "k3", "p1", "p2"))
        for _ in range(max_iter):       # every point steps until all have converged
            if _newton_step(x, y, xd, yd, *coefficients, float(tol)):
                break
        err = _undistort_error(x, y, xd, yd, *coefficients)   # as _distort and _unfolded
        return np.stack([x, y], axis=-1), err

    def _unfolded(self, x, y) -> np.ndarray:
        """Whether undistorted points lie where the lens model is a lens: the radial factor
        positive and the distortion's Jacobian determinant positive (Newton's method also
        finds roots past the fold, on the far side of the centre or on the folded-back
        sheet, which distort to the same point but are not where its ray goes)."""
        k1, k2, k3, p1, p2 = (float(getattr(self, k)) for k in ("k1", "k2", "k3", "p1", "p2"))
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        slope = k1 + r2 * (2 * k2 + 3 * k3 * r2)                    # d radial / d r2
        xx = radial + 2 * x * x * slope + 2 * p1 * y + 6 * p2 * x
        yy = radial + 2 * y * y * slope + 6 * p1 * y + 2 * p2 * x
        xy = 2 * x * y * slope + 2 * p1 * x + 2 * p2 * y
        with np.errstate(invalid="ignore"):
            return (radial > 0) & (xx * yy - xy * xy > 0)

    def normalized_to_pixel(self, xy_d) -> np.ndarray:
        """Pixel coordinates of distorted normalised coordinates ``(N, 2)``."""
        xy_d = as_points(xy_d, "xy_d", 2)
        return self._to_pixel(xy_d)

    def _to_pixel(self, xy_d):
        u = self.cx + self.f * ((1 + self.b1) * xy_d[:, 0] + self.b2 * xy_d[:, 1])
        v = self.cy + self.f * xy_d[:, 1]
        return np.stack([u, v], axis=-1)

    def pixel_to_normalized(self, xy) -> np.ndarray:
        """Distorted normalised coordinates of pixel coordinates ``(N, 2)``."""
        xy = as_points(xy, "xy", 2)
        yd = (xy[:, 1] - self.cy) / self.f
        xd = ((xy[:, 0] - self.cx) / self.f - self.b2 * yd) / (1 + self.b1)
        return np.stack([xd, yd], axis=-1)

    def project(self, X, *, behind: str = "raise") -> np.ndarray:
        """Pixel coordinates ``(N, 2)`` of world points ``X`` ``(N, 3)`` in mm.

        Parameters
        ----------
        X : (N, 3) array
            World points in mm.
        behind : {"raise", "nan"}
            What to do with points on or behind the camera plane (``Zc <= 0``): raise a
            ``ValueError``, or return NaN for them.
        """
        if behind not in ("raise", "nan"):
            raise ValueError(f"behind: expected 'raise' or 'nan', got {behind!r}")
        Xc = self.to_camera(X)
        z = Xc[:, 2]
        front = z > 0
        if behind == "raise" and not front.all():
            raise ValueError(
                f"X: {np.count_nonzero(~front)} point(s) lie on or behind camera "
                f"{self.name or '(unnamed)'} (camera z <= 0)"
            )
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = Xc[:, 0] / z
            yn = Xc[:, 1] / z
        xy = self._to_pixel(self._distort(xn, yn))
        xy[~front] = np.nan
        return xy

    def in_lens(self, X) -> np.ndarray:
        """Whether world points ``X`` ``(N, 3)`` (mm) lie in front of the camera and inside
        its lens model's fold ``(N,)`` bool: past the fold :meth:`project` still gives a
        pixel, but that pixel belongs to another ray."""
        Xc = self.to_camera(X)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return (z > 0) & self._unfolded(Xc[:, 0] / z, Xc[:, 1] / z)

    def rays(self, xy):
        """Viewing rays through pixel coordinates ``xy`` ``(N, 2)``.

        Returns
        -------
        origins : (N, 3) array
            The projection centre (mm), repeated.
        directions : (N, 3) array
            Unit direction vectors in world coordinates; ``project(origin + t * direction)``
            gives back ``xy`` for every ``t > 0``.
        """
        xy_n = self.undistort(self.pixel_to_normalized(xy))
        d_cam = np.concatenate([xy_n, np.ones((len(xy_n), 1))], axis=1)
        d = d_cam @ np.asarray(self.R)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.C, d.shape).copy(), d

    def in_image(self, xy) -> np.ndarray:
        """Boolean ``(N,)``: which pixel coordinates fall inside the image area."""
        xy = as_points(xy, "xy", 2, allow_nan=True)
        with np.errstate(invalid="ignore"):
            return ((xy[:, 0] >= -0.5) & (xy[:, 0] <= self.width - 0.5)
                    & (xy[:, 1] >= -0.5) & (xy[:, 1] <= self.height - 0.5))

    def pixel_grid(self, *, supersample: int = 1) -> np.ndarray:
        """Sample positions ``(H*s, W*s, 2)`` on a regular ``s x s`` grid inside every pixel."""
        s = as_int(supersample, "supersample")
        offsets = (np.arange(s) + 0.5) / s - 0.5
        xs = (np.arange(self.width)[:, None] + offsets[None, :]).ravel()
        ys = (np.arange(self.height)[:, None] + offsets[None, :]).ravel()
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx, gy], axis=-1)

    def __repr__(self) -> str:
        dist = ", ".join(f"{k}={getattr(self, k):.3g}" for k in DISTORTION_NAMES
                         if getattr(self, k))
        return (f"Camera({self.name!r}, {self.width}x{self.height}, f={self.f:.1f}px, "
                f"pp=({self.cx:.1f}, {self.cy:.1f}), C={np.round(self.C, 1).tolist()}"
                + (f", {dist}" if dist else "") + ")")


def scaled_camera(camera: Camera, factor: float) -> Camera:
    """The same camera with an image ``factor`` times as large in each direction.

    Principal distance, principal point and image size scale; distortion (in normalised
    coordinates) and pose stay. ``factor = 0.5`` renders four times faster.
    """
    factor = as_scalar(factor, "factor", positive=True)
    return camera.replace(f=camera.f * factor, cx=(camera.cx + 0.5) * factor - 0.5,
                          cy=(camera.cy + 0.5) * factor - 0.5,
                          width=int(round(camera.width * factor)),
                          height=int(round(camera.height * factor)),
                          pixel_size=None if camera.pixel_size is None
                          else camera.pixel_size / factor)


def cropped_camera(camera: Camera, x0: int, y0: int, width: int, height: int) -> Camera:
    """The same camera seeing only the pixel window ``[x0, x0 + width) x [y0, y0 + height)``
    of its image: the principal point shifts by ``(-x0, -y0)``, the size becomes the
    window's; lens and pose stay."""
    x0, y0 = as_int(x0, "x0", minimum=0), as_int(y0, "y0", minimum=0)
    width, height = as_int(width, "width"), as_int(height, "height")
    if x0 + width > camera.width or y0 + height > camera.height:
        raise ValueError(f"width, height: the window ({x0}, {y0}, {width} x {height}) does not "
                         f"fit the camera's {camera.width} x {camera.height} image")
    return camera.replace(cx=camera.cx - x0, cy=camera.cy - y0, width=width, height=height)


@nb.njit(cache=True, error_model="numpy", parallel=True)
def _newton_step(x, y, xd, yd, k1, k2, k3, p1, p2, tol):
    """One Newton step of :meth:`Camera.undistort` for every point ``x, y`` (in place)
    towards the distorted ``xd, yd``, the same arithmetic as the numpy form it replaced;
    True when every step was below ``tol``."""
    n_open = 0
    for i in nb.prange(len(x)):
        xi, yi = x[i], y[i]
        r2 = xi * xi + yi * yi
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        g = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d(radial)/d(r2)
        ex = xi * radial + 2 * p1 * xi * yi + p2 * (r2 + 2 * xi * xi) - xd[i]
        ey = yi * radial + p1 * (r2 + 2 * yi * yi) + 2 * p2 * xi * yi - yd[i]
        a = radial + 2 * g * xi * xi + 2 * p1 * yi + 6 * p2 * xi
        b = 2 * g * xi * yi + 2 * p1 * xi + 2 * p2 * yi
        d = radial + 2 * g * yi * yi + 6 * p1 * yi + 2 * p2 * xi
        det = a * d - b * b
        dx = (d * ex - b * ey) / det
        dy = (a * ey - b * ex) / det
        x[i] = xi - dx
        y[i] = yi - dy
        if not abs(dx) + abs(dy) < tol:
            n_open += 1
    return n_open == 0


@nb.njit(cache=True, error_model="numpy")
def _undistort_error(x, y, xd, yd, k1, k2, k3, p1, p2):
    """``(N,)`` distance of :meth:`Camera._distort` of ``x, y`` from ``xd, yd`` where
    :meth:`Camera._unfolded`, inf elsewhere: the same arithmetic as those numpy forms, in
    one pass (no temporary arrays)."""
    err = np.empty(len(x))
    for i in range(len(x)):
        xi, yi = x[i], y[i]
        r2 = xi * xi + yi * yi
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        slope = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        xx = radial + 2 * xi * xi * slope + 2 * p1 * yi + 6 * p2 * xi
        yy = radial + 2 * yi * yi * slope + 6 * p1 * yi + 2 * p2 * xi
        xy = 2 * xi * yi * slope + 2 * p1 * xi + 2 * p2 * yi
        if radial > 0 and xx * yy - xy * xy > 0:
            bx = xi * radial + 2 * p1 * xi * yi + p2 * (r2 + 2 * xi * xi)
            by = yi * radial + p1 * (r2 + 2 * yi * yi) + 2 * p2 * xi * yi
            err[i] = np.hypot(bx - xd[i], by - yd[i])
        else:
            err[i] = np.inf
    return err
