"""Markers followed frame by frame on their blobs: any 2-D tracker's step, re-centred on the
blob, and a lost marker picked up again from the blobs near its prediction.

A template tracker (LSM, KLT) follows the patch it was given; on a marker a few pixels
across, in compressed video, on a moving body, the patch's best match wanders a little
from the dot every frame and the errors add up, and a marker lost once (occluded by a
swinging limb, blurred) stays lost. Marker and LED trackers keep the dot itself:

1. *step*: the tracker moves every followed marker from frame ``t`` to ``t + 1`` (from the
   marker's own constant-velocity prediction, if the tracker takes one);
2. *re-centre*: each result moves to the centroid of the dot's core in a
   ``(2 radius + 1)`` window (:func:`dot_centre`: the grey levels above half-way from the
   window's median to its peak, three times over; a core, not the whole window as
   :func:`~lsmta.tracking.markers.refine_centroid`, so that brighter texture beside a dot
   does not hold the centroid off it); a result whose window holds no dot is lost: its
   peak less than ``min_contrast`` above the window's median, or less than
   ``keep_contrast`` times the marker's own contrast in the frame before (a marker's
   contrast changes slowly, as motion blur comes and goes; skin texture beside it is
   fainter); and of two
   markers that end on one dot (within ``radius`` px) the one that moved farther to get
   there is lost;
3. *re-acquire*: a marker lost for at most ``max_gap`` frames is looked for among the blobs
   (:func:`~lsmta.tracking.markers.find_blobs`) within ``reacquire_px`` of its predicted
   position (last position plus its last velocity times the frames since), the nearest one
   not already held by another marker whose contrast lies within a factor
   ``1 / keep_contrast`` of the marker's own (a blob much fainter or brighter is something
   else: a spot of the room, another kind of mark).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_int, as_scalar
from .markers import find_blobs


class FollowStatus(enum.IntEnum):
    """How a marker was found in a frame (:func:`follow_blobs`)."""

    TRACKED = 0      #: the tracker's step, re-centred on the blob (frame 0: the start)
    REACQUIRED = 1   #: lost before, found again among the blobs near its prediction
    LOST = 2         #: not found, or no longer followed


@dataclass(frozen=True)
class FollowParams:
    """Settings of :func:`follow_blobs`.

    Attributes
    ----------
    radius : int or None
        Half-width of the re-centring window, px; None: ``ceil(1.6 sigma)``, at least 2
        (a little more than the dot's radius, about ``1.4 sigma``).
    min_contrast : float
        Smallest peak of a dot above its window's median, grey levels.
    keep_contrast : float
        Smallest share of a marker's contrast in the frame before that it must keep, in
        [0, 1).
    reacquire_px : float
        Search radius around a lost marker's prediction, px (0: never re-acquired).
    max_gap : int
        Frames a lost marker is searched for.
    sigma, min_strength : float
        Blob scale (px) and strength (grey levels) of the re-acquisition's blobs
        (:func:`~lsmta.tracking.markers.find_blobs`).
    """

    radius: int | None = None
    min_contrast: float = 15.0
    keep_contrast: float = 0.5
    reacquire_px: float = 12.0
    max_gap: int = 10
    sigma: float = 2.5
    min_strength: float = 20.0

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "max_gap", as_int(self.max_gap, "max_gap", minimum=0, unit="frames"))
        set_(self, "reacquire_px", as_scalar(self.reacquire_px, "reacquire_px",
                                             nonnegative=True))
        for name in ("min_contrast", "sigma", "min_strength"):
            set_(self, name, as_scalar(getattr(self, name), name, positive=True))
        if self.radius is not None:
            set_(self, "radius", as_int(self.radius, "radius", unit="pixels"))
        keep = as_scalar(self.keep_contrast, "keep_contrast", nonnegative=True)
        if keep >= 1:
            raise ValueError(f"keep_contrast: expected a share in [0, 1), got {keep}")
        set_(self, "keep_contrast", keep)

    def window(self) -> int:
        """The re-centring window's half-width, px (``radius``, or its default)."""
        return self.radius if self.radius is not None else max(2, math.ceil(1.6 * self.sigma))


@dataclass(frozen=True)
class FollowedMarkers:
    """Result of :func:`follow_blobs`.

    Attributes
    ----------
    xy : (T, N, 2) array
        Positions, px (NaN where lost).
    status : (T, N) int array
        :class:`FollowStatus` codes.
    """

    xy: np.ndarray
    status: np.ndarray


def dot_contrast(image, xy, *, radius: int = 4) -> np.ndarray:
    """``(N,)`` peak grey level above the median of the ``(2 radius + 1)`` window around each
    position (NaN where the window leaves the image or the position is NaN)."""
    img = np.asarray(image, np.float64)
    H, W = img.shape
    p = np.asarray(xy, float).reshape(-1, 2)
    out = np.full(len(p), np.nan)
    ok = np.isfinite(p).all(axis=1)
    c = np.zeros_like(p, dtype=int)
    c[ok] = np.rint(p[ok]).astype(int)
    ok &= (c[:, 0] >= radius) & (c[:, 0] < W - radius) & (c[:, 1] >= radius) \
        & (c[:, 1] < H - radius)
    off = np.arange(-radius, radius + 1)
    if ok.any():
        win = img[c[ok, 1, None, None] + off[None, :, None], c[ok, 0, None, None] + off]
        out[ok] = win.max(axis=(1, 2)) - np.median(win, axis=(1, 2))
    return out


def dot_surround(image, xy, *, radius: int = 4, rays: int = 16) -> np.ndarray:
    """``(N,)`` how far each position's core stands above its surround in its brightest
    direction, grey levels: a dot test that an edge, a bright line or flat bright skin fails.

    The core is the mean grey level (bilinear) at the position and at four points
    ``radius / 4`` px from it (right, down, left, up, whatever ``rays``); each of ``rays``
    directions' surround is the mean over five points from ``radius`` to ``1.5 radius`` px
    out along it; the result is the core less the brightest direction's surround. A small
    bright dot (about ``2 radius`` px across: ``radius`` is a little more than the dot's
    radius, as :class:`FollowParams` sets it) is darker around it in every direction, so it
    scores its contrast; beside an edge the directions into the bright side are as bright
    as the core, along a bright line or fold the directions along it are, and flat skin is
    as bright everywhere, so these score about 0 or less, whatever their peak over the
    window's median (:func:`dot_contrast`, which all of them can pass).

    The limits: anything as bright as the dot within the surround's ring scores as that
    ring, so a real dot beside a bright stripe is refused too (``radius`` 4, a dot of
    sigma 1.5 px and 100 grey levels scoring 77 alone, a 3 px wide stripe as bright 5 px
    from its centre: below 0; 6 px: 14; 8 px: 68; :func:`~lsmta.tracking.join_checks.fill_gaps`
    refuses below its floor, 15 by default in the marker stage). A position within
    ``1.5 radius`` px of the image's border scores NaN, which a floor refuses.

    Parameters
    ----------
    image : (H, W) array
        Grey frame.
    xy : (N, 2) array
        Positions (a dot's centre, e.g. from :func:`dot_centre`), px; NaN allowed.
    radius : int
        The dot's window half-width, px (>= 1): the surround starts there.
    rays : int
        Directions of the surround, >= 4 (default 16: 22.5 degrees apart, so that a bright
        line of a dot's width has a direction along it); the core's four points do not
        depend on it.

    Returns
    -------
    (N,) array
        Core less the brightest surround, grey levels; NaN where the surround leaves the
        image or the position is NaN.
    """
    img = np.asarray(image, np.float64)
    if img.ndim != 2:
        raise ValueError(f"image: expected an (H, W) grey frame, got shape {img.shape}")
    p = as_array(xy, "xy", shape=(None, 2), allow_nan=True)
    radius = as_int(radius, "radius", minimum=1, unit="pixels")
    rays = as_int(rays, "rays", minimum=4)
    H, W = img.shape
    reach = 1.5 * radius
    out = np.full(len(p), np.nan)
    ok = np.isfinite(p).all(axis=1)
    ok[ok] = ((p[ok, 0] >= reach) & (p[ok, 0] <= W - 1 - reach) & (p[ok, 1] >= reach)
              & (p[ok, 1] <= H - 1 - reach))
    if not ok.any():
        return out
    ang = 2 * np.pi * np.arange(rays) / rays
    u = np.stack([np.cos(ang), np.sin(ang)], axis=1)                       # (rays, 2)
    ring = u[:, None] * np.linspace(radius, reach, 5)[None, :, None]       # (rays, 5, 2)
    core = 0.25 * radius * np.array([[0.0, 0.0], [1, 0], [0, 1], [-1, 0], [0, -1]])
    q = p[ok]
    core_v = _bilinear(img, q[:, None] + core[None]).mean(axis=1)           # (n,)
    ring_v = _bilinear(img, q[:, None, None] + ring[None]).mean(axis=2)     # (n, rays)
    out[ok] = core_v - ring_v.max(axis=1)
    return out


def _bilinear(img, pts) -> np.ndarray:
    """Grey levels of ``img`` at ``(..., 2)`` points inside it (x, y), bilinear."""
    x, y = pts[..., 0], pts[..., 1]
    x0 = np.clip(np.floor(x).astype(int), 0, img.shape[1] - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, img.shape[0] - 2)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x0 + 1]
            + (1 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])


