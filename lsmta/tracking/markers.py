"""Small-scale marker tracking in video (Davis 2002, thesis section 5.1).

Per frame: the image is stabilised by the dominant translation between the last good
frame and this one (phase correlation, ``cv2.phaseCorrelate``, refined by the median LK
displacement of a lattice of points); every marker is tracked
with pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) from its stabilised position;
a marker whose first search fails (LK status, forward-backward error or patch error over
a threshold) is searched a second time from the position predicted by its own image
velocity; a blurred frame (variance of the Laplacian well below the running median) is
skipped and the markers are searched again in the next frames, from the last good frame.
Lost markers stay lost unless the caller (re)starts them with ``seeds`` (e.g. a marker
identified again by hand when it reappears); there is no automatic re-acquisition.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import cv2
import numpy as np

from .._validate import as_array, as_int, as_scalar


class MarkerStatus(enum.IntEnum):
    """What happened to a marker in a frame."""

    TRACKED = 0        #: found by the first search (frame 0: the start position)
    SECOND_SEARCH = 1  #: found by the search from its own velocity prediction
    BLURRED = 2        #: the frame was skipped as blurred
    LOST = 3           #: not found, or not being tracked
    SEEDED = 4         #: (re)started from ``seeds``



@dataclass(frozen=True)
class MarkerTracks:
    """Result of :func:`track_markers`.

    Attributes
    ----------
    xy : (T, M, 2) array
        Marker positions, px; NaN when lost or in a skipped (blurred) frame.
    status : (T, M) int array
        :class:`MarkerStatus` codes.
    shift : (T, 2) array
        Dominant translation of each frame relative to the previous frame, px (summed
        over skipped frames at the next good one); NaN for skipped frames, 0 for frame 0.
    sharpness : (T,) array
        Variance of the Laplacian of each frame.
    blurred : (T,) bool array
        Frames skipped as blurred.
    """

    xy: np.ndarray
    status: np.ndarray
    shift: np.ndarray
    sharpness: np.ndarray
    blurred: np.ndarray


def _as_images(images) -> np.ndarray:
    arr = np.asarray(images)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)):
        raise TypeError(f"images: expected a real numeric array, got dtype {arr.dtype}")
    if arr.ndim != 3 or min(arr.shape) < 1:
        raise ValueError(f"images: expected a (T, H, W) array of grey images, got shape "
                         f"{arr.shape}")
    if arr.shape[1] < 32 or arr.shape[2] < 32:
        raise ValueError(f"images: expected images of at least 32 x 32 px, got "
                         f"{arr.shape[1:]}")
    if arr.dtype == np.uint8:
        return arr
    if not np.isfinite(arr).all():
        raise ValueError("images: contains non-finite values")
    return np.clip(np.round(arr), 0, 255).astype(np.uint8)


def sharpness(image) -> float:
    """Variance of the Laplacian of a grey image after a 1.5 px Gaussian (which keeps
    pixel noise from dominating); low for blurred frames."""
    smooth = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 1.5)
    return float(cv2.Laplacian(smooth, cv2.CV_32F).var())


def dominant_shift(a, b, *, grid: int = 8) -> np.ndarray:
    """Dominant translation (dx, dy) px taking grey image ``a`` to image ``b``.

    Phase correlation (``cv2.phaseCorrelate``, Hanning window) on the images reduced by
    2 gives a coarse shift; the median of pyramidal LK displacements of a
    ``grid`` x ``grid`` lattice of points started from it (forward-backward error
    < 0.5 px) refines it. Falls back to the coarse shift when no lattice point passes.
    """
    a8 = np.asarray(a, np.uint8)
    b8 = np.asarray(b, np.uint8)
    ha, hb = cv2.pyrDown(a8.astype(np.float32)), cv2.pyrDown(b8.astype(np.float32))
    win = cv2.createHanningWindow(ha.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(ha, hb, win)
    coarse = 2.0 * np.array([dx, dy])
    H, W = a8.shape
    gx, gy = np.meshgrid(np.linspace(0.15, 0.85, grid) * (W - 1),
                         np.linspace(0.15, 0.85, grid) * (H - 1))
    p0 = np.stack([gx.ravel(), gy.ravel()], axis=1)
    lk = dict(winSize=(21, 21), maxLevel=2,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    p1, ok, fb, _ = _lk(a8, b8, p0, p0 + coarse, lk)
    ok &= fb < 0.5
    if not ok.any():
        return coarse
    return np.median(p1[ok] - p0[ok], axis=0)


def refine_centroid(image, xy, *, radius: int = 2, iterations: int = 2) -> np.ndarray:
    """Move each position to the brightness-weighted centroid of the bright dot around it:
    weights are the grey values above the window's median, in a ``(2 radius + 1)``
    square window; windows reaching outside the image leave the position unchanged."""
    img = np.asarray(image, np.float64)
    H, W = img.shape
    p = np.array(xy, dtype=float)
    off = np.arange(-radius, radius + 1)
    for _ in range(iterations):
        c = np.round(p).astype(int)
        ok = ((c[:, 0] >= radius) & (c[:, 0] < W - radius) & (c[:, 1] >= radius)
              & (c[:, 1] < H - radius))
        if not ok.any():
            break
        ix = c[ok, 0, None, None] + off[None, None, :]
        iy = c[ok, 1, None, None] + off[None, :, None]
        win = img[iy, ix]                                    # (n, k, k)
        w = np.clip(win - np.median(win, axis=(1, 2), keepdims=True), 0, None)
        tot = w.sum(axis=(1, 2))
        good = tot > 0
        gx = (w * np.broadcast_to(ix, w.shape)).sum(axis=(1, 2))
        gy = (w * np.broadcast_to(iy, w.shape)).sum(axis=(1, 2))
        sel = np.flatnonzero(ok)[good]
        p[sel, 0] = gx[good] / tot[good]
        p[sel, 1] = gy[good] / tot[good]
    return p


def _lk(prev, nxt, p0, guess, lk):
    p1, st, err = cv2.calcOpticalFlowPyrLK(
        prev, nxt, p0.astype(np.float32).reshape(-1, 1, 2),
        guess.astype(np.float32).reshape(-1, 1, 2), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(
        nxt, prev, p1, p0.astype(np.float32).reshape(-1, 1, 2).copy(),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    p1 = p1.reshape(-1, 2).astype(float)
    fb = np.linalg.norm(back.reshape(-1, 2) - p0, axis=1)
    return p1, (st.ravel() == 1) & (st2.ravel() == 1), fb, err.ravel()


@dataclass(frozen=True)
class MarkerTrackingParams:
    """Settings of :func:`track_markers`.

    Attributes
    ----------
    window : int
        LK window side, px (odd).
    levels : int
        LK pyramid levels above the full image.
    fb_threshold : float
        Largest forward-backward error (px) of an accepted search.
    max_error : float
        Largest LK patch error (mean absolute grey difference) of an accepted search.
    stabilise : bool
        Start each search from the position moved by the frame's dominant translation.
    second_search : bool
        Search failed markers again at position + shift + their own image velocity.
    blur_retry : int
        Consecutive blurred frames skipped at most (0: never skip).
    blur_ratio : float
        A frame is blurred when its sharpness is below ``blur_ratio`` times the median
        sharpness of the last ``blur_history`` good frames.
    blur_history : int
        Good frames whose median sharpness the blur test compares with.
    refine : bool
        Move every found and every start position to the dot's brightness centroid
        (:func:`refine_centroid`), so that a start error or LK drift does not persist.
    max_jump : float
        Largest distance (px) between a search's start and its result; a longer jump
        is taken as a jump to a neighbouring marker and the search fails.
    """

    window: int = 11
    levels: int = 2
    fb_threshold: float = 0.5
    max_error: float = 12.0
    stabilise: bool = True
    second_search: bool = True
    blur_retry: int = 3
    blur_ratio: float = 0.5
    blur_history: int = 10
    refine: bool = True
    max_jump: float = 4.0

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "window", as_int(self.window, "window", minimum=3, odd=True, unit="pixels"))
        set_(self, "levels", as_int(self.levels, "levels", minimum=0))
        set_(self, "blur_retry", as_int(self.blur_retry, "blur_retry", minimum=0))
        set_(self, "blur_history", as_int(self.blur_history, "blur_history"))
        for name in ("fb_threshold", "max_error", "max_jump"):
            set_(self, name, as_scalar(getattr(self, name), name, positive=True))
        set_(self, "blur_ratio", as_scalar(self.blur_ratio, "blur_ratio", nonnegative=True))


def track_markers(images, initial_xy, *, seeds=None, shifts=None, sharpness=None,
                  params: MarkerTrackingParams | None = None) -> MarkerTracks:
    """Track markers through a grey video.

    Parameters
    ----------
    images : (T, H, W) array
        Grey frames (uint8, or numbers in 0..255).
    initial_xy : (M, 2) array
        Marker positions in frame 0, px; NaN for markers not tracked.
    seeds : (T, M, 2) array, optional
        Positions (px, NaN elsewhere) at which a marker that is not being tracked starts
        again in that frame (not used in skipped blurred frames).
    shifts : (T, 2) array, optional
        The dominant translations of an earlier run on the same ``images`` with the same
        ``params`` and ``stabilise`` on (its :attr:`MarkerTracks.shift`), px; shifts from
        other images or a run without stabilisation are used as given, wrongly. Used where
        finite instead of being
        measured again (the blur test skips the same frames, so each is measured from the
        same reference frame); the result is the same, without the phase correlations
        (a third of the tracker's time on notebook 15's videos).
    sharpness : (T,) array, optional
        The frames' sharpness from an earlier run on the same ``images`` (its
        :attr:`MarkerTracks.sharpness`), used instead of being measured again (the same
        numbers: :func:`sharpness` of each frame).
    params : MarkerTrackingParams, optional
        The searches, the blur test and the centroid refinement (default:
        ``MarkerTrackingParams()``).

    Returns
    -------
    MarkerTracks
    """
    p = MarkerTrackingParams() if params is None else params
    if not isinstance(p, MarkerTrackingParams):
        raise TypeError(f"params: expected a MarkerTrackingParams, got {type(p).__name__}")
    imgs = _as_images(images)
    T = len(imgs)
    p0 = as_array(initial_xy, "initial_xy", shape=(None, 2), allow_nan=True)
    search = _Search(
        lk=dict(winSize=(p.window, p.window), maxLevel=p.levels,
                criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)),
        fb_threshold=p.fb_threshold, max_error=p.max_error, max_jump=p.max_jump,
        second_search=bool(p.second_search), refine=bool(p.refine))
    if seeds is not None:
        seeds = as_array(seeds, "seeds", shape=(T, len(p0), 2), allow_nan=True)
    if shifts is not None:
        shifts = as_array(shifts, "shifts", shape=(T, 2), allow_nan=True)
    if sharpness is not None:
        sharpness = as_array(sharpness, "sharpness", shape=(T,)).copy()
        if (sharpness < 0).any():
            raise ValueError("sharpness: expected non-negative numbers (a variance of the "
                             "frame's Laplacian)")
    state = _State.initial(imgs, p0, search.refine, sharpness)
    for t in range(1, T):
        if _blurred(state, t, p.blur_retry, p.blur_ratio, p.blur_history):
            continue
        if not p.stabilise:
            shift = np.zeros(2)
        elif shifts is not None and np.isfinite(shifts[t]).all():
            shift = shifts[t].copy()
        else:
            shift = dominant_shift(imgs[state.ref], imgs[t])
        state.shift[t] = shift
        if state.alive.any():
            _follow(state, imgs, t, shift, search)
        state.ref = t
        _seed(state, t, seeds, imgs[t], search.refine)
    return MarkerTracks(xy=state.xy, status=state.status, shift=state.shift,
                        sharpness=state.sharp, blurred=state.blurred)


@dataclass(frozen=True)
class _Search:
    """How a marker is searched (see :func:`track_markers`)."""

    lk: dict
    fb_threshold: float
    max_error: float
    max_jump: float
    second_search: bool
    refine: bool


@dataclass
class _State:
    """The result arrays, filled frame by frame, and the markers being tracked."""

    xy: np.ndarray          # (T, M, 2)
    status: np.ndarray      # (T, M)
    shift: np.ndarray       # (T, 2)
    sharp: np.ndarray       # (T,)
    blurred: np.ndarray     # (T,)
    alive: np.ndarray       # (M,) being tracked
    pos: np.ndarray         # (M, 2) last position
    vel: np.ndarray         # (M, 2) image velocity per frame, stabilised
    ref: int = 0            # the last good frame
    good: list = field(default_factory=list)   # sharpness of the good frames

    @classmethod
    def initial(cls, imgs, p0, refine: bool, sharp=None) -> _State:
        T, M = len(imgs), len(p0)
        alive = np.isfinite(p0).all(axis=1)
        pos = p0.copy()
        if refine and alive.any():
            pos[alive] = refine_centroid(imgs[0], pos[alive])
        if sharp is None:
            sharp = np.array([sharpness(im) for im in imgs])
        st = cls(xy=np.full((T, M, 2), np.nan),
                 status=np.full((T, M), MarkerStatus.LOST, dtype=np.int64),
                 shift=np.full((T, 2), np.nan), sharp=sharp, blurred=np.zeros(T, bool),
                 alive=alive, pos=pos, vel=np.zeros((M, 2)), good=[sharp[0]])
        st.xy[0, alive] = pos[alive]
        st.status[0, alive] = MarkerStatus.TRACKED
        st.shift[0] = 0.0
        return st


def _blurred(state: _State, t: int, blur_retry: int, ratio: float, history: int) -> bool:
    """Skip frame ``t`` as blurred (sharpness well below the recent good frames') while
    fewer than ``blur_retry`` frames have been skipped; otherwise count it as good."""
    if t - state.ref <= blur_retry and state.sharp[t] < ratio * np.median(state.good[-history:]):
        state.blurred[t] = True
        state.status[t] = MarkerStatus.BLURRED
        return True
    state.good.append(state.sharp[t])
    return False


def _lk_search(prev, nxt, start, guess, search: _Search):
    """LK from ``start`` with the initial ``guess``; found and accepted (LK status,
    forward-backward error, patch error, jump from the guess)."""
    p1, ok, fb, err = _lk(prev, nxt, start, guess, search.lk)
    ok &= (fb < search.fb_threshold) & (err < search.max_error)
    ok &= np.linalg.norm(p1 - guess, axis=1) < search.max_jump
    return p1, ok


def _follow(state: _State, imgs, t: int, shift, search: _Search) -> None:
    """Search the tracked markers in frame ``t`` from the last good frame: first at the
    stabilised position, then (failed ones) at the position predicted by their velocity."""
    H, W = imgs.shape[1:]
    gap = t - state.ref
    idx = np.flatnonzero(state.alive)
    pos = state.pos[idx]
    p1, ok = _lk_search(imgs[state.ref], imgs[t], pos, pos + shift, search)
    st = np.where(ok, MarkerStatus.TRACKED, MarkerStatus.LOST)
    if search.second_search and not ok.all():
        bad = np.flatnonzero(~ok)
        q1, ok2 = _lk_search(imgs[state.ref], imgs[t], pos[bad],
                             pos[bad] + shift + state.vel[idx[bad]] * gap, search)
        p1[bad[ok2]] = q1[ok2]
        ok[bad[ok2]] = True
        st[bad[ok2]] = MarkerStatus.SECOND_SEARCH
    ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= W - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= H - 1)
    if search.refine and ok.any():
        p1[ok] = refine_centroid(imgs[t], p1[ok])
    st[~ok] = MarkerStatus.LOST
    found, lost = idx[ok], idx[~ok]
    state.vel[found] = (p1[ok] - state.pos[found] - shift) / gap
    state.pos[found] = p1[ok]
    state.alive[lost] = False
    state.pos[lost] = np.nan
    state.xy[t, found] = p1[ok]
    state.status[t, idx] = st


def _seed(state: _State, t: int, seeds, image, refine: bool) -> None:
    """(Re)start the markers not being tracked that have a seed in frame ``t``."""
    if seeds is None:
        return
    new = ~state.alive & np.isfinite(seeds[t]).all(axis=1)
    state.alive[new] = True
    state.pos[new] = refine_centroid(image, seeds[t, new]) if refine else seeds[t, new]
    state.vel[new] = 0.0
    state.xy[t, new] = state.pos[new]
    state.status[t, new] = MarkerStatus.SEEDED


def find_blobs(image, *, sigma: float = 2.5, min_strength: float = 20.0,
               roundness: float = 0.5, spacing: int = 9) -> np.ndarray:
    """Small bright round blobs in a grey image (markers, LEDs), to sub-pixel precision.

    A blob is a local maximum of the blob strength ``-sigma^2 lambda_1`` (``lambda_1`` the
    smaller-magnitude eigenvalue of the Hessian of the image smoothed by ``sigma``: bright,
    round blobs of radius about ``1.4 sigma`` px), both eigenvalues negative and in a ratio
    of at least ``roundness``, strongest in its ``spacing`` square and above
    ``min_strength`` (grey levels: about the blob's contrast to its surrounding). Positions
    are refined to the brightness-weighted centroid (:func:`refine_centroid`) in a window of
    half-width ``ceil(2 sigma)``, about three blob radii.

    Parameters
    ----------
    image : (H, W) array
        Grey levels.
    sigma, min_strength, roundness, spacing
        As above (px, grey levels, ratio, px).

    Returns
    -------
    (M, 2) array
        Blob positions, px (x, y), strongest first.
    """
    grey = as_array(image, "image", finite=True)
    if grey.ndim != 2:
        raise ValueError(f"image: expected an (H, W) grey image, got shape {grey.shape}")
    xy, strength = _blobs(grey.astype(np.float64), sigma, min_strength, roundness, spacing)
    xy = xy[np.argsort(-strength, kind="stable")]
    return refine_centroid(grey, xy, radius=int(np.ceil(2 * sigma))) if len(xy) else xy


@dataclass(frozen=True, eq=False)
class SplitBlobs:
    """Result of :func:`split_merged_blobs`.

    Attributes
    ----------
    xy : (N, 2) array
        The dots, px: every blob once, a merged blob as its two dots.
    spread : (N,) array
        The blob each dot comes from, its brightness spread along its long axis beyond that
        across it, as the distance of two equal dots that would spread so,
        ``2 sqrt(lambda_max - lambda_min)`` (the eigenvalues of its brightness-weighted
        covariance), px: about 1 px or less for a round dot, the dots' distance for two
        merged ones; NaN when not measured (a window reaching outside the image, or no
        brightness above its median: the blob left as it was).
    brightness : (N,) array
        Its grey levels above its window's median, summed over the blob's window, half
        of it for each dot of a split blob (NaN when not measured): two merged dots left
        as one blob carry 1.9-2.1 times one dot's when 1.5 px apart or less, 1.3-1.6
        times when 2.5-3 px apart (the window cuts off the farther tails).
    split : (N,) bool array
        The dot is one of a merged blob's two.
    """

    xy: np.ndarray
    spread: np.ndarray
    brightness: np.ndarray
    split: np.ndarray


def split_merged_blobs(image, xy, *, radius: int = 3, min_separation: float = 2.5,
                       max_dip: float = 0.9, dip_noise: float = 3.0,
                       same_px: float = 1.0, iterations: int = 2) -> SplitBlobs:
    """Each blob once, and two touching dots that merged into one blob told apart.

    Two dots a few pixels apart make one elongated blob: :func:`find_blobs` finds it once or
    twice (a strength peak on each lobe, both refined to the whole blob's centroid, between
    the two dots). Here a blob within ``same_px`` of a stronger one (earlier in ``xy``) is
    that blob again and dropped; then each blob's brightness (grey levels above its window's
    median, as :func:`refine_centroid`) in a ``(2 radius + 1)`` square gives its covariance,
    eigenvalues ``lambda_min <= lambda_max``. Two equal dots ``s`` px apart spread by
    ``s**2 / 4`` along their axis beyond a single dot's spread across it, so
    ``s = 2 sqrt(lambda_max - lambda_min)``. A blob is split when ``s >= min_separation``
    and its brightness profile along the long axis (summed over a 2 px wide strip) has two
    maxima, the lower at least half the higher, with a dip between them below ``max_dip``
    times the lower one and deeper than ``dip_noise`` times the profile's noise (the grey
    levels' median absolute deviation in a ring up to ``2 radius + 1`` px around the window,
    scaled to the strip's sum): one elongated dot (stretched or motion-blurred) spreads too
    but has one maximum or a flat top, on which noise alone makes shallow dips. The dip
    decides, not ``s``: dots of sigma 1.3 px 2.5-3 px apart stay one blob, 3.3 px apart
    split when bright (110 grey levels), about half the time when dim (40). A split blob
    becomes two dots ``s / 2`` either side of its centroid along the long axis, each moved
    ``iterations`` times to the centroid of the window's pixels nearer to it. A blob with
    another within ``radius`` px is not split, nor one whose halves would fall within
    ``min_separation`` of another blob (three or more dots crowd there).

    Parameters
    ----------
    image : (H, W) array
        Grey levels.
    xy : (N, 2) array
        Blobs, px, strongest first (:func:`find_blobs`).
    radius : int
        Half-width of the window, px (:func:`find_blobs` refines in ``ceil(2 sigma)``).
    min_separation : float
        Smallest spread ``s`` that lets a blob be split, px (a round dot spreads up to about
        1.5 px); necessary only, the dip decides (above).
    max_dip : float
        Largest ratio of the profile's dip to its lower maximum that splits a blob (0 to
        1; two dots of sigma 1.3 px 3.5 px apart dip to about 0.8).
    dip_noise : float
        Smallest depth of the dip below the lower maximum, in units of the profile's noise.
    same_px : float
        Blobs closer than this are one, px.
    iterations : int
        Passes moving the two dots of a split blob.

    Returns
    -------
    SplitBlobs
        The dots in the order of the blobs they come from.
    """
    grey, pts, radius, min_separation, max_dip, dip_noise, same_px, iterations = \
        _split_args(image, xy, radius, min_separation, max_dip, dip_noise, same_px, iterations)
    pts = _each_blob_once(pts, same_px)
    gap = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.fill_diagonal(gap, np.inf)
    alone = gap.min(axis=1, initial=np.inf) > radius
    out, spread, bright, split = [], [], [], []
    for i, (p, single) in enumerate(zip(pts, alone)):
        two, s, tot = _split_one(grey, p, radius, min_separation if single else np.inf,
                                 max_dip, dip_noise, iterations)
        others = np.delete(pts, i, axis=0)
        if two is not None and len(others) and \
                np.linalg.norm(two[:, None] - others[None], axis=2).min() < min_separation:
            two = None                          # a half on or between other blobs' dots
        n = 1 if two is None else 2
        out.append(p[None] if two is None else two)
        spread += [s] * n
        bright += [tot / n] * n                 # each half of a split blob carries half
        split += [n == 2] * n
    if not out:
        return SplitBlobs(xy=np.zeros((0, 2)), spread=np.zeros(0), brightness=np.zeros(0),
                          split=np.zeros(0, bool))
    return SplitBlobs(xy=np.concatenate(out), spread=np.array(spread, float),
                      brightness=np.array(bright, float), split=np.array(split))


def _split_args(image, xy, radius, min_separation, max_dip, dip_noise, same_px, iterations):
    """The arguments of :func:`split_merged_blobs`, checked."""
    grey = as_array(image, "image", finite=True)
    if grey.ndim != 2:
        raise ValueError(f"image: expected an (H, W) grey image, got shape {grey.shape}")
    max_dip = as_scalar(max_dip, "max_dip", positive=True)
    if max_dip > 1:
        raise ValueError(f"max_dip: expected a ratio in (0, 1], got {max_dip}")
    return (grey, as_array(xy, "xy", shape=(None, 2)), as_int(radius, "radius", minimum=1),
            as_scalar(min_separation, "min_separation", positive=True), max_dip,
            as_scalar(dip_noise, "dip_noise", nonnegative=True),
            as_scalar(same_px, "same_px", nonnegative=True),
            as_int(iterations, "iterations", minimum=0))


def _each_blob_once(pts, same_px):
    """Blobs ``pts`` (N, 2) px without those within ``same_px`` of an earlier one."""
    keep = []
    for i in range(len(pts)):
        if not keep or np.linalg.norm(pts[keep] - pts[i], axis=1).min() >= same_px:
            keep.append(i)
    return pts[keep]


def _split_one(grey, p, radius, min_separation, max_dip, dip_noise, iterations):
    """One blob at ``p`` (2,) px: its two dots (2, 2) px or None (not split), its spread px
    and its brightness (NaN, NaN when its window leaves the image or holds nothing above
    its median); see :func:`split_merged_blobs`."""
    c = np.round(p).astype(int)
    H, W = grey.shape
    if not (radius <= c[0] < W - radius and radius <= c[1] < H - radius):
        return None, np.nan, np.nan
    win = grey[c[1] - radius:c[1] + radius + 1, c[0] - radius:c[0] + radius + 1]
    med = np.median(win)
    w2 = np.clip(win - med, 0, None)
    noise = _noise(grey, c, radius)
    tot = float(w2.sum())
    if not tot > 0:
        return None, np.nan, np.nan
    off = np.arange(-radius, radius + 1, dtype=float)
    g = np.stack([np.broadcast_to(off[None, :] + c[0], win.shape).ravel(),
                  np.broadcast_to(off[:, None] + c[1], win.shape).ravel()], axis=1)
    w = w2.ravel()
    m = w @ g / tot
    d = g - m
    lam, vec = np.linalg.eigh((d * w[:, None]).T @ d / tot)
    s = 2 * np.sqrt(max(lam[1] - lam[0], 0.0))
    if s < min_separation or not _two_maxima(w2, m - (c - radius), vec[:, 1], radius,
                                             max_dip, dip_noise * noise):
        return None, s, tot
    two = m + np.outer([-0.5 * s, 0.5 * s], vec[:, 1])
    for _ in range(iterations):
        near = np.linalg.norm(g[:, None] - two[None], axis=2).argmin(axis=1)
        for j in range(2):
            wj = w * (near == j)
            if wj.sum() > 0:
                two[j] = wj @ g / wj.sum()
    return two, s, tot


def _noise(grey, c, radius):
    """Grey-level noise of one pixel around the window of half-width ``radius`` at ``c``
    (2,) integer px: 1.4826 times the median absolute deviation of the ring of pixels up
    to ``2 radius + 1`` px from ``c`` outside the window (clipped to the image; the window
    itself, mostly the blob, would measure the blob)."""
    R = 2 * radius + 1
    H, W = grey.shape
    y0, x0 = max(c[1] - R, 0), max(c[0] - R, 0)
    big = grey[y0:c[1] + R + 1, x0:c[0] + R + 1]
    yy, xx = np.mgrid[y0:y0 + big.shape[0], x0:x0 + big.shape[1]]
    ring = big[(np.abs(yy - c[1]) > radius) | (np.abs(xx - c[0]) > radius)]
    return float(1.4826 * np.median(np.abs(ring - np.median(ring))))


def _two_maxima(w2, m, axis, radius, max_dip, min_depth):
    """Whether the brightness ``w2`` (2 r + 1, 2 r + 1) of a window, profiled along unit
    ``axis`` (2,) through its centroid ``m`` (2,) (window px; bilinear samples every half
    px, summed across a 2 px strip of five samples), has two maxima, the lower at least
    half the higher, with a dip between them below ``max_dip`` times the lower one and
    more than ``min_depth`` (grey levels of one pixel's noise, scaled here to the strip's
    sum by the square root of its samples) below it."""
    t = np.arange(-radius, radius + 0.25, 0.5)
    u = np.arange(-1.0, 1.25, 0.5)
    across = np.array([-axis[1], axis[0]])
    pos = m + t[:, None, None] * axis + u[None, :, None] * across     # (T, U, 2) x, y
    prof = _bilinear(w2, pos).sum(axis=1)
    peaks = np.flatnonzero((prof[1:-1] > prof[:-2]) & (prof[1:-1] >= prof[2:])) + 1
    if len(peaks) < 2:
        return False
    a, b = np.sort(peaks[np.argsort(prof[peaks])[-2:]])
    low, dip = min(prof[a], prof[b]), prof[a:b + 1].min()
    return bool(dip < max_dip * low and low - dip > min_depth * np.sqrt(len(u))
                and low >= 0.5 * max(prof[a], prof[b]))


def _bilinear(img, pos):
    """``img`` (H, W) at ``pos`` (..., 2) x, y px, bilinearly (0 outside)."""
    H, W = img.shape
    pad = np.pad(img, 1)
    x, y = pos[..., 0] + 1, pos[..., 1] + 1
    inside = (x >= 0) & (x <= W + 1) & (y >= 0) & (y <= H + 1)
    x, y = np.clip(x, 0, W + 1), np.clip(y, 0, H + 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), W), np.minimum(np.floor(y).astype(int), H)
    fx, fy = x - x0, y - y0
    v = (pad[y0, x0] * (1 - fx) * (1 - fy) + pad[y0, x0 + 1] * fx * (1 - fy)
         + pad[y0 + 1, x0] * (1 - fx) * fy + pad[y0 + 1, x0 + 1] * fx * fy)
    return np.where(inside, v, 0.0)


def _blobs(grey, sigma, min_strength, roundness, spacing):
    """Candidate blob centres (integer px) and their strengths (see :func:`find_blobs`)."""
    sigma = as_scalar(sigma, "sigma", positive=True)
    as_int(spacing, "spacing", minimum=1)
    b = cv2.GaussianBlur(grey, (0, 0), sigma)
    gxx = cv2.Sobel(b, cv2.CV_64F, 2, 0, ksize=3)
    gyy = cv2.Sobel(b, cv2.CV_64F, 0, 2, ksize=3)
    gxy = cv2.Sobel(b, cv2.CV_64F, 1, 1, ksize=3)
    half = np.sqrt((gxx - gyy) ** 2 / 4 + gxy ** 2)
    l1 = (gxx + gyy) / 2 + half                      # the larger (less negative) eigenvalue
    l2 = (gxx + gyy) / 2 - half
    round_ = (l1 < 0) & (l1 / np.minimum(l2, -1e-12) >= roundness)
    strength = np.where(round_, -l1 * sigma ** 2, 0.0)
    peak = (strength == cv2.dilate(strength, np.ones((spacing, spacing)))) & \
        (strength > min_strength)
    y, x = np.nonzero(peak)
    return np.stack([x, y], axis=1).astype(float), strength[y, x]


def find_markers(image, *, sigma: float = 2.5, min_strength: float = 20.0,
                 min_dip: float = 20.0, roundness: float = 0.5, min_skin: float = 60.0,
                 max_hue: float = 25.0, spacing: int = 9) -> np.ndarray:
    """Skin markers in a colour image: small round blobs, brighter and greyer than the skin
    around them.

    A candidate is a blob of the grey image (:func:`find_blobs`). It is kept when its
    saturation lies at least ``min_dip`` below the mean of a 17 px square around it, and that
    surrounding looks like skin (saturation above ``min_skin``, hue below ``max_hue``,
    OpenCV's 0-180 hue scale).
    Positions are refined to the brightness-weighted centroid (:func:`refine_centroid`) in a
    window of half-width ``ceil(2 sigma)``, about three blob radii (so that the window's
    median, the centroid's zero, is the surrounding).

    Parameters
    ----------
    image : (H, W, 3) uint8 array
        A BGR frame (OpenCV's order).
    sigma, min_strength, min_dip, roundness, min_skin, max_hue
        As above (px, grey levels, saturation units, ratio, saturation, hue).
    spacing : int
        Side of the square in which a candidate must be the strongest, px.

    Returns
    -------
    (M, 2) array
        Marker positions, px (x, y).
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"image: expected an (H, W, 3) uint8 BGR image, got {img.dtype} "
                         f"{img.shape}")
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float64)
    cand, _ = _blobs(grey, sigma, min_strength, roundness, spacing)
    x, y = cand[:, 0].astype(int), cand[:, 1].astype(int)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV).astype(np.float64)
    sat = cv2.GaussianBlur(hsv[..., 1], (0, 0), 1.0)
    ring, hue = cv2.blur(sat, (17, 17)), cv2.blur(hsv[..., 0], (17, 17))
    keep = ((ring[y, x] - sat[y, x] > min_dip) & (ring[y, x] > min_skin)
            & (hue[y, x] < max_hue))
    xy = np.stack([x[keep], y[keep]], axis=1).astype(float)
    return refine_centroid(grey, xy, radius=int(np.ceil(2 * sigma))) if len(xy) else xy
