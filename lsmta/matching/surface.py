"""Surface measurement from one multi-image frame (LSMTA paper, Section 2.2).

The centre image is the template; dense matches are grown from the seeds into each search
image independently (:func:`~lsmta.matching.grow.grow_matches`), merged into n-tuples at
the common grid nodes, checked by the neighbourhood filter (outliers re-matched once from
their neighbours' prediction), intersected with the calibrated cameras and thinned by the
voxel filter; :class:`MeasureSurfaceParams` holds the settings of every stage. With
``joint=True`` (beyond the paper) every node is matched in all search images at once under
the epipolar condition (:func:`~lsmta.matching.grow.grow_joint`, Gruen & Baltsavias 1988),
so the n-tuples' rays meet by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from skimage.exposure import equalize_adapthist

from .._validate import as_array
from ..camera import Camera
from ..triangulation import Intersection, VoxelCloud, triangulate, voxel_filter
from .filters import neighbourhood_filter
from .grow import GrowParams, grow_joint, grow_matches
from .lsm import LSMParams, _params, _positive, lsm
from .mpgc import CameraGeometry, mpgc
from .spline import check_image


def enhance_contrast(image, *, clip_limit: float = 0.02, kernel_size: int | None = None):
    """Local contrast enhancement (CLAHE, scikit-image's ``equalize_adapthist``).

    Returns a float64 image in [0, 255]; the input is not modified. For poorly textured
    images (skin, plain cloth), as in the paper's Fig. 4.
    """
    img = check_image(image, "image")
    lo, hi = float(img.min()), float(img.max())
    scaled = (img - lo) / (hi - lo) if hi > lo else np.zeros_like(img)
    return 255.0 * equalize_adapthist(scaled, kernel_size=kernel_size, clip_limit=clip_limit)


@dataclass(frozen=True)
class SurfaceResult:
    """One frame's surface measurement, with every stage kept for inspection.

    Attributes
    ----------
    grown : list of GrowResult
        Growth into each search image (in the order of ``search`` indices).
    template_xy : (N, 2) array
        Grid nodes matched in every search image (the n-tuples), template pixels.
    xy : (K, N, 2) array
        The n-tuples' image positions in all K images (template row included).
    sigma_xy : (K, N, 2) array
        LSM standard deviations (zero for the template row).
    neighbourhood_ok : (N,) bool array
        Passed the neighbourhood filter (after re-matching) and, with ``max_reprojection``,
        the geometric check.
    rematched : (N,) bool array
        Removed by the neighbourhood filter, re-matched, and then accepted by it (the
        geometric check may still drop the node).
    intersection : Intersection
        Forward intersection of all n-tuples (before the filters).
    cloud : VoxelCloud or None
        The filtered, thinned points (None without ``voxel``).
    points : (M, 3) array
        The final points: voxel centres, or the filtered intersected points.
    points_xy : (K, M, 2) array
        Image positions of the final points (means within a voxel).
    off_subject : int
        n-tuples dropped afterwards because their template pixel lay off a subject mask
        (:class:`lsmta.systems.SurfaceParams` ``subject_mask``; 0 without one).
    """

    grown: list
    template_xy: np.ndarray
    xy: np.ndarray
    sigma_xy: np.ndarray
    neighbourhood_ok: np.ndarray
    rematched: np.ndarray
    intersection: Intersection
    cloud: VoxelCloud | None
    points: np.ndarray
    points_xy: np.ndarray
    off_subject: int = 0

    @property
    def kept(self) -> np.ndarray:
        """``(N,)`` bool: passed the filters and intersected (the surface's points)."""
        return self.neighbourhood_ok & self.intersection.valid


@dataclass(frozen=True)
class MeasureSurfaceParams:
    """Settings of :func:`measure_surface`: the growth and the filters after it. Built by
    keyword; every field is checked here, and the error names it.

    Attributes
    ----------
    grow : GrowParams
        The growth into the search images (:func:`~lsmta.matching.grow.grow_matches`, or
        :func:`~lsmta.matching.grow.grow_joint` with ``joint``). The neighbourhood filter's
        re-match uses its patch, its LSM model (not its ``max_iter`` and ``tol``), its
        robust attempt and its thresholds (default ``max_displacement = step``).
    enhance : bool
        Match on contrast-enhanced images (:func:`enhance_contrast`).
    neighbourhood : bool
        Apply the neighbourhood filter (``max_position`` px, ``max_affine``, combining
        the neighbours by ``neighbourhood_statistic``, "mean" or "median"; see
        :func:`~lsmta.matching.filters.neighbourhood_filter`).
    max_position, max_affine : float
    neighbourhood_statistic : {"mean", "median"}
    max_reprojection : float, optional
        Geometric check (beyond the paper, which names geometric constraints as its next
        step): an n-tuple whose intersected point reprojects further than this many pixels
        from its match in any image is dropped. The search images are matched
        independently, so a match that slid along its patch's texture rarely agrees with
        the other image's. None (default) turns the check off.
    voxel : float, optional
        Voxel size in mm for the final thinning; None keeps every filtered point.
    joint : bool
        Geometrically constrained multi-photo matching (beyond the paper): grow into all
        search images at once, each node matched jointly with one depth along its template
        ray (:func:`~lsmta.matching.grow.grow_joint`, :class:`~lsmta.matching.mpgc.CameraGeometry`).
        The neighbourhood filter's re-match is joint too. False (default): the paper's
        independent matching into each search image.
    """

    grow: GrowParams = field(default_factory=GrowParams)
    enhance: bool = False
    neighbourhood: bool = True
    max_position: float = 0.5
    max_affine: float = 0.1
    neighbourhood_statistic: str = "mean"
    max_reprojection: float | None = None
    voxel: float | None = None
    joint: bool = False

    def __post_init__(self):
        if not isinstance(self.grow, GrowParams):
            raise TypeError(f"grow: expected a GrowParams, got {type(self.grow).__name__}")
        for name in ("enhance", "neighbourhood", "joint"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name}: expected True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        for name in ("max_position", "max_affine"):
            if not _positive(getattr(self, name)):
                raise ValueError(f"{name}: expected a positive number, got "
                                 f"{getattr(self, name)!r}")
        if self.neighbourhood_statistic not in ("mean", "median"):
            raise ValueError(f"neighbourhood_statistic: expected 'mean' or 'median', got "
                             f"{self.neighbourhood_statistic!r}")
        if self.max_reprojection is not None and not _positive(self.max_reprojection):
            raise ValueError(f"max_reprojection: expected a positive number of pixels or None, "
                             f"got {self.max_reprojection}")
        if self.voxel is not None and not _positive(self.voxel):
            raise ValueError(f"voxel: expected a positive voxel size in mm or None, "
                             f"got {self.voxel!r}")


def measure_surface(images, cameras, seeds_xy, *, template: int = 1, mask=None,
                    template_mask=None, seeds_A=None,
                    params: MeasureSurfaceParams | None = None) -> SurfaceResult:
    """Dense surface points from K >= 2 images of one frame.

    Parameters
    ----------
    images : sequence of K (H, W) arrays
        One frame of the K cameras, all of one size.
    cameras : sequence of K Camera
    seeds_xy : (K, S, 2) array
        Approximate seed correspondences (e.g. picked by hand); NaN seeds are skipped.
    template : int
        Index of the template image (the centre camera of the triplet).
    mask, template_mask : (H, W) bool arrays, optional
        Where in the template to grow, and the template pixels on the object (see
        :func:`~lsmta.matching.grow.grow_matches`); ``template_mask`` serves the
        neighbourhood filter's re-match too.
    seeds_A : (K, S, 2, 2) array, optional
        The seeds' starting affine maps from the template's patch into every image (e.g.
        :attr:`~lsmta.matching.Seeds.A`; the template's row is not used); default identity.
    params : MeasureSurfaceParams, optional
        The growth and the filters (default :class:`MeasureSurfaceParams`).

    Returns
    -------
    SurfaceResult
    """
    p = _params(params, MeasureSurfaceParams)
    imgs, cameras, seeds, seeds_A = _checked(images, cameras, seeds_xy, template, seeds_A)
    K = len(imgs)
    if p.enhance:
        imgs = [enhance_contrast(im) for im in imgs]
    searches = [k for k in range(K) if k != template]
    geometry = CameraGeometry(cameras, template) if p.joint else None
    grown = _grow(imgs, seeds, template, searches, geometry, p.grow, mask, template_mask,
                  seeds_A)
    t_xy, xy, sig, pos = _tuples(grown, template, searches)
    ok, rematched = _neighbourhood(imgs, template, searches, grown, pos, xy, sig, t_xy,
                                   geometry, p, template_mask)
    intersection = triangulate(cameras, xy)
    if p.max_reprojection is not None:
        worst = np.where(np.isnan(intersection.reprojection_error), -np.inf,
                         intersection.reprojection_error).max(axis=0)
        ok &= worst <= p.max_reprojection
    keep = ok & intersection.valid
    if p.voxel is not None:
        cloud = voxel_filter(np.where(keep[:, None], intersection.points, np.nan), p.voxel)
        points = cloud.points
        points_xy = np.stack([cloud.mean_of(xy[k]) for k in range(K)])
    else:
        cloud = None
        points = intersection.points[keep]
        points_xy = xy[:, keep]
    return SurfaceResult(grown=grown, template_xy=t_xy, xy=xy, sigma_xy=sig,
                         neighbourhood_ok=ok, rematched=rematched, intersection=intersection,
                         cloud=cloud, points=points, points_xy=points_xy)


def _grow(imgs, seeds, template: int, searches, geometry, grow: GrowParams, mask,
          template_mask, seeds_A=None) -> list:
    """Growth into each search image: jointly under the epipolar condition (``geometry``
    given) or independently, image by image (the paper)."""
    if geometry is not None:
        return grow_joint(imgs[template], [imgs[k] for k in searches], seeds[template],
                          seeds[searches], geometry, mask=mask, template_mask=template_mask,
                          seeds_A=None if seeds_A is None else seeds_A[searches],
                          params=grow)
    return [grow_matches(imgs[template], imgs[k], seeds[template], seeds[k], mask=mask,
                         template_mask=template_mask,
                         seeds_A=None if seeds_A is None else seeds_A[k], params=grow)
            for k in searches]


def _neighbourhood(imgs, template: int, searches, grown, pos, xy, sig, t_xy, geometry,
                   p: MeasureSurfaceParams, template_mask):
    """The neighbourhood filter of every search image's growth, its rejects re-matched once
    (``xy`` and ``sig`` take the re-matches). Returns which n-tuples pass and which of them
    were re-matched."""
    ok = np.ones(len(t_xy), dtype=bool)
    rematched = np.zeros(len(t_xy), dtype=bool)
    if not p.neighbourhood:
        return ok, rematched
    checks = [neighbourhood_filter(g, max_position=p.max_position, max_affine=p.max_affine,
                                   statistic=p.neighbourhood_statistic) for g in grown]
    # the re-match uses the grower's LSM model (and its robust LSM, where it used one)
    g = p.grow
    model = LSMParams(patch=g.patch, geometry=g.geometry, radiometry=g.radiometry,
                      method=g.method, support=g.support, partial=g.partial,
                      thresholds=g.lsm_thresholds())
    if p.joint:
        return _rematch_joint(imgs, template, searches, pos, checks, xy, sig, t_xy, geometry,
                              model, max_position=p.max_position, template_mask=template_mask)
    robust = None if g.robust is None else replace(model, patch=g.robust_patch or g.patch,
                                                   robust=g.robust)
    for check, q, k in zip(checks, pos, searches):
        ok &= _rematch_outliers(check, q, imgs[template], imgs[k], t_xy, xy[k], sig[k],
                                rematched, model, robust, max_position=p.max_position,
                                template_mask=template_mask)
    return ok, rematched


def _checked(images, cameras, seeds_xy, template, seeds_A=None):
    """The images (checked, one size), the cameras, the seeds given in every image and
    their maps (or None)."""
    images = list(images)
    cameras = list(cameras)
    K = len(images)
    if K < 2:
        raise ValueError(f"images: expected at least 2 images, got {K}")
    if len(cameras) != K or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError(f"cameras: expected {K} lsmta.camera.Camera, one per image")
    imgs = [check_image(im, f"images[{k}]") for k, im in enumerate(images)]
    if any(im.shape != imgs[0].shape for im in imgs):
        raise ValueError(f"images: expected one size, got {[im.shape for im in imgs]}")
    if not 0 <= template < K:
        raise ValueError(f"template: expected an index in [0, {K - 1}], got {template}")
    seeds = as_array(seeds_xy, "seeds_xy", shape=(K, None, 2), allow_nan=True)
    good_seeds = np.isfinite(seeds).all(axis=(0, 2))
    if not good_seeds.any():
        raise ValueError("seeds_xy: no seed is given in all images")
    if seeds_A is not None:
        seeds_A = as_array(seeds_A, "seeds_A", shape=(K, seeds.shape[1], 2, 2))[:, good_seeds]
    return imgs, cameras, seeds[:, good_seeds], seeds_A


def _tuples(grown, template: int, searches):
    """n-tuples: the nodes matched in every search image. Returns their template positions
    (N, 2), all images' positions and standard deviations (K, N, 2), and each grower's
    row of every tuple."""
    rows, cols = grown[0].grid_shape
    keys = [g.node_index[:, 0] * cols + g.node_index[:, 1] for g in grown]
    common = keys[0]
    for k in keys[1:]:
        common = np.intersect1d(common, k)
    pos = [np.searchsorted(k, common) for k in keys]       # node keys come sorted
    K, N = len(searches) + 1, len(common)
    xy = np.zeros((K, N, 2))
    sig = np.zeros((K, N, 2))
    t_xy = grown[0].template_xy[pos[0]]
    xy[template] = t_xy
    for g, p, k in zip(grown, pos, searches):
        xy[k] = g.search_xy[p]
        sig[k] = g.sigma_xy[p]
    return t_xy, xy, sig, pos


def _rematch_outliers(check, p, template_img, search_img, t_xy, xy_k, sig_k, rematched,
                      model: LSMParams, robust: LSMParams | None, *, max_position,
                      template_mask):
    """Nodes the neighbourhood filter rejects are matched once more from the neighbours'
    prediction with ``model`` (and with ``robust`` where the grower used robust LSM and the
    plain re-match failed); ``xy_k``, ``sig_k`` and ``rematched`` (this function's own
    arrays) take the re-matches. Returns which tuples pass in this search image."""
    bad = np.flatnonzero(~check.keep[p] & np.isfinite(check.predicted_xy[p]).all(axis=1))
    passed = check.keep[p].copy()
    if not bad.size:
        return passed
    start, A0 = check.predicted_xy[p][bad], check.mean_A[p][bad]
    res = lsm(template_img, search_img, t_xy[bad], start, initial_A=A0,
              template_mask=template_mask, params=model)
    got, new_xy, new_sig = res.ok, res.xy.copy(), res.sigma_xy.copy()
    if robust is not None and not got.all():
        j = np.flatnonzero(~got)
        res2 = lsm(template_img, search_img, t_xy[bad[j]], start[j], initial_A=A0[j],
                   template_mask=template_mask, params=robust)
        got[j], new_xy[j], new_sig[j] = res2.ok, res2.xy, res2.sigma_xy
    fixed = got & (np.linalg.norm(new_xy - start, axis=1) <= max_position)
    xy_k[bad[fixed]] = new_xy[fixed]
    sig_k[bad[fixed]] = new_sig[fixed]
    passed[bad[fixed]] = True
    rematched[bad[fixed]] = True
    return passed


def _rematch_joint(imgs, template, searches, pos, checks, xy, sig, t_xy, geometry,
                   model: LSMParams, *, max_position, template_mask):
    """The neighbourhood filter for joint matches: a node that fails in any search image is
    re-matched once in all of them jointly (:func:`~lsmta.matching.mpgc.mpgc`), from its
    neighbours' predictions; it passes when every new position stays within
    ``max_position`` of its prediction."""
    keep = np.stack([c.keep[p] for c, p in zip(checks, pos)])                  # (K-1, N)
    pred = np.stack([c.predicted_xy[p] for c, p in zip(checks, pos)], axis=1)  # (N, K-1, 2)
    A0 = np.stack([c.mean_A[p] for c, p in zip(checks, pos)], axis=1)
    ok = keep.all(axis=0)
    rematched = np.zeros(len(t_xy), dtype=bool)
    bad = np.flatnonzero(~ok & np.isfinite(pred).all(axis=(1, 2)))
    if bad.size:
        t0 = geometry.parameter(t_xy[bad], pred[bad])
        res = mpgc(imgs[template], [imgs[k] for k in searches], t_xy[bad], t0, geometry,
                   initial_A=A0[bad], template_mask=template_mask, params=model)
        new = res.xy.transpose(1, 0, 2)                                        # (n, K-1, 2)
        fixed = res.ok & (np.linalg.norm(new - pred[bad], axis=2) <= max_position).all(axis=1)
        for j, k in enumerate(searches):
            xy[k, bad[fixed]] = res.xy[j, fixed]
            sig[k, bad[fixed]] = res.sigma_xy[j, fixed]
        ok[bad[fixed]] = True
        rematched[bad[fixed]] = True
    return ok, rematched