def dot_centre(image, xy, *, radius: int = 4, iterations: int = 3) -> np.ndarray:
    """``(N, 2)`` centroid of each dot's core, px: in the ``(2 radius + 1)`` window around
    the position, the grey levels above half-way from the window's median to its peak,
    weighted by their excess, ``iterations`` times (the window moved to the last centroid);
    positions whose window leaves the image, or NaN, are returned as given."""
    img = np.asarray(image, np.float64)
    H, W = img.shape
    p = np.array(xy, dtype=float).reshape(-1, 2)
    off = np.arange(-radius, radius + 1)
    for _ in range(iterations):
        ok = np.isfinite(p).all(axis=1)
        c = np.zeros_like(p, dtype=int)
        c[ok] = np.rint(p[ok]).astype(int)
        ok &= (c[:, 0] >= radius) & (c[:, 0] < W - radius) & (c[:, 1] >= radius) \
            & (c[:, 1] < H - radius)
        if not ok.any():
            break
        iy = c[ok, 1, None, None] + off[None, :, None]
        ix = c[ok, 0, None, None] + off[None, None, :]
        win = img[iy, ix]
        med = np.median(win, axis=(1, 2), keepdims=True)
        w = np.clip(win - 0.5 * (med + win.max(axis=(1, 2), keepdims=True)), 0, None)
        tot = w.sum(axis=(1, 2))
        good = tot > 0
        sel = np.flatnonzero(ok)[good]
        p[sel, 0] = (w * ix).sum(axis=(1, 2))[good] / tot[good]
        p[sel, 1] = (w * iy).sum(axis=(1, 2))[good] / tot[good]
    return p


