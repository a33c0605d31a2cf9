"""Markers joined across views (:mod:`.view_tracks`), checked, completed and filled.

Three steps on tracks already joined by their paths, each a rule on the data (none looks at
what a recording is scored on):

1. :func:`check_joins` takes out joins that are wrong, in this order:

   * *a view that disagrees*: in a marker held by three or more views, a view whose track
     lies more than ``max_px`` (median over the frames) from the projection of the point
     intersected from the marker's other views is taken out of it (the worst first, until
     the rest agree or two views are left);
   * *ambiguous*: two tracks whose paths both stay on one epipolar band cannot be told
     apart by the band (a walker's markers move alike, so the band holds several). In a
     marker held by three or more views, a view whose track has a rival in that view
     nearly as close to the projection of the point intersected from the marker's other
     views (the rival's median distance less than ``min_ratio`` times the track's own) is
     taken out of it (the most ambiguous first, until none is or two views are left): a
     third view that confirms the marker keeps it. A marker left with two views (a
     two-view link) whose track has another partner nearly as good (the second-best
     median pair residual of either track less than ``min_ratio`` times the link's own)
     is dropped;
   * *below the floor*: a marker whose median height (along ``up``) lies more than
     ``floor_margin_mm`` below ``floor_mm`` (a subject's markers are on or above the floor;
     None: not checked) is dropped.

2. :func:`attach_views` adds a view's free track (never joined, or taken out by step 1) to
   the marker whose 3-D path projects onto it: the median distance over the frames both
   have at most ``max_px``, in at least ``min_shared`` of the marker's 3-D frames, each the
   other's best. The marker's 3-D path is known, so any view can be attached, at any angle
   to the views that joined it: every view that sees a marker is used.

3. :func:`fill_gaps` looks for a marker where one of its views lost it (motion blur, a
   short occlusion): frame by frame, forwards then backwards, the marker's 3-D position
   (intersected in the frame from its other views, or extrapolated at constant velocity
   from the last two frames with one, at most ``max_gap`` frames back) is projected into
   each of its views that lacks it; the dot's core is centred there
   (:func:`~lsmta.tracking.blob_follow.dot_centre`, a window of ``radius`` px moved to the
   centroid three times) and taken when its contrast is at least ``min_contrast``, it lies
   within ``search_px`` of the projection (an extrapolation over a few frames of a swinging
   foot is off by more than a dot's radius) and not within ``radius`` of another marker or
   any other track of that view, and the point intersected with it reprojects within
   ``max_px`` in every view. A dot so found is a measurement of the frame, not an
   interpolation: a frame whose dot cannot be found stays empty. With ``line_px``, a view
   in which that search finds nothing, in a frame where exactly one view holds the marker,
   is searched again along that view's epipolar line: the extrapolated position is moved
   onto the holding view's ray (its projection then lies on the line, and only its depth
   is unknown), the blobs within ``radius`` of another marker's or track's dot in the view
   are set aside, and the dot is the blob within ``max_px`` of the line and ``line_px``
   along it from the projection, nearest to it, the next such blob at least twice as far
   (else ambiguous: none taken). An extrapolation over a few frames of a swinging limb is
   off mostly in depth, tens of pixels along the line, while the line itself is known (the
   holding view sees the marker). The line is drawn straight, through the projections of
   two points 50 mm apart on the ray; the lens bends the true epipolar curve (by review on
   the Pose2Sim demo's cameras: at most 0.14 px off the straight line over +-48 px, median
   0.008 px). For a marker of two views such a dot is checked by nothing more than those
   rules: the point intersected with it reprojects within about its distance from the line
   whatever its depth, so the reprojection test adds nothing, and the depth is bounded only
   by ``line_px``. :class:`Filled` says which search found a dot. With ``min_surround``,
   a dot of either search must also stand that far above its surround in every direction
   (:func:`~lsmta.tracking.blob_follow.dot_surround`: its core less the brightest of 16
   directions' surround from ``radius`` to ``1.5 radius`` px out): a small bright marker
   is darker around it everywhere, while an edge (into its bright side), a bright fold
   (along it) or flat bright skin is not, though each can stand ``min_contrast`` above a
   window's median (the peak test alone took such spots on the Pose2Sim demo). A real dot
   beside anything as bright within ``1.5 radius`` px (a bright stripe) fails it too, and
   one within ``1.5 radius`` px of the frame's border is not tested and so refused. A
   refused fill also cuts off the dots after it (the fill follows a lost dot from each
   frame's find to the next), and a gap is searched only up to ``max_gap`` frames from
   its ends.

   With ``grow`` (the *reach search*, :attr:`Filled.REACH`), once the searches above have
   filled what they can, they run again on their result with one more: where one view
   holds the marker and they find nothing, the holding view's epipolar line is searched
   whatever the gap, on the part of its ray (:func:`ray_piece`, which stops at the camera)
   within the marker's own reach of its last intersected 3-D point: the marker's fastest
   3-D step between two consecutive frames intersected from the joined tracks, before the
   fill (:func:`marker_speeds`), times the frames since that point (in the view: a disc
   around the projected piece's middle, half its length plus ``radius``). The line's rules
   (its width ``max_px``, the nearest dot with a clear lead, other markers' and tracks'
   dots set aside) and the dot test hold, and the point intersected with the dot must lie
   within the reach.
   Run after the others and only adding to their result, the reach search keeps every
   fill they make. Its passes run forwards and backwards, so a dot found after a gap is
   followed back into it from where the marker shows again, and on by the searches above.
   An image-speed bound (the marker's fastest step in the searched view's image times the
   frames since) was tried first and took another marker's dot on the Pose2Sim demo.
   All the demo's gaps of moving markers held by one view lie in frames 50-99 (none in
   0-49), so the rule was designed looking at the frames it is reported on: nothing held
   out. Limits: two dots on the line within the reach, the nearer not half as far from the
   last point's place on the ray as the next, are ambiguous and neither is taken. The
   reach is the largest raw step, so one wrong intersection (a wrong join, a dot of
   another marker) sets it for the whole recording, and it grows with the gap, and with it
   the room for another marker's dot on the line; a marker seen only moving slowly gets a
   small reach. A robust quantile of the steps (after the residual gate, which runs later
   in the marker stage) or a cap on the reach was not chosen: either changes what the
   demo's one reach find needs, which only the full demo can judge. The cost: the searched
   window grows with the reach's projected length (its area with the square, up to the
   frame), per frame of a gap and per view lacking the marker; the second round of passes
   visits only the markers one view holds in some frame another of their views lacks.
   On the demo (a full run at 15a0092, loaded, before the second round: 1 dot found by the
   reach, frame 84 of cam01, and 16 followed from it, each on a dot in both views by eye)
   the pelvis marker of cam01's track 65 is faint at the body's edge in frames 78-91 (the
   dot test refuses it there; the peak test alone had followed it) and a clear dot again
   from frame 92, but from 94, when it comes within the reach, another marker's clear dot
   lies on the same line about as far on the other side (its point several hundred mm
   from the marker's path), so none is taken.

4. :func:`check_dots` takes out a view whose track is not on a dot: a track of a joined
   marker whose positions stand ``min_surround`` above their surround in every direction
   (:func:`~lsmta.tracking.blob_follow.dot_surround`, the fill's dot test) in less than
   ``min_share`` of the frames it holds is taken out of the marker, and a marker left with
   fewer than two views is dropped. A small bright retro-reflective or skin marker passes
   in most frames; a bright patch of skin, a highlight or an edge that the detector took
   for a marker and the follower kept (its peak stands above its window's median) fails
   in most (see :func:`check_dots`).

5. :func:`silhouette_hits` says, for one view, where markers' 3-D positions project inside
   that view's silhouette of the moving subject (masks of some frames, e.g.
   :func:`lsmta.systems.subject.subject_masks`): a point on the subject projects inside
   the subject's silhouette in every view whose frame holds its projection, whatever
   hides it there (the silhouette is the projection of the whole body), while a wrong
   join's point, metres off, projects onto the background. A frame whose mask is empty
   (fewer than ``min_area`` pixels) is not judged in that view: a still subject or a frozen
   view leaves the mask empty, which says nothing about the markers.
   :func:`silhouette_share` is a marker's least share of hits over the views that see it
   in at least ``min_seen`` of its frames and in at least ``min_positions`` frames; the
   marker stage drops the moving markers below a share (``MarkerParams.silhouette``). The
   limit: a wrong join whose two tracks both lie on the subject lands inside in its own
   views; only another view whose frame holds its point where the subject is not can tell
   it.
"""

