"""A user's own recording through the LSMTA system, judged without truth (notebooks 17 and
21, ``experiments/capture_demo.py``): the Pose2Sim demo's four videos and camera file.

A real recording has no truth, so the markers are judged by what needs none:

* *coverage*: the share of the frames in which each moving marker has a 3-D position;
* *residual*: how far the intersected marker reprojects from its tracked positions;
* *rigidity*: the distance between two markers on one rigid segment should not change. The
  pair is chosen by a rule that does not look at the distance's spread (which is what is
  scored). The rule, and its ``max_relative`` threshold in particular, was set in the same
  change as the first full-size score of the Pose2Sim demo (issue #40's marker fix), so it
  cannot be shown to have been fixed before that result was seen. Of the moving markers in
  3-D in at least half of the frames and above the floor (a median height below 0 is a
  wrong join), the pairs that

  - are seen by the same views (a pair intersected by different cameras adds the two camera
    groups' disagreement to its distance);
  - lie ``distance_range`` apart (median; 60-250 mm: a foot's heel to forefoot, the
    pelvis's markers, a segment's two markers);
  - *move together*: the RMS of their relative motion (each marker's displacement from its
    median position, the one's minus the other's) is at most ``max_relative`` (0.5) times
    the RMS of their common motion (the mean of the two displacements). Markers on one
    segment share its translation and differ by its rotation times their lever; markers of
    two segments (the two feet, thigh and shank through a bending knee) swing apart. The
    threshold is coarse on purpose: it tells segments apart, it does not rank pairs by
    their noise;

  and of those, the one with the most frames with both in 3-D, then the lowest in the room
  (a foot's markers are the lowest of a standing or walking person). Without ``views`` the
  same-views condition is left out. The rule cannot say which segment it found: a marker
  on a knee and one on the shank below it move together while the knee is nearly
  straight; the markers' heights are reported so that a reader can judge.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar


@dataclass(frozen=True)
class RigidPair:
    """Two markers on one segment and their distance over time.

    Attributes
    ----------
    markers : (int, int)
        Indices into the markers given.
    distance : (T,) array
        Their distance per frame, mm (NaN where either is missing).
    median_mm, std_mm : float
        Median and standard deviation of the distance over the frames with both.
    frames : int
        Frames with both.
    """

    markers: tuple
    distance: np.ndarray
    median_mm: float
    std_mm: float
    frames: int


def rigid_pair(xyz, *, views=None, distance_range=(60.0, 250.0), min_share: float = 0.5,
               max_relative: float = 0.5, up=(0.0, 0.0, 1.0)) -> RigidPair | None:
    """The pair of markers that move together at a segment's span held longest in 3-D (see
    the module docstring).

    Parameters
    ----------
    xyz : (T, M, 3) array
        Moving markers' positions, mm (NaN where missing).
    views : (M, K) bool array, optional
        The views that hold each marker; a pair must be held by the same views.
    distance_range : (float, float)
        Accepted median distance, mm.
    min_share : float
        Share of the frames each marker of the pair must be in 3-D.
    max_relative : float
        Largest ratio of the RMS relative motion to the RMS common motion, > 0.
    up : (3,) array
        The world's up direction.

    Returns
    -------
    RigidPair or None
        None when no pair qualifies.
    """
    X = as_array(xyz, "xyz", shape=(None, None, 3), allow_nan=True)
    if views is not None:
        views = np.asarray(views, bool)
        if views.ndim != 2 or len(views) != X.shape[1]:
            raise ValueError(f"views: expected an ({X.shape[1]}, K) bool array (the views "
                             f"of each marker), got shape {views.shape}")
    max_relative = as_scalar(max_relative, "max_relative", positive=True)
    up = np.asarray(up, float) / np.linalg.norm(up)
    present = np.isfinite(X).all(axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # markers often missing
        height = np.nanmedian(X @ up, axis=0)
        ok = np.flatnonzero((present.mean(axis=0) >= min_share) & (height >= 0))
        best = None
        for i, j in itertools.combinations(ok, 2):
            if views is not None and not np.array_equal(views[i], views[j]):
                continue
            d = np.linalg.norm(X[:, i] - X[:, j], axis=1)
            med = np.nanmedian(d)
            if not distance_range[0] <= med <= distance_range[1]:
                continue
            if not relative_motion(X[:, i], X[:, j]) <= max_relative:
                continue
            key = (-int(np.isfinite(d).sum()), height[i] + height[j])
            if best is None or key < best[0]:
                best = (key, (int(i), int(j)), d)
    if best is None:
        return None
    _, pair, d = best
    both = np.isfinite(d)
    return RigidPair(markers=pair, distance=d, median_mm=float(np.median(d[both])),
                     std_mm=float(np.std(d[both])), frames=int(both.sum()))


def relative_motion(a, b) -> float:
    """RMS of two markers' relative motion over the RMS of their common motion, over the
    frames both are in 3-D (``(T, 3)`` arrays, mm; NaN with fewer than 3 such frames).

    Each marker's displacement is taken from its median position over those frames; the
    relative motion is the difference of the two displacements, the common motion their
    mean. 0 for two markers that only translate together."""
    a = as_array(a, "a", shape=(None, 3), allow_nan=True)
    b = as_array(b, "b", shape=(len(a), 3), allow_nan=True)
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    if both.sum() < 3:
        return float("nan")
    da = a[both] - np.median(a[both], axis=0)
    db = b[both] - np.median(b[both], axis=0)
    common = np.sqrt(np.mean(np.sum((0.5 * (da + db)) ** 2, axis=1)))
    rel = np.sqrt(np.mean(np.sum((da - db) ** 2, axis=1)))
    return float(rel / common) if common > 0 else float("inf")


def moving_pairs(capture) -> list[dict]:
    """Every pair of a :class:`~lsmta.systems.MarkerCapture`'s moving markers with what
    :func:`rigid_pair`'s rule looks at (not the distance's spread): ``"markers"`` (two
    indices into the capture's markers), ``"same_views"``, ``"median_mm"``,
    ``"relative_motion"`` and ``"frames_both"``."""
    m = capture
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # pairs never both in 3-D
        for i, j in itertools.combinations(np.flatnonzero(m.moving), 2):
            d = np.linalg.norm(m.xyz[:, i] - m.xyz[:, j], axis=1)
            out.append({"markers": [int(i), int(j)],
                        "same_views": bool(np.array_equal(m.members[i] >= 0,
                                                          m.members[j] >= 0)),
                        "median_mm": float(np.nanmedian(d)),
                        "relative_motion": relative_motion(m.xyz[:, i], m.xyz[:, j]),
                        "frames_both": int(np.isfinite(d).sum())})
    return out


def marker_scores(capture, *, pair=None, xyz=None) -> dict:
    """Coverage, residual and rigidity of a :class:`~lsmta.systems.MarkerCapture`'s moving
    markers, as plain numbers (NaN where undefined).

    ``pair`` (two indices into the capture's markers, e.g. another capture's ``"pair"`` of
    the same markers) scores that pair's distance instead of choosing one with
    :func:`rigid_pair`. ``xyz`` ((T, M, 3) array, mm; default the capture's raw
    intersections ``capture.xyz``) are the positions whose pair is chosen and scored (its
    distance, relative motion and heights), e.g. ``capture.xyz_filtered``; the coverage and
    residual are the capture's own."""
    m = capture
    X = m.xyz if xyz is None else as_array(xyz, "xyz", shape=m.xyz.shape, allow_nan=True)
    moving = np.flatnonzero(m.moving)
    share = m.triangulated_share()[moving]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        residual = float(np.nanmedian(m.residual[:, moving])) if len(moving) else np.nan
    if pair is None:
        found = rigid_pair(X[:, moving], views=m.members[moving] >= 0)
        pair = None if found is None else tuple(int(moving[i]) for i in found.markers)
        d = None if found is None else found.distance
    else:
        pair = tuple(int(i) for i in pair)
        if len(set(pair)) != 2 or not all(0 <= i < len(m.moving) for i in pair):
            raise ValueError(f"pair: expected two different indices of the capture's "
                             f"{len(m.moving)} markers, got {pair}")
        d = np.linalg.norm(X[:, pair[0]] - X[:, pair[1]], axis=1)
    both = np.isfinite(d) if d is not None else None
    has = d is not None and both.any()
    return {"moving": int(len(moving)), "joined": int(len(m.members)),
            "share_mean": float(share.mean()) if len(share) else np.nan,
            "share_ge_90": float((share >= 0.9).mean()) if len(share) else np.nan,
            "share_min": float(share.min()) if len(share) else np.nan,
            "residual_px": residual,
            "pair": pair,
            "pair_frames": int(both.sum()) if has else 0,
            "pair_median_mm": float(np.median(d[both])) if has else np.nan,
            "pair_std_mm": float(np.std(d[both])) if has else np.nan,
            "pair_relative_motion": (relative_motion(X[:, pair[0]], X[:, pair[1]])
                                     if has else np.nan),
            "pair_height_mm": ([float(np.nanmedian(X[:, i, 2])) for i in pair]
                               if has else None),
            "joins": dict(m.joins),
            "seconds": m.seconds}
