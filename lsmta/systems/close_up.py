"""Pieces of the mixed-scale system's close-up stages (:func:`~lsmta.systems.
capture_mixed_scale`): the frame from which the face markers are tracked, the pair of heads
that measures each marker (:func:`best_pairs`), and where lost markers may start again (the
filled face projected into each head, on a dot)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..pantilt import PanTiltCamera
from ..triangulation import triangulate


def first_settled(times, head_since, settle: float) -> int:
    """The first frame at which the heads have been aimed at the same target for
    ``settle`` s (``head_since``: when the frame's head target became the head, NaN for
    none), or 0 when there is none."""
    with np.errstate(invalid="ignore"):
        ok = np.flatnonzero(np.asarray(times) - np.asarray(head_since) >= settle)
    return int(ok[0]) if len(ok) else 0


@dataclass(frozen=True, eq=False)
class PairChoice:
    """The markers of one frame, each measured by its best pair of heads (:func:`best_pairs`).

    Attributes
    ----------
    points : (M, 3) array
        mm; NaN where no pair of heads gives a usable intersection.
    pair : (M, 2) int array
        The heads ``(a, b)``, ``a < b``, that measured each marker; ``(-1, -1)`` where none.
    predicted : (M,) array
        The chosen pair's predicted error per degree of ray error, mm/° (NaN where none).
    candidates : (P, M) array
        Every pair's predicted error, mm/°, the pairs in the order of ``pairs``; NaN where
        the pair gives no usable intersection.
    pairs : (P, 2) int array
        All pairs of the K heads, ``itertools.combinations`` order.
    """

    points: np.ndarray
    pair: np.ndarray
    predicted: np.ndarray
    candidates: np.ndarray
    pairs: np.ndarray


def predicted_pair_error(X, Ca, Cb) -> np.ndarray:
    """How far the intersection of two rays moves per degree of error in each ray, mm/°.

    For rays from projection centres ``Ca`` and ``Cb`` meeting at ``X``, each turned by a
    small angle σ (independently), the intersection moves in the plane of the rays by about
    σ √(d_a² + d_b²) / sin θ, d_k the distance from centre k to X and θ the angle between
    the rays: the depth error of a stereo pair, which grows as the rays become parallel
    and as the heads stand farther away.

    Parameters
    ----------
    X : (M, 3) array
        Points, mm (NaN allowed: NaN out).
    Ca, Cb : (3,) arrays
        Projection centres, mm.

    Returns
    -------
    (M,) array
        mm per degree; inf where the rays are parallel.
    """
    X = np.asarray(X, float)
    ua, ub = X - np.asarray(Ca, float), X - np.asarray(Cb, float)
    da, db = np.linalg.norm(ua, axis=-1), np.linalg.norm(ub, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sin = np.linalg.norm(np.cross(ua, ub), axis=-1) / (da * db)
        return np.radians(1.0) * np.sqrt(da**2 + db**2) / sin


def best_pairs(cameras, xy, *, min_angle_deg: float = 2.0,
               max_reprojection_px: float = 4.0) -> PairChoice:
    """Each marker of one frame measured by the best pair of heads that sees it.

    Every pair of heads that both see a marker intersects its two rays
    (:func:`lsmta.triangulation.triangulate`); an intersection is *usable* when the rays'
    angle is at least ``min_angle_deg`` and it reprojects within ``max_reprojection_px`` of
    the marker's image in both heads. Of the usable ones, the marker takes the pair with the
    smallest predicted error (:func:`predicted_pair_error`: σ √(d_a² + d_b²) / sin θ per
    degree σ of ray error); ties go to the pair listed first.

    Why one pair per marker, and why this one. Davis (2002, §5.2): the heads' poses are
    known only approximately (here: angles read back to 0.1°), so a point from a pair
    carries that pair's bias; rays of three or four heads averaged into one point would mix
    the biases of every head in each marker. A single pair per marker keeps each marker's
    error that of one pair (the thesis goes further and takes one pair for the whole frame,
    which with heads on every side loses the markers that pair does not see: the face turns
    away from a head, and a marker at the side of the face is seen only by the heads on
    that side). Of the pairs, the one with the smallest predicted error rather than the
    widest angle: the heads stand at different distances, and a far pair with a slightly
    wider angle moves the point more per degree than a near one; with heads at equal
    distances the two rules agree. The read-back error (a fixed angle per head and frame)
    and the image noise (px, i.e. an angle at a fixed zoom) are both angles, so an error
    per degree ranks the pairs without knowing σ.

    Parameters
    ----------
    cameras : sequence of K >= 2 Camera
        The heads at one frame's angles.
    xy : (K, M, 2) array
        The markers' images, px (NaN: not seen by that head).
    min_angle_deg, max_reprojection_px : float
        As :class:`~lsmta.systems.MixedScaleParams`.

    Returns
    -------
    PairChoice
        Nothing passed in is modified.
    """
    cams = list(cameras)
    if len(cams) < 2 or not all(isinstance(c, Camera) for c in cams):
        raise TypeError(f"cameras: expected a sequence of at least 2 lsmta.camera.Camera, got "
                        f"{[type(c).__name__ for c in cams]}")
    xy = as_array(xy, "xy", shape=(len(cams), None, 2), allow_nan=True)
    as_scalar(min_angle_deg, "min_angle_deg", nonnegative=True)
    as_scalar(max_reprojection_px, "max_reprojection_px", positive=True)
    M = xy.shape[1]
    pairs = np.array(list(itertools.combinations(range(len(cams)), 2)))
    seen = np.isfinite(xy).all(axis=2)
    cand = np.full((len(pairs), M), np.nan)
    pts = np.full((len(pairs), M, 3), np.nan)
    for n, (a, b) in enumerate(pairs):
        both = seen[a] & seen[b]
        if not both.any():
            continue
        r = triangulate([cams[a], cams[b]], xy[[a, b]][:, both], min_angle_deg=min_angle_deg)
        with np.errstate(invalid="ignore"):
            ok = r.valid & (np.fmax.reduce(r.reprojection_error, axis=0) <= max_reprojection_px)
        m = np.flatnonzero(both)[ok]
        pts[n, m] = r.points[ok]
        cand[n, m] = predicted_pair_error(r.points[ok], cams[a].C, cams[b].C)
    usable = np.isfinite(cand)
    pick = np.argmin(np.where(usable, cand, np.inf), axis=0)
    any_ = usable.any(axis=0)
    idx = np.arange(M)
    return PairChoice(points=np.where(any_[:, None], pts[pick, idx], np.nan),
                      pair=np.where(any_[:, None], pairs[pick], -1),
                      predicted=np.where(any_, cand[pick, idx], np.nan),
                      candidates=cand, pairs=pairs)


_NINE = np.stack(np.meshgrid(np.arange(-4, 5), np.arange(-4, 5)), -1).reshape(-1, 2)  # (x, y)


def reacquisition_seeds(images, heads, settings, face, found, *, dot_contrast: float = 30.0,
                        crowd_px: float = 6.0) -> np.ndarray:
    """Where lost markers may start again: the filled face projected into each head.

    Parameters
    ----------
    images : (K, F, H, W) array
    heads : sequence of K PanTiltCamera
        As calibrated.
    settings : (K, F, 2) array
        Read-back angles, degrees.
    face : (F, M, 3) array
        The filled face, mm (NaN where not fitted).
    found : (K, F, M) bool array
        Markers the tracker has in each frame (they are not restarted).
    dot_contrast : float
        The image at the projection must exceed the median of its 9 x 9 neighbourhood by
        this many grey levels (a dot, not skin; a marker turned away draws none).
    crowd_px : float
        Projections closer than this to another one are not used (their dots merge).

    Returns
    -------
    (K, F, M, 2) array
        Seeds for :func:`~lsmta.tracking.markers.track_markers`, px (NaN elsewhere).
    """
    if np.ndim(images) != 4:
        raise ValueError(f"images: expected an array of shape (K, F, H, W), got shape "
                         f"{np.shape(images)}")
    K, F, H, W = np.shape(images)
    heads = list(heads)
    if len(heads) != K or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError(f"heads: expected {K} lsmta.pantilt.PanTiltCamera (one per image "
                        "sequence)")
    settings = as_array(settings, "settings", shape=(K, F, 2))
    face = as_array(face, "face", shape=(F, None, 3), allow_nan=True)
    M = face.shape[1]
    found = np.asarray(found)
    if found.dtype != bool or found.shape != (K, F, M):
        raise ValueError(f"found: expected a bool array of shape ({K}, {F}, {M}), got "
                         f"{found.dtype} {found.shape}")
    as_scalar(dot_contrast, "dot_contrast", nonnegative=True)
    as_scalar(crowd_px, "crowd_px", nonnegative=True)
    seeds = np.full((K, F, M, 2), np.nan)
    for k, head in enumerate(heads):
        for f in np.flatnonzero(np.isfinite(face).all(axis=(1, 2))):
            cam = head.camera_at(*settings[k, f])
            p = cam.project(face[f], behind="nan")
            finite = np.isfinite(p).all(axis=1)
            d = np.nan_to_num(np.linalg.norm(p[:, None] - p[None], axis=2), nan=np.inf)
            np.fill_diagonal(d, np.inf)
            c = np.rint(np.where(finite[:, None], p, -100.0)).astype(int)
            ok = finite & ~found[k, f] & (c[:, 0] >= 4) & (c[:, 0] < W - 4) & (c[:, 1] >= 4) \
                & (c[:, 1] < H - 4) & (d.min(axis=1) >= crowd_px)
            m = np.flatnonzero(ok)
            patch = images[k, f][c[m, 1, None] + _NINE[:, 1], c[m, 0, None] + _NINE[:, 0]]
            dot = patch[:, 40].astype(float) - np.median(patch, axis=1) >= dot_contrast
            seeds[k, f, m[dot]] = p[m[dot]]
    return seeds
