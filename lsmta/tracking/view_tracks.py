"""2-D tracks of several views joined into 3-D points.

Each view's points are tracked on their own (2-D mode); which track of one view is which
track of another is decided by the whole of their paths, not by one frame. For every pair
of views, every pair of their tracks is intersected in every frame both hold, and scored by
the median of its larger reprojection error over those frames. A track pair is a match
when that median is at most ``max_px``, it shares at least ``min_shared`` of the frames,
its points lie in front of both cameras, and each track is the other's best partner
(mutual). Matches are chained over the view pairs into multi-view points (the connected
components of the match graph, :func:`scipy.sparse.csgraph.connected_components`); a
chain that holds two tracks of one view is dropped. A position outside its image, or where
the camera's lens model cannot be inverted, is not an observation.

A coincidence along an epipolar line holds in one frame, rarely through a moving path:
joining by paths is what makes an unlabelled 2-D track usable with cameras a few pixels
off, where a per-frame epipolar test at that tolerance is ambiguous.

A join right over its whole path can still be wrong in some frames: a view's track picked
up again on a neighbouring dot after a gap. :func:`triangulate_gated` gates the positions
by their residual (:func:`residual_gate`: ``k`` times a robust scale of all the
positions' residuals, floored by the cameras' own residual), leaves out the view to blame
where three or more views hold the point, and takes out a view's run of frames (its track
between gaps) that is out in most of them, throughout.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .._validate import as_array, as_scalar, freeze
from ..camera import Camera
from ..triangulation import triangulate


@dataclass(frozen=True)
class JoinedTracks:
    """Tracks of K views joined into M points (:func:`join_view_tracks`).

    Attributes
    ----------
    members : (M, K) int array
        The track of each view that belongs to each point, -1 for none.
    pair_px : (M,) array
        The worst (over the point's view pairs) median pair residual, px.
    """

    members: np.ndarray
    pair_px: np.ndarray

    def __post_init__(self):
        freeze(self, ("members", "pair_px"))

    def __len__(self) -> int:
        return len(self.members)


def _checked(cameras, xy) -> tuple[list, list]:
    cams = list(cameras)
    if len(cams) < 2 or not all(isinstance(c, Camera) for c in cams):
        raise TypeError("cameras: expected a sequence of at least 2 lsmta.camera.Camera")
    if len(xy) != len(cams):
        raise ValueError(f"xy: expected {len(cams)} track arrays (one per camera), got "
                         f"{len(xy)}")
    arrays = [as_array(a, f"xy[{k}]", shape=(None, None, 2), allow_nan=True)
              for k, a in enumerate(xy)]
    if len({a.shape[0] for a in arrays}) != 1:
        raise ValueError(f"xy: expected the same number of frames in every view, got "
                         f"{[a.shape[0] for a in arrays]}")
    return cams, [_observed(c, a) for c, a in zip(cams, arrays)]


def _observed(camera: Camera, xy: np.ndarray) -> np.ndarray:
    """A copy of ``xy`` with NaN where a position is outside the image or where the lens
    model cannot be inverted (a track that drifted there is no observation)."""
    out = np.array(xy, float)
    flat = out.reshape(-1, 2)
    inside = (np.isfinite(flat).all(axis=1) & (flat[:, 0] >= -0.5)
              & (flat[:, 0] <= camera.width - 0.5) & (flat[:, 1] >= -0.5)
              & (flat[:, 1] <= camera.height - 0.5))
    idx = np.flatnonzero(inside)
    inside[idx] = camera.invertible(flat[idx]) if idx.size else inside[idx]
    flat[~inside] = np.nan
    return out


#: track pairs intersected per call of :func:`pair_residuals` (bounds its memory)
_CHUNK = 200_000


def _pair_errors(camera_a, camera_b, xy_a, xy_b) -> np.ndarray:
    """``(T, Na, Nb)`` larger reprojection error of every pair in every frame, px: NaN where
    either is missing, inf where the point lies behind a camera or the rays do not meet."""
    T, Na, _ = xy_a.shape
    Nb = xy_b.shape[1]
    a = np.broadcast_to(xy_a[:, :, None], (T, Na, Nb, 2)).reshape(-1, 2)
    b = np.broadcast_to(xy_b[:, None], (T, Na, Nb, 2)).reshape(-1, 2)
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    err = np.full(len(a), np.nan)
    if both.any():
        res = triangulate([camera_a, camera_b], np.stack([a[both], b[both]]),
                          min_angle_deg=0.0)
        X = res.points
        depth = np.stack([((X - c.C) @ c.R[2]) for c in (camera_a, camera_b)])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # rays that did not meet
            e = np.nanmax(res.reprojection_error, axis=0)
        err[both] = np.where((depth > 0).all(axis=0) & res.valid, e, np.inf)
    return err.reshape(T, Na, Nb)


def pair_residuals(camera_a: Camera, camera_b: Camera, xy_a, xy_b, *,
                   min_shared: float = 0.5) -> np.ndarray:
    """Median over frames of the larger reprojection error of every track pair, px.

    Parameters
    ----------
    camera_a, camera_b : Camera
    xy_a, xy_b : (T, Na, 2) and (T, Nb, 2) arrays
        Tracked positions, NaN where a track has none.
    min_shared : float
        Share of the T frames a pair must hold together; pairs with fewer, or with a point
        behind either camera in any of them, are NaN.

    Returns
    -------
    (Na, Nb) array
    """
    T, Na, _ = xy_a.shape
    Nb = xy_b.shape[1]
    err = np.full((T, Na, Nb), np.nan)
    step = max(1, _CHUNK // max(1, Na * Nb))           # frames per intersection call
    for t0 in range(0, T, step):
        err[t0:t0 + step] = _pair_errors(camera_a, camera_b, xy_a[t0:t0 + step],
                                         xy_b[t0:t0 + step])
    shared = np.isfinite(err) | np.isinf(err)
    enough = shared.sum(axis=0) >= max(1, min_shared * T)
    behind = np.isinf(err).any(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # pairs that share no frame
        med = np.nanmedian(np.where(np.isinf(err), np.nan, err), axis=0)
    return np.where(enough & ~behind, med, np.nan)


def join_view_tracks(cameras, xy, *, max_px: float = 3.0, min_shared: float = 0.5,
                     pairs=None) -> JoinedTracks:
    """Join the 2-D tracks of K views into multi-view points (see the module docstring).

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks (px, NaN where a track has none).
    max_px : float
        Largest median pair residual of a match, px.
    min_shared : float
        Share of the frames a matched pair holds together, in (0, 1].
    pairs : sequence of (a, b), optional
        The view pairs to match (default: all).

    Returns
    -------
    JoinedTracks
        Ordered by the number of views, then the pair residual.
    """
    cams, arrays = _checked(cameras, xy)
    max_px = as_scalar(max_px, "max_px", positive=True)
    min_shared = as_scalar(min_shared, "min_shared", positive=True)
    if min_shared > 1:
        raise ValueError(f"min_shared: expected a share in (0, 1], got {min_shared}")
    K = len(cams)
    offsets = np.concatenate([[0], np.cumsum([a.shape[1] for a in arrays])])
    links = []
    for a, b in (pairs if pairs is not None else itertools.combinations(range(K), 2)):
        if arrays[a].shape[1] == 0 or arrays[b].shape[1] == 0:
            continue
        r = pair_residuals(cams[a], cams[b], arrays[a], arrays[b], min_shared=min_shared)
        filled = np.where(np.isfinite(r), r, np.inf)
        best_b, best_a = filled.argmin(axis=1), filled.argmin(axis=0)
        for i, j in enumerate(best_b):
            if filled[i, j] <= max_px and best_a[j] == i:
                links.append((offsets[a] + i, offsets[b] + j, r[i, j]))
    n = int(offsets[-1])
    ij = np.array([(i, j) for i, j, _ in links], int).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)       # the chains
    view = np.searchsorted(offsets, np.arange(n), side="right") - 1
    worst = {}
    for i, _, r in links:
        worst[label[i]] = max(worst.get(label[i], 0.0), r)
    groups: dict[int, list] = {}
    for i in range(n):
        groups.setdefault(label[i], []).append(i)
    members, pair_px = [], []
    for key, idx in groups.items():
        if len(idx) < 2 or len(set(view[idx])) < len(idx):
            continue
        m = np.full(K, -1)
        m[view[idx]] = np.asarray(idx) - offsets[view[idx]]
        members.append(m)
        pair_px.append(worst[key])
    members = np.array(members, int).reshape(-1, K)
    pair_px = np.array(pair_px, float)
    order = np.lexsort((pair_px, -(members >= 0).sum(axis=1)))
    return JoinedTracks(members=members[order], pair_px=pair_px[order])


def joined_positions(xy, members) -> np.ndarray:
    """``(T, K, M, 2)`` image positions of the joined points (NaN where a view has none)."""
    arrays = [np.asarray(a, float) for a in xy]
    members = np.asarray(members, int)
    T, K, M = arrays[0].shape[0], len(arrays), len(members)
    out = np.full((T, K, M, 2), np.nan)
    for k in range(K):
        has = members[:, k] >= 0
        out[:, k, has] = arrays[k][:, members[has, k]]
    return out


def triangulate_joined(cameras, xy, members):
    """Every frame's 3-D position of the joined points, from the views that hold them.

    Returns
    -------
    xyz : (T, M, 3) array
        mm; NaN where fewer than two views hold the point.
    residual : (T, M) array
        Largest reprojection error of the point's views, px.
    n_views : (T, M) int array
    """
    cams, arrays = _checked(cameras, xy)
    pos = joined_positions(arrays, members)
    xyz, residual = _intersect(cams, pos)
    return xyz, residual, np.isfinite(pos).all(axis=3).sum(axis=1)


def _intersect(cams, pos):
    """``(T, M, 3)`` points and ``(T, M)`` residuals of ``(T, K, M, 2)`` positions."""
    T, K, M, _ = pos.shape
    res = triangulate(cams, np.moveaxis(pos, 1, 0).reshape(K, T * M, 2), min_angle_deg=1.0)
    xyz = np.where(res.valid[:, None], res.points, np.nan).reshape(T, M, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # points not intersected
        residual = np.where(res.valid, np.nanmax(res.reprojection_error, axis=0),
                            np.nan).reshape(T, M)
    return xyz, residual


#: the residual's robust scale: sigma of a zero-mean normal error from the median of its size
_MAD_SIGMA = 1.4826


def residual_gate(residual, *, k: float = 4.0, floor_px: float = 0.5):
    """Which intersected positions have a reprojection residual in line with the recording's.

    The residual of a right intersection is the size of a zero-mean image error (the
    trackers' and the cameras'), so its scale is measured robustly on all of them
    together: ``sigma = 1.4826 * median(residual)`` (the median absolute deviation about
    zero, which a minority of wrong positions hardly moves), held at no less than
    ``floor_px`` (the cameras' own residual: below it the cameras cannot tell right from
    wrong). A position whose residual exceeds ``k * sigma`` is out: a track on another
    dot than its partners, a view's dot mistaken after a gap.

    Parameters
    ----------
    residual : (T, M) array
        Largest reprojection error of each point's views in each frame, px, >= 0 (NaN
        where not intersected; :func:`triangulate_joined`).
    k : float
        The bound in units of sigma, > 0.
    floor_px : float
        Least sigma, px, >= 0.

    Returns
    -------
    keep : (T, M) bool array
        False where the residual exceeds the bound (an infinite one too; NaN residuals
        are kept: nothing to judge).
    bound_px : float
        ``k * sigma``, px (NaN when no residual is finite).
    """
    r = as_array(residual, "residual", shape=(None, None), finite=False)
    if (r < 0).any():
        raise ValueError("residual: expected reprojection errors >= 0 (NaN where none), got "
                         f"{r[r < 0].min():g}")
    k = as_scalar(k, "k", positive=True)
    floor_px = as_scalar(floor_px, "floor_px", nonnegative=True)
    finite = np.isfinite(r)
    if not finite.any():
        return np.ones(r.shape, bool), float("nan")
    bound = k * max(_MAD_SIGMA * float(np.median(r[finite])), floor_px)
    with np.errstate(invalid="ignore"):
        return ~(r > bound), bound                  # NaN: kept; inf (no meeting): out


@dataclass(frozen=True)
class GatedPoints:
    """Joined points intersected with the residual gate (:func:`triangulate_gated`).

    Attributes
    ----------
    xyz : (T, M, 3) array
        mm; NaN where fewer than two views hold the point or its residual is out.
    residual : (T, M) array
        Largest reprojection error of the views used, px (NaN likewise).
    n_views : (T, M) int array
        The views used.
    dropped : int
        Positions dropped (held by two or more views, out of the bound).
    views_out : int
        Positions kept with one view left out (in frames) or a view's run of frames taken
        out (counted per position).
    bound_px : float
        The gate's bound, px (:func:`residual_gate`; NaN: nothing intersected).
    """

    xyz: np.ndarray
    residual: np.ndarray
    n_views: np.ndarray
    dropped: int
    views_out: int
    bound_px: float

    def __post_init__(self):
        freeze(self, ("xyz", "residual", "n_views"))


def _leave_one_out(cams, pos, bound):
    """The points of ``(T, K, M, 2)`` positions, the residual gate applied at ``bound``:
    a position out of it held by three or more views intersected with each view left out
    in turn, the least residual kept where it is within the bound. Returns the points,
    residuals, the positions still out (``(T, M)``; their points not yet NaN), and per
    ``(T, K, M)`` the views to blame (the one left out; every view of a position still
    out: two views cannot say which of them is wrong)."""
    xyz, residual = _intersect(cams, pos)
    with np.errstate(invalid="ignore"):
        still = residual > bound                                 # NaN: not judged
    blame = np.zeros(pos.shape[:3], bool)
    held = np.isfinite(pos).all(axis=3)                          # (T, K, M)
    for t, j in zip(*np.nonzero(still)):
        views = np.flatnonzero(held[t, :, j])
        best = (np.inf, None, None)
        for k in views if len(views) >= 3 else ():
            one = pos[t:t + 1, :, j:j + 1].copy()
            one[0, k] = np.nan
            X, r = _intersect(cams, one)
            if r[0, 0] <= min(bound, best[0]):
                best = (r[0, 0], X[0, 0], k)
        if best[2] is None:
            blame[t, views, j] = True
            continue
        xyz[t, j], residual[t, j] = best[1], best[0]
        blame[t, best[2], j] = True
        still[t, j] = False
    return xyz, residual, still, blame


def _worst_run(held, blame):
    """``(start, stop, view, point)`` of the run of a view's frames (``held[:, k, j]``
    True between gaps) blamed in the largest share of its frames, if more than half; else
    None."""
    best, worst = 0.5, None
    for k in range(held.shape[1]):
        for j in range(held.shape[2]):
            d = np.diff(np.concatenate([[0], held[:, k, j].astype(int), [0]]))
            for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
                share = blame[a:b, k, j].mean()
                if share > best:
                    best, worst = share, (a, b, k, j)
    return worst


def triangulate_gated(cameras, xy, members, *, k: float = 4.0,
                      floor_px: float = 0.5) -> GatedPoints:
    """Every frame's 3-D position of the joined points (:func:`triangulate_joined`), with
    the residual gate (:func:`residual_gate`, its bound set once on all the positions).

    A position out of the bound held by three or more views is intersected again with each
    view left out in turn and kept, from the others, where the least of these residuals is
    within the bound; otherwise it is dropped. A view is blamed in such a frame: the view
    left out, or every view of a dropped position (two views cannot say which is wrong).
    A run of a view's frames (its track between gaps, e.g. one picked up again on another
    dot after a gap) blamed in more than half of its frames is wrong throughout, also where
    it happens to lie near the epipolar line: the run blamed in the largest share is taken
    out of the point, the points are intersected and gated again, and so on until no run
    is blamed in more than half of its frames. A right view's run is blamed only in the
    frames it shares with a wrong one; taking the worst run first clears those.

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px.
    members : (M, K) int array
        The joins.
    k, floor_px : float
        :func:`residual_gate`'s.

    Returns
    -------
    GatedPoints
    """
    cams, arrays = _checked(cameras, xy)
    pos = joined_positions(arrays, members)
    held0 = np.isfinite(pos).all(axis=3)                         # (T, K, M)
    xyz, residual = _intersect(cams, pos)
    keep, bound = residual_gate(residual, k=k, floor_px=floor_px)
    first = np.isfinite(residual)                                # intersected at all
    if np.isnan(bound) or keep.all():
        return GatedPoints(xyz=xyz, residual=residual, n_views=held0.sum(axis=1), dropped=0,
                           views_out=0, bound_px=bound)
    while True:
        xyz, residual, still, blame = _leave_one_out(cams, pos, bound)
        worst = _worst_run(np.isfinite(pos).all(axis=3), blame)
        if worst is None:
            break
        a, b, v, j = worst
        pos[a:b, v, j] = np.nan                             # the run: wrong throughout
    xyz[still], residual[still] = np.nan, np.nan
    kept = np.isfinite(residual)
    left = kept & (blame.sum(axis=1) > 0)                   # a view left out in the frame
    n_views = np.where(kept, np.isfinite(pos).all(axis=3).sum(axis=1) - left, 0)
    return GatedPoints(xyz=xyz, residual=residual, n_views=n_views,
                       dropped=int((first & ~kept).sum()),
                       views_out=int((kept & (n_views < held0.sum(axis=1))).sum()),
                       bound_px=bound)
