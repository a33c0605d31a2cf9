"""Tie points refined by least squares matching (Gruen 1985) in the frames they come from.

:func:`~lsmta.calibration.find_tie_points` gives the positions of feature keypoints: where
SIFT's (or ASIFT's) scale-space extremum lies in each view, found in each view apart. A
keypoint is the detector's estimate, not where the same patch of surface lies in the other
views. Least squares matching puts it there: for each tie point one view is the template,
and in every other view that holds the point a ``patch x patch`` patch under an affine map
with linear radiometry is matched to the template's (:func:`lsmta.matching.lsm`, Gruen's
forward iterations), starting from the tie point's position. The template's position stays
as found; the others move to where the template's patch lies in them. All points of one
frame, template view and search view are matched in one call.

The template view of a point. The point is intersected with the given cameras (nothing here
depends on an adjustment of them) and its local plane found (below); the template is the
view that sees that plane most nearly head-on (the reference view of a patch in
Furukawa & Ponce's PMVS: the template then holds the most of the surface, and the others
are matched to a patch of it seen obliquely) where it does so clearly, by ``HEAD_ON_MARGIN``
in cosine over the view whose ray from its camera centre is closest to the mean of the
point's rays; else (and where the neighbours give no plane) that view. Of views equally
near, the first. A still feature should keep one template in every frame: its positions
otherwise differ between frames by the match's shift and no longer form one place in
:func:`lsmta.systems.refine_rig`. Both views of a two-view point are exactly as near the
mean ray (a choice left to rounding took either), and the plane is refitted in each frame
from that frame's neighbours, the moving subject's included, so it tilts a little from
frame to frame: the margin keeps such a point on its first view unless a plane clearly
faces the other. A point the cameras do not intersect takes its first view.

The start of the patch's shape (:class:`Start`): the identity; where the tie points of the
same frame near the point (``neighbours`` nearest in the template view, held by both views)
give a local affine map by least squares whose singular values lie within ``1 / max_scale ..
max_scale``, that map; and the wide-baseline start from the geometry (``plane_start``): the
point intersected with the given cameras (never an adjusted set), a local plane through it
(the normal of least spread of its ``neighbours`` nearest intersected points of the frame
where they lie near a plane, spread across it at most ``max_flatness`` times along it; else
the plane facing the template camera), and the local affine map (the Jacobian at the
template position) of the homography that plane induces between the two views, where the
plane faces both cameras and the map lies within ``max_scale``. Every start is matched; of
the accepted matches the one with the smallest residual (``sigma0``) is kept.

A match fails where LSM does not converge, leaves the image, moves further than
``max_shift_px`` from the tie point's position (another feature), ends with a standard
deviation of either coordinate above ``max_sigma_px`` or an affine map with a singular value
beyond ``max_scale`` (or below its inverse); the shear of the map is not limited
(:class:`lsmta.matching.LSMThresholds` ``max_shear`` = 1: any angle between its columns).
The view is then dropped from the point, and a point left with fewer than two views is
dropped. Both are counted (:class:`TieLSM`).

A still feature. A static background shows the same feature at the same pixels in every
frame; matched in each frame alone, its frames land apart wherever the match is uncertain
(weak or one-sided texture: an edge, a cable), and a frame whose match fails loses its
point, so the feature no longer forms one place of several frames in
:func:`lsmta.systems.refine_rig` (on the Pose2Sim demo's wide pairs, most of them). Given
``groups`` (the tie points of one still feature, from their positions as found), each group
is matched once: one template view (its first member's) at one template position (the
members' median there), every member's frame matched from its own start, and in each view
the converged match with the smallest standard deviation taken for every member; a view
that no member matched is dropped from all of them. The failed matches are still counted
as failed; :attr:`TieLSM.shared` counts the positions taken from another member.

Where to match. :func:`lsmta.systems.refine_rig` matches in the frames the tie points were
found in (halved until the longer side is at most ``tie_max_side``), the keypoints' own
scale: a patch of ``patch`` pixels there covers four times the surface of one at full size
(halved once), where a compressed video's fine detail is weak. Gruen's forward iterations
are used (not the inverse compositional ones). These were choices made on one-off probes
of the Pose2Sim demo that no script in this repository reproduces; no number is claimed
for them here. The counts of one run (matched, failed, dropped, the starts kept) are in
:class:`TieLSM` and in ``experiments/refinement_held_out.py``'s output.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar, freeze
from ..matching.lsm import LSMParams, LSMResult, LSMThresholds, Status, lsm
from ..matching.spline import SplineImage
from ..triangulation import triangulate
from .tie_points import TiePoints

#: status of an observation that was not matched: the template view, or a view without the point
NOT_MATCHED = -1


class Start(enum.IntEnum):
    """Where a match's affine map started (:attr:`TieLSM.start`)."""

    IDENTITY = 0     #: the identity
    NEIGHBOURS = 1   #: the map fitted to the neighbouring tie points' positions
    PLANE = 2        #: the local affine map of the homography of the point's local plane


