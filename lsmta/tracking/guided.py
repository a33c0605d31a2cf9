"""Guided tracking (Davis 2002, Fig. 56): the tracking state of every marker over time, an
enlarged view of one feature, and a marker placed by hand from which tracking resumes.

Automated tracking sometimes fails; the thesis gives its user an overview of the tracking
state, an enlarged view of one feature and controls to restart it. These are the plain
functions behind such an interface (the widget is :mod:`lsmta.tracking.guided_ui`):

* :func:`tracking_state`: a ``(T, N)`` array of :class:`MarkerState` codes from
  :class:`~lsmta.tracking.points.Tracks` (live, found again, placed by hand, missing and
  still searched, lost, not started);
* :func:`feature_view`: the pixels around one position (the enlarged view);
  :func:`last_known` the position to centre it on when the marker is not tracked there;
* :func:`resume_from`: a user-placed position of one marker at one frame; the position is
  refined with the marker's own first template (``snap``), then the marker is tracked on
  from there with :func:`~lsmta.tracking.points.track_points`, and the result is merged
  into a new :class:`Tracks` (the caller's is never modified).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_int
from .points import TrackerParams, Tracks, TrackStatus, as_sequences, track_points, track_step


class MarkerState(enum.IntEnum):
    """State of one marker in one frame (:func:`tracking_state`)."""

    LIVE = 0         #: tracked
    RECOVERED = 1    #: tracked, found again by the tracker after missing frames
    PLACED = 2       #: placed by hand (:func:`resume_from`)
    MISSING = 3      #: not found, still searched (at most ``max_gap`` frames since tracked)
    LOST = 4         #: not found for more than ``max_gap`` frames: the tracker gave up
    NOT_STARTED = 5  #: before the marker's first tracked frame, or never started


@dataclass(frozen=True)
class FeatureView:
    """The pixels around one image position (the enlarged view of a feature).

    Attributes
    ----------
    patch : (2 h + 1, 2 h + 1) float array
        Grey values; NaN outside the image.
    x0, y0 : int
        Pixel coordinates of ``patch[0, 0]`` (x right, y down).
    xy : (2,) array
        The position the view is centred on, px.
    """

    patch: np.ndarray
    x0: int
    y0: int
    xy: np.ndarray

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(left, right, bottom, top)`` for ``imshow`` in pixel coordinates."""
        h, w = self.patch.shape
        return (self.x0 - 0.5, self.x0 + w - 0.5, self.y0 + h - 0.5, self.y0 - 0.5)


@dataclass(frozen=True)
class Resumed:
    """Result of :func:`resume_from`.

    Attributes
    ----------
    tracks : Tracks
        A new Tracks: the marker's track replaced from ``frame`` on.
    placed : (T, N) bool array
        Frames where a marker's position was placed by hand (earlier placements kept,
        except the marker's own after ``frame``, which the new track replaces).
    marker, frame : int
    click : (K, 2) array
        The position given by the user, px.
    xy : (K, 2) array
        The position used at ``frame``: the click refined with the marker's first
        template where ``snapped``, else the click, px.
    snapped : bool
        The click was refined (the marker's template from its start frame matched within
        ``params.radius`` px of the click).
    """

    tracks: Tracks
    placed: np.ndarray
    marker: int
    frame: int
    click: np.ndarray
    xy: np.ndarray
    snapped: bool

    @property
    def frames_tracked(self) -> int:
        """Frames after ``frame`` in which the marker is tracked."""
        return int(self.tracks.alive[self.frame + 1:, self.marker].sum())


def _check_placed(placed, tracks: Tracks) -> np.ndarray:
    shape = (tracks.n_frames, len(tracks))
    if placed is None:
        return np.zeros(shape, bool)
    arr = np.asarray(placed)
    if arr.shape != shape or arr.dtype != bool:
        raise ValueError(f"placed: expected a {shape} bool array, got {arr.dtype} {arr.shape}")
    return arr.copy()


