"""Tie points of a calibrated rig found in its own images.

In each frame of a synchronised recording, features of every view are matched with every
other view's. The features are SIFT's (OpenCV's ``cv2.SIFT``: a scale- and
rotation-invariant detector and 128-value descriptor) or, for views far apart, ASIFT's
(OpenCV's ``cv2.AffineFeature`` around SIFT, Morel & Yu 2009: SIFT run again on the image
seen under simulated tilts, so that a surface seen obliquely by one camera and head-on by
another still gives matching descriptors). SIFT's descriptors hold to about 30-40 degrees
of viewpoint change; the default ``detector="auto"`` takes ASIFT when two of the cameras'
optical axes are more than ``asift_above_deg`` apart.

The given cameras guide the matching: a feature of view *b* is a candidate for one of view
*a* only within ``band_px`` of its epipolar line (so a camera file that is some pixels off
still finds its matches, and repeated texture elsewhere in the image cannot be chosen).
The search is compiled (numba, on its threads), one pass each way per view pair, on the
descriptors as bytes (SIFT's are whole numbers in 0..255, so the distances are exact) and
with the lines taken in blocks of similar ones, so that each candidate's descriptor is
read once per block: for each feature, the nearest descriptor among the candidates in the
band, and the nearest among those not at the same place (a place holds several features:
one per orientation, and with ASIFT one per simulated tilt). Lowe's ratio test between the
two (a lone candidate passes it) and a mutual check keep unambiguous pairs. Each view
pair's matches must then agree with one relative orientation of their own: an essential
matrix fitted by MAGSAC++ (``cv2.findEssentialMat`` with ``cv2.USAC_MAGSAC``) on the
features' undistorted normalised positions, inliers within ``ransac_px``; a pair with
fewer than ``min_matches`` inliers gives none. A wrong match that happens to lie in the
band does not agree with the others' relative orientation, so the band can be wide. Then
(``recording_geometry``) a pair's matches of all frames must agree with one relative
orientation: the cameras do not move, and one frame's few matches of a wide pair let a
wrong match of repeated structure pass; a frame's pair left with fewer than ``min_matches``
gives none (:func:`recording_inliers` is the same check on chained tie points, which
:func:`lsmta.systems.refine_rig` applies to the places it adjusts only). The pairs'
matches are chained into multi-view tie points (union-find); a chain that holds two
features of one view is dropped.

Features of a still background give the same 3-D point in every frame; features of a
moving subject give new points in each frame (the views are synchronised), spread through
the volume where the subject moves.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numba as nb
import numpy as np

from .._validate import as_int, as_scalar, freeze
from ..build_cache import cached_arrays, content_key
from ..camera import Camera


@dataclass(frozen=True)
class TieParams:
    """Settings of :func:`find_tie_points`.

    Attributes
    ----------
    detector : {"auto", "sift", "asift"}
        The features: SIFT, ASIFT (SIFT under simulated tilts), or ASIFT when two of the
        cameras' optical axes are more than ``asift_above_deg`` apart.
    n_features : int
        Most SIFT features per view and frame.
    asift_features : int
        With ASIFT: most features per simulated view (a view and frame holds about 20
        simulated views at ``max_tilt=3``).
    contrast : float
        SIFT's contrast threshold (OpenCV's default 0.04; lower finds more in flat light).
    max_tilt : int
        ASIFT's highest tilt index: tilts ``sqrt(2) ** k`` for k = 0 .. max_tilt (3: up to
        2.8, a plane seen about 70 degrees from head-on).
    asift_above_deg : float
        Angle between optical axes above which ``"auto"`` takes ASIFT, degrees.
    band_px : float
        Half-width of the epipolar band searched with the given cameras, px.
    ratio : float
        Lowe's ratio: the best candidate's descriptor distance must be below ``ratio``
        times the second best's.
    distinct_px : float
        The second best is taken only among candidates farther than this from the best,
        px. SIFT gives one place several features (one per dominant orientation) and ASIFT
        finds it again under each simulated tilt: such a twin is not a rival, and counting
        it as one rejects the match.
    ransac_px : float
        Largest distance to a pair's own epipolar line, px.
    min_matches : int
        Fewest inliers for a view pair to count.
    recording_geometry : bool
        After each frame's own check, a pair's inlier matches of all frames together must
        agree with ONE relative orientation (an essential matrix fitted to them all, inliers
        within ``ransac_px``): the cameras do not move during a recording, and a pair's
        matches of one frame (on a wide pair, some tens) let a wrong match of repeated
        structure pass their own fit. On the Pose2Sim demo's rear pair it dropped a treadmill
        post matched to its twin post (9-11 px off the refined cameras' epipolar geometry).
        Only with matches in two or more frames; a frame's pair left with fewer than
        ``min_matches`` gives none. :func:`lsmta.systems.refine_rig` applies it after its
        hold-out split, to the places it adjusts only (:func:`recording_inliers`). Off by
        default: applied that way (held-out places judged as matched per frame), it made the
        demo's judged held-out residual worse in cam03 on two frame splits (2.59 -> 4.06
        and 1.29 -> 3.54 px at full size; README, "Your own recording").
    """

    detector: str = "auto"
    n_features: int = 6000
    asift_features: int = 800
    contrast: float = 0.02
    max_tilt: int = 3
    asift_above_deg: float = 40.0
    band_px: float = 50.0
    ratio: float = 0.8
    distinct_px: float = 2.0
    ransac_px: float = 1.5
    min_matches: int = 15
    recording_geometry: bool = False

    def __post_init__(self):
        if self.detector not in ("auto", "sift", "asift"):
            raise ValueError(f"detector: expected 'auto', 'sift' or 'asift', got "
                             f"{self.detector!r}")
        as_int(self.n_features, "n_features")
        as_int(self.asift_features, "asift_features")
        as_int(self.max_tilt, "max_tilt", minimum=1)
        as_int(self.min_matches, "min_matches", minimum=8)
        as_scalar(self.distinct_px, "distinct_px", nonnegative=True)
        for name in ("contrast", "band_px", "ransac_px", "asift_above_deg"):
            as_scalar(getattr(self, name), name, positive=True)
        r = as_scalar(self.ratio, "ratio", positive=True)
        if r >= 1:
            raise ValueError(f"ratio: expected a number in (0, 1), got {r}")
        if not isinstance(self.recording_geometry, bool):
            raise TypeError(f"recording_geometry: expected True or False, got "
                            f"{self.recording_geometry!r}")


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


def _lines(a: Camera, b: Camera, na) -> np.ndarray:
    """(Na, 3) epipolar lines in b of a's undistorted positions ``na`` (pixel units), scaled
    so that ``line . (x_b, y_b, 1)`` is the distance in b's pixels."""
    ha = np.c_[na / a.f, np.ones(len(na))]
    lines = ha @ _essential(a, b).T
    lines /= np.hypot(lines[:, :1], lines[:, 1:2])
    lines[:, 2] *= b.f
    return lines