from __future__ import annotations

import enum
import warnings
from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_scalar, freeze
from ..triangulation import triangulate
from .blob_follow import _free_blobs, dot_centre, dot_contrast, dot_surround
from .view_tracks import (
    _CHUNK,
    _checked,
    joined_positions,
    pair_residuals,
    triangulate_joined,
)

__all__ = ["DotCheck", "Filled", "JoinCheck", "attach_views", "check_dots", "check_joins",
           "fill_gaps", "marker_speeds", "ray_piece", "silhouette_hits", "silhouette_share"]


class Filled(enum.IntEnum):
    """Which search of :func:`fill_gaps` found a view's dot in a frame."""

    NONE = 0         #: none (held by the view's track, or not found)
    NEAR = 1         #: near the projection of the 3-D position (``search_px``)
    LINE = 2         #: along the epipolar line of the one view that holds it (``line_px``)
    REACH = 3        #: along that line, within the marker's own reach of its last
    #: intersected 3-D point (``grow``)


@dataclass(frozen=True)
class JoinCheck:
    """Result of :func:`check_joins`.

    Attributes
    ----------
    members : (M', K) int array
        The joins kept (views taken out set to -1).
    ambiguous : int
        Two-view markers dropped as ambiguous.
    views_out : int
        Views taken out of markers whose other views disagree with them.
    below_floor : int
        Markers dropped below the floor.
    ambiguous_views : int
        Views taken out of markers of three or more views as ambiguous.
    """

    members: np.ndarray
    ambiguous: int
    views_out: int
    below_floor: int
    ambiguous_views: int = 0

    def __post_init__(self):
        freeze(self, ("members",))


def _share(min_shared) -> float:
    min_shared = as_scalar(min_shared, "min_shared", positive=True)
    if min_shared > 1:
        raise ValueError(f"min_shared: expected a share in (0, 1], got {min_shared}")
    return min_shared


def _members(members, K) -> np.ndarray:
    m = np.asarray(members)
    if m.ndim != 2 or m.shape[1] != K or not np.issubdtype(m.dtype, np.integer):
        raise ValueError(f"members: expected an (M, {K}) int array (-1: no track), got "
                         f"shape {m.shape} and dtype {m.dtype}")
    return m.astype(int)


def _project(camera, X) -> np.ndarray:
    """``(N, 2)`` projections of ``(N, 3)`` points, NaN where a point is NaN or behind."""
    X = np.asarray(X, float).reshape(-1, 3)
    out = np.full((len(X), 2), np.nan)
    ok = np.isfinite(X).all(axis=1)
    if ok.any():
        out[ok] = camera.project(X[ok], behind="nan")
    return out