def tracking_state(tracks: Tracks, *, placed=None, max_gap: int | None = None) -> np.ndarray:
    """Tracking state of every marker in every frame.

    Parameters
    ----------
    tracks : Tracks
    placed : (T, N) bool array, optional
        Frames placed by hand (:attr:`Resumed.placed`); they are ``PLACED``.
    max_gap : int, optional
        The tracker's ``max_gap`` (default ``TrackerParams().max_gap``): a marker not found
        for at most this many frames since it was last tracked is ``MISSING``, beyond it
        ``LOST``.

    Returns
    -------
    (T, N) int8 array
        :class:`MarkerState` codes.
    """
    if not isinstance(tracks, Tracks):
        raise ValueError(f"tracks: expected lsmta.tracking.Tracks, got {type(tracks).__name__}")
    gap = TrackerParams().max_gap if max_gap is None else as_int(max_gap, "max_gap", minimum=0,
                                                                  unit="frames")
    done = _check_placed(placed, tracks)
    T, N = done.shape
    alive = tracks.alive | done
    t = np.arange(T)[:, None]
    last = np.maximum.accumulate(np.where(alive, t, -1), axis=0)     # last tracked frame <= t
    state = np.full((T, N), MarkerState.NOT_STARTED, np.int8)
    begun = (last >= 0) & (tracks.status != TrackStatus.NOT_STARTED)[None, :]
    since = t - last
    state[begun & ~alive & (since <= gap)] = MarkerState.MISSING
    state[begun & ~alive & (since > gap)] = MarkerState.LOST
    state[begun & alive] = MarkerState.LIVE
    state[begun & alive & tracks.recovered] = MarkerState.RECOVERED
    state[done] = MarkerState.PLACED
    return state


