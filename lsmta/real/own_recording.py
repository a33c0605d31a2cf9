"""A user's own recording through the LSMTA system, judged without truth (notebook 21,
``experiments/capture_demo.py``): the Pose2Sim demo's four videos and camera file.

A real recording has no truth, so the markers are judged by what needs none:

* *coverage*: the share of the frames in which each moving marker has a 3-D position;
* *residual*: how far the intersected marker reprojects from its tracked positions;
* *rigidity*: the distance between two markers on one rigid segment should not change. The
  pair is chosen by a rule that does not look at the distance's spread (which is what is
  scored): of the moving markers in 3-D in at least half of the frames and above the floor
  (a median height below 0 is a wrong join), the pairs seen by the same views (one side of
  the segment: a pair of markers intersected by different cameras adds the two camera
  groups' disagreement to its distance) whose median distance lies in ``distance_range``
  (a foot's heel-to-forefoot span), the one with the most frames with both in 3-D, and of
  those equally many the lowest in the room (the feet are the lowest markers of a person
  standing or walking). Without ``views`` the same-views condition is left out.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from .._validate import as_array


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
               up=(0.0, 0.0, 1.0)) -> RigidPair | None:
    """The pair of markers at a foot's span held longest in 3-D (see the module docstring).

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
            key = (-int(np.isfinite(d).sum()), height[i] + height[j])
            if best is None or key < best[0]:
                best = (key, (int(i), int(j)), d)
    if best is None:
        return None
    _, pair, d = best
    both = np.isfinite(d)
    return RigidPair(markers=pair, distance=d, median_mm=float(np.median(d[both])),
                     std_mm=float(np.std(d[both])), frames=int(both.sum()))


def marker_scores(capture, *, pair=None) -> dict:
    """Coverage, residual and rigidity of a :class:`~lsmta.systems.MarkerCapture`'s moving
    markers, as plain numbers (NaN where undefined).

    ``pair`` (two indices into the capture's markers, e.g. another capture's ``"pair"`` of
    the same markers) scores that pair's distance instead of choosing one with
    :func:`rigid_pair`."""
    m = capture
    moving = np.flatnonzero(m.moving)
    share = m.triangulated_share()[moving]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        residual = float(np.nanmedian(m.residual[:, moving])) if len(moving) else np.nan
    if pair is None:
        found = rigid_pair(m.xyz[:, moving], views=m.members[moving] >= 0)
        pair = None if found is None else tuple(int(moving[i]) for i in found.markers)
        d = None if found is None else found.distance
    else:
        pair = tuple(int(i) for i in pair)
        if len(set(pair)) != 2 or not all(0 <= i < len(m.moving) for i in pair):
            raise ValueError(f"pair: expected two different indices of the capture's "
                             f"{len(m.moving)} markers, got {pair}")
        d = np.linalg.norm(m.xyz[:, pair[0]] - m.xyz[:, pair[1]], axis=1)
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
            "seconds": m.seconds}
