"""Ray-cast renderer of the synthetic world, with per-pixel ground truth.

Each pixel is the mean of ``s x s`` rays (``s`` = ``supersample``, odd) cast through a
regular grid inside the pixel, every ray undistorted through the camera's own lens
model, so images carry exactly the camera's distortion. A ray takes the nearest of its
intersections with the body's ellipsoids and the static background (a textured wall
and floor), which makes occlusion depth-correct. Grey value = albedo x solid texture x
Lambertian shading (ambient plus one distant light), scaled to [0, 255], then optional
additive Gaussian noise and rounding to 8 bits.

Ground-truth maps come from the ray through the pixel *centre* (the middle ray of the
odd supersampling grid): which part it hits (:data:`BACKGROUND` for wall and floor,
:data:`NOTHING` for no hit), the part-local surface point, the world point and the
depth (camera z, mm). The rays are cast compiled, one ray per pass of a ``prange`` loop
over the parts (numba, :func:`cast_body`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from .._validate import as_array, as_int, as_rng, as_scalar
from ..camera import Camera
from .body import Body, Motion, SolidTexture

BACKGROUND = -1
NOTHING = -2


@dataclass(frozen=True, eq=False)
class Background:
    """A static textured wall (the plane Y = ``wall_y``) and floor (Z = 0).

    Build with :func:`make_background`.
    """

    wall_y: float
    floor: bool
    albedo: float
    texture: SolidTexture


def make_background(*, rng: np.random.Generator | int | None = None, wall_y: float = 2500.0,
                    floor: bool = True, albedo: float = 0.45, contrast: float = 0.15,
                    wavelength=(80.0, 600.0)) -> Background:
    """A wall behind the subject and a floor, with their own solid texture (world frame)."""
    rng = as_rng(rng)
    texture = SolidTexture.random(1, contrast, rng=rng, wavelength=wavelength, n_waves=24)
    return Background(wall_y=as_scalar(wall_y, "wall_y"), floor=bool(floor),
                      albedo=as_scalar(albedo, "albedo", nonnegative=True), texture=texture)


@dataclass(frozen=True, eq=False)
class Scene:
    """What the cameras see: a body, its motion, an optional background and the light.

    Attributes
    ----------
    body : Body
    motion : Motion
    background : Background or None
    light : (3,) array
        Direction towards the distant light (world frame; normalised on construction).
    ambient : float
        Share of ambient light in [0, 1]; the rest is Lambertian.
    backdrop : float
        Grey level (0-255, before noise) of rays that hit nothing: a dark backdrop. 0 is
        pure black, where 8-bit rounding clips half the noise; a real camera's black level
        (pedestal) keeps a dark backdrop a few grey levels above 0, so its noise stays
        measurable.
    """

    body: Body
    motion: Motion
    background: Background | None = None
    light: np.ndarray = field(default_factory=lambda: np.array([0.3, -1.0, 1.2]))
    ambient: float = 0.55
    backdrop: float = 0.0

    def __post_init__(self):
        light = as_array(self.light, "light", shape=(3,))
        if np.linalg.norm(light) == 0:
            raise ValueError("light: expected a non-zero direction")
        object.__setattr__(self, "light", light / np.linalg.norm(light))
        a = as_scalar(self.ambient, "ambient")
        if not 0 <= a <= 1:
            raise ValueError(f"ambient: expected a value in [0, 1], got {a}")
        b = as_scalar(self.backdrop, "backdrop")
        if not 0 <= b <= 255:
            raise ValueError(f"backdrop: expected a grey level in [0, 255], got {b}")


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    """Images of one frame in K cameras, and their ground truth.

    Attributes
    ----------
    frame : int
    images : (K, H, W) array
        Grey images: uint8 (rounded, clipped to 0-255) or float64 (0-255 before noise; the
        noise is not clipped), the ``dtype`` of :class:`Renderer`.
    part_id : (K, H, W) int16 array
        Part hit by the pixel-centre ray; :data:`BACKGROUND` (-1) or :data:`NOTHING` (-2).
    local_xyz : (K, H, W, 3) array
        Part-local coordinates of the surface point (mm), NaN off the body.
    world_xyz : (K, H, W, 3) array
        World coordinates of the surface point (mm), NaN where nothing is hit.
    depth : (K, H, W) array
        Camera z of the surface point (mm), NaN where nothing is hit.
    """

    frame: int
    images: np.ndarray
    part_id: np.ndarray
    local_xyz: np.ndarray
    world_xyz: np.ndarray
    depth: np.ndarray


@dataclass(frozen=True, eq=False)
class SurfaceProjection:
    """True image positions of body-local surface points.

    Attributes
    ----------
    xy : (T, K, N, 2) array
        Pixel coordinates in each camera (NaN behind the camera).
    visible : (T, K, N) bool array
        In front of the camera, inside the image, and not hidden by any surface.
    world : (T, N, 3) array
        World coordinates (mm).
    """

    xy: np.ndarray
    visible: np.ndarray
    world: np.ndarray


class Renderer:
    """Renders a :class:`Scene` in a list of cameras, frame by frame.

    The sample rays of every camera and the static background are computed once and
    reused for every frame.

    Parameters
    ----------
    scene : Scene
    cameras : sequence of Camera
    supersample : int
        Odd number ``s``: each pixel averages ``s x s`` rays (default 3).
    noise_sigma : float
        Standard deviation of additive Gaussian noise, in grey levels.
    dtype : numpy dtype
        ``numpy.uint8`` (rounded and clipped, as a frame grabber delivers) or
        ``numpy.float64`` (no quantisation).
    """

    def __init__(self, scene: Scene, cameras, *, supersample: int = 3, noise_sigma: float = 0.0,
                 dtype=np.uint8):
        if not isinstance(scene, Scene):
            raise TypeError(f"scene: expected an lsmta.synth.Scene, got {type(scene).__name__}")
        self.cameras = list(cameras)
        if not self.cameras or not all(isinstance(c, Camera) for c in self.cameras):
            raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
        as_int(supersample, "supersample", odd=True)
        dtype = np.dtype(dtype)
        if dtype not in (np.dtype(np.uint8), np.dtype(np.float64)):
            raise ValueError(f"dtype: expected numpy.uint8 or numpy.float64, got {dtype}")
        self.scene = scene
        self.supersample = int(supersample)
        self.noise_sigma = as_scalar(noise_sigma, "noise_sigma", nonnegative=True)
        self.dtype = dtype
        self._cache: dict[int, dict] = {}

    def with_scene(self, scene: Scene) -> Renderer:
        """The same cameras and settings on another scene (e.g. another texture).

        The per-camera rays (and background hits, when ``scene`` has the same background
        object and backdrop) are shared, so the new renderer's first frame costs no set-up.
        """
        other = Renderer(scene, self.cameras, supersample=self.supersample,
                         noise_sigma=self.noise_sigma, dtype=self.dtype)
        if (scene.background is self.scene.background
                and scene.backdrop == self.scene.backdrop):
            other._cache = self._cache
        else:
            other._cache = {k: {"dirs": c["dirs"]} for k, c in self._cache.items()}
        return other

    def _camera_cache(self, k: int) -> dict:
        entry = self._cache.get(k, {})
        if "t_bg" not in entry:
            cam = self.cameras[k]
            dirs = entry.get("dirs")
            if dirs is None:
                _, dirs = cam.rays(cam.pixel_grid(supersample=self.supersample).reshape(-1, 2))
            t_bg, grey_bg = _background_hits(self.scene, cam.C, dirs)
            self._cache[k] = {"dirs": dirs, "t_bg": t_bg, "grey_bg": grey_bg}
        return self._cache[k]

    def render(self, frame: int, *, rng: np.random.Generator | int | None = None,
               noise_sigma: float | None = None) -> RenderedFrame:
        """Render one frame in every camera.

        Parameters
        ----------
        frame : int
            Frame index of the scene's motion.
        rng : numpy.random.Generator, int or None
            Needed when the noise is > 0: draws the image noise.
        noise_sigma : float, optional
            Noise for this frame only (default: the renderer's ``noise_sigma``).
        """
        sigma = self.noise_sigma if noise_sigma is None else as_scalar(
            noise_sigma, "noise_sigma", nonnegative=True)
        if sigma > 0:
            if rng is None:
                raise ValueError("rng: a numpy.random.Generator or a seed is needed when "
                                 "noise_sigma > 0")
            rng = as_rng(rng)
        if np.ndim(frame) != 0:
            raise ValueError(f"frame: expected one frame index, got {frame!r}; render frames "
                             "one at a time")
        frame = int(self.scene.motion._frames(frame)[0])
        poses = self.scene.body.part_poses(self.scene.motion, frames=frame)[0]
        s = self.supersample
        out = {key: [] for key in ("images", "part_id", "local_xyz", "world_xyz", "depth")}
        for k, cam in enumerate(self.cameras):
            cache = self._camera_cache(k)
            dirs = cache["dirs"]
            hit = cast_body(self.scene.body, poses, cam.C, dirs)
            body_wins = hit.t < cache["t_bg"]
            grey = cache["grey_bg"].copy()
            if body_wins.any():
                grey[body_wins] = _body_grey(self.scene, poses, hit, body_wins)
            H, W = cam.height, cam.width
            image = grey.reshape(H, s, W, s).mean(axis=(1, 3))
            # ground truth from the central ray of each pixel
            centre = np.zeros((H, s, W, s), dtype=bool)
            centre[:, s // 2, :, s // 2] = True
            centre = centre.ravel()
            t = np.minimum(hit.t, cache["t_bg"])[centre]
            t = np.where(np.isfinite(t), t, np.nan)
            on_body = body_wins[centre]
            part = np.where(on_body, hit.part[centre],
                            np.where(np.isnan(t), NOTHING, BACKGROUND)).astype(np.int16)
            world = cam.C + t[:, None] * dirs[centre]
            local = np.where(on_body[:, None], hit.local[centre], np.nan)
            depth = (world - cam.C) @ cam.R[2]
            out["images"].append(image)
            out["part_id"].append(part.reshape(H, W))
            out["local_xyz"].append(local.reshape(H, W, 3))
            out["world_xyz"].append(world.reshape(H, W, 3))
            out["depth"].append(depth.reshape(H, W))
        images = np.stack(out["images"])
        if sigma > 0:
            images = images + rng.normal(0.0, sigma, images.shape)
        if self.dtype == np.uint8:
            images = np.clip(np.rint(images), 0, 255).astype(np.uint8)
        return RenderedFrame(frame=frame, images=images,
                             **{k: np.stack(v) for k, v in out.items() if k != "images"})


@dataclass(frozen=True)
class BodyHits:
    """Nearest ray-body intersections: ``t`` (M,) (inf for a miss), ``part`` (M,),
    ``local`` (M, 3) part-local point, ``normal`` (M, 3) world unit normal."""

    t: np.ndarray
    part: np.ndarray
    local: np.ndarray
    normal: np.ndarray


def cast_body(body: Body, poses: np.ndarray, origin: np.ndarray, dirs: np.ndarray) -> BodyHits:
    """Nearest intersection of rays from one ``origin`` with the body's ellipsoids.

    Parameters
    ----------
    body : Body
    poses : (P, 4, 4) array
        Part -> world transforms of one frame (:meth:`Body.part_poses`).
    origin : (3,) array
        Common origin of the rays (a projection centre), mm.
    dirs : (M, 3) array
        Unit ray directions.
    """
    P = len(body.parts)
    # per part: rotation, translation, centre and radii; the bounding sphere's cone
    # (cheap test, exact: never misses a hit), and the origin in the unit-sphere frame
    rot = np.ascontiguousarray(np.asarray(poses, float)[:P, :3, :3])
    geo = np.zeros((P, 9))           # centre (3), radii (3), use the cone, its cos, |o_s|^2 - 1
    cone = np.zeros((P, 3))
    o_unit = np.zeros((P, 3))
    for p, spec in enumerate(body.parts):
        R, T = poses[p, :3, :3], poses[p, :3, 3]
        c = np.asarray(spec.centre, float)
        r = np.asarray(spec.radii, float)
        centre_w = R @ c + T
        to_c = centre_w - origin
        dist = np.linalg.norm(to_c)
        rad = r.max()
        geo[p, :3], geo[p, 3:6] = c, r
        if dist > rad:
            geo[p, 6], geo[p, 7] = 1.0, np.sqrt(1 - (rad / dist) ** 2)
            cone[p] = to_c / dist
        o_s = (R.T @ (origin - T) - c) / r                    # (3,) in unit-sphere frame
        o_unit[p] = o_s
        geo[p, 8] = o_s @ o_s - 1.0
    t_best, part, local, normal = _cast(np.ascontiguousarray(dirs, float), rot, geo, cone,
                                        o_unit)
    return BodyHits(t=t_best, part=part, local=local, normal=normal)


@nb.njit(cache=True, error_model="numpy", parallel=True)
def _cast(dirs, rot, geo, cone, o_unit):
    """Nearest ellipsoid hit of each ray (:func:`cast_body`): ``t (M,)`` (inf: a miss),
    ``part (M,)`` (-1), the part-local point ``(M, 3)`` and the world unit normal
    ``(M, 3)`` (NaN for a miss)."""
    M, P = len(dirs), len(rot)
    t_best = np.full(M, np.inf)
    part = np.full(M, -1, np.int64)
    local = np.full((M, 3), np.nan)
    normal = np.full((M, 3), np.nan)
    for m in nb.prange(M):
        u0, u1, u2 = dirs[m, 0], dirs[m, 1], dirs[m, 2]
        for p in range(P):
            if geo[p, 6] > 0 and (u0 * cone[p, 0] + u1 * cone[p, 1] + u2 * cone[p, 2]
                                  < geo[p, 7] - 1e-12):
                continue
            d0 = (u0 * rot[p, 0, 0] + u1 * rot[p, 1, 0] + u2 * rot[p, 2, 0]) / geo[p, 3]
            d1 = (u0 * rot[p, 0, 1] + u1 * rot[p, 1, 1] + u2 * rot[p, 2, 1]) / geo[p, 4]
            d2 = (u0 * rot[p, 0, 2] + u1 * rot[p, 1, 2] + u2 * rot[p, 2, 2]) / geo[p, 5]
            a = d0 * d0 + d1 * d1 + d2 * d2
            b = d0 * o_unit[p, 0] + d1 * o_unit[p, 1] + d2 * o_unit[p, 2]
            cc = geo[p, 8]
            disc = b * b - a * cc
            if not disc >= 0:
                continue
            q = -(b + np.copysign(np.sqrt(disc), b))          # stable quadratic roots
            t1, t2 = q / a, cc / q
            if np.isnan(t1) or np.isnan(t2):
                continue
            t = min(t1, t2)
            if not t > 0:
                t = max(t1, t2)                               # origin inside: far root
            if t > 0 and t < t_best[m]:
                t_best[m] = t
                part[m] = p
                local[m, 0] = (o_unit[p, 0] + t * d0) * geo[p, 3] + geo[p, 0]
                local[m, 1] = (o_unit[p, 1] + t * d1) * geo[p, 4] + geo[p, 1]
                local[m, 2] = (o_unit[p, 2] + t * d2) * geo[p, 5] + geo[p, 2]
        k = part[m]
        if k >= 0:                                            # the gradient of |x / r|^2
            n0 = (local[m, 0] - geo[k, 0]) / geo[k, 3] ** 2
            n1 = (local[m, 1] - geo[k, 1]) / geo[k, 4] ** 2
            n2 = (local[m, 2] - geo[k, 2]) / geo[k, 5] ** 2
            w0 = n0 * rot[k, 0, 0] + n1 * rot[k, 0, 1] + n2 * rot[k, 0, 2]
            w1 = n0 * rot[k, 1, 0] + n1 * rot[k, 1, 1] + n2 * rot[k, 1, 2]
            w2 = n0 * rot[k, 2, 0] + n1 * rot[k, 2, 1] + n2 * rot[k, 2, 2]
            norm = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            normal[m, 0], normal[m, 1], normal[m, 2] = w0 / norm, w1 / norm, w2 / norm
    return t_best, part, local, normal


def _background_distances(bg: Background | None, origin: np.ndarray, dirs: np.ndarray):
    """Distance along each ray to the wall and to the floor (inf where missed)."""
    M = len(dirs)
    if bg is None:
        return np.full(M, np.inf), np.full(M, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = (bg.wall_y - origin[1]) / dirs[:, 1]
        z_wall = origin[2] + t_wall * dirs[:, 2]
        t_wall = np.where((t_wall > 0) & (z_wall >= 0 if bg.floor else True), t_wall, np.inf)
        if bg.floor:
            t_floor = -origin[2] / dirs[:, 2]
            y_floor = origin[1] + t_floor * dirs[:, 1]
            t_floor = np.where((t_floor > 0) & (y_floor <= bg.wall_y), t_floor, np.inf)
        else:
            t_floor = np.full(M, np.inf)
    return t_wall, t_floor


def _background_hits(scene: Scene, origin: np.ndarray, dirs: np.ndarray):
    """Distance along each ray to the wall or floor, and the grey value there (0-255)."""
    t_wall, t_floor = _background_distances(scene.background, origin, dirs)
    t = np.minimum(t_wall, t_floor)
    grey = np.full(len(dirs), float(scene.backdrop))
    hit = np.isfinite(t)
    if hit.any():
        bg = scene.background
        pts = origin + t[hit, None] * dirs[hit]
        tex = bg.texture.value(np.zeros(hit.sum(), dtype=int), pts)
        shade = np.where(t_floor[hit] < t_wall[hit], 0.85, 1.0)
        grey[hit] = 255.0 * np.clip(bg.albedo * tex * shade, 0.0, 1.0)
    return t, grey


def _body_grey(scene: Scene, poses, hit: BodyHits, sel: np.ndarray) -> np.ndarray:
    part = hit.part[sel]
    tex = scene.body.texture.value(part, hit.local[sel])
    albedo = np.array([p.albedo for p in scene.body.parts])[part]
    lambert = np.clip(hit.normal[sel] @ scene.light, 0.0, None)
    shade = scene.ambient + (1 - scene.ambient) * lambert
    return 255.0 * np.clip(albedo * tex * shade, 0.0, 1.0)


def project_surface_points(scene: Scene, cameras, part, local_points, *, frames=None,
                           tol: float = 1e-3) -> SurfaceProjection:
    """True image positions and visibility of body-local surface points.

    Parameters
    ----------
    scene : Scene
    cameras : sequence of K Camera
    part : str, int or (N,) int array
        Part of each point.
    local_points : (N, 3) array
        Points on the part ellipsoids, in part-local coordinates (mm), for example from
        :meth:`Body.sample_surface` or a rendering's ``local_xyz``.
    frames : int or sequence of int, optional
        Frames (default: all).
    tol : float
        A point is hidden when a surface lies more than ``tol`` mm in front of it along
        the viewing ray.

    Returns
    -------
    SurfaceProjection
    """
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    body, motion = scene.body, scene.motion
    pts = as_array(local_points, "local_points", shape=(None, 3))
    part_idx = body._part_indices(part, pts)
    frames = motion._frames(frames)
    world = body.to_world(motion, part_idx, pts, frames=frames)         # (T, N, 3)
    poses_all = body.part_poses(motion, frames=frames)
    T, N = world.shape[:2]
    xy = np.full((T, len(cameras), N, 2), np.nan)
    visible = np.zeros((T, len(cameras), N), dtype=bool)
    for k, cam in enumerate(cameras):
        for ti in range(T):
            proj = cam.project(world[ti], behind="nan")
            xy[ti, k] = proj
            cand = np.flatnonzero(cam.in_image(proj))
            if cand.size == 0:
                continue
            vec = world[ti, cand] - cam.C
            dist = np.linalg.norm(vec, axis=1)
            dirs = vec / dist[:, None]
            t_body = cast_body(body, poses_all[ti], cam.C, dirs).t
            t_wall, t_floor = _background_distances(scene.background, cam.C, dirs)
            nearest = np.minimum(t_body, np.minimum(t_wall, t_floor))
            visible[ti, k, cand] = nearest >= dist - tol
    return SurfaceProjection(xy=xy, visible=visible, world=world)
