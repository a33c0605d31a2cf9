"""More views for points a view pair measured: each point matched in every other camera that
sees it, then intersected from all its views.

A pair's point (e.g. from :func:`~lsmta.systems.rectified.measure_rectified_pair`) has two
views, so its reprojection residual is ~0 by construction and says nothing. Here each
point is projected into every other camera and matched there, so that its residual over
three or more views can judge it:

1. *a local plane*: the point's normal from its neighbours among the pair's points (the
   ``neighbours`` nearest within ``radius_factor`` times the median nearest-neighbour
   spacing, at least 5; fewer: no normal and no other view tried), turned towards the
   reference camera;
2. *visibility* (the rule): a camera is tried where the point lies in front of it and inside
   its lens model (:meth:`~lsmta.camera.Camera.in_lens`), projects inside its image with the
   patch around it, and the normal faces it within ``max_view_angle_deg`` (default 75, the
   view groups' limit: :func:`~lsmta.systems.views.view_groups`);
3. *LSM* (:func:`~lsmta.matching.lsm`, affine) of the reference camera's patch at the
   point's reference pixel into that camera, started at the projection with the affine map
   the local plane induces between the two views, the patch and then the retry patches; a
   view counts only where LSM converges and passes ``thresholds`` (the default: the
   rectified pairs' growth's, ``max_sigma0`` 20 grey levels; a growth group's own
   ``max_sigma0`` follows its noise, pass it to match it);
4. all counted views intersected (:func:`~lsmta.triangulation.triangulate`); the residual of
   a point is its largest reprojection error over its views.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar
from ..camera import Camera
from ..matching import LSMParams, LSMThresholds, Status, lsm
from ..triangulation import Intersection, triangulate


@dataclass(frozen=True)
class MoreViewsParams:
    """Settings of :func:`add_views` (module docstring).

    Attributes
    ----------
    neighbours : int
        Nearest points for the local plane.
    radius_factor : float
        Neighbours count within this many median nearest-neighbour spacings.
    max_view_angle_deg : float
        Largest angle between the normal and the direction to a camera tried, degrees.
    patch : int
        LSM patch, px; ``retry_patch`` the retries' patches.
    retry_patch : tuple of int
    thresholds : LSMThresholds
        Acceptance of a match (default: the rectified pairs' growth's, ``max_sigma0`` 20).
    """

    neighbours: int = 8
    radius_factor: float = 3.0
    max_view_angle_deg: float = 75.0
    patch: int = 13
    retry_patch: tuple = (21,)
    thresholds: LSMThresholds = field(default_factory=lambda: LSMThresholds(
        max_displacement=4.0, max_sigma_xy=0.2, scale_range=(0.5, 2.0), max_shear=0.5))

    def __post_init__(self):
        as_int(self.neighbours, "neighbours", minimum=5)
        as_scalar(self.radius_factor, "radius_factor", positive=True)
        if not 0 < self.max_view_angle_deg < 90:
            raise ValueError(f"max_view_angle_deg: expected an angle in (0, 90) degrees, got "
                             f"{self.max_view_angle_deg!r}")
        for size in (self.patch, *self.retry_patch):
            as_int(size, "patch", minimum=3, odd=True)
        if not isinstance(self.thresholds, LSMThresholds):
            raise TypeError(f"thresholds: expected an LSMThresholds, got "
                            f"{type(self.thresholds).__name__}")


@dataclass(frozen=True)
class MultiViewPoints:
    """Points matched in every camera that sees them (:func:`add_views`).

    Attributes
    ----------
    xy : (K, N, 2) array
        Image positions, px; NaN where a camera has no counted view.
    tried : (K, N) bool array
        Views tried by LSM (the visibility rule passed; the given views not included).
    normals : (N, 3) array
        Local plane normals (NaN: too few neighbours).
    intersection : Intersection
        All counted views intersected.
    n_views : (N,) int array
        Counted views per point.
    residual : (N,) array
        Largest reprojection error over the point's views, px (NaN: not intersected).
    census : list of K dict
        Per camera: ``given``, ``no_normal``, ``not_in_image``, ``not_facing``, ``tried``,
        ``accepted`` and LSM's statuses of the last attempt of those not accepted.
    """

    xy: np.ndarray
    tried: np.ndarray
    normals: np.ndarray
    intersection: Intersection
    n_views: np.ndarray
    residual: np.ndarray
    census: list


def group_xy(result, cameras, n_cameras: int) -> np.ndarray:
    """A view group's surface points as rows of all K cameras, for :func:`add_views`.

    Parameters
    ----------
    result : SurfaceResult
        The group's surface (:func:`~lsmta.systems.measure_surfaces`); its kept points.
    cameras : sequence of int
        The group's cameras among the K, in ``result.xy``'s row order.
    n_cameras : int
        K.

    Returns
    -------
    (K, N, 2) array
        The kept points' pixels in the group's rows, NaN in the other cameras' rows.
    """
    rows = [as_int(k, "cameras", minimum=0) for k in cameras]
    K = as_int(n_cameras, "n_cameras", minimum=1)
    if len(rows) != result.xy.shape[0] or max(rows) >= K:
        raise ValueError(f"cameras: expected {result.xy.shape[0]} camera indices in "
                         f"[0, {K - 1}] (one per row of result.xy), got {list(cameras)}")
    xy = np.full((K, int(result.kept.sum()), 2), np.nan)
    xy[rows] = result.xy[:, result.kept]
    return xy


def normal_angles(normals, points, cameras) -> np.ndarray:
    """Angles between each point's normal and the direction from it to each camera.

    Parameters
    ----------
    normals : (N, 3) array
        Unit normals (e.g. :attr:`MultiViewPoints.normals`); NaN rows: no normal.
    points : (N, 3) array
        The points, mm.
    cameras : sequence of C Camera

    Returns
    -------
    (C, N) array
        Degrees in [0, 180]; a camera faces a point's surface within ``a`` degrees where
        the angle is at most ``a`` (the visibility rule, module docstring). NaN without a
        normal or a point.
    """
    n, X = np.asarray(normals, float), np.asarray(points, float)
    out = []
    for cam in cameras:
        to = cam.C - X
        with np.errstate(invalid="ignore"):
            cos = np.einsum("ij,ij->i", n, to) / np.linalg.norm(to, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out) if out else np.empty((0, len(X)))


def local_normals(points, *, neighbours: int = 8, radius_factor: float = 3.0) -> np.ndarray:
    """Normals of planes fitted to each point's neighbours (module docstring).

    Parameters
    ----------
    points : (N, 3) array
        Points, mm; non-finite rows get no normal.
    neighbours : int
        Nearest points for the plane.
    radius_factor : float
        Neighbours count within this many median nearest-neighbour spacings.

    Returns
    -------
    (N, 3) array
        Unit normals, not oriented; NaN where fewer than 5 neighbours lie within the radius.
    """
    X = np.asarray(points, float)
    out = np.full(X.shape, np.nan)
    good = np.isfinite(X).all(axis=1)
    if good.sum() < 5:
        return out
    P = X[good]
    tree = cKDTree(P)
    k = min(neighbours + 1, len(P))
    dist, idx = tree.query(P, k=k)
    radius = radius_factor * float(np.median(dist[:, 1]))
    normals = np.full(P.shape, np.nan)
    for i in range(len(P)):
        near = idx[i][dist[i] <= radius]
        if len(near) < 5:
            continue
        Q = P[near] - P[near].mean(axis=0)
        normals[i] = np.linalg.svd(Q, full_matrices=False)[2][-1]
    out[good] = normals
    return out


def _induced_affine(ref: Camera, cam: Camera, xy, X, n) -> np.ndarray:
    """``(N, 2, 2)``: the affine map the planes ``(X, n)`` induce from ``ref``'s pixels ``xy``
    into ``cam`` (columns: one reference pixel along x and along y)."""
    cols = []
    base = cam.project(X, behind="nan")
    for step in (np.array([1.0, 0.0]), np.array([0.0, 1.0])):
        o, d = ref.rays(xy + step)
        t = np.einsum("ij,ij->i", X - o, n) / np.einsum("ij,ij->i", d, n)
        cols.append(cam.project(o + t[:, None] * d, behind="nan") - base)
    return np.stack(cols, axis=2)


def _match(ref_img, img, t_xy, s_xy, A0, p: MoreViewsParams):
    """LSM with the patch, then the retries; (accepted (N,) bool, xy (N, 2), last status)."""
    n = len(t_xy)
    ok, xy = np.zeros(n, bool), np.full((n, 2), np.nan)
    status = np.full(n, int(Status.CONVERGED))
    todo = np.arange(n)
    for size in (p.patch, *p.retry_patch):
        if todo.size == 0:
            break
        r = lsm(ref_img, img, t_xy[todo], s_xy[todo], initial_A=A0[todo],
                params=LSMParams(patch=size, thresholds=p.thresholds))
        st = np.asarray(r.status)
        good = st == Status.CONVERGED
        ok[todo[good]] = True
        xy[todo[good]] = r.xy[good]
        status[todo] = st
        todo = todo[~good]
    return ok, xy, status


def add_views(images, cameras, xy, *, reference: int,
              params: MoreViewsParams | None = None) -> MultiViewPoints:
    """Match points measured in some views in every other camera that sees them.

    Parameters
    ----------
    images : sequence of K (H_k, W_k) arrays
        One grey image per camera (each its camera's size).
    cameras : sequence of K Camera
    xy : (K, N, 2) array
        The points' measured positions, px; NaN in the views to add (at least two views
        given per point, e.g. a pair's).
    reference : int
        The camera whose patch is matched (a given view of every point, e.g. the pair's
        template).
    params : MoreViewsParams, optional

    Returns
    -------
    MultiViewPoints
    """
    p = params or MoreViewsParams()
    cams = list(cameras)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    K = len(cams)
    if len(images) != K:
        raise ValueError(f"images: expected {K} images (one per camera), got {len(images)}")
    imgs = [np.asarray(im, float) for im in images]
    for k, (im, c) in enumerate(zip(imgs, cams)):
        if im.shape != (c.height, c.width):
            raise ValueError(f"images: image {k} is {im.shape[1]} x {im.shape[0]} px but its "
                             f"camera is {c.width} x {c.height}")
    xy = np.array(xy, float)
    if xy.ndim != 3 or xy.shape[0] != K or xy.shape[2] != 2:
        raise ValueError(f"xy: expected a ({K}, N, 2) array, got shape {xy.shape}")
    reference = as_int(reference, "reference", minimum=0)
    if reference >= K or not np.isfinite(xy[reference]).all():
        raise ValueError(f"reference: expected a camera in [0, {K - 1}] in which every point "
                         f"is given, got {reference}")
    X = triangulate(cams, xy).points
    n = local_normals(X, neighbours=p.neighbours, radius_factor=p.radius_factor)
    ref = cams[reference]
    flip = np.einsum("ij,ij->i", n, ref.C - X) < 0
    n[flip] *= -1
    given = np.isfinite(xy).all(axis=2)
    tried = np.zeros((K, xy.shape[1]), bool)
    census = [_add_view(imgs, cams, xy, X, n, k, reference, given, tried, p) for k in range(K)]
    inter = triangulate(cams, xy)
    with np.errstate(invalid="ignore"):
        err = inter.reprojection_error
        residual = np.where(inter.valid, np.nanmax(np.where(np.isnan(err), -np.inf, err),
                                                    axis=0), np.nan)
    n_views = np.where(inter.valid, np.isfinite(xy).all(axis=2).sum(axis=0), 0)
    return MultiViewPoints(xy=xy, tried=tried, normals=n, intersection=inter, n_views=n_views,
                           residual=residual, census=census)


def _add_view(imgs, cams, xy, X, n, k, reference, given, tried, p) -> dict:
    """Camera ``k``'s views: the visibility rule, then LSM (fills ``xy[k]``, ``tried[k]``)."""
    cam = cams[k]
    todo = ~given[k]
    row = {"given": int(given[k].sum())}
    has_n = np.isfinite(n).all(axis=1) & np.isfinite(X).all(axis=1)
    row["no_normal"] = int((todo & ~has_n).sum())
    todo &= has_n
    half = max(p.patch, *p.retry_patch) // 2 + 1
    proj = np.full((len(X), 2), np.nan)
    idx = np.flatnonzero(todo)
    if idx.size:
        inside = cam.in_lens(X[idx])
        proj[idx[inside]] = cam.project(X[idx[inside]], behind="nan")
    with np.errstate(invalid="ignore"):
        in_image = ((proj[:, 0] >= half) & (proj[:, 0] <= cam.width - 1 - half)
                    & (proj[:, 1] >= half) & (proj[:, 1] <= cam.height - 1 - half))
    row["not_in_image"] = int((todo & ~in_image).sum())
    todo &= in_image
    to_cam = cam.C - X
    with np.errstate(invalid="ignore"):
        cos = np.einsum("ij,ij->i", n, to_cam) / np.linalg.norm(to_cam, axis=1)
    facing = cos >= np.cos(np.radians(p.max_view_angle_deg))
    row["not_facing"] = int((todo & ~facing).sum())
    todo &= facing
    idx = np.flatnonzero(todo)
    tried[k, idx] = True
    row["tried"] = int(idx.size)
    row["accepted"] = 0
    if idx.size == 0:
        return row
    with np.errstate(invalid="ignore", divide="ignore"):
        A0 = _induced_affine(cams[reference], cam, xy[reference, idx], X[idx], n[idx])
    finite = np.isfinite(A0).all(axis=(1, 2))       # a plane along the reference ray: none
    A0[~finite] = np.eye(2)
    ok, got, status = _match(imgs[reference], imgs[k], xy[reference, idx], proj[idx], A0, p)
    ok &= finite
    xy[k, idx[ok]] = got[ok]
    row["accepted"] = int(ok.sum())
    for s in Status:
        if s != Status.CONVERGED:
            row[s.name.lower()] = int((status[~ok] == s).sum())
    return row
