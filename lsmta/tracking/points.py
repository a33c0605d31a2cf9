"""LSMTA point and surface tracking in image space (D'Apuzzo 2000, Section 2.3, Figs. 6-9).

For every live track and every camera independently, from frame ``t`` to ``t + 1``:

1. *prediction*: ``x_t + (x_t - x_{t-1})`` (linear, from the two previous positions); a
   track born at ``t`` has no history and takes the median image velocity of its
   ``neighbours`` nearest live tracks (zero if there are none);
2. *correlation*: the patch at ``x_t`` in frame ``t`` is searched in a box of half-width
   ``radius`` around the prediction in frame ``t + 1`` (normalised cross-correlation,
   :func:`~lsmta.matching.correlation_search`);
3. *temporal LSM*: frame ``t``'s patch is matched into frame ``t + 1`` starting at the best
   correlation position (:func:`~lsmta.matching.lsm`, affine, quality thresholds).

Then the *spatial LSM* matches the template camera's new patch into the other cameras'
frame ``t + 1``, starting at their temporal results (with each track's previous spatial
affinity). A track is accepted when every temporal LSM passed its thresholds and every
spatial LSM stayed within ``max_disagreement`` pixels of the temporal result. Rejected
tracks are searched again in a box of half-width ``retry_radius``; rejected twice, the track
stops and its later positions are NaN (never a made-up position). A track without history
is searched in the ``retry_radius`` box first and then in one twice as large.

With one camera (2-D mode, paper Section 2.3.3) there is no spatial LSM: a track is accepted
when the temporal LSM passes its thresholds (among them the largest distance from the
correlation peak, ``thresholds.max_displacement``).

*Surface tracking* (Fig. 9): with ``new_points``, every ``density_every`` frames the live
tracks are checked for density in the template image
(:func:`~lsmta.tracking.density.sparse_candidates`), and that frame's measured surface
points are added where the tracks have thinned out (newly visible surface).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from .._validate import as_array, as_scalar, check_patch
from ..matching.correlation import CorrelationStatus, correlation_search
from ..matching.lsm import LSMThresholds, lsm
from ..matching.spline import SplineImage, check_image
from .density import sparse_candidates


class TrackStatus(enum.IntEnum):
    """How a track ended."""

    ALIVE = 0        #: tracked to the last frame
    LOST = 1         #: rejected in the normal and in the bigger search box
    NOT_STARTED = 2  #: its start position was incomplete (NaN in some camera)


@dataclass(frozen=True)
class TrackerParams:
    """Parameters of :func:`track_points`.

    Attributes
    ----------
    patch : int
        LSM and correlation patch size (odd, pixels).
    radius, retry_radius : int
        Half-widths of the normal and the bigger search box (pixels).
    max_disagreement : float
        Largest distance between the spatial and the temporal LSM result (pixels).
    template : int
        Camera whose patch is the template of the spatial LSM (the centre camera).
    thresholds : LSMThresholds
        Quality thresholds of the temporal and spatial LSM.
    geometry : str
        LSM geometry (``"affine"`` as in the paper).
    max_iter : int
        LSM iteration limit (a match still moving after it is rejected).
    tol : float
        LSM convergence tolerance, pixels.
    neighbours : int
        Neighbours whose median velocity predicts a track without history.
    density_every : int
        Frequency of the density check, frames (surface tracking only).
    cell, min_per_cell, min_distance
        Density check (:func:`~lsmta.tracking.density.sparse_candidates`).
    """

    patch: int = 9
    radius: int = 4
    retry_radius: int = 10
    max_disagreement: float = 1.0
    template: int = 1
    thresholds: LSMThresholds = field(default_factory=lambda: LSMThresholds(
        max_sigma0=15.0, max_sigma_xy=0.4, max_displacement=3.0, scale_range=(0.5, 2.0),
        max_shear=0.6))
    geometry: str = "affine"
    max_iter: int = 60
    tol: float = 0.01
    neighbours: int = 8
    density_every: int = 2
    cell: float = 16.0
    min_per_cell: int = 2
    min_distance: float = 3.0


@dataclass(frozen=True)
class Tracks:
    """Tracked image positions of N points in K cameras over T frames.

    Attributes
    ----------
    xy : (T, K, N, 2) array
        Pixel positions; NaN before a track's start and after its end.
    start, end : (N,) int arrays
        First and last tracked frame (inclusive).
    status : (N,) int array
        :class:`TrackStatus` codes.
    retried : (T, N) bool array
        The frame's position was found only in the bigger search box.
    added : (N,) bool array
        The track was added by a density check (not one of the initial points).
    origin : (N,) int array
        For an added track, its index in ``new_points[start]`` (after dropping the
        candidates with NaN); -1 for the initial points.
    """

    xy: np.ndarray
    start: np.ndarray
    end: np.ndarray
    status: np.ndarray
    retried: np.ndarray
    added: np.ndarray
    origin: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.xy.shape[0]

    @property
    def alive(self) -> np.ndarray:
        """``(T, N)`` bool: tracked in that frame."""
        return np.isfinite(self.xy).all(axis=(1, 3))

    def __len__(self) -> int:
        return self.xy.shape[2]


def as_sequences(images) -> np.ndarray:
    """Image sequences as a ``(K, T, H, W)`` array, after checking their lengths and sizes.

    ``images`` may be a ``(K, T, H, W)`` array or a sequence of K sequences of images
    (a ``(T, H, W)`` stack is one camera: pass ``[stack]``).
    """
    if isinstance(images, np.ndarray):
        if images.ndim != 4:
            raise ValueError(f"images: expected (K, T, H, W) image sequences, got shape "
                             f"{images.shape}; a single sequence of shape (T, H, W) is "
                             "passed as [sequence]")
        seqs = list(images)
    else:
        seqs = list(images)
    if not seqs:
        raise ValueError("images: expected at least one image sequence")
    lengths = [len(s) for s in seqs]
    if len(set(lengths)) != 1:
        raise ValueError(f"images: the cameras' sequences have unequal lengths {lengths}; "
                         "expected one length")
    if lengths[0] < 2:
        raise ValueError(f"images: expected at least 2 frames, got {lengths[0]}")
    out = []
    for k, s in enumerate(seqs):
        frames = [check_image(im, f"images[{k}][{t}]") for t, im in enumerate(s)]
        sizes = {f.shape for f in frames}
        out.append(frames)
        if len(sizes) != 1:
            raise ValueError(f"images[{k}]: frames of unequal size {sorted(sizes)}")
    sizes = [o[0].shape for o in out]
    if len(set(sizes)) != 1:
        raise ValueError(f"images: the cameras' images have unequal sizes {sizes}; "
                         "expected one size")
    return np.stack([np.stack(o) for o in out])


def track_points(images, initial_xy, *, params: TrackerParams | None = None,
                 new_points=None, initial_velocity=None, progress: bool = False) -> Tracks:
    """Track points through K synchronised image sequences (LSMTA, Fig. 7 and Fig. 9).

    Parameters
    ----------
    images : (K, T, H, W) array or sequence of K image sequences
        Grey images; every camera has the same number of frames of one size. ``K = 1`` is
        the 2-D mode.
    initial_xy : (K, N, 2) array
        Spatially matched positions at frame 0 (pixels); a point with NaN in any camera is
        not tracked (status ``NOT_STARTED``).
    params : TrackerParams, optional
    new_points : mapping or sequence, optional
        Surface tracking: ``new_points[t]`` is a ``(K, M, 2)`` array of frame ``t``'s
        measured surface points (or None). Checked every ``params.density_every`` frames.
    initial_velocity : (K, N, 2) array, optional
        Image velocity (pixels/frame) for the first prediction; default: none (the first
        search uses the bigger box).
    progress : bool
        Show a progress bar over the frames.

    Returns
    -------
    Tracks
    """
    p = params or TrackerParams()
    _check_params(p)
    seq = as_sequences(images)
    K, T = seq.shape[:2]
    if K > 1 and not 0 <= p.template < K:
        raise ValueError(f"params.template: expected a camera index in [0, {K - 1}], "
                         f"got {p.template}")
    xy0 = as_array(initial_xy, "initial_xy", shape=(K, None, 2), allow_nan=True)
    started = np.isfinite(xy0).all(axis=(0, 2))
    if not started.any():
        raise ValueError("initial_xy: the first frame has no point matched in every camera; "
                         "nothing to track")
    vel0 = None
    if initial_velocity is not None:
        vel0 = as_array(initial_velocity, "initial_velocity", shape=xy0.shape, allow_nan=True)
    state = _State.initial(xy0, started, T)
    splines = [SplineImage(seq[k, 0], "images") for k in range(K)]
    if K > 1:
        state.spatial_A[:, started] = _spatial_affine(splines, xy0[:, started], p)
    for t in tqdm(range(T - 1), desc="tracking", disable=not progress):
        nxt = [SplineImage(seq[k, t + 1], "images") for k in range(K)]
        _advance(state, seq, splines, nxt, t, p, vel0 if t == 0 else None)
        if new_points is not None and (t + 1) % p.density_every == 0:
            _add_where_sparse(state, new_points, nxt, t + 1, p)
        splines = nxt
    return Tracks(xy=state.xy, start=state.start, end=state.end,
                  status=np.asarray(state.status, np.int64), retried=state.retried,
                  added=state.added, origin=state.origin)


def _check_params(p: TrackerParams) -> None:
    check_patch(p.patch)
    for name in ("radius", "retry_radius"):
        r = getattr(p, name)
        if isinstance(r, bool) or int(r) != r or r < 1:
            raise ValueError(f"params.{name}: expected an integer >= 1 (pixels), got {r}")
    if isinstance(p.density_every, bool) or int(p.density_every) != p.density_every \
            or p.density_every < 1:
        raise ValueError(f"params.density_every: expected an integer >= 1 (frames), got "
                         f"{p.density_every}")
    if isinstance(p.neighbours, bool) or int(p.neighbours) != p.neighbours or p.neighbours < 1:
        raise ValueError(f"params.neighbours: expected an integer >= 1 (tracks), got "
                         f"{p.neighbours}")
    as_scalar(p.max_disagreement, "params.max_disagreement", positive=True)
    as_scalar(p.min_distance, "params.min_distance", nonnegative=True)


def _advance(state: _State, seq, splines, nxt, t: int, p: TrackerParams, vel0) -> None:
    """Frame ``t`` -> ``t + 1`` for the live tracks: prediction, a step in the normal box,
    the rejected ones again in the bigger box; tracks rejected twice are lost."""
    live = np.flatnonzero(state.status == TrackStatus.ALIVE)
    live = live[state.end[live] == t]
    if not live.size:
        return
    pred, known = _predict(state.xy, live, t, p.neighbours)
    if vel0 is not None:
        v = vel0[:, live]
        has = np.isfinite(v).all(axis=(0, 2))
        pred[:, has] = state.xy[0][:, live[has]] + v[:, has]
        known |= has
    radius = np.where(known, p.radius, p.retry_radius)
    st = _step(seq, splines, nxt, t, state.xy[t][:, live], pred, radius,
               state.spatial_A[:, live], p)
    ok, new_xy, A = st.ok, st.xy, st.spatial_A
    todo = ~ok
    if todo.any():
        r2 = np.where(known[todo], p.retry_radius, 2 * p.retry_radius)
        st2 = _step(seq, splines, nxt, t, state.xy[t][:, live[todo]], pred[:, todo], r2,
                    state.spatial_A[:, live[todo]], p)
        idx = np.flatnonzero(todo)
        ok[idx[st2.ok]] = True
        new_xy[:, idx[st2.ok]] = st2.xy[:, st2.ok]
        A[:, idx[st2.ok]] = st2.spatial_A[:, st2.ok]
        state.retried[t + 1, live[idx[st2.ok]]] = True
    acc = live[ok]
    state.xy[t + 1][:, acc] = new_xy[:, ok]
    state.spatial_A[:, acc] = A[:, ok]
    state.end[acc] = t + 1
    state.status[live[~ok]] = TrackStatus.LOST


def _add_where_sparse(state: _State, new_points, nxt, t: int, p: TrackerParams) -> None:
    """Density check at frame ``t`` (Fig. 9): frame ``t``'s surface points where the live
    tracks have thinned out in the template image start new tracks."""
    K = len(nxt)
    cand = _candidates(new_points, t, K)
    if cand is None:
        return
    tmpl = p.template if K > 1 else 0
    alive_now = state.xy[t][tmpl][state.end == t]
    add = sparse_candidates(alive_now, cand[tmpl], cell=p.cell, min_per_cell=p.min_per_cell,
                            min_distance=p.min_distance)
    if add.size:
        state.append(cand[:, add], t, add)
        if K > 1:
            state.spatial_A[:, -add.size:] = _spatial_affine(nxt, cand[:, add], p)


@dataclass
class _State:
    xy: np.ndarray
    start: np.ndarray
    end: np.ndarray
    status: np.ndarray
    retried: np.ndarray
    added: np.ndarray
    origin: np.ndarray
    spatial_A: np.ndarray

    @classmethod
    def initial(cls, xy0, started, T: int) -> _State:
        """The initial points at frame 0 (the state grows when the density check adds)."""
        K, N = xy0.shape[:2]
        xy = np.full((T, K, N, 2), np.nan)
        xy[0] = np.where(started[None, :, None], xy0, np.nan)
        return cls(xy=xy, start=np.zeros(N, np.int64),
                   end=np.where(started, 0, -1).astype(np.int64),
                   status=np.where(started, TrackStatus.ALIVE, TrackStatus.NOT_STARTED),
                   retried=np.zeros((T, N), bool), added=np.zeros(N, bool),
                   origin=np.full(N, -1, np.int64),
                   spatial_A=np.broadcast_to(np.eye(2), (K, N, 2, 2)).copy())

    def append(self, new_xy, t, origin):
        K, M = new_xy.shape[:2]
        T = self.xy.shape[0]
        block = np.full((T, K, M, 2), np.nan)
        block[t] = new_xy
        self.xy = np.concatenate([self.xy, block], axis=2)
        self.start = np.concatenate([self.start, np.full(M, t)])
        self.end = np.concatenate([self.end, np.full(M, t)])
        self.status = np.concatenate([self.status, np.full(M, TrackStatus.ALIVE)])
        self.retried = np.concatenate([self.retried, np.zeros((T, M), bool)], axis=1)
        self.added = np.concatenate([self.added, np.ones(M, bool)])
        self.origin = np.concatenate([self.origin, origin])
        self.spatial_A = np.concatenate(
            [self.spatial_A, np.broadcast_to(np.eye(2), (K, M, 2, 2))], axis=1)


def _candidates(new_points, t, K):
    try:
        c = new_points[t]
    except (KeyError, IndexError):
        return None
    if c is None:
        return None
    c = as_array(c, f"new_points[{t}]", shape=(K, None, 2), allow_nan=True)
    good = np.isfinite(c).all(axis=(0, 2))
    return c[:, good] if good.any() else None


def _predict(xy, live, t, neighbours):
    """Linear prediction (K, n, 2) and whether the track had a history (n,)."""
    cur = xy[t][:, live]
    prev = xy[t - 1][:, live] if t >= 1 else np.full_like(cur, np.nan)
    known = np.isfinite(prev).all(axis=(0, 2))
    vel = np.where(known[None, :, None], cur - prev, 0.0)
    born = np.flatnonzero(~known)
    if born.size and known.sum() >= 1:
        src = np.flatnonzero(known)
        for k in range(cur.shape[0]):
            tree = cKDTree(cur[k, src])
            _, nn = tree.query(cur[k, born], k=min(neighbours, len(src)))
            nn = np.atleast_2d(nn.reshape(len(born), -1))
            vel[k, born] = np.median(vel[k, src][nn], axis=1)
        # a neighbour-based prediction is an estimate, not a history: keep the bigger box
    return cur + vel, known


def _spatial_affine(splines, xy, p: TrackerParams):
    """Affinities (K, n, 2, 2) from the template camera's patches into the others (spatial
    LSM at the start positions; identity where it fails)."""
    K, n = xy.shape[:2]
    A = np.broadcast_to(np.eye(2), (K, n, 2, 2)).copy()
    for k in range(K):
        if k == p.template:
            continue
        res = lsm(splines[p.template], splines[k], xy[p.template], xy[k], patch=p.patch,
                  geometry=p.geometry, thresholds=p.thresholds, max_iter=p.max_iter, tol=p.tol)
        A[k, res.ok] = res.A[res.ok]
    return A


@dataclass(frozen=True)
class StepResult:
    """One attempt of one temporal step for n tracks in K cameras (see :func:`track_step`).

    Attributes
    ----------
    ok : (n,) bool array
        Accepted: correlation found, every temporal LSM passed its thresholds and (K > 1)
        every spatial LSM stayed within ``max_disagreement`` of the temporal result.
    correlation_xy : (K, n, 2) array
        Best correlation positions in the next frame, px (NaN: none, or not reached).
    xy : (K, n, 2) array
        Temporal LSM results, px (NaN where the correlation or the LSM failed).
    temporal_A : (K, n, 2, 2) array
        Affine parts of the temporal LSM (NaN where not computed).
    spatial_xy : (K, n, 2) array
        Spatial LSM results (template camera matched into camera k), px; NaN for the
        template camera and where not computed.
    spatial_A : (K, n, 2, 2) array
        Spatial affinities after the step (the input's where the step failed).
    """

    ok: np.ndarray
    correlation_xy: np.ndarray
    xy: np.ndarray
    temporal_A: np.ndarray
    spatial_xy: np.ndarray
    spatial_A: np.ndarray


def track_step(frame, next_frame, xy, predicted, radius, *, params: TrackerParams | None = None,
               spatial_A=None) -> StepResult:
    """One temporal step of the tracker (Fig. 7), exactly as :func:`track_points` makes it.

    Correlation search around the prediction, temporal LSM from the best correlation
    position, then (K > 1) the spatial LSM check; no retry in a bigger box (call again with
    ``params.retry_radius``).

    Parameters
    ----------
    frame, next_frame : (K, H, W) arrays
        The K cameras' images at frames t and t + 1.
    xy : (K, n, 2) array
        Positions at frame t, px.
    predicted : (K, n, 2) array
        Predicted positions at frame t + 1, px.
    radius : int or (n,) int array
        Half-width of the search box, px.
    params : TrackerParams, optional
    spatial_A : (K, n, 2, 2) array, optional
        Spatial affinities from the template camera into each camera (default: identity).

    Returns
    -------
    StepResult
    """
    p = params or TrackerParams()
    check_patch(p.patch)
    if len(frame) != len(next_frame):
        raise ValueError(f"next_frame: expected {len(frame)} images (one per camera), got "
                         f"{len(next_frame)}")
    seq = as_sequences([[a, b] for a, b in zip(frame, next_frame)])      # (K, 2, H, W)
    K = seq.shape[0]
    cur = as_array(xy, "xy", shape=(K, None, 2))
    pred = as_array(predicted, "predicted", shape=cur.shape)
    n = cur.shape[1]
    r = np.broadcast_to(np.asarray(radius), (n,))
    if r.size and (r.dtype == bool or np.any(r != np.rint(r)) or np.any(r < 1)):
        raise ValueError(f"radius: expected integers >= 1 (pixels), got {radius}")
    if spatial_A is None:
        spatial_A = np.broadcast_to(np.eye(2), (K, n, 2, 2))
    A = as_array(spatial_A, "spatial_A", shape=(K, n, 2, 2))
    splines = [SplineImage(seq[k, 0], "frame") for k in range(K)]
    nxt = [SplineImage(seq[k, 1], "next_frame") for k in range(K)]
    return _step(seq, splines, nxt, 0, cur, pred, r.astype(np.int64), A, p)


def _step(seq, splines, nxt, t, cur, pred, radius, spatial_A, p: TrackerParams) -> StepResult:
    """One attempt: correlation + temporal LSM per camera, spatial LSM."""
    K, n = cur.shape[:2]
    new_xy = np.full((K, n, 2), np.nan)
    ok = np.ones(n, bool)
    A_out = np.array(spatial_A, float)
    corr_xy = np.full((K, n, 2), np.nan)
    tA = np.full((K, n, 2, 2), np.nan)
    sp_xy = np.full((K, n, 2), np.nan)

    def result():
        return StepResult(ok=ok, correlation_xy=corr_xy, xy=new_xy, temporal_A=tA,
                          spatial_xy=sp_xy, spatial_A=A_out)

    for k in range(K):
        found = np.zeros(n, bool)
        for r in np.unique(radius):
            sel = np.flatnonzero((radius == r) & ok)
            if sel.size == 0:
                continue
            c = correlation_search(seq[k, t], seq[k, t + 1], cur[k, sel], pred[k, sel],
                                   patch=p.patch, radius=int(r))
            good = c.status == CorrelationStatus.OK
            corr_xy[k, sel[good]] = c.xy[good]
            found[sel[good]] = True
        ok &= found
        sel = np.flatnonzero(ok)
        if sel.size == 0:
            return result()
        res = lsm(splines[k], nxt[k], cur[k, sel], corr_xy[k, sel], patch=p.patch,
                  geometry=p.geometry, thresholds=p.thresholds, max_iter=p.max_iter, tol=p.tol)
        tA[k, sel] = res.A
        ok[sel[~res.ok]] = False
        new_xy[k, sel[res.ok]] = res.xy[res.ok]
    if K == 1 or not ok.any():
        return result()
    tm = p.template
    for k in range(K):
        if k == tm:
            continue
        sel = np.flatnonzero(ok)
        if sel.size == 0:
            break
        res = lsm(nxt[tm], nxt[k], new_xy[tm, sel], new_xy[k, sel], patch=p.patch,
                  geometry=p.geometry, initial_A=spatial_A[k, sel], thresholds=p.thresholds,
                  max_iter=p.max_iter, tol=p.tol)
        sp_xy[k, sel] = res.xy
        d = np.linalg.norm(res.xy - new_xy[k, sel], axis=1)
        agree = res.ok & (d <= p.max_disagreement)
        ok[sel[~agree]] = False
        A_out[k, sel[agree]] = res.A[agree]
    return result()