def _recentre(image, moved, start, least, p: FollowParams) -> np.ndarray:
    """The step's results on their dots (NaN: no dot of at least ``least`` contrast; the
    farther-moved of two on one dot)."""
    q = np.array(moved, float)
    ok = np.isfinite(q).all(axis=1)
    if ok.any():
        q[ok] = dot_centre(image, q[ok], radius=p.radius)
        ok &= dot_contrast(image, q, radius=p.radius) >= least
    q[~ok] = np.nan
    idx = np.flatnonzero(ok)
    travel = np.linalg.norm(q - start, axis=1)
    for a in idx[np.argsort(travel[idx], kind="stable")]:
        if not np.isfinite(q[a, 0]):
            continue
        near = np.linalg.norm(q[idx] - q[a], axis=1) <= p.radius
        near[idx == a] = False
        q[idx[near]] = np.nan                   # on the dot held by the nearer-moved one
    return q


def _free_blobs(img, c, half, taken, *, sigma, min_strength, radius):
    """Blobs (:func:`~lsmta.tracking.markers.find_blobs`) of ``img`` within ``half`` px (a
    square) of ``c``, px, less those within ``radius`` of a ``taken`` dot; None where the
    crop is under 8 px wide."""
    H, W = img.shape
    x0, y0 = max(0, int(c[0]) - half), max(0, int(c[1]) - half)
    x1, y1 = min(W, int(c[0]) + half + 1), min(H, int(c[1]) + half + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    blobs = find_blobs(np.asarray(img[y0:y1, x0:x1], np.float64), sigma=sigma,
                       min_strength=min_strength) + [x0, y0]
    if len(taken) and len(blobs):
        free = np.linalg.norm(blobs[:, None] - np.asarray(taken)[None], axis=2).min(axis=1)
        blobs = blobs[free > radius]
    return blobs


def _reacquire(image, pred, held, own, p: FollowParams) -> np.ndarray:
    """Nearest free blob within ``reacquire_px`` of each prediction whose contrast is within
    a factor ``1 / keep_contrast`` of the marker's ``own``, px (NaN: none)."""
    img = np.asarray(image, np.float64)
    out = np.full_like(pred, np.nan)
    taken = [h for h in held if np.isfinite(h).all()]
    half = int(np.ceil(p.reacquire_px + 3 * p.sigma + 2))
    for i, c in enumerate(pred):
        if not np.isfinite(c).all():
            continue
        blobs = _free_blobs(img, c, half, taken, sigma=p.sigma, min_strength=p.min_strength,
                            radius=p.radius)
        if blobs is None:
            continue
        if len(blobs) and p.keep_contrast > 0:
            ratio = dot_contrast(img, blobs, radius=p.radius) / own[i]
            blobs = blobs[(ratio >= p.keep_contrast) & (ratio <= 1 / p.keep_contrast)]
        d = np.linalg.norm(blobs - c, axis=1)
        if len(d) and d.min() <= p.reacquire_px:
            out[i] = blobs[np.argmin(d)]
            taken.append(out[i])
    return out


def follow_blobs(frames, start_xy, step, *, params: FollowParams | None = None
                 ) -> FollowedMarkers:
    """Follow markers through a grey video on their blobs (see the module docstring).

    Parameters
    ----------
    frames : (T, H, W) array
        Grey frames.
    start_xy : (N, 2) array
        The markers in frame 0, px (NaN: not followed).
    step : callable
        ``step(t, xy, predicted) -> (n, 2) array``: the tracker's positions in frame
        ``t + 1`` of the points at ``xy`` (``(n, 2)``, px) in frame ``t``, NaN where it
        lost them; ``predicted`` is each point's constant-velocity prediction (a tracker
        may ignore it).
    params : FollowParams, optional

    Returns
    -------
    FollowedMarkers
    """
    p = FollowParams() if params is None else params
    if not isinstance(p, FollowParams):
        raise TypeError(f"params: expected a FollowParams, got {type(p).__name__}")
    if not callable(step):
        raise TypeError(f"step: expected a callable step(t, xy, predicted), got "
                        f"{type(step).__name__}")
    p = replace(p, radius=p.window())
    imgs = np.asarray(frames)
    if imgs.ndim != 3 or len(imgs) == 0:
        raise ValueError(f"frames: expected a (T, H, W) stack of grey frames with T >= 1, got "
                         f"shape {imgs.shape}")
    start = as_array(start_xy, "start_xy", shape=(None, 2), allow_nan=True)
    T, N = len(imgs), len(start)
    xy = np.full((T, N, 2), np.nan)
    status = np.full((T, N), FollowStatus.LOST, dtype=np.int64)
    xy[0] = _recentre(imgs[0], start, start, p.min_contrast, p)
    own = dot_contrast(imgs[0], xy[0], radius=p.radius)      # each marker's contrast
    least = np.maximum(p.min_contrast, p.keep_contrast * np.nan_to_num(own))
    status[0, np.isfinite(xy[0, :, 0])] = FollowStatus.TRACKED
    last = np.where(np.isfinite(xy[0, :, 0]), 0, -1)       # last frame each was found in
    vel = np.zeros((N, 2))
    for t in range(T - 1):
        alive = np.flatnonzero(np.isfinite(xy[t, :, 0]))
        new = np.full((N, 2), np.nan)
        if alive.size:
            moved = np.asarray(step(t, xy[t, alive], xy[t, alive] + vel[alive]), float)
            if moved.size != 2 * alive.size:
                raise ValueError(f"step: expected ({alive.size}, 2) positions for frame {t + 1}, "
                                 f"got shape {moved.shape}")
            new[alive] = _recentre(imgs[t + 1], moved.reshape(-1, 2), xy[t, alive],
                                   least[alive], p)
        gap = t + 1 - last
        lost = np.flatnonzero(~np.isfinite(new[:, 0]) & (last >= 0) & (gap <= p.max_gap + 1))
        status_new = np.where(np.isfinite(new[:, 0]), FollowStatus.TRACKED, FollowStatus.LOST)
        if p.reacquire_px > 0 and lost.size:
            pred = xy[last[lost], lost] + vel[lost] * gap[lost, None]
            found = _reacquire(imgs[t + 1], pred, new, own[lost], p)
            got = np.isfinite(found[:, 0])
            new[lost[got]] = found[got]
            status_new[lost[got]] = FollowStatus.REACQUIRED
        ok = np.flatnonzero(np.isfinite(new[:, 0]))
        own[ok] = dot_contrast(imgs[t + 1], new[ok], radius=p.radius)
        least[ok] = np.maximum(p.min_contrast, p.keep_contrast * np.nan_to_num(own[ok]))
        vel[ok] = np.where((last[ok] == t)[:, None], new[ok] - xy[t, ok], 0.0)
        last[ok] = t + 1
        xy[t + 1] = new
        status[t + 1] = status_new
    return FollowedMarkers(xy=xy, status=status)
