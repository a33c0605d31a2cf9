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
    T, K, M, _ = pos.shape
    res = triangulate(cams, np.moveaxis(pos, 1, 0).reshape(K, T * M, 2), min_angle_deg=1.0)
    xyz = np.where(res.valid[:, None], res.points, np.nan).reshape(T, M, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # points not intersected
        residual = np.where(res.valid, np.nanmax(res.reprojection_error, axis=0),
                            np.nan).reshape(T, M)
    n_views = np.isfinite(pos).all(axis=3).sum(axis=1)
    return xyz, residual, n_views