def feature_view(image, xy, *, half: int = 15) -> FeatureView:
    """The ``(2 half + 1)``-pixel square of ``image`` around ``xy`` (its nearest pixel).

    Parameters
    ----------
    image : (H, W) array
        Grey image.
    xy : (2,) array
        Centre, px.
    half : int
        Half-width of the view, px.

    Returns
    -------
    FeatureView
        Pixels outside the image are NaN.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image: expected a (H, W) grey image, got shape {img.shape}")
    h = as_int(half, "half", minimum=1, unit="pixels")
    c = as_array(xy, "xy", shape=(2,))
    cx, cy = (int(v) for v in np.rint(c))
    H, W = img.shape
    patch = np.full((2 * h + 1, 2 * h + 1), np.nan)
    xs, ys = slice(max(cx - h, 0), min(cx + h + 1, W)), slice(max(cy - h, 0), min(cy + h + 1, H))
    if xs.start < xs.stop and ys.start < ys.stop:
        patch[ys.start - (cy - h):ys.stop - (cy - h),
              xs.start - (cx - h):xs.stop - (cx - h)] = img[ys, xs]
    return FeatureView(patch=patch, x0=cx - h, y0=cy - h, xy=c.copy())


def last_known(tracks: Tracks, marker: int, frame: int, *, camera: int = 0) -> np.ndarray:
    """Where to look for ``marker`` at ``frame``: its tracked position there, else its last
    tracked position before, else its first after; NaN if it was never tracked. ``(2,)`` px."""
    m = as_int(marker, "marker", minimum=0)
    f = as_int(frame, "frame", minimum=0)
    if m >= len(tracks) or f >= tracks.n_frames:
        raise ValueError(f"marker, frame: expected < {len(tracks)} and < {tracks.n_frames}, "
                         f"got {marker} and {frame}")
    xy = tracks.xy[:, camera, m]
    ok = np.flatnonzero(np.isfinite(xy).all(axis=1))
    if not ok.size:
        return np.full(2, np.nan)
    before = ok[ok <= f]
    return xy[before[-1] if before.size else ok[0]].copy()


def _refined(seq, tracks: Tracks, m: int, f: int, click, p: TrackerParams):
    """The click ``(K, 2)`` refined with the marker's template at its start frame (matched
    into frame ``f`` from the click), and whether it was; the click itself where the match
    fails or lands more than ``p.radius`` px from it."""
    s = int(tracks.start[m])
    if tracks.status[m] == TrackStatus.NOT_STARTED or s == f:
        return click.copy(), False
    step = track_step(seq[:, s], seq[:, f], tracks.xy[s][:, [m]], click[:, None], p.radius,
                      params=p)
    if step.ok[0] and np.all(np.linalg.norm(step.xy[:, 0] - click, axis=1) <= p.radius):
        return step.xy[:, 0].copy(), True
    return click.copy(), False


def _tracked_on(seq, tracks: Tracks, m: int, f: int, pos, p: TrackerParams) -> Tracks:
    """A new Tracks: marker ``m`` at ``pos`` ``(K, 2)`` in frame ``f``, tracked on from there
    (its frames before ``f`` kept)."""
    K, T = seq.shape[:2]
    arrays = {name: np.array(getattr(tracks, name)) for name in
              ("xy", "start", "end", "status", "retried", "anchor", "recovered")}
    for name in ("retried", "recovered"):
        arrays[name][f:, m] = False
    arrays["xy"][f:, :, m] = np.nan
    arrays["anchor"][f:, m] = -1
    arrays["xy"][f, :, m] = pos
    arrays["anchor"][f, m] = f
    status = TrackStatus.ALIVE
    if f < T - 1:
        sub = track_points(seq[:, f:], pos[:, None], params=p,
                           initial_velocity=np.zeros((K, 1, 2)))
        if sub.status[0] == TrackStatus.NOT_STARTED:
            status = TrackStatus.LOST
        else:
            status = TrackStatus(int(sub.status[0]))
            arrays["xy"][f + 1:, :, m] = sub.xy[1:, :, 0]
            arrays["retried"][f + 1:, m] = sub.retried[1:, 0]
            arrays["recovered"][f + 1:, m] = sub.recovered[1:, 0]
            arrays["anchor"][f + 1:, m] = np.where(sub.anchor[1:, 0] >= 0,
                                                   sub.anchor[1:, 0] + f, -1)
    tracked = np.flatnonzero(np.isfinite(arrays["xy"][:, :, m]).all(axis=(1, 2)))
    arrays["start"][m] = tracked[0]
    arrays["end"][m] = tracked[-1]
    arrays["status"][m] = status
    return replace(tracks, **arrays)


def resume_from(images, tracks: Tracks, marker: int, frame: int, xy, *,
                params: TrackerParams | None = None, snap: bool = True,
                placed=None) -> Resumed:
    """Place ``marker`` by hand at ``frame`` and track it on from there.

    The click is first refined (``snap``): the marker's template at its start frame is
    matched into ``frame`` from the click (:func:`~lsmta.tracking.points.track_step`), so
    a click off by a pixel does not shift every later frame; if that match fails or lands
    more than ``params.radius`` px from the click, the click is used as it is. From the
    position, the marker is tracked through frames ``frame .. T - 1`` with
    :func:`~lsmta.tracking.points.track_points` (zero initial velocity, a new anchored
    template at ``frame``) and its track from ``frame`` on is replaced.

    Parameters
    ----------
    images : (K, T, H, W) array or sequence of K image sequences
        The sequences ``tracks`` came from.
    tracks : Tracks
        Not modified.
    marker : int
        Index of the track.
    frame : int
        Frame of the placed position.
    xy : (K, 2) array, or (2,) with one camera
        The placed position in every camera, px.
    params : TrackerParams, optional
        As used for ``tracks``.
    snap : bool
        Refine the click with the marker's first template.
    placed : (T, N) bool array, optional
        Earlier placements (:attr:`Resumed.placed`), carried over.

    Returns
    -------
    Resumed
    """
    p = params or TrackerParams()
    seq = as_sequences(images)
    K, T = seq.shape[:2]
    if not isinstance(tracks, Tracks) or tracks.xy.shape[:2] != (T, K):
        got = tracks.xy.shape[:2] if isinstance(tracks, Tracks) else type(tracks).__name__
        raise ValueError(f"tracks: expected Tracks of {T} frames in {K} cameras (as images), "
                         f"got {got}")
    N = len(tracks)
    m = as_int(marker, "marker", minimum=0)
    f = as_int(frame, "frame", minimum=0)
    if m >= N:
        raise ValueError(f"marker: expected a track index < {N}, got {marker}")
    if f >= T:
        raise ValueError(f"frame: expected a frame index < {T}, got {frame}")
    click = as_array(xy, "xy", shape=(2,) if K == 1 and np.ndim(xy) == 1 else (K, 2))
    click = click.reshape(K, 2)
    H, W = seq.shape[2:]
    if np.any(click < -0.5) or np.any(click[:, 0] > W - 0.5) or np.any(click[:, 1] > H - 0.5):
        raise ValueError(f"xy: expected positions inside the {W} x {H} image, got "
                         f"{click.tolist()}")
    done = _check_placed(placed, tracks)
    pos, snapped = _refined(seq, tracks, m, f, click, p) if snap else (click.copy(), False)
    new = _tracked_on(seq, tracks, m, f, pos, p)
    done[f:, m] = False
    done[f, m] = True
    return Resumed(tracks=new, placed=done, marker=m, frame=f,
                   click=click, xy=pos, snapped=snapped)
