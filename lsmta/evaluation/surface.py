"""Surface-measurement trials: seeds from the generator, scores against the true surface."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .._validate import as_rng
from ..matching.masks import backdrop_mask
from ..matching.surface import MeasureSurfaceParams, SurfaceResult
from ..synth.render import RenderedFrame, Scene, project_surface_points


def beyond_the_paper(noise_sigma: float, template_image, params: MeasureSurfaceParams, *,
                     backdrop: float = 12.0) -> dict:
    """Keywords of :func:`~lsmta.matching.measure_surface` (``params``, ``template_mask``)
    for the "beyond the paper" variant of notebook 03 and
    ``experiments/surface_benchmark.py``: ``params`` with a robust retry (Tukey cut-off
    4.7 sqrt(2) ``noise_sigma`` grey levels, 9 x 9 patch), shifted windows (3 px), the median
    neighbourhood filter with an affine limit of 0.3 and the geometric check at 0.2 px, and a
    template mask from :func:`~lsmta.matching.backdrop_mask` at grey level ``backdrop``.
    """
    grow = replace(params.grow, robust=4.7 * np.sqrt(2.0) * noise_sigma, robust_patch=9,
                   shift=3)
    return dict(params=replace(params, grow=grow, neighbourhood_statistic="median",
                               max_affine=0.3, max_reprojection=0.2),
                template_mask=backdrop_mask(template_image, backdrop))


def joint_beyond(noise_sigma: float, template_image, params: MeasureSurfaceParams, *,
                 backdrop: float = 12.0, border: int = 7) -> dict:
    """Keywords of :func:`~lsmta.matching.measure_surface` (``params``, ``mask``,
    ``template_mask``) for the joint variant of notebook 03 and
    ``experiments/surface_benchmark.py``: ``params`` with geometrically constrained matching
    of the triplet (``joint=True``), the robust retry and the median neighbourhood filter of
    :func:`beyond_the_paper` with a position limit of 0.4 px; growth only at least ``border``
    px inside the backdrop mask (no windows across the silhouette), and its template mask. No
    shifted windows (their carried-back positions leave the epipolar curves) and no
    geometric check (jointly matched rays meet by construction).
    """
    mask = backdrop_mask(template_image, backdrop)
    grow = replace(params.grow, robust=4.7 * np.sqrt(2.0) * noise_sigma, robust_patch=9)
    return dict(params=replace(params, grow=grow, joint=True, neighbourhood_statistic="median",
                               max_affine=0.3, max_position=0.4),
                mask=ndimage.binary_erosion(mask, iterations=border), template_mask=mask)


def seeds_from_truth(scene: Scene, cameras, frame: int, *,
                     rng: np.random.Generator | int | None = None, per_part: int = 1,
                     perturb_px: float = 1.0, min_px: int = 40):
    """Seeds as a user would click them: points visible in every camera, one (or
    ``per_part``) on each body part that shows at least ``min_px`` such points, moved by up
    to ``perturb_px`` pixels in each image. Returns ``(K, S, 2)`` pixel positions."""
    rng = as_rng(rng)
    part, local = scene.body.sample_surface(n_per_part=200, rng=rng)
    proj = project_surface_points(scene, cameras, part, local, frames=frame)
    seen = proj.visible[0].all(axis=0)
    chosen = []
    for p in np.unique(part[seen]):
        idx = np.flatnonzero(seen & (part == p))
        if len(idx) < min_px // 5:
            continue
        # the most central visible points of the part (in the first camera's image)
        centre = proj.xy[0, 0, idx].mean(axis=0)
        order = np.argsort(np.linalg.norm(proj.xy[0, 0, idx] - centre, axis=1))
        chosen.extend(idx[order[:per_part]])
    xy = proj.xy[0][:, chosen]
    return xy + rng.uniform(-perturb_px, perturb_px, xy.shape)


def node_truth(rendered: RenderedFrame, scene: Scene, cameras, *, template: int = 1,
               step: int = 4, patch: int = 13):
    """Ground truth on the template's node grid.

    Returns a dict of ``(rows, cols)`` grids: ``world`` (3-D truth at the node pixel),
    ``on_body``, ``visible`` (the surface point at the node is seen by every camera) and
    ``interior`` (the whole ``patch x patch`` window lies on the body).
    """
    pid = rendered.part_id[template]
    H, W = pid.shape
    rr, cc = np.mgrid[0:H:step, 0:W:step]
    on_body = pid[rr, cc] >= 0
    interior = ndimage.minimum_filter(pid, size=patch, mode="constant", cval=-2)[rr, cc] >= 0
    visible = np.zeros_like(on_body)
    parts = pid[rr, cc]
    local = rendered.local_xyz[template][rr, cc]
    for p in np.unique(parts[on_body]):
        m = on_body & (parts == p)
        pr = project_surface_points(scene, cameras, int(p), local[m], frames=rendered.frame)
        visible[m] = pr.visible[0].all(axis=0)
    return {"world": rendered.world_xyz[template][rr, cc], "on_body": on_body,
            "visible": visible, "interior": interior, "step": step}


def score_surface(result: SurfaceResult, truth: dict) -> dict:
    """Density and 3-D errors of a surface measurement against :func:`node_truth`.

    ``density``: share of the visible interior body nodes matched in every image and kept by
    the filters; errors (mm) before the filters (``raw``), after the neighbourhood filter
    (``filtered``) and after the voxel filter (``voxel``, each voxel centre against the
    mean truth of its members); ``gross``: share of errors above 5 x the median;
    ``gross_target``: the same share among the target nodes only (the population of
    ``density``; nodes near the silhouette, whose windows reach off the body, left out).
    """
    step = truth["step"]
    r = (result.template_xy[:, 1] // step).astype(int)
    c = (result.template_xy[:, 0] // step).astype(int)
    target = truth["visible"] & truth["interior"]
    matched = np.zeros_like(target)
    matched[r[result.neighbourhood_ok], c[result.neighbourhood_ok]] = True
    world = truth["world"][r, c]
    body = truth["on_body"][r, c]
    err = np.linalg.norm(result.intersection.points - world, axis=1)
    out = {"density": float(matched[target].mean()), "n_target": int(target.sum())}
    in_target = target[r, c]
    for name, sel in (("raw", body & result.intersection.valid),
                      ("filtered", body & result.neighbourhood_ok & result.intersection.valid)):
        out[name] = _error_stats(err[sel], in_target[sel])
    if result.cloud is not None:
        # a voxel's truth is the mean truth of its nodes; voxels holding an off-body node
        # (no true surface there) get NaN and are left out
        t = result.cloud.mean_of(np.where(body[:, None], world, np.nan))
        good = np.isfinite(t).all(axis=1)
        e = np.linalg.norm(result.cloud.points[good] - t[good], axis=1)
        out["voxel"] = _error_stats(e)
    return out


def _error_stats(e, in_target=None) -> dict:
    """Count, median, 95th percentile and gross share (> 5 x the median) of errors ``e``
    (mm); NaN statistics when there is no error to score (nothing matched)."""
    if not len(e):
        out = {"n": 0, "median_mm": np.nan, "p95_mm": np.nan, "gross": np.nan}
    else:
        med = float(np.median(e))
        out = {"n": len(e), "median_mm": med, "p95_mm": float(np.percentile(e, 95)),
               "gross": float(np.mean(e > 5 * med))}
    if in_target is not None:
        out["gross_target"] = (float(np.mean(e[in_target] > out["median_mm"] * 5))
                               if in_target.any() else np.nan)
    return out


def score_points(points, xy_first, truth: dict, rendered: RenderedFrame, *, template: int = 1):
    """Density and 3-D error of any point cloud whose points carry a template pixel
    (e.g. SGBM's): error against the true surface point at that (rounded) pixel; density:
    share of the visible interior body nodes whose grid cell receives a point."""
    step = truth["step"]
    ij = np.rint(xy_first).astype(int)
    H, W = rendered.part_id[template].shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    ij, pts = ij[inside], points[inside]
    on_body = rendered.part_id[template][ij[:, 1], ij[:, 0]] >= 0
    gt = rendered.world_xyz[template][ij[:, 1], ij[:, 0]]
    e = np.linalg.norm(pts - gt, axis=1)[on_body]
    covered = np.zeros_like(truth["on_body"])
    rr = np.clip((ij[on_body, 1] + step // 2) // step, 0, covered.shape[0] - 1)
    cc = np.clip((ij[on_body, 0] + step // 2) // step, 0, covered.shape[1] - 1)
    covered[rr, cc] = True
    target = truth["visible"] & truth["interior"]
    med = float(np.median(e))
    return {"density": float(covered[target].mean()), "n": int(on_body.sum()),
            "median_mm": med, "p95_mm": float(np.percentile(e, 95)),
            "gross": float(np.mean(e > 5 * med))}


def classify_misses(result: SurfaceResult, truth: dict, rendered: RenderedFrame, *,
                    template: int = 1, window: int = 9, jump_mm: float = 20.0) -> dict:
    """Why were target nodes missed? Counts of missed nodes with a depth jump above
    ``jump_mm`` inside a ``window x window`` neighbourhood (an occlusion border inside the
    silhouette), and of the others, split by which search images matched them."""
    step = truth["step"]
    target = truth["visible"] & truth["interior"]
    got = np.zeros_like(target)
    r = (result.template_xy[:, 1] // step).astype(int)
    c = (result.template_xy[:, 0] // step).astype(int)
    got[r[result.neighbourhood_ok], c[result.neighbourhood_ok]] = True
    depth = np.nan_to_num(rendered.depth[template], nan=1e9)
    jump = (ndimage.maximum_filter(depth, size=window)
            - ndimage.minimum_filter(depth, size=window))[::step, ::step] > jump_mm
    miss = target & ~got
    out = {"target": int(target.sum()), "missed": int(miss.sum()),
           "at_depth_jump": int((miss & jump).sum())}
    smooth = miss & ~jump
    for k, g in enumerate(result.grown):
        seen = np.zeros_like(target)
        seen[g.node_index[:, 0], g.node_index[:, 1]] = True
        out[f"smooth_missed_matched_in_search_{k}"] = int((smooth & seen).sum())
    out["smooth_missed"] = int(smooth.sum())
    return out


def surface_truth_at(rendered: RenderedFrame, xy, *, template: int = 1) -> np.ndarray:
    """The true surface point ``(N, 3)`` seen at sub-pixel positions ``xy`` ``(N, 2)`` of the
    template image: the rendered per-pixel world points, bilinearly interpolated; NaN where
    the four pixels around ``xy`` are not all on one body part (silhouettes, depth jumps)."""
    xy = np.asarray(xy, dtype=float)
    pid = rendered.part_id[template]
    world = rendered.world_xyz[template]
    H, W = pid.shape
    x0 = np.floor(xy[:, 0]).astype(int)
    y0 = np.floor(xy[:, 1]).astype(int)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < W - 1) & (y0 < H - 1)
    x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
    fx, fy = (xy[:, 0] - x0)[:, None], (xy[:, 1] - y0)[:, None]
    corners = [(y0, x0), (y0, x0 + 1), (y0 + 1, x0), (y0 + 1, x0 + 1)]
    parts = np.stack([pid[r, c] for r, c in corners])
    ok &= (parts[0] >= 0) & np.all(parts == parts[0], axis=0)
    w = [(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]
    out = sum(wi * world[r, c] for wi, (r, c) in zip(w, corners))
    out[~ok] = np.nan
    return out


def node_errors(result: SurfaceResult, truth: dict) -> np.ndarray:
    """3-D error (mm) of every kept node of a surface measurement, as a ``(rows, cols)``
    grid of :func:`node_truth`'s nodes (NaN: not kept or not on the body)."""
    step = truth["step"]
    grid = np.full(truth["on_body"].shape, np.nan)
    keep = result.neighbourhood_ok & result.intersection.valid
    r = (result.template_xy[keep, 1] // step).astype(int)
    c = (result.template_xy[keep, 0] // step).astype(int)
    err = np.linalg.norm(result.intersection.points[keep] - truth["world"][r, c], axis=1)
    grid[r, c] = np.where(truth["on_body"][r, c], err, np.nan)
    return grid


def point_errors(points, xy, truth: dict, rendered: RenderedFrame, *, template: int = 1,
                 radius: float | None = None) -> np.ndarray:
    """3-D error (mm) of a dense method's points at the nodes of :func:`node_truth`, as a
    ``(rows, cols)`` grid: each node takes the point whose template position ``xy`` is
    nearest to it, if within ``radius`` px (default half the grid step: the node's cell),
    scored against the true surface at that point's exact position
    (:func:`surface_truth_at`; no rounding to pixels)."""
    step = truth["step"]
    radius = step / 2 if radius is None else radius
    rows, cols = truth["on_body"].shape
    grid = np.full((rows, cols), np.nan)
    xy = np.asarray(xy, dtype=float)
    if len(xy) == 0:
        return grid
    rr, cc = np.mgrid[0:rows, 0:cols]
    nodes = np.stack([cc.ravel() * step, rr.ravel() * step], axis=1).astype(float)
    dist, j = cKDTree(xy).query(nodes, distance_upper_bound=radius)
    has = np.isfinite(dist)
    err = np.linalg.norm(np.asarray(points)[j[has]]
                         - surface_truth_at(rendered, xy[j[has]], template=template), axis=1)
    grid.ravel()[np.flatnonzero(has)] = err
    return grid


def grid_scores(errors: np.ndarray, truth: dict, *, population=None, gross_mm: float = 2.0):
    """Scores of a ``(rows, cols)`` error grid over a population of nodes (default: the
    target nodes, visible and interior): ``density`` (share of the population with an
    error, i.e. an estimate scored against a known surface), and over those ``median_mm``,
    ``p95_mm`` and ``gross`` (share above ``gross_mm``)."""
    pop = truth["visible"] & truth["interior"] if population is None else population
    e = errors[pop & np.isfinite(errors)]
    if e.size == 0:
        return {"density": 0.0, "n": 0, "median_mm": np.nan, "p95_mm": np.nan, "gross": np.nan}
    return {"density": float(e.size / pop.sum()), "n": int(e.size),
            "median_mm": float(np.median(e)), "p95_mm": float(np.percentile(e, 95)),
            "gross": float(np.mean(e > gross_mm))}
