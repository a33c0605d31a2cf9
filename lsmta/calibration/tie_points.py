"""Tie points of a calibrated rig found in its own images.

In each frame of a synchronised recording, SIFT features (OpenCV's ``cv2.SIFT``: a
scale- and rotation-invariant detector and 128-value descriptor) of every view are matched
with every other view's. The given cameras guide the matching: a feature of view *b* is a
candidate for one of view *a* only within ``band_px`` of its epipolar line (so a camera
file that is a few pixels off still finds its matches, and repeated texture elsewhere in
the image cannot be chosen). Among the candidates, Lowe's ratio test (a lone candidate in
the band passes it) and a mutual check keep unambiguous pairs. Each view pair's matches
must then agree with one epipolar geometry of their own: a fundamental matrix fitted by
MAGSAC++ (``cv2.USAC_MAGSAC``) on the features' undistorted positions, with inliers
within ``ransac_px``; a pair with fewer than ``min_matches`` inliers gives none. The
pairs' matches are chained into multi-view tie points (union-find); a chain that holds
two features of one view is dropped.

Features of a still background give the same 3-D point in every frame; features of a
moving subject give new points in each frame (the views are synchronised), spread through
the volume where the subject moves.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_int, as_scalar, freeze
from ..camera import Camera


@dataclass(frozen=True)
class TieParams:
    """Settings of :func:`find_tie_points`.

    Attributes
    ----------
    n_features : int
        Most SIFT features per view and frame.
    contrast : float
        SIFT's contrast threshold (OpenCV's default 0.04; lower finds more in flat light).
    band_px : float
        Half-width of the epipolar band searched with the given cameras, px.
    ratio : float
        Lowe's ratio: the best candidate's descriptor distance must be below ``ratio``
        times the second best's.
    ransac_px : float
        Largest distance to a pair's own fitted epipolar line, px.
    min_matches : int
        Fewest inliers for a view pair to count.
    """

    n_features: int = 6000
    contrast: float = 0.02
    band_px: float = 30.0
    ratio: float = 0.8
    ransac_px: float = 1.5
    min_matches: int = 15

    def __post_init__(self):
        as_int(self.n_features, "n_features")
        as_int(self.min_matches, "min_matches", minimum=8)
        for name in ("contrast", "band_px", "ransac_px"):
            as_scalar(getattr(self, name), name, positive=True)
        r = as_scalar(self.ratio, "ratio", positive=True)
        if r >= 1:
            raise ValueError(f"ratio: expected a number in (0, 1), got {r}")


@dataclass(frozen=True)
class TiePoints:
    """Tie points found by :func:`find_tie_points`.

    Attributes
    ----------
    xy : (K, N, 2) array
        Image positions, px; NaN where a view does not hold the point.
    frame : (N,) int array
        Index (in the frames given) of the frame each point was found in.
    pair_matches : (K, K) int array
        Inlier matches per view pair, summed over the frames (upper triangle).
    pair_guided : (K, K) int array
        Matches in the epipolar band before the pair's own geometry was fitted.
    """

    xy: np.ndarray
    frame: np.ndarray
    pair_matches: np.ndarray
    pair_guided: np.ndarray

    def __post_init__(self):
        freeze(self, ("xy", "frame", "pair_matches", "pair_guided"))


def _ideal(camera: Camera, xy) -> np.ndarray:
    """Undistorted positions in pixel units (f times the normalised coordinates)."""
    return camera.undistort(camera.pixel_to_normalized(xy)) * camera.f


def _essential(a: Camera, b: Camera) -> np.ndarray:
    R = np.asarray(b.R) @ np.asarray(a.R).T
    t = np.asarray(b.R) @ (np.asarray(a.C) - np.asarray(b.C))
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ R


def _band(a: Camera, b: Camera, na, nb, band_px: float) -> np.ndarray:
    """(Na, Nb) uint8 mask: b's features within ``band_px`` of a's epipolar lines."""
    ha = np.c_[na / a.f, np.ones(len(na))]
    hb = np.c_[nb / b.f, np.ones(len(nb))].astype(np.float32)
    lines = ha @ _essential(a, b).T                              # (Na, 3) lines in b
    lines = (lines * b.f / np.hypot(lines[:, :1], lines[:, 1:2])).astype(np.float32)
    mask = np.empty((len(na), len(nb)), np.uint8)
    for i in range(0, len(na), 1024):                             # bounded memory
        mask[i:i + 1024] = np.abs(lines[i:i + 1024] @ hb.T) < band_px
    return mask


def _mutual(da, db, mask, ratio: float):
    matcher = cv2.BFMatcher(cv2.NORM_L2)

    def best(q, t, m):
        out = {}
        for pair in matcher.knnMatch(q, t, k=2, mask=m):
            if pair and (len(pair) == 1 or pair[0].distance < ratio * pair[1].distance):
                out[pair[0].queryIdx] = pair[0].trainIdx
        return out

    ab = best(da, db, mask)
    ba = best(db, da, np.ascontiguousarray(mask.T))
    keep = [(i, j) for i, j in ab.items() if ba.get(j) == i]
    return np.array(keep, int).reshape(-1, 2)


def _features(images, params: TieParams):
    sift = cv2.SIFT_create(nfeatures=params.n_features, contrastThreshold=params.contrast)
    out = []
    for g in images:
        kp, des = sift.detectAndCompute(g, None)
        xy = np.array([k.pt for k in kp], float).reshape(-1, 2)
        out.append((xy, des if des is not None else np.zeros((0, 128), np.float32)))
    return out


def _chain(n_views: int, offsets, matches):
    """Union-find over (view, feature) nodes; returns (K, M) feature indices (-1: none)."""
    parent = np.arange(offsets[-1])

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for (a, b), m in matches.items():
        for i, j in m:
            ra, rb = find(offsets[a] + i), find(offsets[b] + j)
            if ra != rb:
                parent[ra] = rb
    roots = np.array([find(i) for i in range(offsets[-1])])
    view = np.repeat(np.arange(n_views), np.diff(offsets))
    local = np.arange(offsets[-1]) - offsets[view]
    tracks = {}
    for node in np.nonzero(np.bincount(roots, minlength=len(roots))[roots] > 1)[0]:
        tracks.setdefault(roots[node], []).append(node)
    out = []
    for nodes in tracks.values():
        views = view[nodes]
        if len(set(views)) != len(views):
            continue                                            # two features of one view
        row = -np.ones(n_views, int)
        row[views] = local[nodes]
        out.append(row)
    return np.array(out, int).reshape(-1, n_views).T


def find_tie_points(frames, cameras, *, params: TieParams | None = None) -> TiePoints:
    """Tie points of K calibrated views in frames of a synchronised recording.

    Parameters
    ----------
    frames : sequence of F sequences of K grey images
        Each item holds one instant's images, one per camera (``(H_k, W_k)`` uint8), as
        :class:`lsmta.io.Videos` yields them.
    cameras : sequence of K Camera
        The rig as given; it guides the matching (see the module docstring).
    params : TieParams, optional

    Returns
    -------
    TiePoints
    """
    params = TieParams() if params is None else params
    cameras = list(cameras)
    K = len(cameras)
    if K < 2 or not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras: expected a sequence of at least two lsmta Camera")
    pair_matches = np.zeros((K, K), int)
    pair_guided = np.zeros((K, K), int)
    xy_all, frame_all = [], []
    for f, images in enumerate(frames):
        images = list(images)
        if len(images) != K:
            raise ValueError(f"frames: frame {f} holds {len(images)} images, expected {K} "
                             "(one per camera)")
        for k, (g, c) in enumerate(zip(images, cameras)):
            g = np.asarray(g)
            if g.ndim != 2 or g.dtype != np.uint8 or g.shape != (c.height, c.width):
                raise ValueError(f"frames: image {k} of frame {f} is {g.dtype} {g.shape}; "
                                 f"expected uint8 ({c.height}, {c.width}) like its camera")
        feats = _features(images, params)
        ideal = [_ideal(c, xy) if len(xy) else xy for c, (xy, _) in zip(cameras, feats)]
        matches = {}
        for a, b in itertools.combinations(range(K), 2):
            (xa, da), (xb, db) = feats[a], feats[b]
            if len(xa) < 2 or len(xb) < 2:
                continue
            mask = _band(cameras[a], cameras[b], ideal[a], ideal[b], params.band_px)
            m = _mutual(da, db, mask, params.ratio)
            pair_guided[a, b] += len(m)
            if len(m) < params.min_matches:
                continue
            cv2.setRNGSeed(0)                       # MAGSAC's sampling, reproducible
            _, inl = cv2.findFundamentalMat(ideal[a][m[:, 0]], ideal[b][m[:, 1]],
                                            cv2.USAC_MAGSAC, params.ransac_px, 0.999, 10000)
            if inl is None or inl.sum() < params.min_matches:
                continue
            matches[a, b] = m[inl.ravel().astype(bool)]
            pair_matches[a, b] += len(matches[a, b])
        offsets = np.concatenate([[0], np.cumsum([len(x) for x, _ in feats])])
        idx = _chain(K, offsets, matches)
        xy = np.full((K, idx.shape[1], 2), np.nan)
        for k in range(K):
            ok = idx[k] >= 0
            xy[k, ok] = feats[k][0][idx[k, ok]]
        xy_all.append(xy)
        frame_all.append(np.full(idx.shape[1], f))
    if not xy_all:
        raise ValueError("frames: expected at least one frame")
    return TiePoints(xy=np.concatenate(xy_all, axis=1), frame=np.concatenate(frame_all),
                     pair_matches=pair_matches, pair_guided=pair_guided)
