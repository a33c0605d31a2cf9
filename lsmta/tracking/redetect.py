"""Markers detected again in later frames, tracked both ways and merged into the tracks they
meet: a marker not seen in the first frame (turned away, hidden by an arm) or lost for good
by the tracker gets a track where it is seen again.

Every ``every`` frames (the *key frames*), the view's markers are detected again; a detection
within ``2 radius`` of a position some track holds in that frame is that track's marker and
is skipped. Each new detection is tracked forwards to the last frame and backwards to the
first (one *piece*). A piece that comes within ``radius`` of an earlier track in some frame
is that track's marker: it fills the frames the track lacks (the track's own positions are
kept); a piece that meets none is a new track. ``radius`` is the re-centring window of the
blob following (:class:`~lsmta.tracking.blob_follow.FollowParams`), within which two markers
end on one dot.

The pieces and their merges are recorded as *starts* (track, frame, x, y), so that another
tracker can be run from the same start points into the same tracks
(:func:`tracks_from_starts`), as the marker stage's peer comparison needs.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array, as_int, as_scalar


def _piece(frames, xy, s, track) -> np.ndarray:
    """``(T, n, 2)`` tracks of points seen in frame ``s``: forwards and backwards from it."""
    fwd = np.asarray(track(frames[s:], xy), float)
    if s == 0:
        return fwd
    bwd = np.asarray(track(np.ascontiguousarray(frames[s::-1]), xy), float)[::-1]
    return np.concatenate([bwd[:-1], fwd], axis=0)


def _checked(frames, track, every, radius):
    if np.ndim(frames) != 3 or len(frames) == 0:
        raise ValueError(f"frames: expected a (T, H, W) stack of grey frames with T >= 1, got "
                         f"shape {np.shape(frames)}")
    if not callable(track):
        raise TypeError(f"track: expected a callable track(frames, xy) -> (T, n, 2), got "
                        f"{type(track).__name__}")
    return (as_int(every, "every", minimum=1, unit="frames"),
            as_scalar(radius, "radius", positive=True))


def redetected_tracks(frames, detect, track, *, every: int, radius: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """A view's marker tracks from its first frame and its key frames (module docstring).

    Parameters
    ----------
    frames : (T, H, W) array
        Grey frames of the view.
    detect : callable
        ``detect(t) -> (n, 2)`` markers found in frame ``t``, px.
    track : callable
        ``track(frames, xy) -> (T', n, 2)``: points ``xy`` ``(n, 2)`` of the first of
        ``frames`` tracked through them (NaN once lost).
    every : int
        Frames between key frames (>= 1).
    radius : float
        Two positions within it are one marker's, px (> 0).

    Returns
    -------
    xy : (T, N, 2) array
        The tracks, px.
    starts : (S, 4) array
        Each piece's track index, start frame and start position (x, y) px, in the order
        they were merged.
    """
    every, radius = _checked(frames, track, every, radius)
    T = len(frames)
    first = as_array(detect(0), "detect(0)", shape=(None, 2))
    xy = _piece(frames, first, 0, track)
    starts = [[i, 0, x, y] for i, (x, y) in enumerate(first)]
    for s in range(every, T, every):
        d = as_array(detect(s), f"detect({s})", shape=(None, 2))
        held = xy[s][np.isfinite(xy[s, :, 0])]
        if len(held) and len(d):
            d = d[np.linalg.norm(d[:, None] - held[None], axis=2).min(axis=1) > 2 * radius]
        if not len(d):
            continue
        new = _piece(frames, d, s, track)
        for i in range(len(d)):
            j = _meets(xy, new[:, i], radius)
            if j is None:
                j = xy.shape[1]
                xy = np.concatenate([xy, new[:, i:i + 1]], axis=1)
            else:
                lack = ~np.isfinite(xy[:, j, 0])
                xy[lack, j] = new[lack, i]
            starts.append([j, s, *d[i]])
    return xy, np.array(starts, float).reshape(-1, 4)


def _meets(xy, piece, radius) -> int | None:
    """The track a piece comes within ``radius`` of in the most frames, or None."""
    if not xy.shape[1]:
        return None
    with np.errstate(invalid="ignore"):
        close = (np.linalg.norm(xy - piece[:, None], axis=2) <= radius).sum(axis=0)
    return int(np.argmax(close)) if close.max() >= 1 else None


def tracks_from_starts(frames, starts, track) -> np.ndarray:
    """The tracks of :func:`redetected_tracks`' ``starts``, with another tracker.

    Parameters
    ----------
    frames : (T, H, W) array
        Grey frames of the view.
    starts : (S, 4) array
        Track index, start frame, x, y px (:func:`redetected_tracks`).
    track : callable
        As in :func:`redetected_tracks`.

    Returns
    -------
    (T, N, 2) array
        N the number of track indices: each track is its first piece, the frames it lacks
        filled by its later pieces in the order given.
    """
    _checked(frames, track, 1, 1.0)
    st = as_array(starts, "starts", shape=(None, 4))
    T = len(frames)
    if len(st) and (st[:, 1].min() < 0 or st[:, 1].max() >= T or (st[:, :2] % 1).any()
                    or st[:, 0].min() < 0):
        raise ValueError(f"starts: expected rows (track >= 0, frame in 0..{T - 1}, x, y) with "
                         f"whole track and frame numbers")
    N = int(st[:, 0].max()) + 1 if len(st) else 0
    out = np.full((T, N, 2), np.nan)
    pieces = {}
    for s in np.unique(st[:, 1]).astype(int):
        rows = np.flatnonzero(st[:, 1] == s)
        pieces.update(zip(rows, np.moveaxis(_piece(frames, st[rows, 2:], s, track), 1, 0)))
    for r in range(len(st)):
        j = int(st[r, 0])
        lack = ~np.isfinite(out[:, j, 0])
        out[lack, j] = pieces[r][lack]
    return out