@dataclass(frozen=True)
class TieLSMParams:
    """Settings of :func:`refine_tie_points`.

    Attributes
    ----------
    patch : int
        Odd side of the matched patch, px of the frames given. Default 21: the smallest odd
        patch of at least 400 pixels (a choice, not tuned on any score).
    max_shift_px : float
        Largest move from the tie point's position, px. Default 3: twice the tie points' own
        tolerance to their pair's epipolar geometry (``TieParams.ransac_px``, 1.5 px); a
        match further off has found another feature.
    max_sigma_px : float
        Largest standard deviation of either coordinate of a match, px. Default 0.1: a fifth
        of the 0.5-px target of issue #40.
    neighbours : int
        Tie points of the same frame that give the start of a patch's shape (>= 3).
    max_scale : float
        A start map with a singular value above this or below its inverse is not taken (the
        identity is), and a match whose affine map ends there is refused. Default 3: beyond
        ASIFT's largest simulated tilt (2.8). The map's shear is not limited
        (:class:`lsmta.matching.LSMThresholds` ``max_shear`` = 1, which every map passes: a
        wide baseline shears a patch, and ``max_scale`` already bounds its shape).
    max_iter : int
        LSM's iteration limit.
    tol_px : float
        LSM's convergence limit, px. Default 0.01: a fiftieth of the 0.5-px target (a
        compressed video's patches keep moving by thousandths of a pixel).
    plane_start : bool
        Also start from the local affine map of the homography of the point's local plane
        (see the module docstring). Default True.
    max_flatness : float
        The neighbours' spread across their plane, as a share of their spread along its
        shorter side, up to which their plane is taken (else the plane facing the template
        camera). Default 0.5: at most half as thick as wide (a rule, not tuned on a score).
    larger_patches : tuple of int
        Larger odd patches tried in turn, from every start, where every match with the
        smaller ones failed (the same thresholds): a patch of weak texture (the dark deck of
        a treadmill, a plain wall) diverges or stays uncertain where a larger one takes in
        texture around it. Default ``()``: none (off by the rule that a matching rule is on
        by default only if it worsens no camera's judged held-out residual at full size on
        the Pose2Sim demo; ``(41, 61)``, about twice and three times the side of ``patch``,
        gave 0.31/0.30/0.94/0.40 px against 0.25/0.23/0.60/0.46 without, cam01-cam04,
        ``experiments/refinement_held_out.py --lsm on --larger-patches 41,61``).
    """

    patch: int = 21
    max_shift_px: float = 3.0
    max_sigma_px: float = 0.1
    neighbours: int = 8
    max_scale: float = 3.0
    max_iter: int = 60
    tol_px: float = 0.01
    plane_start: bool = True
    max_flatness: float = 0.5
    larger_patches: tuple = ()

    def __post_init__(self):
        as_int(self.patch, "patch", minimum=5, odd=True, unit="pixels")
        as_scalar(self.max_shift_px, "max_shift_px", positive=True)
        as_scalar(self.max_sigma_px, "max_sigma_px", positive=True)
        as_int(self.neighbours, "neighbours", minimum=3)
        if as_scalar(self.max_scale, "max_scale", positive=True) <= 1:
            raise ValueError(f"max_scale: expected a number above 1, got {self.max_scale}")
        as_int(self.max_iter, "max_iter", minimum=1)
        as_scalar(self.tol_px, "tol_px", positive=True)
        if not isinstance(self.plane_start, bool):
            raise TypeError(f"plane_start: expected True or False, got {self.plane_start!r}")
        as_scalar(self.max_flatness, "max_flatness", positive=True)
        if not isinstance(self.larger_patches, tuple):
            raise TypeError(f"larger_patches: expected a tuple of odd sizes, got "
                            f"{self.larger_patches!r}")
        for p in self.larger_patches:
            as_int(p, "larger_patches", minimum=self.patch + 2, odd=True, unit="pixels")

    def lsm_params(self) -> LSMParams:
        """The settings of each :func:`lsmta.matching.lsm` call."""
        return LSMParams(patch=self.patch, geometry="affine", radiometry="linear",
                         method="forward", max_iter=self.max_iter, tol=self.tol_px,
                         thresholds=LSMThresholds(
                             max_sigma0=np.inf, max_sigma_xy=self.max_sigma_px,
                             max_displacement=self.max_shift_px,
                             scale_range=(1.0 / self.max_scale, self.max_scale),
                             max_shear=1.0))