def _second_best(r: np.ndarray, i: int, j: int) -> float:
    """Smallest residual of row i or column j other than (i, j)."""
    row = np.delete(r[i], j)
    col = np.delete(r[:, j], i)
    rest = np.concatenate([row, col])
    rest = rest[np.isfinite(rest)]
    return float(rest.min()) if rest.size else np.inf


def _ambiguous(cams, arrays, members, min_ratio, min_shared) -> np.ndarray:
    """``(M,)`` True where a two-view marker's link has a near-equal rival partner (markers
    of three or more views are judged view by view, :func:`_ambiguous_view`)."""
    out = np.zeros(len(members), bool)
    cache = {}
    for j, m in enumerate(members):
        views = np.flatnonzero(m >= 0)
        if len(views) != 2:
            continue
        a, b = views
        if (a, b) not in cache:
            cache[a, b] = pair_residuals(cams[a], cams[b], arrays[a], arrays[b],
                                         min_shared=min_shared)
        r = cache[a, b]
        own = r[m[a], m[b]]
        if np.isfinite(own) and _second_best(r, m[a], m[b]) < min_ratio * own:
            out[j] = True
    return out


def _ambiguous_view(cams, arrays, m, min_ratio, min_shared) -> int | None:
    """The view of a marker of three or more views whose track has the nearest rival
    (another track of that view, holding at least ``min_shared`` of the frames, whose
    median distance from the projection of the point of the marker's other views is less
    than ``min_ratio`` times the track's own), or None."""
    worst, worst_ratio = None, min_ratio
    T = arrays[0].shape[0]
    for k in np.flatnonzero(m >= 0):
        others = m.copy()
        others[k] = -1
        xyz, _, _ = triangulate_joined(cams, arrays, others[None])
        proj = _project(cams[k], xyz[:, 0])                                   # (T, 2)
        d = np.linalg.norm(arrays[k] - proj[:, None], axis=2)                  # (T, N_k)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(d, axis=0)
        med = np.where(np.isfinite(d).sum(axis=0) >= max(1, min_shared * T), med, np.nan)
        own = med[m[k]]
        rivals = np.delete(med, m[k])
        rivals = rivals[np.isfinite(rivals)]
        if not (np.isfinite(own) and rivals.size):
            continue
        ratio = rivals.min() / own if own > 0 else np.inf
        if ratio < worst_ratio:
            worst, worst_ratio = int(k), ratio
    return worst