@nb.njit(cache=True)
def _cell_index(xb, cell):                                            # pragma: no cover
    """b's features sorted into square cells of side ``cell`` (at least 1/512 of their
    spread): the cell side, the grid's origin and shape, each cell's slice of ``order``
    (``start``), and ``order`` (NaN rows left out)."""
    n = xb.shape[0]
    x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
    for j in range(n):
        if np.isfinite(xb[j, 0]) and np.isfinite(xb[j, 1]):
            x0, x1 = min(x0, xb[j, 0]), max(x1, xb[j, 0])
            y0, y1 = min(y0, xb[j, 1]), max(y1, xb[j, 1])
    if not x0 <= x1:
        return cell, 0.0, 0.0, 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64)
    cell = max(cell, (x1 - x0) / 512.0, (y1 - y0) / 512.0)
    nx = int((x1 - x0) // cell) + 1
    ny = int((y1 - y0) // cell) + 1
    cid = np.full(n, -1, np.int64)
    count = np.zeros(nx * ny + 1, np.int64)
    for j in range(n):
        if np.isfinite(xb[j, 0]) and np.isfinite(xb[j, 1]):
            cid[j] = int((xb[j, 1] - y0) // cell) * nx + int((xb[j, 0] - x0) // cell)
            count[cid[j] + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    order = np.empty(start[-1], np.int64)
    for j in range(n):                                   # ascending j within each cell
        if cid[j] >= 0:
            order[fill[cid[j]]] = j
            fill[cid[j]] += 1
    return cell, x0, y0, nx, ny, start, order


@nb.njit(parallel=True, fastmath={"reassoc", "contract"}, cache=True)
def _band_kernel(lines, xb, da, db, band, distinct, rank, block):   # pragma: no cover
    """:func:`_nearest_in_band` on byte descriptors, the lines taken ``block`` at a time in
    the order ``rank`` (similar lines together).

    b's features are put in square cells of side ``band`` and copied in cell order (their
    descriptors contiguous); a block of lines walks the cells that the union of its bands
    crosses (along its first line's longer extent), so each candidate's descriptor is loaded
    from memory once per block, and is tested against each line of the block exactly. Squared
    distances of byte descriptors are summed in 32-bit integers: exact."""
    na = da.shape[0]
    dim = da.shape[1]
    best = np.full(na, -1, np.int64)
    d1 = np.full(na, np.inf)
    d2 = np.full(na, np.inf)
    cell, x0, y0, nx, ny, start, order = _cell_index(xb, max(band, 1e-3))
    ns = order.shape[0]
    xs = np.empty((ns, 2))
    ds = np.empty((ns, dim), np.uint8)
    for q in range(ns):
        xs[q, 0] = xb[order[q], 0]
        xs[q, 1] = xb[order[q], 1]
        ds[q] = db[order[q]]
    big = np.int64(2 ** 31 - 1)
    n_blocks = (na + block - 1) // block
    per = 16                                       # blocks per chunk (buffers reused)
    for ch in nb.prange((n_blocks + per - 1) // per):
        lb = np.empty((block, 3))
        ab = np.empty((block, dim), np.uint8)
        cand = np.empty((block, ns), np.int32)      # each line's candidates (cell order)
        cdist = np.empty((block, ns), np.int32)
        m = np.zeros(block, np.int64)
        bq = np.empty(block, np.int64)
        bj = np.empty(block, np.int64)
        bd = np.empty(block, np.int64)
        for blk in range(ch * per, min(n_blocks, (ch + 1) * per)):
            ids = rank[blk * block:min(na, (blk + 1) * block)]
            nl = ids.shape[0]
            for t in range(nl):
                lb[t] = lines[ids[t]]
                ab[t] = da[ids[t]]
                m[t] = 0
                bq[t] = -1
                bj[t] = -1
                bd[t] = big
            flat = abs(lb[0, 1]) >= abs(lb[0, 0])   # walk along x (cells in columns)
            n_walk, n_across = (nx, ny) if flat else (ny, nx)
            o_walk, o_across = (x0, y0) if flat else (y0, x0)
            for w in range(n_walk):
                u0 = o_walk + w * cell
                lo, hi = n_across, -1
                for t in range(nl):
                    l0, l1, l2 = lb[t, 0], lb[t, 1], lb[t, 2]
                    a, b_ = (l0, l1) if flat else (l1, l0)
                    if abs(b_) < 1e-12:                 # along the walk: every cell across
                        lo, hi = 0, n_across - 1
                        break
                    half = band / abs(b_) + 1e-9 * (1.0 + abs(l2))
                    va = -(a * u0 + l2) / b_
                    vb = -(a * (u0 + cell) + l2) / b_
                    lo = min(lo, int(np.floor((min(va, vb) - half - o_across) / cell)))
                    hi = max(hi, int(np.floor((max(va, vb) + half - o_across) / cell)))
                for c in range(max(lo, 0), min(hi, n_across - 1) + 1):
                    k = c * nx + w if flat else w * nx + c
                    for q in range(start[k], start[k + 1]):
                        qx, qy = xs[q, 0], xs[q, 1]
                        for t in range(nl):
                            if not abs(lb[t, 0] * qx + lb[t, 1] * qy + lb[t, 2]) < band:
                                continue
                            d = np.int32(0)
                            for e_ in range(dim):                # vectorised (SIMD)
                                e = np.int32(ab[t, e_]) - np.int32(ds[q, e_])
                                d = np.int32(d + e * e)
                            cand[t, m[t]] = q
                            cdist[t, m[t]] = d
                            m[t] += 1
                            j = order[q]
                            if d < bd[t] or (d == bd[t] and j < bj[t]):
                                bd[t] = d
                                bj[t] = j
                                bq[t] = q
            for t in range(nl):
                if bq[t] < 0:
                    continue
                i = ids[t]
                best[i] = bj[t]
                d1[i] = bd[t]
                px, py = xs[bq[t], 0], xs[bq[t], 1]
                dd = big
                for r in range(m[t]):
                    q = cand[t, r]
                    if cdist[t, r] < dd and (xs[q, 0] - px) ** 2 + (xs[q, 1] - py) ** 2 \
                            > distinct ** 2:
                        dd = cdist[t, r]
                if dd < big:
                    d2[i] = dd
    return best, d1, d2


def _nearest_in_band(lines, xb, da, db, band, distinct):
    """For each row of ``da``: the nearest descriptor of ``db`` among b's features within
    ``band`` of its line, and the nearest among those farther than ``distinct`` from it
    (squared distances; index -1: none; of equal distances the lower index).

    ``lines`` (Na, 3) are normalised (``l0² + l1² = 1``); ``da``, ``db`` are byte
    descriptors (Na, D), (Nb, D) uint8 (SIFT's, see :func:`_bytes`). The lines are taken
    in blocks of similar ones (sorted by direction, then offset) so that a candidate is loaded
    once per block (:func:`_band_kernel`); the result does not depend on the order."""
    lines = np.ascontiguousarray(lines, float)
    canon = np.where(((lines[:, 1] < 0) | ((lines[:, 1] == 0) & (lines[:, 0] < 0)))[:, None],
                     -lines, lines)
    rank = np.lexsort((canon[:, 2], np.arctan2(canon[:, 1], canon[:, 0])))
    return _band_kernel(lines, np.ascontiguousarray(xb, float),
                        np.ascontiguousarray(_bytes(da)), np.ascontiguousarray(_bytes(db)),
                        float(band), float(distinct), rank, 32)


def _bytes(des) -> np.ndarray:
    """SIFT's descriptors as bytes: OpenCV rounds them to whole numbers in 0..255 (and
    returns them as float32), so nothing is lost; distances between them are exact."""
    des = np.asarray(des)
    if des.dtype != np.uint8 and (des.size and (des.min() < 0 or des.max() > 255
                                                or not np.array_equal(des, np.round(des)))):
        raise ValueError("descriptors: expected whole numbers in 0..255 (SIFT's, as OpenCV "
                         "returns them)")
    return des.astype(np.uint8)


def _one_way(a, b, ideal_a, ideal_b, da, db, params) -> dict:
    best, d1, d2 = _nearest_in_band(_lines(a, b, ideal_a), ideal_b, da, db,
                                    params.band_px, params.distinct_px)
    ok = (best >= 0) & (np.sqrt(d1) < params.ratio * np.sqrt(d2))   # a lone candidate: d2 inf
    return dict(zip(np.flatnonzero(ok).tolist(), best[ok].tolist()))


def _mutual(cams, ideal, feats, params) -> np.ndarray:
    """Matches of two views that are each other's unambiguous nearest in the band."""
    (a, b), (ia, ib), ((_, da), (_, db)) = cams, ideal, feats
    ab = _one_way(a, b, ia, ib, da, db, params)
    ba = _one_way(b, a, ib, ia, db, da, params)
    keep = [(i, j) for i, j in ab.items() if ba.get(j) == i]
    return np.array(keep, int).reshape(-1, 2)


def _detector(cameras, params: TieParams):
    z = np.stack([np.asarray(c.R)[2] for c in cameras])          # optical axes
    widest = np.degrees(np.arccos(np.clip(z @ z.T, -1.0, 1.0))).max()
    wide = (params.detector == "asift"
            or params.detector == "auto" and widest > params.asift_above_deg)
    if not wide:
        return (cv2.SIFT_create(nfeatures=params.n_features, contrastThreshold=params.contrast),
                ("sift", params.n_features, params.contrast))
    sift = cv2.SIFT_create(nfeatures=params.asift_features, contrastThreshold=params.contrast)
    return (cv2.AffineFeature_create(sift, maxTilt=params.max_tilt),
            ("asift", params.asift_features, params.contrast, params.max_tilt))


def _features(images, detector):
    """Each image's features ``(xy, descriptors)`` from ``detector`` (``(cv2 detector, its
    settings)``); kept for the next notebook of a ``lsmta reproduce`` build (the same frames
    in notebooks 17 and 21: :mod:`lsmta.build_cache`)."""
    det, settings = detector
    code = Path(__file__).read_bytes()      # this module's code makes them too
    out = []
    for g in images:
        def compute(g=g):
            kp, des = det.detectAndCompute(g, None)
            xy = np.array([k.pt for k in kp], float).reshape(-1, 2)
            return {"xy": xy, "des": _bytes(des) if des is not None
                    else np.zeros((0, 128), np.uint8)}
        key = content_key("tie features", cv2.__version__, settings, code, np.asarray(g))
        f = cached_arrays("tie_features", key, compute)
        out.append((f["xy"], f["des"]))
    return out


def _own_geometry(a: Camera, b: Camera, xa, xb, params: TieParams) -> np.ndarray:
    """Inlier mask of the matches under the pair's own essential matrix (MAGSAC++)."""
    na = a.undistort(a.pixel_to_normalized(xa))
    nb_ = b.undistort(b.pixel_to_normalized(xb))
    cv2.setRNGSeed(0)                               # MAGSAC's sampling, reproducible
    _, inl = cv2.findEssentialMat(na, nb_, np.eye(3), cv2.USAC_MAGSAC, 0.999,
                                  params.ransac_px / np.sqrt(a.f * b.f))
    return np.zeros(len(xa), bool) if inl is None else inl.ravel().astype(bool)


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
    roots = np.array([find(i) for i in range(offsets[-1])], dtype=np.int64)
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


def _frame_matches(f, images, cameras, detector, params):
    """One frame's features per view, its pairs' matches that agree with the pair's own
    relative orientation, and the (K, K) matches in the band before it."""
    K = len(cameras)
    if len(images) != K:
        raise ValueError(f"frames: frame {f} holds {len(images)} images, expected {K} "
                         "(one per camera)")
    for k, (g, c) in enumerate(zip(images, cameras)):
        g = np.asarray(g)
        if g.ndim != 2 or g.dtype != np.uint8 or g.shape != (c.height, c.width):
            raise ValueError(f"frames: image {k} of frame {f} is {g.dtype} {g.shape}; "
                             f"expected uint8 ({c.height}, {c.width}) like its camera")
    feats = _features(images, detector)
    ideal = [_ideal(c, xy) if len(xy) else xy for c, (xy, _) in zip(cameras, feats)]
    matches, guided = {}, np.zeros((K, K), int)
    for a, b in itertools.combinations(range(K), 2):
        if len(feats[a][0]) < 2 or len(feats[b][0]) < 2:
            continue
        m = _mutual((cameras[a], cameras[b]), (ideal[a], ideal[b]), (feats[a], feats[b]),
                    params)
        guided[a, b] += len(m)
        if len(m) < params.min_matches:
            continue
        inl = _own_geometry(cameras[a], cameras[b], feats[a][0][m[:, 0]],
                            feats[b][0][m[:, 1]], params)
        if inl.sum() >= params.min_matches:
            matches[a, b] = m[inl]
    return feats, matches, guided


def _one_geometry(found, cameras, params):
    """``found`` with each pair's matches kept only where they agree with one relative
    orientation fitted to the pair's matches of all frames (pairs matched in >= 2 frames)."""
    pairs = {p for _, matches in found for p in matches}
    out = [(feats, dict(matches)) for feats, matches in found]
    for a, b in sorted(pairs):
        frames = [f for f, (_, matches) in enumerate(found) if (a, b) in matches]
        if len(frames) < 2:
            continue
        xa = np.concatenate([found[f][0][a][0][found[f][1][a, b][:, 0]] for f in frames])
        xb = np.concatenate([found[f][0][b][0][found[f][1][a, b][:, 1]] for f in frames])
        inl = _own_geometry(cameras[a], cameras[b], xa, xb, params)
        split = np.cumsum([len(found[f][1][a, b]) for f in frames])[:-1]
        for f, keep in zip(frames, np.split(inl, split)):
            if keep.sum() >= params.min_matches:
                out[f][1][a, b] = found[f][1][a, b][keep]
            else:                                 # too few left: the frame's pair gives none
                del out[f][1][a, b]
    return out


def recording_inliers(cameras, xy, *, params: TieParams | None = None) -> np.ndarray:
    """Which tie points agree, in every view pair, with ONE relative orientation of that
    pair fitted to all of them (the cameras do not move during a recording).

    For each pair of views, an essential matrix is fitted by MAGSAC++ to the tie points seen
    in both (their undistorted normalised positions); a point farther than
    ``params.ransac_px`` from its epipolar line in that pair fails. A pair with fewer than
    ``params.min_matches`` points, or inliers, gives none: all its points fail. The check
    of ``params.recording_geometry`` (:func:`find_tie_points`), on tie points already
    chained, e.g. on only those an adjustment is to use.

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : (K, N, 2) array
        Image positions, px of ``cameras``; NaN where a view does not hold the point.
    params : TieParams, optional
        Its ``ransac_px`` (px of ``cameras``) and ``min_matches``.

    Returns
    -------
    (N,) bool array
        True where the point passes every pair it is seen in.
    """
    params = TieParams() if params is None else params
    cameras = list(cameras)
    xy = np.asarray(xy, float)
    if not all(isinstance(c, Camera) for c in cameras):
        raise ValueError("cameras: expected a sequence of lsmta Camera")
    if xy.ndim != 3 or xy.shape[0] != len(cameras) or xy.shape[2] != 2:
        raise ValueError(f"xy: expected ({len(cameras)}, N, 2) positions (one row per "
                         f"camera), got shape {xy.shape}")
    seen = np.isfinite(xy).all(axis=2)
    ok = np.ones(xy.shape[1], bool)
    for a, b in itertools.combinations(range(len(cameras)), 2):
        both = np.flatnonzero(seen[a] & seen[b])
        if len(both) == 0:
            continue
        inl = (_own_geometry(cameras[a], cameras[b], xy[a, both], xy[b, both], params)
               if len(both) >= params.min_matches else np.zeros(len(both), bool))
        ok[both if inl.sum() < params.min_matches else both[~inl]] = False
    return ok


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
    detector = _detector(cameras, params)
    pair_matches = np.zeros((K, K), int)
    pair_guided = np.zeros((K, K), int)
    found = []                                  # per frame: features, the pairs' matches
    for f, images in enumerate(frames):
        feats, matches, guided = _frame_matches(f, list(images), cameras, detector, params)
        pair_guided += guided
        found.append((feats, matches))
    if not found:
        raise ValueError("frames: expected at least one frame")
    if params.recording_geometry:
        found = _one_geometry(found, cameras, params)
    xy_all, frame_all = [], []
    for f, (feats, matches) in enumerate(found):
        for (a, b), m in matches.items():
            pair_matches[a, b] += len(m)
        offsets = np.concatenate([[0], np.cumsum([len(x) for x, _ in feats])])
        idx = _chain(K, offsets, matches)
        xy = np.full((K, idx.shape[1], 2), np.nan)
        for k in range(K):
            ok = idx[k] >= 0
            xy[k, ok] = feats[k][0][idx[k, ok]]
        xy_all.append(xy)
        frame_all.append(np.full(idx.shape[1], f))
    return TiePoints(xy=np.concatenate(xy_all, axis=1), frame=np.concatenate(frame_all),
                     pair_matches=pair_matches, pair_guided=pair_guided)