@dataclass(frozen=True)
class TieLSM:
    """What :func:`refine_tie_points` did.

    Attributes
    ----------
    template : (N,) int array
        The template view of each tie point (of the tie points given).
    status : (K, N) int array
        :class:`lsmta.matching.Status` of each view's match; ``NOT_MATCHED`` (-1) for the
        template view and the views without the point.
    shift : (K, N) array
        How far each match moved from the tie point's position, px (NaN: not matched or
        failed).
    sigma : (K, N) array
        The larger standard deviation of the two coordinates of each view's match as it ended
        (converged or not), px (NaN: not matched).
    kept : (N,) bool array
        Tie points kept (at least two views left).
    start : (K, N) int array
        The :class:`Start` each view's match was kept from; ``NOT_MATCHED`` (-1) where
        not matched.
    matched, failed, dropped_points : int
        Views matched, views whose match failed (dropped from their point, unless another
        frame's match of its group holds), tie points dropped (fewer than two views left).
    shared : int
        Views of grouped tie points whose position is another frame's match of the same
        still feature (the group's best; its own failed or was less certain).
    seconds : float
        Wall time of the refinement.
    """

    template: np.ndarray
    status: np.ndarray
    shift: np.ndarray
    sigma: np.ndarray
    kept: np.ndarray
    start: np.ndarray
    matched: int
    failed: int
    dropped_points: int
    shared: int
    seconds: float

    def __post_init__(self):
        freeze(self, ("template", "status", "shift", "sigma", "kept", "start"))

    def summary(self) -> dict:
        """The counts and the median shift, as plain numbers."""
        ok = np.isfinite(self.shift)
        return {"matched": self.matched, "failed": self.failed,
                "dropped_points": self.dropped_points, "kept_points": int(self.kept.sum()),
                "shared": self.shared,
                "median_shift_px": float(np.median(self.shift[ok])) if ok.any() else None,
                "starts": {k.name.lower(): int((self.start == k).sum()) for k in Start},
                "seconds": round(self.seconds, 2)}