def _leave_one_out(cams, arrays, m) -> np.ndarray:
    """``(K,)`` median distance of each view's track from the point of the others, px."""
    out = np.full(len(cams), np.nan)
    views = np.flatnonzero(m >= 0)
    for k in views:
        others = m.copy()
        others[k] = -1
        xyz, _, _ = triangulate_joined(cams, arrays, others[None])
        proj = _project(cams[k], xyz[:, 0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[k] = np.nanmedian(np.linalg.norm(proj - arrays[k][:, m[k]], axis=1))
    return out


def check_joins(cameras, xy, members, *, max_px: float = 3.0, min_ratio: float = 2.0,
                min_shared: float = 0.5, floor_mm: float | None = None,
                floor_margin_mm: float = 50.0, up=(0.0, 0.0, 1.0)) -> JoinCheck:
    """Take out wrong joins (see the module docstring).

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px.
    members : (M, K) int array
        The joins (:attr:`~lsmta.tracking.view_tracks.JoinedTracks.members`).
    max_px : float
        Largest median distance of a view from its marker's other views, px.
    min_ratio : float
        A link's second-best rival must have at least this times its residual, >= 1.
    min_shared : float
        Share of the frames a rival must hold (together with its partner, or with the
        projection of the marker's other views), in (0, 1] (as when joining).
    floor_mm : float or None
        Height of the floor along ``up``, mm; None: not checked.
    floor_margin_mm : float
        How far below the floor a marker's median height may lie, mm.
    up : (3,) array
        The world's up direction.

    Returns
    -------
    JoinCheck
    """
    cams, arrays = _checked(cameras, xy)
    m = _members(members, len(cams)).copy()
    max_px = as_scalar(max_px, "max_px", positive=True)
    min_ratio = as_scalar(min_ratio, "min_ratio", positive=True)
    if min_ratio < 1:
        raise ValueError(f"min_ratio: expected a ratio >= 1, got {min_ratio}")
    min_shared = _share(min_shared)
    floor = None if floor_mm is None else as_scalar(floor_mm, "floor_mm")
    floor_margin_mm = as_scalar(floor_margin_mm, "floor_margin_mm", nonnegative=True)
    u = as_array(up, "up", shape=(3,))
    if np.linalg.norm(u) == 0:
        raise ValueError("up: expected a non-zero direction")
    u = u / np.linalg.norm(u)
    views_out = ambiguous_views = 0
    for j in range(len(m)):
        while (m[j] >= 0).sum() >= 3:
            d = _leave_one_out(cams, arrays, m[j])
            k = int(np.nanargmax(np.where(np.isfinite(d), d, -np.inf)))
            if not d[k] > max_px:
                break
            m[j, k] = -1
            views_out += 1
        while (m[j] >= 0).sum() >= 3:
            k = _ambiguous_view(cams, arrays, m[j], min_ratio, min_shared)
            if k is None:
                break
            m[j, k] = -1
            ambiguous_views += 1
    ambiguous = _ambiguous(cams, arrays, m, min_ratio, min_shared)
    m = m[~ambiguous]
    below = np.zeros(len(m), bool)
    if floor is not None and len(m):
        xyz, _, _ = triangulate_joined(cams, arrays, m)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # never intersected
            height = np.nanmedian(xyz @ u, axis=0)
        below = height < floor - floor_margin_mm
    return JoinCheck(members=m[~below], ambiguous=int(ambiguous.sum()), views_out=views_out,
                     below_floor=int(below.sum()), ambiguous_views=ambiguous_views)


def attach_views(cameras, xy, members, *, max_px: float = 3.0,
                 min_shared: float = 0.5) -> tuple[np.ndarray, int]:
    """Attach free tracks of any view to the markers whose 3-D paths project onto them
    (see the module docstring).

    Parameters
    ----------
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
    members : (M, K) int array
    max_px : float
        Largest median distance of a track from the marker's projection, px.
    min_shared : float
        Share of the marker's 3-D frames the track must hold, in (0, 1].

    Returns
    -------
    members : (M, K) int array
        With the attached tracks.
    attached : int
        How many tracks were attached.
    """
    cams, arrays = _checked(cameras, xy)
    m = _members(members, len(cams)).copy()
    max_px = as_scalar(max_px, "max_px", positive=True)
    min_shared = _share(min_shared)
    if not len(m):
        return m, 0
    xyz, _, _ = triangulate_joined(cams, arrays, m)
    has3d = np.isfinite(xyz).all(axis=2)                              # (T, M)
    attached = 0
    for k, cam in enumerate(cams):
        need = np.flatnonzero((m[:, k] < 0) & has3d.any(axis=0))
        free = np.setdiff1d(np.arange(arrays[k].shape[1]), m[:, k])
        if not need.size or not free.size:
            continue
        med = _attach_medians(cam, xyz[:, need], arrays[k][:, free],
                              min_shared * has3d[:, need].sum(axis=0))
        for i, row in enumerate(med):
            f = int(np.argmin(row))
            if row[f] <= max_px and int(np.argmin(med[:, f])) == i:
                m[need[i], k] = free[f]
                attached += 1
    return m, attached


def _attach_medians(cam, xyz, tracks, need_frames) -> np.ndarray:
    """``(n, f)`` median distance of f tracks ``(T, f, 2)`` from the projections of n
    markers' 3-D paths ``(T, n, 3)``, inf where they share fewer than ``need_frames``
    ``(n,)`` frames. The ``(T, rows, f)`` distances are built for a few markers at a time
    (at most about ``_CHUNK`` values)."""
    T, n, _ = xyz.shape
    f = tracks.shape[1]
    med = np.full((n, f), np.inf)
    rows = max(1, _CHUNK // max(1, T * f))
    for i0 in range(0, n, rows):
        i1 = min(n, i0 + rows)
        proj = _project(cam, xyz[:, i0:i1]).reshape(T, i1 - i0, 2)
        d = np.linalg.norm(proj[:, :, None] - tracks[:, None], axis=3)    # (T, rows, f)
        shared = np.isfinite(d).sum(axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            m = np.nanmedian(d, axis=0)
        enough = shared >= need_frames[i0:i1, None]
        med[i0:i1] = np.where(enough & np.isfinite(m), m, np.inf)
    return med


def _predict(xyz, t, step, max_gap) -> np.ndarray | None:
    """The marker's 3-D position in frame t: intersected there, or extrapolated at constant
    velocity from the last two earlier frames (in the pass's direction) with one."""
    if np.isfinite(xyz[t]).all():
        return xyz[t]
    seen = [s for s in range(t - step, t - step * (max_gap + 2), -step)
            if 0 <= s < len(xyz) and np.isfinite(xyz[s]).all()]
    if not seen or abs(t - seen[0]) > max_gap:
        return None
    if len(seen) == 1:
        return xyz[seen[0]]
    a, b = seen[0], seen[1]
    return xyz[a] + (xyz[a] - xyz[b]) * (t - a) / (a - b)


def _line_dot(cam_k, img, held_cam, held_xy, X, others, radius, line_px, max_px, floor,
              disc=None):
    """The dot of a view on the epipolar line of the one view that holds the marker
    (:func:`fill_gaps`' ``line_px``, None: no reach along the line; ``others``: other
    markers' and tracks' dots of the view, set aside; ``floor``: ``(min_contrast,
    min_surround)``; ``disc``: ``((2,) centre, r)`` px, the dot within r of the centre
    too), px, or None."""
    min_contrast = floor[0]
    o, d = held_cam.rays(np.asarray(held_xy, float)[None])
    o, d = o[0], d[0] / np.linalg.norm(d[0])
    Xr = o + d * float(np.dot(X - o, d))                    # X moved onto the ray
    c, c2 = _project(cam_k, np.stack([Xr, Xr + 50.0 * d]))  # and 50 mm deeper
    if not (np.isfinite(c).all() and np.isfinite(c2).all()) or np.allclose(c, c2):
        return None
    u = (c2 - c) / np.linalg.norm(c2 - c)
    centre, half = (c, line_px) if disc is None else disc
    blobs = _free_blobs(img, centre, int(np.ceil(half + 2 * radius)), others,
                        sigma=radius / 1.6, min_strength=min_contrast, radius=radius)
    if blobs is None or not len(blobs):
        return None
    blobs = dot_centre(img, blobs, radius=radius)
    rel = blobs - c
    along = np.abs(rel @ u)
    perp = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
    ok = (perp <= max_px) & _is_dot(img, blobs, radius, floor)
    if line_px is not None:
        ok &= along <= line_px
    if disc is not None:
        ok &= np.linalg.norm(blobs - disc[0], axis=1) <= disc[1]
    if not ok.any():
        return None
    order = np.argsort(along[ok])
    if order.size > 1 and along[ok][order[1]] < 2 * along[ok][order[0]]:
        return None                                         # two dots on the line
    return blobs[ok][order[0]]


def _is_dot(img, xy, radius, floor) -> np.ndarray:
    """``(N,)`` whether each position's dot passes the fill's floors ``(min_contrast,
    min_surround)`` (:func:`fill_gaps`)."""
    ok = dot_contrast(img, xy, radius=radius) >= floor[0]
    if floor[1] is not None and ok.any():
        ok[ok] = dot_surround(img, xy[ok], radius=radius) >= floor[1]
    return ok


def _near_dot(cam_k, img, X, radius, search_px, floor):
    """The dot centred from X's projection within ``search_px`` of it, px, or None."""
    c = _project(cam_k, X)[0]
    if not np.isfinite(c).all():
        return None
    q = dot_centre(img, c[None], radius=radius)[0]
    if not (np.isfinite(q).all() and np.linalg.norm(q - c) <= search_px
            and _is_dot(img, q[None], radius, floor)[0]):
        return None
    return q


def ray_piece(camera, xy, centre, r) -> np.ndarray | None:
    """The piece of a view's ray within a ball: where a marker that view holds can be, given
    how far it can have moved from a known position (the reach search of :func:`fill_gaps`,
    :func:`~lsmta.tracking.second_view.hidden_frames`).

    Parameters
    ----------
    camera : Camera
        The view that holds the marker.
    xy : (2,) array
        Its pixel in that view, px.
    centre : (3,) array
        The ball's centre (the marker's known position), mm.
    r : float
        The ball's radius, mm (>= 0).

    Returns
    -------
    (2, 3) array or None
        The piece's ends, mm, nearer first; clamped at the camera's centre (no point behind
        the camera). None where the ray misses the ball or the ball lies wholly behind the
        camera.
    """
    xy = np.asarray(xy, float)
    centre = np.asarray(centre, float)
    if xy.shape != (2,) or centre.shape != (3,):
        raise ValueError(f"xy, centre: expected a (2,) pixel and a (3,) point, got shapes "
                         f"{xy.shape} and {centre.shape}")
    if not (np.isfinite(r) and r >= 0):
        raise ValueError(f"r: expected a radius >= 0 mm, got {r}")
    o, d = camera.rays(xy[None])
    o, d = o[0], d[0] / np.linalg.norm(d[0])
    s0 = float(np.dot(centre - o, d))
    p2 = float(np.sum((centre - o - s0 * d) ** 2))
    if p2 > r * r or s0 + np.sqrt(r * r - p2) <= 0:
        return None
    half = np.sqrt(r * r - p2)
    return np.stack([o + d * max(s0 - half, 0.0), o + d * (s0 + half)])


def _reach_disc(cam_k, held_cam, held_xy, reach, radius):
    """The part of the holding view's ray within ``reach``'s r of its last point
    (:func:`ray_piece`), as a disc in view k (``((2,) centre, radius)`` px: the projected
    segment's middle, half its length plus ``radius``), or None where the ray passes farther
    than r (or the segment does not project)."""
    piece = ray_piece(held_cam, held_xy, reach[0], reach[1])
    if piece is None:
        return None
    ends = _project(cam_k, piece)
    if not np.isfinite(ends).all():
        return None
    return ends.mean(axis=0), 0.5 * float(np.linalg.norm(ends[1] - ends[0])) + radius


def _find_dots(cams, stacks, arrays, pos, t, j, X, members, radius, search_px,
               floor, line=None, reach=None):
    """Dots near X's projection in the marker's views that lack it in frame t, else (with
    ``line``: ``(line_px, max_px)``, a marker one view holds) along the holding view's
    epipolar line, else (with ``reach``: ``((3,) last point mm, r mm, stale)``) along it
    where the ray lies within r of the last point (only this where ``stale``: no position
    was predicted for frame t, X is the last point): ``{view: ((2,) px, Filled)}``."""
    found = {}
    views = np.flatnonzero(members[j] >= 0)
    held = [k for k in views if np.isfinite(pos[t, k, j]).all()]
    for k in views:
        if k in held:
            continue
        img = stacks[k][t]
        others = np.concatenate([np.delete(pos[t, k], j, axis=0),
                                 np.delete(arrays[k][t], members[j, k], axis=0)])
        others = others[np.isfinite(others).all(axis=1)]
        stale = reach is not None and reach[2]
        q, how = None if stale else _near_dot(cams[k], img, X, radius, search_px,
                                              floor), Filled.NEAR
        if _taken(q, others, radius):
            q = None                                # another marker's or track's dot
        if q is None and line is not None and len(held) == 1 and not stale:
            q, how = _line_dot(cams[k], img, cams[held[0]], pos[t, held[0], j], X, others,
                               radius, line[0], line[1], floor), Filled.LINE
        if q is None and reach is not None and len(held) == 1:
            disc = _reach_disc(cams[k], cams[held[0]], pos[t, held[0], j], reach, radius)
            q, how = None if disc is None else _line_dot(
                cams[k], img, cams[held[0]], pos[t, held[0], j], X, others, radius, None,
                line[1], floor, disc), Filled.REACH
        if q is not None and not _taken(q, others, radius):
            found[int(k)] = (q, how)
    return found


def _taken(q, others, radius) -> bool:
    """Whether dot ``q`` lies within ``radius`` of one of ``others`` ((n, 2) px)."""
    return q is not None and bool(others.size) and bool(
        np.linalg.norm(others - q, axis=1).min() <= radius)


def _check_stacks(stacks, cams, T) -> None:
    """One ``(T, H_k, W_k)`` stack per camera, each of its camera's frame size."""
    if len(stacks) != len(cams):
        raise ValueError(f"stacks: expected {len(cams)} frame stacks (one per camera), got "
                         f"{len(stacks)}")
    if any(len(s) != T for s in stacks):
        raise ValueError(f"stacks: expected {T} frames in every view (as the tracks), got "
                         f"{[len(s) for s in stacks]}")
    for k, (s, c) in enumerate(zip(stacks, cams)):
        if np.ndim(s) != 3 or tuple(np.shape(s)[1:]) != (c.height, c.width):
            raise ValueError(f"stacks[{k}]: expected (T, {c.height}, {c.width}) frames (camera "
                             f"{c.name!r} is {c.width} x {c.height}), got shape {np.shape(s)}")


def _take(cams, pos, found, xyz, t, j, dots, max_px, sphere=None) -> None:
    """Write the dots found for marker j in frame t into ``pos``, ``found`` and ``xyz`` (in
    place) when the point intersected with them reprojects within ``max_px`` in every view
    (and, with ``sphere``: ``((3,) centre, r)`` mm, lies within r of the centre)."""
    trial = pos[t, :, j].copy()
    for k, (q, _) in dots.items():
        trial[k] = q
    seen = np.isfinite(trial).all(axis=1)
    if seen.sum() < 2:
        return
    res = triangulate([cams[k] for k in np.flatnonzero(seen)], trial[seen][:, None],
                      min_angle_deg=1.0)
    if not (res.valid[0] and np.all(res.reprojection_error[:, 0] <= max_px)):
        return
    if sphere is not None and not np.linalg.norm(res.points[0] - sphere[0]) <= sphere[1]:
        return                                      # faster than the marker ever moved
    for k, (q, how) in dots.items():
        pos[t, k, j] = q
        found[t, k, j] = how
    xyz[t, j] = res.points[0]


def marker_speeds(xyz) -> np.ndarray:
    """``(M,)`` each marker's fastest 3-D step, mm per frame: the largest distance between
    its positions in two consecutive frames both intersected (NaN: no such two frames).

    Parameters
    ----------
    xyz : (T, M, 3) array
        The markers' positions, mm (NaN: not intersected).
    """
    a = as_array(xyz, "xyz", shape=(None, None, 3), allow_nan=True)
    if a.shape[0] < 2:
        return np.full(a.shape[1], np.nan)
    steps = np.linalg.norm(np.diff(a, axis=0), axis=2)                   # (T - 1, M)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)              # no step held
        return np.nanmax(steps, axis=0)


def _last_seen(a, t, step) -> int | None:
    """The frame nearest to t before it in the pass's direction (``step`` +-1) where ``a``
    ((T, d)) is finite, or None."""
    held = np.isfinite(a).all(axis=1)
    before = np.flatnonzero(held[:t]) if step > 0 else t + 1 + np.flatnonzero(held[t + 1:])
    if not before.size:
        return None
    return int(before[-1] if step > 0 else before[0])


def _passes(cams, stacks, arrays, m, state, sizes, floor, line, markers, fastest=None):
    """One forward and one backward pass over the frames of ``markers``, writing the dots
    found into ``state`` ``(pos, found, xyz)`` (in place); with ``fastest`` ((M,) mm per
    frame) the reach search too."""
    pos, found, xyz = state
    radius, search_px, max_gap, max_px = sizes
    T = len(xyz)
    for step, frames in ((1, range(T)), (-1, range(T - 1, -1, -1))):
        for t in frames:
            for j in markers:
                X, reach = _predict(xyz[:, j], t, step, max_gap), None
                s = None if fastest is None else _last_seen(xyz[:, j], t, step)
                if s is not None and np.isfinite(fastest[j]):    # the last intersected frame
                    reach = (xyz[s, j], fastest[j] * abs(t - s), X is None)
                    X = xyz[s, j] if X is None else X
                if X is None:
                    continue
                dots = _find_dots(cams, stacks, arrays, pos, t, j, X, m, radius, search_px,
                                  floor, line, reach)
                far = any(h == Filled.REACH for _, h in dots.values())
                if dots:
                    _take(cams, pos, found, xyz, t, j, dots, max_px, reach[:2] if far else None)


def _fill_passes(cams, stacks, arrays, m, sizes, floor, line, grow):
    """:func:`fill_gaps`' passes: the joined positions with the dots found ``(T, K, M, 2)``
    and where (``(T, K, M)`` :class:`Filled` codes). ``sizes``: ``(radius, search_px,
    max_gap, max_px)``; ``grow``: then the reach search, on the fill's result (so that it
    only adds to it), for the markers one view holds in some frame another of their views
    lacks."""
    pos = joined_positions(arrays, m)                               # (T, K, M, 2)
    xyz, _, _ = triangulate_joined(cams, arrays, m)
    fastest = marker_speeds(xyz)                      # (M,) mm per frame, before the fill
    found = np.zeros(pos.shape[:3], np.int8)
    state = (pos, found, xyz)
    _passes(cams, stacks, arrays, m, state, sizes, floor, line, range(len(m)))
    if grow:
        held = np.isfinite(pos).all(axis=3)                         # (T, K, M)
        own = (m >= 0).T[None]                                      # (1, K, M)
        one = ((held & own).sum(axis=1) == 1) & (~held & own).any(axis=1)
        _passes(cams, stacks, arrays, m, state, sizes, floor, line,
                np.flatnonzero(one.any(axis=0)), fastest)
    return pos, found


def fill_gaps(stacks, cameras, xy, members, *, radius: int = 4, search_px: float = 12.0,
              min_contrast: float = 15.0, max_gap: int = 10, max_px: float = 3.0,
              line_px: float | None = None, min_surround: float | None = None,
              grow: bool = False) -> tuple[tuple, np.ndarray]:
    """Find markers again where one of their views lost them (see the module docstring).

    Parameters
    ----------
    stacks : sequence of K (T, H_k, W_k) arrays
        Grey frames of every view.
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px (not modified).
    members : (M, K) int array
    radius : int
        Half-width of the dot's window, and the closest another marker may be, px.
    search_px : float
        Largest distance of the dot from the projection, px.
    min_contrast : float
        Smallest peak of a dot above its window's median, grey levels.
    max_gap : int
        Frames over which a 3-D position is extrapolated.
    max_px : float
        Largest reprojection error of the point intersected with the dot, px; with
        ``line_px`` also the largest distance of a dot from the epipolar line.
    line_px : float or None
        Reach along the epipolar line of the second search (where one view holds the
        marker and the first found nothing; module docstring), px (> 0); None: none.
    min_surround : float or None
        With it, a dot is taken only where it also stands at least this far above its
        surround in every direction (:func:`~lsmta.tracking.blob_follow.dot_surround`, at
        ``radius``), grey levels (> 0), in both searches: an edge, a bright fold or flat
        bright skin passes ``min_contrast`` (a peak over the window's median) but not this
        (module docstring); None (default): not tested. Its cost: a real dot beside a
        stripe as bright (with ``radius`` 4, 5-6 px from its centre) scores below 15 and is
        refused, as is one within ``1.5 radius`` px of the frame's border (NaN); and a
        refused fill cuts off the fills after it (module docstring; ``grow``).
    grow : bool
        With ``line_px`` (without it ``grow`` adds nothing): after the other searches, run
        them again on their result with the reach search too: where one view holds the
        marker and they found nothing, search the holding view's epipolar line where its
        ray lies within the marker's own reach of its last intersected point (its fastest
        3-D step, :func:`marker_speeds`, times the frames since), whatever the gap, in both
        passes; the point intersected with the dot must lie within that reach (module
        docstring). It only adds: every fill made without it is made with it. Default
        False.

    Returns
    -------
    xy : tuple of K (T, N_k, 2) arrays
        The tracks with the dots found.
    found : (T, K, M) int8 array
        Where a dot was found (> 0), by which search (:class:`Filled`).
    """
    cams, arrays = _checked(cameras, xy)
    m = _members(members, len(cams))
    radius = as_int(radius, "radius", minimum=1, unit="pixels")
    search_px = as_scalar(search_px, "search_px", positive=True)
    min_contrast = as_scalar(min_contrast, "min_contrast", positive=True)
    max_gap = as_int(max_gap, "max_gap", minimum=0, unit="frames")
    max_px = as_scalar(max_px, "max_px", positive=True)
    line = None if line_px is None else (as_scalar(line_px, "line_px", positive=True), max_px)
    floor = (min_contrast, None if min_surround is None
             else as_scalar(min_surround, "min_surround", positive=True))
    if not isinstance(grow, bool):
        raise TypeError(f"grow: expected True or False, got {grow!r}")
    T = arrays[0].shape[0]
    _check_stacks(stacks, cams, T)
    pos, found = _fill_passes(cams, stacks, arrays, m, (radius, search_px, max_gap, max_px),
                              floor, line, grow and line is not None)
    out = []
    for k, a in enumerate(arrays):
        a = a.copy()
        has = m[:, k] >= 0
        a[:, m[has, k]] = np.where(found[:, k, has, None] > 0, pos[:, k, has], a[:, m[has, k]])
        out.append(a)
    return tuple(out), found


@dataclass(frozen=True)
class DotCheck:
    """Result of :func:`check_dots`.

    Attributes
    ----------
    members : (M', K) int array
        The markers kept, views whose track is not on a dot set to -1.
    shares : (M, K) array
        Each view track's share of its frames on a dot, for the markers given (NaN: no
        track, or one that holds no frame).
    views_out : int
        Tracks taken out of markers that kept two views or more.
    dropped : int
        Markers dropped (fewer than two views on a dot).
    """

    members: np.ndarray
    shares: np.ndarray
    views_out: int
    dropped: int

    def __post_init__(self):
        freeze(self, ("members", "shares"))


def check_dots(stacks, cameras, xy, members, *, radius: int = 4, min_surround: float = 15.0,
               min_share: float = 0.5) -> DotCheck:
    """Take out the views of joined markers whose tracks are not on a dot (module docstring).

    A marker is a small bright dot: in every frame a view holds it, its core stands above
    its surround in every direction. A track whose positions stand at least
    ``min_surround`` above it (:func:`~lsmta.tracking.blob_follow.dot_surround` at
    ``radius``; NaN, within ``1.5 radius`` px of the border, fails) in less than
    ``min_share`` of the frames it holds is not on a dot (a bright patch of skin, a
    highlight, an edge) and is taken out of its marker; a marker left with fewer than two
    views is dropped. The share 0.5 (a majority: "most of its frames") was set before
    looking at any share; a dot passes in most frames, not all (blur, a passing edge beside
    it). On the Pose2Sim demo at full size (the marker stage's defaults, the floor 15 the
    follower's contrast floor) it was looked at on frames 0-49 (design) and reported on
    frames 50-99 (held out): the two tracks of a moving "marker" on the skin of a foot
    pass in 0.06 and 0.48 of the design frames and 0.29 and 0.10 of the held-out ones; the
    least of the other moving markers' tracks 0.72 and 0.63 (one recording, no other
    held out). A real dot that stays beside something as bright (within ``1.5 radius``
    px) in most of its frames fails too.

    Parameters
    ----------
    stacks : sequence of K (T, H_k, W_k) arrays
        Grey frames of every view.
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px (not modified).
    members : (M, K) int array
    radius : int
        The dot's window half-width, px (>= 1; the follower's).
    min_surround : float
        Smallest core over the brightest surround of a dot, grey levels (> 0).
    min_share : float
        Smallest share of a track's frames on a dot, in (0, 1].

    Returns
    -------
    DotCheck
    """
    cams, arrays = _checked(cameras, xy)
    m = _members(members, len(cams))
    radius = as_int(radius, "radius", minimum=1, unit="pixels")
    min_surround = as_scalar(min_surround, "min_surround", positive=True)
    min_share = as_scalar(min_share, "min_share", positive=True)
    if min_share > 1:
        raise ValueError(f"min_share: expected a share in (0, 1], got {min_share}")
    _check_stacks(stacks, cams, arrays[0].shape[0])
    shares = np.full(m.shape, np.nan)
    for k, a in enumerate(arrays):
        has = np.flatnonzero(m[:, k] >= 0)
        if not has.size:
            continue
        tracks = a[:, m[has, k]]                                    # (T, n, 2)
        held = np.isfinite(tracks).all(axis=2)
        dot = np.stack([dot_surround(stacks[k][t], tracks[t], radius=radius)
                        for t in range(len(tracks))]) >= min_surround
        n = held.sum(axis=0)
        shares[has, k] = np.where(n > 0, (dot & held).sum(axis=0) / np.maximum(n, 1), np.nan)
    out = m.copy()
    out[shares < min_share] = -1
    keep = (out >= 0).sum(axis=1) >= 2
    views_out = int(((m >= 0) & (out < 0))[keep].sum())
    return DotCheck(members=out[keep], shares=shares, views_out=views_out,
                    dropped=int((~keep).sum()))


def silhouette_hits(camera, xyz, masks, *, min_area: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Where markers' 3-D positions project inside one view's silhouettes of the subject.

    Parameters
    ----------
    camera : Camera
        The view.
    xyz : (S, M, 3) array
        The markers' positions in S frames, mm (NaN: none).
    masks : (S, H, W) bool array
        The view's silhouette (subject mask) in the same S frames, at the camera's size.
    min_area : int
        A frame whose mask has fewer pixels than this is not judged (``seen`` False there):
        an empty mask (a still subject, a frozen view) says nothing about the markers;
        >= 1 (default 1: only empty masks).

    Returns
    -------
    inside : (S, M) bool array
        The projection lies on the mask (only where ``seen``).
    seen : (S, M) bool array
        The position is known, in front of the camera and inside its lens model, its
        projection (rounded) inside the frame, and the frame's mask holds at least
        ``min_area`` pixels: the view can judge it.
    """
    X = as_array(xyz, "xyz", shape=(None, None, 3), allow_nan=True)
    m = np.asarray(masks)
    if m.dtype != bool or m.shape != (X.shape[0], camera.height, camera.width):
        raise ValueError(f"masks: expected a ({X.shape[0]}, {camera.height}, {camera.width}) "
                         f"bool array (one mask per frame of xyz, camera {camera.name!r}'s "
                         f"size), got shape {m.shape} and dtype {m.dtype}")
    min_area = as_int(min_area, "min_area", minimum=1)
    S, M, _ = X.shape
    flat = X.reshape(-1, 3)
    seen = np.isfinite(flat).all(axis=1) & np.repeat(m.sum(axis=(1, 2)) >= min_area, M)
    if seen.any():
        seen[seen] = camera.in_lens(flat[seen])
    ij = np.full((len(flat), 2), -1)
    if seen.any():
        ij[seen] = np.rint(camera.project(flat[seen])).astype(int)
    seen &= (ij[:, 0] >= 0) & (ij[:, 0] < m.shape[2]) & (ij[:, 1] >= 0) & (ij[:, 1] < m.shape[1])
    frame = np.repeat(np.arange(S), M)
    inside = np.zeros(len(flat), bool)
    inside[seen] = m[frame[seen], ij[seen, 1], ij[seen, 0]]
    return inside.reshape(S, M), seen.reshape(S, M)


def silhouette_share(inside, seen, *, min_seen: float = 0.5,
                     min_positions: int = 3) -> np.ndarray:
    """Each marker's least share of positions inside the silhouettes over the views that
    judge it.

    A view judges a marker when it sees (:func:`silhouette_hits`' ``seen``) at least
    ``min_seen`` of the frames in which any view sees it, and at least ``min_positions``
    frames; its share is its hits over the positions it sees. A marker no view judges
    (seen in fewer than ``min_positions`` frames, say) gets NaN: too few positions to
    judge it on. A point on the subject lands inside in every view (where the mask
    holds the subject), so the least share over the judging views is the one that tells.

    Parameters
    ----------
    inside, seen : (V, S, M) bool arrays
        :func:`silhouette_hits` of V views, stacked.
    min_seen : float
        Share of the frames a view must see, in (0, 1].
    min_positions : int
        Fewest frames a view must see, >= 1.

    Returns
    -------
    (M,) array
        The least share over the judging views, in [0, 1]; NaN where no view judges.
    """
    i, s = np.asarray(inside, bool), np.asarray(seen, bool)
    if i.shape != s.shape or i.ndim != 3:
        raise ValueError(f"inside, seen: expected two (V, S, M) bool arrays of one shape, got "
                         f"shapes {i.shape} and {s.shape}")
    min_seen = as_scalar(min_seen, "min_seen", positive=True)
    if min_seen > 1:
        raise ValueError(f"min_seen: expected a share in (0, 1], got {min_seen}")
    min_positions = as_int(min_positions, "min_positions", minimum=1)
    n = s.sum(axis=1)                                               # (V, M)
    frames = s.any(axis=0).sum(axis=0)                              # (M,)
    judges = (n >= min_positions) & (n >= min_seen * frames)
    share = np.where(judges, (i & s).sum(axis=1) / np.maximum(n, 1), np.inf)
    least = share.min(axis=0) if len(share) else np.full(i.shape[2], np.inf)
    return np.where(np.isfinite(least), least, np.nan)