def _templates(cameras, xy, X, normal) -> np.ndarray:
    """(N,) the template view of each point (``X``: (N, 3) the points intersected with
    ``cameras``, mm; ``normal``: (N, 3) their local planes' normals, NaN where there is
    none): the view that sees the plane most nearly head-on where it does so by at least
    ``HEAD_ON_MARGIN`` (cosine) more than the view nearest the point's mean viewing
    direction, else that view; of views equally near (within 1e-9: both views of a
    two-view point are, exactly) the first; the first view holding it where the
    intersection fails."""
    seen = np.isfinite(xy[..., 0])
    first = np.argmax(seen, axis=0)
    C = np.stack([np.asarray(c.C, float) for c in cameras])                       # (K, 3)
    rays = X[None] - C[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    rays[~seen] = 0.0
    mean = rays.sum(axis=0)
    plane = np.isfinite(normal).all(axis=1)
    facing = np.where(plane[:, None], -normal * np.sign(np.einsum(
        "nd,nd->n", np.nan_to_num(normal), mean))[:, None], mean)  # the plane faces the views
    near_mean = _first_best(np.where(seen, np.einsum("knd,nd->kn", rays, mean), -np.inf))
    head_on = np.nan_to_num(np.where(seen, np.einsum("knd,nd->kn", rays, -facing), -np.inf),
                            nan=-np.inf)
    columns = np.arange(len(first))
    clearer = head_on.max(axis=0) >= head_on[near_mean, columns] + HEAD_ON_MARGIN
    best = np.where(plane & clearer, _first_best(head_on), near_mean)
    return np.where(np.isfinite(X).all(axis=1), best, first)


#: cosine by which the plane's most head-on view must beat the view nearest the mean ray to
#: be the template: a plane refitted in each frame tilts by a degree or so with its
#: neighbours, and a two-view point seen symmetrically would take either view by that tilt
HEAD_ON_MARGIN = 0.05


def _first_best(score) -> np.ndarray:
    """(N,) the row of the largest of each column of ``score`` (K, N); of rows within 1e-9
    of it (both views of a two-view point are exactly as near its mean ray), the first."""
    score = np.nan_to_num(score, nan=-np.inf)
    return np.argmax(score >= score.max(axis=0) - 1e-9, axis=0)


def _affine_starts(t_all, s_all, idx, k: int, max_scale: float):
    """(n, 2, 2) local affine maps from the template view to the search view at the points
    ``idx`` (of ``t_all``, ``s_all``: (M, 2) positions of the frame's points held by both
    views), from their ``k`` nearest neighbours in the template view; and (n,) whether each
    was taken (else the identity)."""
    n = len(idx)
    A = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    taken = np.zeros(n, bool)
    if len(t_all) < 4 or n == 0:
        return A, taken
    kk = min(k + 1, len(t_all))
    _, nb = cKDTree(t_all).query(t_all[idx], k=kk)
    nb = nb[:, 1:]                                                     # not the point itself
    dt = t_all[nb] - t_all[idx][:, None]                               # (n, k, 2)
    ds = s_all[nb] - s_all[idx][:, None]
    N = np.einsum("nki,nkj->nij", dt, dt)
    B = np.einsum("nki,nkj->nij", dt, ds)
    ok = np.linalg.det(N) > 1e-6 * np.einsum("nii->n", N) ** 2
    sol = np.linalg.solve(np.where(ok[:, None, None], N, np.eye(2)), B)   # A^T
    M = sol.transpose(0, 2, 1)
    sv = np.linalg.svd(M, compute_uv=False)
    ok &= np.isfinite(sv).all(axis=1) & (sv[:, 0] <= max_scale) & (sv[:, 1] >= 1 / max_scale)
    A[ok] = M[ok]
    taken[ok] = True
    return A, taken


def _normals(X, frame, k: int, max_flatness: float):
    """(N, 3) unit normals of the local planes at the points ``X`` (N, 3), mm: the direction
    of least spread of the point and its ``k`` nearest intersected neighbours of the same
    frame where their spread across it is at most ``max_flatness`` times that along the
    plane's shorter side; NaN elsewhere (and where ``X`` is)."""
    n = np.full_like(X, np.nan)
    ok = np.isfinite(X).all(axis=1)
    for f in np.unique(frame):
        idx = np.flatnonzero((frame == f) & ok)
        if len(idx) < 4:
            continue
        kk = min(k + 1, len(idx))
        _, nb = cKDTree(X[idx]).query(X[idx], k=kk)
        P = X[idx][nb] - X[idx][nb].mean(axis=1, keepdims=True)             # (m, kk, 3)
        w, v = np.linalg.eigh(np.einsum("mki,mkj->mij", P, P))                # ascending
        flat = np.sqrt(np.maximum(w[:, 0], 0)) <= max_flatness * np.sqrt(w[:, 1])
        n[idx[flat]] = v[flat, :, 0]
    return n


def _facing(normal, X, C_t) -> np.ndarray:
    """``normal`` (N, 3) turned to face the template cameras' centres ``C_t`` (N, 3); the
    direction towards ``C_t`` where it is NaN (the plane facing the template camera)."""
    d = C_t - X
    with np.errstate(invalid="ignore", divide="ignore"):
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = np.where(np.isfinite(normal).all(axis=1)[:, None], normal, d)
    return n * np.sign(np.einsum("nd,nd->n", n, d))[:, None]


def _plane_starts(cam_t, cam_s, t_xy, X, normal, h: float, max_scale: float):
    """(n, 2, 2) the local affine maps from the template view to the search view of the
    homographies induced by the planes through ``X`` (n, 3) with ``normal`` (n, 3) (the
    homography's Jacobian at the template positions ``t_xy`` (n, 2), by central differences
    of ``h`` px through the cameras' own projection, distortion included); and (n,) whether
    each is taken: the plane in front of both cameras and facing the search one, and the
    map's singular values within ``1 / max_scale .. max_scale`` (else the identity)."""
    n = len(t_xy)
    A = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    if n == 0:
        return A, np.zeros(0, bool)
    steps = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    pix = (t_xy[:, None] + steps).reshape(-1, 2)
    C, d = np.full((len(pix), 3), np.nan), np.full((len(pix), 3), np.nan)
    inv = cam_t.invertible(pix)                  # no ray where the given lens model folds
    if inv.any():
        C[inv], d[inv] = cam_t.rays(pix[inv])
    Xr, nr = np.repeat(X, 4, axis=0), np.repeat(normal, 4, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        lam = np.einsum("nd,nd->n", Xr - C, nr) / np.einsum("nd,nd->n", d, nr)
    P = C + lam[:, None] * d
    P[~(lam > 0)] = np.nan
    p = cam_s.project(np.nan_to_num(P, nan=0.0), behind="nan")
    p[~np.isfinite(P).all(axis=1)] = np.nan
    p = p.reshape(n, 4, 2)
    M = np.stack([p[:, 0] - p[:, 1], p[:, 2] - p[:, 3]], axis=2) / (2 * h)   # columns
    Cs = np.asarray(cam_s.C, float)
    faces = np.einsum("nd,nd->n", Cs - X, normal) > 0
    ok = np.isfinite(M).all(axis=(1, 2)) & faces
    sv = np.linalg.svd(np.where(ok[:, None, None], M, np.eye(2)), compute_uv=False)
    ok &= (sv[:, 0] <= max_scale) & (sv[:, 1] >= 1 / max_scale) & (np.linalg.det(
        np.where(ok[:, None, None], M, np.eye(2))) > 0)
    A[ok] = M[ok]
    return A, ok


def _starts(xy, idx, both, views, cameras, X, normal, params) -> dict:
    """{Start: ((n, 2, 2) maps, (n,) taken)} for matching the points ``idx`` from the
    template view to the search view (``views``: their indices) of ``xy`` (K, N, 2);
    ``both``: the points of the frame held by both views (the neighbours)."""
    t, s = views
    starts = {Start.IDENTITY: (np.broadcast_to(np.eye(2), (len(idx), 2, 2)),
                               np.ones(len(idx), bool)),
              Start.NEIGHBOURS: _affine_starts(xy[t, both], xy[s, both],
                                               np.searchsorted(both, idx),
                                               params.neighbours, params.max_scale)}
    if params.plane_start:
        starts[Start.PLANE] = _plane_starts(cameras[t], cameras[s], xy[t, idx], X[idx],
                                            normal[idx], params.patch // 2, params.max_scale)
    return starts


def _grown(t_img, s_img, t_xy, s_xy, starts, lp, larger):
    """:func:`_best`, then the points whose matches all failed matched again with each
    patch of ``larger`` in turn (from every start)."""
    r, kind = _best(t_img, s_img, t_xy, s_xy, starts, lp)
    for p in larger:
        at = np.flatnonzero(~r.ok)
        if not len(at):
            break
        sub = {k: (A[at], taken[at]) for k, (A, taken) in starts.items()}
        ra, ka = _best(t_img, s_img, t_xy[at], s_xy[at], sub, replace(lp, patch=p))
        r = _merge(r, at[ra.ok], ra, ra.ok)
        kind[at[ra.ok]] = ka[ra.ok]
    return r, kind


def _best(t_img, s_img, t_xy, s_xy, starts, lp):
    """Every start of ``starts`` ({Start: ((n, 2, 2) maps, (n,) taken)}; the first takes
    all) matched from ``t_xy`` to ``s_xy`` (n, 2), px; of the accepted matches of each
    point the one with the smallest ``sigma0``. Returns the LSMResult and (n,) the Start
    kept."""
    r, kind = None, np.full(len(t_xy), Start.IDENTITY, np.int64)
    for name, (A0, taken) in starts.items():
        if not taken.any():
            continue
        at = np.flatnonzero(taken)
        ra = lsm(t_img, s_img, t_xy[at], s_xy[at], initial_A=A0[at], params=lp)
        if r is None:                                              # the identity: all
            r = ra
            continue
        better = ra.ok & ((~r.ok[at]) | (ra.sigma0 < r.sigma0[at]))
        r = _merge(r, at[better], ra, better)
        kind[at[better]] = name
    return r, kind


def _merge(r: LSMResult, at, other: LSMResult, pick) -> LSMResult:
    """``r`` with its rows ``at`` replaced by the rows ``pick`` of ``other``."""
    fields = {}
    for name in ("xy", "params", "fixed", "sigma0", "sigma_xy", "cov_xy", "iterations",
                 "displacement", "status", "weight_share"):
        a = getattr(r, name).copy()
        a[at] = getattr(other, name)[pick]
        fields[name] = a
    return LSMResult(**fields)


def _checked_groups(groups, tie: TiePoints):
    """``groups`` checked: None, or (N,) whole numbers, each at most once per frame."""
    if groups is None:
        return None
    g = np.asarray(groups)
    N = tie.xy.shape[1]
    if g.shape != (N,) or (N and not np.issubdtype(g.dtype, np.integer)):
        raise ValueError(f"groups: expected {N} whole-number labels (one per tie point), got "
                         f"shape {g.shape} of {g.dtype}")
    pairs = np.unique(np.c_[g, tie.frame], axis=0) if N else np.zeros((0, 2))
    if len(pairs) != N:
        raise ValueError("groups: expected each label at most once per frame (a still "
                         "feature holds one tie point per frame)")
    return g


def _members(groups):
    """The index arrays of the groups with two or more tie points."""
    order = np.argsort(groups, kind="stable")
    split = np.split(order, np.flatnonzero(np.diff(groups[order])) + 1)
    return [m for m in split if len(m) > 1]


def _group_templates(xy, template, groups):
    """Each group's template view (its first member's) for all its members that hold it,
    and ``xy`` (K, N, 2) with those members' positions in it set to their median: one
    template patch per still feature."""
    template, xy = template.copy(), np.array(xy, dtype=float)
    if groups is None:
        return template, xy
    for m in _members(groups):
        t = template[m[0]]
        held = m[np.isfinite(xy[t, m, 0])]              # a member without that view keeps its own
        template[held] = t
        xy[t, held] = np.median(xy[t, held], axis=0)
    return template, xy


def _group_best(xy, status, sigma, template, groups) -> int:
    """In place: each grouped view's position (``xy`` (K, N, 2); NaN where its match
    failed) set to that of the group's converged match with the smallest ``sigma`` (K, N),
    in every member that holds the view; NaN where none converged. Returns how many
    positions came from another member's match."""
    if groups is None:
        return 0
    shared = 0
    for m in _members(groups):
        m = m[template[m] == template[m[0]]]                    # those sharing its template
        for s in range(xy.shape[0]):
            own = m[status[s, m] >= 0]                         # matched (not the template)
            if s == template[m[0]] or not len(own):
                continue
            ok = own[status[s, own] == Status.CONVERGED]
            if not len(ok):
                continue
            best = ok[np.argmin(sigma[s, ok])]
            shared += int(np.sum(own != best))
            xy[s, own] = xy[s, best]
    return shared


def _checked(frames, tie, cameras, params) -> list:
    """:func:`refine_tie_points`'s arguments checked; returns ``frames`` as a list of lists."""
    if not isinstance(params, TieLSMParams):
        raise TypeError(f"params: expected TieLSMParams or None, got {type(params).__name__}")
    if not isinstance(tie, TiePoints):
        raise TypeError("tie: expected TiePoints (from find_tie_points)")
    K, N, _ = tie.xy.shape
    if len(cameras) != K:
        raise ValueError(f"cameras: expected {K} cameras (one per view of tie), got "
                         f"{len(cameras)}")
    if np.shape(tie.frame) != (N,) or (N and int(np.min(tie.frame)) < 0):
        raise ValueError(f"tie.frame: expected {N} frame indices >= 0 (one per tie point), "
                         f"got shape {np.shape(tie.frame)}"
                         + (f", smallest {int(np.min(tie.frame))}" if np.size(tie.frame) else ""))
    frames = [list(f) for f in frames]
    if N and int(tie.frame.max()) >= len(frames):
        raise ValueError(f"frames: tie points come from {int(tie.frame.max()) + 1} frames, "
                         f"got {len(frames)}")
    if any(len(f) != K for f in frames):
        raise ValueError(f"frames: expected {K} images per frame, got "
                         f"{[len(f) for f in frames]}")
    want = [(c.height, c.width) for c in cameras]
    bad = [(i, k) for i, f in enumerate(frames) for k, g in enumerate(f)
           if np.shape(g)[:2] != want[k]]
    if bad:
        i, k = bad[0]
        raise ValueError(f"frames: image {k} of frame {i} is {np.shape(frames[i][k])[:2]}, "
                         f"expected {want[k]} (camera {k}'s height, width)")
    return frames


def refine_tie_points(frames, tie: TiePoints, cameras, *, params: TieLSMParams | None = None,
                      groups=None) -> tuple[TiePoints, TieLSM]:
    """Tie points moved by least squares matching to where each view shows the template
    view's patch (see the module docstring).

    Parameters
    ----------
    frames : sequence of F sequences of K (H_k, W_k) arrays
        The grey frames the tie points were found in (``tie.frame`` indexes them), at the
        size of ``tie.xy``'s pixels.
    tie : TiePoints
        (K, N) positions, px; NaN where a view does not hold a point.
    cameras : sequence of K Camera
        The given cameras (they choose each point's template view only).
    params : TieLSMParams, optional
    groups : (N,) int array, optional
        Tie points of one still feature found in several frames share a label (each label at
        most once per frame; :func:`lsmta.systems.refinement._places` on the positions as
        found): such a feature is matched once (see "A still feature" in the module
        docstring). None: every tie point alone.

    Returns
    -------
    TiePoints
        The kept points (``TieLSM.kept``), the failed views NaN; the template views'
        positions unchanged (of a group: its members' median). ``pair_matches`` and
        ``pair_guided`` are those given.
    TieLSM
    """
    params = TieLSMParams() if params is None else params
    frames = _checked(frames, tie, cameras, params)
    K, N, _ = tie.xy.shape
    groups = _checked_groups(groups, tie)
    t0 = time.perf_counter()
    seen = np.isfinite(tie.xy[..., 0])
    frame = np.asarray(tie.frame)
    status = np.full((K, N), NOT_MATCHED, np.int64)
    shift = np.full((K, N), np.nan)
    sigma = np.full((K, N), np.nan)
    start = np.full((K, N), NOT_MATCHED, np.int64)
    X = triangulate(list(cameras), tie.xy, min_angle_deg=0.0).points if N else np.zeros((0, 3))
    normal = _normals(X, frame, params.neighbours, params.max_flatness)
    template = _templates(cameras, tie.xy, X, normal) if N else np.zeros(0, int)
    template, xy = _group_templates(tie.xy, template, groups)
    tie = replace(tie, xy=xy.copy())                   # the template positions shared
    C = np.stack([np.asarray(c.C, float) for c in cameras])
    normal = _facing(normal, X, C[template])
    lp = params.lsm_params()
    for f in np.unique(frame):
        in_frame = frame == f
        splines = [SplineImage(g, f"frames[{f}][{k}]") for k, g in enumerate(frames[f])]
        for s in range(K):
            for t in range(K):
                idx = np.flatnonzero(in_frame & (template == t) & seen[s] & (s != t))
                if not len(idx):
                    continue
                both = np.flatnonzero(in_frame & seen[t] & seen[s])
                starts = _starts(tie.xy, idx, both, (t, s), cameras, X, normal, params)
                t_xy, s_xy = tie.xy[t, idx], tie.xy[s, idx]
                r, kind = _grown(splines[t], splines[s], t_xy, s_xy, starts, lp,
                                 params.larger_patches)
                status[s, idx] = r.status
                start[s, idx] = kind
                sigma[s, idx] = np.fmax(r.sigma_xy[:, 0], r.sigma_xy[:, 1])
                good = r.status == Status.CONVERGED
                shift[s, idx[good]] = r.displacement[good]
                xy[s, idx[good]] = r.xy[good]
                xy[s, idx[~good]] = np.nan
    shared = _group_best(xy, status, sigma, template, groups)
    matched = status >= 0
    failed = matched & (status != Status.CONVERGED)
    kept = np.isfinite(xy[..., 0]).sum(axis=0) >= 2
    out = replace(tie, xy=xy[:, kept], frame=np.asarray(tie.frame)[kept])
    return out, TieLSM(template=template, status=status, shift=shift, sigma=sigma, kept=kept,
                       start=start, matched=int(matched.sum()),
                       failed=int(failed.sum()), dropped_points=int((~kept).sum()),
                       shared=shared, seconds=time.perf_counter() - t0)
