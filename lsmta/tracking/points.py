"""LSMTA point and surface tracking in image space (D'Apuzzo 2000, Section 2.3, Figs. 6-9),
with drift-free anchored templates and recovery of lost points (beyond the paper).

*Anchored templates* (Matthews, Ishikawa & Baker 2004, "The template update problem").
The paper matches frame ``t``'s patch into frame ``t + 1``; each match errs a little and the
errors add up, a random walk of the position (``anchor="previous"`` keeps that). Here
every track keeps, per camera, its *first template* (its patch in its first frame, with the
affinity ``A`` accumulated since; :mod:`~lsmta.tracking.templates`) and matches it into
every new frame; the previous frame's solution is only the start. From frame ``t`` to
``t + 1``, for every track and camera:

1. *prediction*: ``x_t + (x_t - x_{t-1})`` (linear, from the trajectory); a track without
   history takes the median image velocity of its ``neighbours`` nearest tracks, and a
   track missing since frame ``e`` is predicted ``t + 1 - e`` steps ahead;
2. *anchored temporal LSM* of the first template from the prediction, started with ``A``;
3. where it fails, the track's *fallback template*: its patch in frame ``t`` (the last frame
   its first template matched, so the fallback starts where no drift has accumulated), or
   the fallback it already holds; matched from the prediction, then, where that fails, from
   the best *correlation* position in a box of half-width ``radius`` around the prediction
   (the paper's step 2). A track without history, after its match from the prediction, is
   searched in the box with its first template. With ``return_to_first`` a track the
   fallback found tries its first template again from there;
4. where all that fails (beyond the paper): a fallback template anchored before frame
   ``t`` is replaced by the track's patch in frame ``t``, and a *coarse-to-fine
   prediction* is made: the track's patch in its last tracked frame is matched into frame
   ``t + 1`` at pyramid level ``pyramid_levels`` (images halved ``cv2.pyrDown``-wise, as
   KLT does) down to level 1, from the prediction (a shift and a grey offset, as KLT's
   Lucas-Kanade). A track it moves by more than a pixel (in some camera) *jumped*: from
   the coarse-to-fine position only its first template may match (a frame-to-frame
   template is not trusted after a jump: it let more tracks go astray on the webcam
   videos). A track that did not jump and whose fallback was just re-anchored tries that
   fresh fallback from the prediction (its first template, which just failed from there,
   is not matched again). A single-level LSM converges only from within about half a
   patch; the pyramid reaches ``2**pyramid_levels`` times further;
5. live tracks still not found are searched in the ``retry_radius`` box.

Matches with the fallback can drift, as the paper's do, until the first template matches
again (it is tried first in every frame: that is the drift correction). *Re-anchoring
rule*: a fallback template is replaced by the track's patch in the current frame when its
``sigma0`` grows beyond ``reanchor_sigma0`` times its value at its first match, or when its
affinity departs from the identity by more than ``reanchor_distortion`` (spectral norm of
``A - I``: about 14 degrees of rotation or 25 % of scale). ``Tracks.anchor`` records the
frame of the template that matched each frame (the track's start where it matched its
first template).

*Spatial check* (K > 1): the template camera's template (of the set that matched) is
matched into camera ``k``'s frame ``t + 1``, started where the spatial relation measured
when the templates were anchored puts it (affinity ``A_k S_k``, offset ``A_k D_k``). A track
is accepted when every temporal LSM passed its thresholds and every spatial LSM stayed
within ``max_disagreement`` pixels of that relation: the spatial LSM's own bias between
two views of a curved surface is measured at the anchor and does not count. With the
calibrated ``cameras`` (beyond the paper) every accepted frame must also intersect with a
reprojection error of at most ``max_reprojection``. Rejected live tracks are searched again
in a box of half-width ``retry_radius`` (twice that for a track without history). A start
point whose templates are flat or whose spatial LSM does not land within
``max_disagreement`` of it is not tracked.

*Recovery.* A track not found in a frame is *missing*, not ended: in every following frame
its first template is matched at the position its trajectory predicts, and at each
density check it is searched in the ``retry_radius`` box there (before the check adds new
points, so a recovered point is not tracked twice); it ends (status LOST; later positions
NaN, never a made-up position) when it has been missing for more than ``max_gap`` frames.
The missing frames of a recovered track stay NaN.

With one camera (2-D mode, paper Section 2.3.3) there is no spatial check.

*Image border* (beyond the paper; ``partial``): KLT keeps a window that reaches over the
image border, and so does this tracker. A point whose patch reaches over the border gets a
*partial* template (its pixels outside the image masked; at least half of them inside), and
a patch that leaves the image in a later frame is matched with the outside pixels given
zero weight (the forward LSM with partial patches, see
:func:`~lsmta.tracking.templates.match_templates`); away from the border nothing changes.

*Surface tracking* (Fig. 9): with ``new_points``, every ``density_every`` frames the live
tracks are checked for density in the template image
(:func:`~lsmta.tracking.density.sparse_candidates`), and that frame's measured surface
points are added where the tracks have thinned out (newly visible surface).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, fields, make_dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from .._validate import as_array, as_int, as_scalar, check_patch
from ..camera import Camera
from ..matching.lsm import LSMThresholds
from ..matching.seeds import camera_depth, predicted_maps, warped_images
from ..matching.spline import SplineImage, check_grey
from ..triangulation import triangulate
from .density import sparse_candidates
from .templates import (
    Templates,
    _match,
    match_templates,
    match_translation,
    offsets,
    sample_templates,
    search_templates,
)

ANCHORS = ("first", "previous")


class TrackStatus(enum.IntEnum):
    """How a track ended.

    Arrays are compared with ``.value`` (see :class:`~lsmta.matching.lsm.Status`).
    """

    ALIVE = 0        #: tracked in the last frame
    LOST = 1         #: missing for more than ``max_gap`` frames, then ended
    NOT_STARTED = 2  #: its start position was incomplete (NaN in some camera)
    MISSING = 3      #: not found in the last frame, missing for at most ``max_gap`` frames


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
    max_iter : int
        LSM iteration limit (a match still moving after it is rejected).
    tol : float
        LSM convergence tolerance, pixels.
    neighbours : int
        Neighbours whose median velocity predicts a track without history.
    anchor : {"first", "previous"}
        ``"first"``: drift-free anchored templates, re-anchored by the rule below;
        ``"previous"``: the previous frame's patch is the template (the paper's).
    reanchor_sigma0 : float
        Re-anchor when ``sigma0`` grows beyond this factor of its value at the first match
        after anchoring.
    reanchor_distortion : float
        Re-anchor when the accumulated affinity departs from the identity by more than
        this (spectral norm of ``A - I``).
    max_gap : int
        Frames a track may be missing before it ends (0: it ends when first lost).
    pyramid_levels : int
        Levels above the full image of the coarse-to-fine prediction tried where the match
        from the trajectory's prediction fails (0: none). Each level halves the image, so
        the prediction may be off by about ``patch * 2**pyramid_levels / 2`` pixels; 3 is
        the depth of the peer (:func:`~lsmta.tracking.klt.track_klt`).
    partial : bool
        Patches may reach over the image border, as KLT's windows do: a point whose patch
        leaves the image gets a *partial* template (its pixels outside masked, at least
        half of them inside) and a track whose patch leaves the image is matched with the
        outside pixels given zero weight (forward LSM, ``partial`` of
        :func:`~lsmta.tracking.templates.match_templates`). False: such points are not
        started (``NOT_STARTED``) and such matches fail.
    retry_rejected : bool
        Temporal matches: retry a failed inverse compositional match with the forward LSM
        also where it converged but failed the thresholds, or found no positive
        correlation at its start (the default). False: only where it diverged or kept
        moving (on caliscope cam_0 the retry rescued 28 % and 13 % of those, 4 % and 1 %
        of the others, each retry a forward LSM): 2-9 % less CPU on the real videos, but
        1.3 % fewer survivors on the generated triplet walk, so not the default
        (``experiments/real_video_tracking.py``).
    return_to_first : bool
        A track found with its fallback template tries its first template again, from
        where the fallback found it (the inverse compositional match, the forward LSM
        retry, then the correlation search in the same box around it); where that passes,
        the frame is the first template's and the fallback's drift ends there. False (the
        default): the first template is tried only from the prediction. On the eight real
        videos 1882 survivors against 1855, kept with FB > 0.5 px 177 against 196, but
        pose2sim cam03 265 -> 262, so not the default
        (``experiments/real_video_tracking.py``).
    max_reprojection : float
        Largest reprojection error of an accepted frame, px (only with ``cameras``).
    density_every : int
        Frequency of the density check, frames (surface tracking only).
    cell, min_per_cell, min_distance
        Density check (:func:`~lsmta.tracking.density.sparse_candidates`).
    """

    patch: int = 11
    radius: int = 4
    retry_radius: int = 10
    max_disagreement: float = 1.0
    template: int = 1
    thresholds: LSMThresholds = field(default_factory=lambda: LSMThresholds(
        max_sigma0=15.0, max_sigma_xy=0.4, max_displacement=3.0, scale_range=(0.5, 2.0),
        max_shear=0.6))
    max_iter: int = 20
    tol: float = 0.01
    neighbours: int = 8
    anchor: str = "first"
    reanchor_sigma0: float = 2.0
    reanchor_distortion: float = 0.25
    max_gap: int = 10
    pyramid_levels: int = 3
    partial: bool = True
    retry_rejected: bool = True
    return_to_first: bool = False
    max_reprojection: float = 1.0
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
        Pixel positions; NaN before a track's start, after its end and in the frames where
        it was missing.
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
    anchor : (T, N) int array
        Frame of the template the track holds after frame t (t itself where it was
        anchored or re-anchored in frame t); -1 where untracked.
    recovered : (T, N) bool array
        Found again in frame t after missing frames.
    """

    xy: np.ndarray
    start: np.ndarray
    end: np.ndarray
    status: np.ndarray
    retried: np.ndarray
    added: np.ndarray
    origin: np.ndarray
    anchor: np.ndarray
    recovered: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.xy.shape[0]

    @property
    def alive(self) -> np.ndarray:
        """``(T, N)`` bool: tracked in that frame."""
        return np.isfinite(self.xy).all(axis=(1, 3))

    @property
    def reanchored(self) -> np.ndarray:
        """``(T, N)`` bool: the track took a new template in frame t (after its start)."""
        t = np.arange(self.n_frames)[:, None]
        return (self.anchor == t) & (t > self.start[None, :])

    def __len__(self) -> int:
        return self.xy.shape[2]


def as_sequences(images) -> np.ndarray:
    """Image sequences as a ``(K, T, H, W)`` array of their own dtype, after checking their
    lengths, sizes and grey values.

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
        # checked one at a time, not converted: 8-bit video stays 8-bit; a (T, H, W) array
        # is used as it is (stacked once, below)
        frames = s if isinstance(s, np.ndarray) and s.ndim == 3 else \
            [np.asarray(im) for im in s]
        for t, im in enumerate(frames):
            check_grey(im, f"images[{k}][{t}]")
        sizes = {f.shape for f in frames}
        out.append(frames)
        if len(sizes) != 1:
            raise ValueError(f"images[{k}]: frames of unequal size {sorted(sizes)}")
    sizes = [o[0].shape for o in out]
    if len(set(sizes)) != 1:
        raise ValueError(f"images: the cameras' images have unequal sizes {sizes}; "
                         "expected one size")
    return np.stack([o if isinstance(o, np.ndarray) else np.stack(o) for o in out])


def track_points(images, initial_xy, *, params: TrackerParams | None = None,
                 new_points=None, initial_velocity=None, cameras=None, start_cameras=None,
                 progress: bool = False) -> Tracks:
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
    cameras : sequence of K Camera, optional
        The calibrated cameras (K > 1): a frame is accepted only if its K positions
        intersect with every reprojection error at most ``params.max_reprojection`` px
        (a geometric check beyond the paper's spatial LSM).
    start_cameras : sequence of K Camera, optional
        Calibrated cameras used only to start the spatial LSM of a new track: into a camera
        that sees the template camera's patch turned by more than
        :data:`~lsmta.matching.seeds.AUTO_TURN_DEG` or scaled by more than
        :data:`~lsmta.matching.seeds.AUTO_SCALE` (a camera mounted on its side; beyond them
        LSM does not pull in from the identity), from the map they predict
        (:func:`~lsmta.matching.seeds.warped_images`, ``"auto"``) instead of the identity.
        No reprojection check (that is ``cameras``).
    progress : bool
        Show a progress bar over the frames.

    Returns
    -------
    Tracks
    """
    p = params or TrackerParams()
    seq = as_sequences(images)
    K, T = seq.shape[:2]
    _check_params(p, K)
    xy0 = as_array(initial_xy, "initial_xy", shape=(K, None, 2), allow_nan=True)
    started = np.isfinite(xy0).all(axis=(0, 2))
    if not started.any():
        raise ValueError("initial_xy: the first frame has no point matched in every camera; "
                         "nothing to track")
    vel0 = None
    if initial_velocity is not None:
        vel0 = as_array(initial_velocity, "initial_velocity", shape=xy0.shape, allow_nan=True)
    if cameras is not None:
        cameras = list(cameras)
        if K < 2 or len(cameras) != K or not all(isinstance(c, Camera) for c in cameras):
            raise ValueError(f"cameras: expected {K} lsmta.camera.Camera (one per image "
                             "sequence, at least 2), or None")
    if start_cameras is not None:
        start_cameras = list(start_cameras)
        if K < 2 or len(start_cameras) != K or not all(isinstance(c, Camera)
                                                       for c in start_cameras):
            raise ValueError(f"start_cameras: expected {K} lsmta.camera.Camera (one per image "
                             "sequence, at least 2), or None")
    splines = [SplineImage(seq[k, 0], "images") for k in range(K)]
    first = _Anchors.sampled(splines, xy0, 0, p)
    started &= _spatial_start(first, splines, xy0, p, start_cameras)
    state = _State.initial(xy0, started, T, first, cameras)
    state.start_cameras = start_cameras
    pyramids = _Pyramids(seq, p.pyramid_levels)
    for t in tqdm(range(T - 1), desc="tracking", disable=not progress):
        nxt = [SplineImage(seq[k, t + 1], "images") for k in range(K)]
        _advance(state, seq, splines, nxt, t, p, vel0 if t == 0 else None, pyramids)
        if new_points is not None and (t + 1) % p.density_every == 0:
            _search_missing(state, seq, nxt, t + 1, p)
            _add_where_sparse(state, new_points, nxt, t + 1, p)
        _end_missing(state, t + 1, p.max_gap)
        # a later coarse-to-fine step starts from a track's last tracked frame only
        pyramids.keep(state.end[state.in_play()])
        splines = nxt
    return state.result()


def _check_params(p: TrackerParams, K: int) -> None:
    check_patch(p.patch, "params.patch")
    for name, low, unit in (("radius", 1, "pixels"), ("retry_radius", 1, "pixels"),
                            ("density_every", 1, "frames"), ("neighbours", 1, "tracks"),
                            ("max_gap", 0, "frames"), ("max_iter", 1, "iterations"),
                            ("pyramid_levels", 0, "pyramid levels")):
        as_int(getattr(p, name), f"params.{name}", minimum=low, unit=unit)
    if K > 1 and not (isinstance(p.template, int | np.integer) and 0 <= p.template < K):
        raise ValueError(f"params.template: expected a camera index in [0, {K - 1}], "
                         f"got {p.template}")
    for name in ("partial", "retry_rejected", "return_to_first"):
        if not isinstance(getattr(p, name), bool | np.bool_):
            raise ValueError(f"params.{name}: expected True or False, got "
                             f"{getattr(p, name)!r}")
    if p.anchor not in ANCHORS:
        raise ValueError(f"params.anchor: expected one of {list(ANCHORS)}, got {p.anchor!r}")
    as_scalar(p.max_disagreement, "params.max_disagreement", positive=True)
    as_scalar(p.min_distance, "params.min_distance", nonnegative=True)
    as_scalar(p.tol, "params.tol", positive=True)
    as_scalar(p.max_reprojection, "params.max_reprojection", positive=True)
    as_scalar(p.reanchor_distortion, "params.reanchor_distortion", positive=True)
    if not as_scalar(p.reanchor_sigma0, "params.reanchor_sigma0") > 1:
        raise ValueError(f"params.reanchor_sigma0: expected a factor > 1, got "
                         f"{p.reanchor_sigma0}")


# ---------------------------------------------------------------------- state
@dataclass
class _Anchors:
    """One anchor template per track and camera, and the affinities that go with it."""

    templates: list           # K Templates
    A: np.ndarray             # (K, N, 2, 2) template -> the last frame it matched
    S: np.ndarray             # (K, N, 2, 2) template camera's template -> camera k's
    D: np.ndarray             # (K, N, 2) spatial LSM result - own position, when anchored
    frame: np.ndarray         # (N,) anchor frame (-1: none yet)
    sigma_ref: np.ndarray     # (K, N) sigma0 of the first match after anchoring

    @classmethod
    def sampled(cls, splines, xy, frame: int, p: TrackerParams) -> _Anchors:
        """Templates at ``xy`` ``(K, n, 2)`` of the images ``splines`` (frame ``frame``)."""
        K, n = xy.shape[:2]
        return cls(templates=[sample_templates(s, xy[k], p.patch, partial=p.partial)
                              for k, s in enumerate(splines)],
                   A=_eye(K, n), S=_eye(K, n), D=np.zeros((K, n, 2)),
                   frame=np.full(n, frame, np.int64), sigma_ref=np.full((K, n), np.nan))

    def take(self, rows) -> _Anchors:
        return _Anchors(templates=[tm.take(rows) for tm in self.templates], A=self.A[:, rows],
                        S=self.S[:, rows], D=self.D[:, rows], frame=self.frame[rows],
                        sigma_ref=self.sigma_ref[:, rows])

    def extend(self, other: _Anchors) -> None:
        self.templates = [a.extend(b) for a, b in zip(self.templates, other.templates)]
        for name, axis in (("A", 1), ("S", 1), ("D", 1), ("frame", 0), ("sigma_ref", 1)):
            setattr(self, name, np.concatenate([getattr(self, name), getattr(other, name)],
                                               axis=axis))

    def put(self, rows, other: _Anchors) -> None:
        for a, b in zip(self.templates, other.templates):
            a.put(rows, b)
        self.A[:, rows], self.S[:, rows], self.D[:, rows] = other.A, other.S, other.D
        self.frame[rows], self.sigma_ref[:, rows] = other.frame, other.sigma_ref


# the result's arrays (see Tracks), mutable while tracking
_TrackArrays = make_dataclass("_TrackArrays", [(f.name, np.ndarray) for f in fields(Tracks)])


@dataclass
class _State(_TrackArrays):
    first: _Anchors           # the first templates: A maps them to the last tracked frame
    fallback: _Anchors        # used where the first ones fail (see the module docstring)
    link: np.ndarray          # (K, N, 2, 2) first template -> the fallback's anchor frame
    on_fallback: np.ndarray   # (N,) the last tracked frame was matched with the fallback
    cameras: list | None      # for the geometric check
    start_cameras: list | None = None   # predict the spatial LSM's starting maps

    @classmethod
    def initial(cls, xy0, started, T: int, first: _Anchors, cameras=None) -> _State:
        """The initial points at frame 0 (the state grows when the density check adds)."""
        K, N = xy0.shape[:2]
        xy = np.full((T, K, N, 2), np.nan)
        xy[0] = np.where(started[None, :, None], xy0, np.nan)
        anchor = np.full((T, N), -1, np.int64)
        anchor[0, started] = 0
        fallback = _Anchors(templates=[tm.take(np.arange(N)) for tm in first.templates],
                            A=_eye(K, N), S=_eye(K, N), D=np.zeros((K, N, 2)),
                            frame=np.full(N, -1, np.int64), sigma_ref=np.full((K, N), np.nan))
        return cls(xy=xy, start=np.zeros(N, np.int64),
                   end=np.where(started, 0, -1).astype(np.int64),
                   status=np.where(started, TrackStatus.ALIVE, TrackStatus.NOT_STARTED),
                   retried=np.zeros((T, N), bool), added=np.zeros(N, bool),
                   origin=np.full(N, -1, np.int64), anchor=anchor,
                   recovered=np.zeros((T, N), bool), first=first, fallback=fallback,
                   link=_eye(K, N), on_fallback=np.zeros(N, bool), cameras=cameras)

    def append(self, new_xy, t: int, origin, first: _Anchors) -> np.ndarray:
        """Add tracks starting at frame ``t``; returns their indices."""
        K, M = new_xy.shape[:2]
        T, N = self.xy.shape[0], self.xy.shape[2]
        block = np.full((T, K, M, 2), np.nan)
        block[t] = new_xy
        anchor = np.full((T, M), -1, np.int64)
        anchor[t] = t
        self.xy = np.concatenate([self.xy, block], axis=2)
        self.start = np.concatenate([self.start, np.full(M, t)])
        self.end = np.concatenate([self.end, np.full(M, t)])
        self.status = np.concatenate([self.status, np.full(M, TrackStatus.ALIVE)])
        self.retried = np.concatenate([self.retried, np.zeros((T, M), bool)], axis=1)
        self.added = np.concatenate([self.added, np.ones(M, bool)])
        self.origin = np.concatenate([self.origin, origin])
        self.anchor = np.concatenate([self.anchor, anchor], axis=1)
        self.recovered = np.concatenate([self.recovered, np.zeros((T, M), bool)], axis=1)
        self.first.extend(first)
        self.fallback.extend(_Anchors(
            templates=[tm.take(np.arange(M)) for tm in first.templates], A=_eye(K, M),
            S=_eye(K, M), D=np.zeros((K, M, 2)), frame=np.full(M, -1, np.int64),
            sigma_ref=np.full((K, M), np.nan)))
        self.link = np.concatenate([self.link, _eye(K, M)], axis=1)
        self.on_fallback = np.concatenate([self.on_fallback, np.zeros(M, bool)])
        return np.arange(N, N + M)

    def in_play(self) -> np.ndarray:
        return np.flatnonzero((self.status == TrackStatus.ALIVE.value)
                              | (self.status == TrackStatus.MISSING.value))

    def result(self) -> Tracks:
        arrays = {f.name: getattr(self, f.name) for f in fields(Tracks)}
        arrays["status"] = np.asarray(self.status, np.int64)
        return Tracks(**arrays)


def _lsm(p: TrackerParams) -> dict:
    """Settings of every template match: the paper's forward additive LSM for templates that
    change every frame (``anchor="previous"``, see :func:`match_templates`)."""
    return dict(thresholds=p.thresholds, max_iter=p.max_iter, tol=p.tol,
                inverse=p.anchor == "first", partial=p.partial)


def _eye(K, n):
    return np.broadcast_to(np.eye(2), (K, n, 2, 2)).copy()


# ---------------------------------------------------------------------- stages
def _advance(state: _State, seq, prev, nxt, t: int, p: TrackerParams, vel0,
             pyramids: _Pyramids) -> None:
    """Frame ``t`` -> ``t + 1`` for the tracks in play (steps 1-5 of the module docstring):
    the prediction; every track's first template matched from it (the fallback template
    where that fails, for tracks with a history; the box search for those without); a
    stale failed fallback re-anchored at frame ``t``; for the tracks still failing, the
    coarse-to-fine prediction, from which a track that jumped matches only its first
    template, while one that did not jump but was re-anchored tries only its fresh
    fallback; the live ones that still fail searched in the bigger box. What is not found
    is missing."""
    idx = state.in_play()
    if not idx.size:
        return
    pred, known = _predict(state, idx, t + 1, p.neighbours, vel0)
    live = state.end[idx] == t
    first = p.anchor == "first"
    box = live & (~known | (not first))
    fallback = live & known & first
    ok = _attempt(state, seq, prev, nxt, t + 1, idx, pred,
                  np.where(known, p.radius, p.retry_radius), p, direct=np.ones(idx.size, bool),
                  box=box, fallback=fallback)
    # a fallback template anchored before frame t that failed gives way to the track's
    # patch in frame t (where its first or its fallback template last matched)
    stale = ~ok & fallback & (state.fallback.frame[idx] < t)
    _anchor_fallback(state, prev, t, idx[stale], p)
    if not ok.all():
        start = pred.copy()
        moved = np.zeros(idx.size, bool)
        if p.pyramid_levels:
            sel = np.flatnonzero(~ok)
            c2f = _coarse_to_fine(state, pyramids, idx[sel], pred[:, sel], t + 1, p)
            # where it lands within a pixel of the prediction, the match from there failed
            far = np.nan_to_num(np.linalg.norm(c2f - pred[:, sel], axis=2), nan=0.0) > 1.0
            moved[sel] = np.isfinite(c2f).all(axis=(0, 2)) & far.any(axis=0)
            start[:, sel[moved[sel]]] = c2f[:, moved[sel]]
        sel = np.flatnonzero(moved | stale)
        if sel.size:
            # a stale track that did not move: its first template was just matched from
            # this very start and failed; only its re-anchored fallback is new
            ok[sel] = _attempt(state, seq, prev, nxt, t + 1, idx[sel], start[:, sel],
                               np.where(known[sel], p.radius, p.retry_radius), p,
                               direct=np.ones(sel.size, bool), box=box[sel],
                               fallback=fallback[sel] & ~moved[sel], first=moved[sel])
    again = live & ~ok
    if again.any():
        r2 = np.where(known[again], p.retry_radius, 2 * p.retry_radius)
        ok2 = _attempt(state, seq, prev, nxt, t + 1, idx[again], pred[:, again], r2, p,
                       direct=np.zeros(again.sum(), bool), box=~(known[again] & first),
                       fallback=known[again] & first)
        state.retried[t + 1, idx[again][ok2]] = True
    state.status[idx[state.end[idx] < t + 1]] = TrackStatus.MISSING.value


class _Pyramids:
    """Spline interpolants of the pyramid levels 1..``levels`` of the frames ``seq[k, t]``
    (fewer where the image gets too small; index 0, the image, is None), each level halved by
    ``cv2.pyrDown``: pixel ``i`` of level ``l`` lies at pixel ``2**l i`` of the image. Made
    only when a coarse-to-fine step asks for them, and kept only for the frames that are
    some track's last tracked frame (the only sources a later step uses). Also keeps, per
    camera and level, the patches of the tracks its last coarse-to-fine step matched
    (:meth:`templates`; no more rows than that step had): a track that stays missing has
    its patches sampled once, not in every frame."""

    def __init__(self, seq, levels: int):
        self.seq, self.levels, self.kept, self.patches = seq, levels, {}, {}

    def get(self, k: int, t: int) -> list:
        if (k, t) not in self.kept:
            im = np.asarray(self.seq[k, t], np.float32)
            out = [None]                    # level 0: the image itself, not needed here
            for _ in range(self.levels):
                if min(im.shape) < 20:
                    break
                im = cv2.pyrDown(im)
                out.append(SplineImage(im))
            self.kept[(k, t)] = out
        return self.kept[(k, t)]

    def keep(self, frames) -> None:
        """Forget the pyramids of every frame not in ``frames``."""
        frames = set(np.unique(frames).tolist())
        for key in [key for key in self.kept if key[1] not in frames]:
            del self.kept[key]

    def templates(self, k: int, lv: int, idx, last, xy, *, patch: int) -> Templates:
        """:func:`_sampled_from` of the tracks ``idx``'s patches at pyramid level ``lv`` of
        camera ``k``'s frames ``last`` ``(n,)``, centred at ``xy`` ``(n, 2)`` (full-size
        px). Per camera and level, the patches of the tracks of the last call are kept (and
        only those: each call replaces them with its own): a track asked again from the
        same frame and position, as a missing track is in every frame it stays missing,
        reuses its patch; the others are sampled. A kept row is the fresh sample bit for
        bit (each row is sampled on its own; checked on caliscope cam_0's 20 262 rows)."""
        n = len(idx)
        values, gx, gy = (np.zeros((n, patch * patch)) for _ in range(3))
        ok, hit = np.zeros(n, bool), np.zeros(n, bool)
        old = self.patches.get((k, lv))
        if old is not None and len(old["idx"]) and n:
            pos = np.minimum(np.searchsorted(old["idx"], idx), len(old["idx"]) - 1)
            hit = ((old["idx"][pos] == idx) & (old["frame"][pos] == last)
                   & (old["xy"][pos] == xy).all(axis=1))
            src = pos[hit]
            values[hit], gx[hit], gy[hit], ok[hit] = (old[name][src]
                                                      for name in ("values", "gx", "gy", "ok"))
        miss = np.flatnonzero(~hit)
        if miss.size:
            frames, which = np.unique(last[miss], return_inverse=True)
            tm = _sampled_from([self.get(k, f)[lv] for f in frames], which,
                               xy[miss] / 2.0 ** lv, patch)
            values[miss], gx[miss], gy[miss], ok[miss] = tm.values, tm.gx, tm.gy, tm.ok
        order = np.argsort(idx)                     # sorted by track for the next lookup
        self.patches[(k, lv)] = {"idx": idx[order], "frame": last[order], "xy": xy[order],
                                 "values": values[order], "gx": gx[order], "gy": gy[order],
                                 "ok": ok[order]}
        return _translation_templates(values, gx, gy, ok, patch)


def _coarse_to_fine(state: _State, pyramids: _Pyramids, idx, pred, t: int,
                    p: TrackerParams) -> np.ndarray:
    """Coarse-to-fine predictions ``(K, n, 2)`` px at frame ``t`` for the tracks ``idx``
    ``(n,)``, started from their predictions ``pred`` ``(K, n, 2)`` px (full-size pixels).

    Each track's patch in its last tracked frame is matched into frame ``t`` at pyramid
    level ``p.pyramid_levels`` down to level 1 (a shift and a grey offset,
    :func:`~lsmta.tracking.templates.match_translation`, to ``p.tol`` px of that level
    (a looser 0.1 px let a track go astray in the jerky-motion test and saved no measurable
    time), no quality thresholds: the anchored match at full size decides), started at
    ``pred`` and then at the level above's result; a level that does not converge keeps
    the estimate from above. NaN where no level converged. Each level is one call for all
    the tracks, whatever their last frames (each track's patch sampled from its own
    frame's level, once while it stays missing: :meth:`_Pyramids.templates`); every
    track is solved on its own, so the result is that of matching the tracks of each last
    frame separately."""
    K, n = pred.shape[:2]
    out = np.full((K, n, 2), np.nan)
    last = state.end[idx]
    rows = np.arange(n)
    for k in range(K):
        target = pyramids.get(k, t)
        at = state.xy[last, k, idx]                                 # (n, 2) full-size px
        est = np.array(pred[k], float)
        found = np.zeros(n, bool)
        for lv in range(len(target) - 1, 0, -1):
            s = 2.0 ** lv
            tm = pyramids.templates(k, lv, idx, last, at, patch=p.patch)
            xy, conv = match_translation(tm, rows, target[lv], est / s, max_iter=p.max_iter,
                                         tol=p.tol)
            est[conv] = xy[conv] * s
            found[conv] = True
        out[k, found] = est[found]
    return out


def _sampled_from(images, which, xy, patch: int) -> Templates:
    """:func:`~lsmta.tracking.templates.sample_templates` (``normals=False``) of the
    positions ``xy`` ``(n, 2)``, row ``j`` sampled from ``images[which[j]]``."""
    U = offsets(patch)
    n, P = len(xy), len(U)
    values, gx, gy = np.zeros((n, P)), np.zeros((n, P)), np.zeros((n, P))
    ok = np.zeros(n, bool)
    for w, image in enumerate(images):
        sel = np.flatnonzero(which == w)
        inside = image.inside(xy[sel], margin=patch // 2) & np.isfinite(xy[sel]).all(axis=1)
        ok[sel] = inside
        r = sel[inside]
        if r.size:
            values[r], gx[r], gy[r] = image.sample(xy[r, None, :] + U, gradient=True)
    f = values - values.mean(axis=1, keepdims=True)
    ok &= (f * f).sum(axis=1) > 1e-9 * P
    return _translation_templates(values, gx, gy, ok, patch)


def _translation_templates(values, gx, gy, ok, patch: int) -> Templates:
    """:class:`~lsmta.tracking.templates.Templates` of ``n`` full, unmasked patches for
    :func:`~lsmta.tracking.templates.match_translation` (``values``, ``gx``, ``gy``
    ``(n, patch**2)``, ``ok`` ``(n,)``); ``update`` and ``q_xy`` NaN."""
    n = len(values)
    return Templates(values=values, gx=gx, gy=gy, update=np.full((n, 6, 6), np.nan),
                     q_xy=np.full((n, 2, 2), np.nan), ok=ok,
                     mask=np.ones((n, patch * patch), bool), full=np.ones(n, bool),
                     patch=patch)


def _search_missing(state: _State, seq, nxt, t: int, p: TrackerParams) -> None:
    """Density check at frame ``t``, first part: the missing tracks are searched in the
    ``retry_radius`` box around their predicted positions before sparse cells get new
    points."""
    idx = np.flatnonzero(state.status == TrackStatus.MISSING.value)
    if idx.size:
        n = idx.size
        pred, _ = _predict(state, idx, t, p.neighbours, None)
        ok = _attempt(state, seq, None, nxt, t, idx, pred, np.full(n, p.retry_radius), p,
                      direct=np.zeros(n, bool), box=np.ones(n, bool), fallback=np.zeros(n, bool))
        state.retried[t, idx[ok]] = True


def _end_missing(state: _State, t: int, max_gap: int) -> None:
    gone = (state.status == TrackStatus.MISSING.value) & (t - state.end > max_gap)
    state.status[gone] = TrackStatus.LOST.value


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
        first = _Anchors.sampled(nxt, cand[:, add], t, p)
        confirmed = _spatial_start(first, nxt, cand[:, add], p, state.start_cameras)
        if confirmed.any():
            keep = np.flatnonzero(confirmed)
            state.append(cand[:, add[keep]], t, add[keep], first.take(keep))


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


def _predict(state: _State, idx, t: int, neighbours: int, vel0):
    """Predicted positions ``(K, n, 2)`` at frame ``t`` from each track's last two tracked
    frames, extrapolated over its gap, and whether the track had a history ``(n,)``."""
    last = state.end[idx]
    cur = state.xy[last, :, idx].transpose(1, 0, 2)               # (K, n, 2)
    prev = np.full_like(cur, np.nan)
    has = last >= 1
    prev[:, has] = state.xy[last[has] - 1, :, idx[has]].transpose(1, 0, 2)
    known = np.isfinite(prev).all(axis=(0, 2))
    vel = np.where(known[None, :, None], cur - prev, 0.0)
    born = np.flatnonzero(~known)
    src = np.flatnonzero(known & (last == t - 1))
    if born.size and src.size:
        # a neighbour-based prediction is an estimate, not a history: keep the bigger box
        for k in range(cur.shape[0]):
            _, nn = cKDTree(cur[k, src]).query(cur[k, born], k=min(neighbours, len(src)))
            nn = np.atleast_2d(nn.reshape(len(born), -1))
            vel[k, born] = np.median(vel[k, src][nn], axis=1)
    if vel0 is not None:
        v = vel0[:, idx]
        given = np.isfinite(v).all(axis=(0, 2))
        vel[:, given] = v[:, given]
        known = known | given
    return cur + vel * (t - last)[None, :, None], known


@dataclass(frozen=True)
class _Temporal:
    ok: np.ndarray              # (n,) every camera accepted
    xy: np.ndarray              # (K, n, 2)
    temporal_A: np.ndarray      # (K, n, 2, 2)
    sigma0: np.ndarray          # (K, n)
    correlation_xy: np.ndarray  # (K, n, 2) NaN where not searched
    direct: np.ndarray          # (K, n) matched from the prediction


def _attempt(state: _State, seq, prev, nxt, t: int, idx, pred, radius, p: TrackerParams, *,
             direct, box, fallback, first=None) -> np.ndarray:
    """One attempt at frame ``t`` for the tracks ``idx``; the accepted tracks are written
    into the state. Returns ``ok (n,)``.

    The first templates are matched from the prediction where ``direct``, and searched in
    the box of ``radius`` where ``box`` (where the direct match failed or was not tried);
    where they fail and ``fallback``, the fallback templates (anchored in frame ``t - 1``
    unless the track holds a fresh one) are matched from the prediction (where ``direct``)
    and in the box (with ``p.return_to_first``, a track they found then tries its first
    templates from there, and keeps them where they pass). Then the spatial check per
    template set and (with cameras) the
    geometric check. Where ``first`` ``(n,)`` is False (default: all True) the first
    templates are not tried at all (an exact repeat of a failed match).
    """
    try_first = np.ones(idx.size, bool) if first is None else first
    st = _temporal(state.first, seq, nxt, t, idx, pred, radius, p, direct=direct & try_first,
                   box=box & try_first)
    use_fb = fallback & ~st.ok
    if use_fb.any():
        _anchor_fallback(state, prev, t - 1, idx[use_fb & ~state.on_fallback[idx]], p)
        sel = np.flatnonzero(use_fb)
        st = _merge(st, sel, _temporal(state.fallback, seq, nxt, t, idx[sel], pred[:, sel],
                                       radius[sel], p, direct=direct[sel],
                                       box=np.ones(sel.size, bool)))
    back = np.flatnonzero(use_fb & st.ok) if p.return_to_first else np.zeros(0, np.int64)
    if back.size:
        # the first template again, from where the fallback found the track
        st1 = _temporal(state.first, seq, nxt, t, idx[back], st.xy[:, back], radius[back], p,
                        direct=np.ones(back.size, bool), box=np.ones(back.size, bool))
        got = np.flatnonzero(st1.ok)
        st = _merge(st, back[got], _take(st1, got))
        use_fb = use_fb & ~np.isin(np.arange(idx.size), back[got])
    ok = st.ok.copy()
    M, off = st.temporal_A.copy(), np.zeros(st.xy.shape)
    if len(nxt) > 1:
        for anchors, mask in ((state.first, ok & ~use_fb), (state.fallback, ok & use_fb)):
            sel = np.flatnonzero(mask)
            if sel.size:
                agree, M[:, sel], pos = _spatial(anchors, nxt, idx[sel], st.xy[:, sel],
                                                 st.temporal_A[:, sel], p)
                off[:, sel] = np.nan_to_num(pos - st.xy[:, sel])
                ok[sel[~agree]] = False
    if state.cameras is not None and ok.any():
        sel = np.flatnonzero(ok)
        res = triangulate(state.cameras, st.xy[:, sel])
        ok[sel] = res.valid & (np.nanmax(res.reprojection_error, axis=0) <= p.max_reprojection)
    if ok.any():
        _accept(state, nxt, t, idx[ok], st.xy[:, ok], st.temporal_A[:, ok], st.sigma0[:, ok],
                M[:, ok], off[:, ok], use_fb[ok], p)
    return ok


def _take(st: _Temporal, rows) -> _Temporal:
    """``st``'s tracks ``rows``."""
    fields = {}
    for name in _Temporal.__dataclass_fields__:
        a = getattr(st, name)
        fields[name] = a[(slice(None),) * (a.ndim > 1) + (rows,)]
    return _Temporal(**fields)


def _merge(st: _Temporal, sel, other: _Temporal) -> _Temporal:
    """``st`` with the tracks ``sel`` replaced by ``other``'s."""
    fields = {}
    for name in _Temporal.__dataclass_fields__:
        a = getattr(st, name).copy()
        a[(slice(None),) * (a.ndim > 1) + (sel,)] = getattr(other, name)
        fields[name] = a
    return _Temporal(**fields)


def _temporal(anchors: _Anchors, seq, nxt, t: int, idx, pred, radius, p: TrackerParams, *,
              direct, box) -> _Temporal:
    """Temporal LSM of the ``anchors`` templates in every camera: from the prediction where
    ``direct`` (inverse compositional only where not ``box``), else (or when that fails,
    where ``box``) from the best correlation position in the box of ``radius``."""
    K, n = pred.shape[:2]
    xy = np.full((K, n, 2), np.nan)
    A = np.full((K, n, 2, 2), np.nan)
    sigma0 = np.full((K, n), np.nan)
    corr = np.full((K, n, 2), np.nan)
    by_pred = np.zeros((K, n), bool)
    ok = np.ones(n, bool)

    def match(k, sel, start, fallback):
        res = _match(anchors.templates[k], idx[sel], nxt[k], start, anchors.A[k, idx[sel]],
                     fallback=fallback, retry_rejected=p.retry_rejected,
                     max_displacement=None, **_lsm(p))
        good = res.ok
        xy[k, sel[good]], A[k, sel[good]] = res.xy[good], res.A[good]
        sigma0[k, sel[good]] = res.sigma0[good]
        return sel[good]

    for k in range(K):
        got = np.zeros(n, bool)
        sel = np.flatnonzero(direct & ok)
        if sel.size:                    # the forward LSM retry only where box: per track
            got[match(k, sel, pred[k, sel], box[sel])] = True
        by_pred[k] = got
        for r in np.unique(radius[~got & ok & box]):
            sel = np.flatnonzero(~got & ok & box & (radius == r))
            c = search_templates(anchors.templates[k], idx[sel], seq[k, t], pred[k, sel], int(r))
            corr[k, sel] = c
            found = np.isfinite(c).all(axis=1)
            got[match(k, sel[found], c[found], True)] = True
        ok &= got
    return _Temporal(ok=ok, xy=xy, temporal_A=A, sigma0=sigma0, correlation_xy=corr,
                     direct=by_pred)


def _spatial(anchors: _Anchors, nxt, idx, xy, A, p: TrackerParams):
    """Spatial LSM: the template camera's template into every other camera's frame, started
    where the spatial relation at the anchor (``S``, ``D``) puts it. Returns ``agree (m,)``
    (within ``max_disagreement`` of that), the affinities ``M (K, m, 2, 2)`` from the
    template camera's template into each camera's frame and the positions ``(K, m, 2)``
    (NaN for the template camera)."""
    K, m = xy.shape[:2]
    tm = p.template
    agree = np.ones(m, bool)
    M = A.copy()
    pos = np.full((K, m, 2), np.nan)
    for k in range(K):
        if k == tm:
            continue
        expect = xy[k] + np.einsum("nij,nj->ni", A[k], anchors.D[k, idx])
        res = match_templates(anchors.templates[tm], idx, nxt[k], expect,
                              A[k] @ anchors.S[k, idx], **_lsm(p))
        pos[k] = res.xy
        agree &= res.ok & (np.linalg.norm(res.xy - expect, axis=1) <= p.max_disagreement)
        M[k] = res.A
    return agree, M, pos


def _start_maps(template: int, xy, cams) -> np.ndarray:
    """The spatial LSM's starting maps ``(K, n, 2, 2)`` at the points ``xy`` ``(K, n, 2)``:
    the identity, or (cameras ``cams``) the predicted map into the cameras that need it."""
    K, n = xy.shape[:2]
    A = _eye(K, n)
    if cams is None or not n:
        return A
    X = triangulate(cams, xy, min_angle_deg=0.0).points
    depth = camera_depth(cams[template], X)
    good = np.isfinite(depth) & (depth > 0)
    if not good.any():
        return A
    warped = warped_images(cams, template, float(np.median(depth[good])), warp="auto")
    if not warped:
        return A
    maps = predicted_maps(cams, template, X[good])
    for k in warped:
        ok = np.isfinite(maps[k]).all(axis=(1, 2))
        A[k, np.flatnonzero(good)[ok]] = maps[k][ok]
    return A


def _spatial_start(anchors: _Anchors, splines, xy, p: TrackerParams,
                   start_cameras=None) -> np.ndarray:
    """Spatial relation ``S``, ``D`` of freshly sampled templates (all rows of ``anchors``)
    at their positions ``xy`` ``(K, n, 2)``, the LSM started from the identity or from the
    map ``start_cameras`` predict (:func:`_start_maps`). Returns ``confirmed (n,)``: every
    template is textured and (K > 1) the spatial LSM lands within ``max_disagreement`` of
    each camera's start position."""
    K, n = xy.shape[:2]
    confirmed = np.all([tm.ok for tm in anchors.templates], axis=0)
    tm, rows = p.template, np.arange(n)
    start = _start_maps(tm, xy, start_cameras) if K > 1 and n else None
    for k in range(K if K > 1 and n else 0):
        if k == tm:
            continue
        res = match_templates(anchors.templates[tm], rows, splines[k], xy[k], start[k],
                              **_lsm(p))
        anchors.S[k, res.ok] = res.A[res.ok]
        anchors.D[k, res.ok] = res.xy[res.ok] - xy[k, res.ok]
        confirmed &= res.ok & (np.linalg.norm(res.xy - xy[k], axis=1) <= p.max_disagreement)
    return confirmed


def _anchor_fallback(state: _State, splines, t: int, rows, p: TrackerParams) -> None:
    """Fallback templates from frame ``t`` (the tracks' last frame, matched with their first
    templates): the spatial relation is carried over from the first templates."""
    if not rows.size:
        return
    K = len(splines)
    new = _Anchors.sampled(splines, state.xy[t][:, rows], t, p)
    A1 = state.first.A[:, rows]
    if K > 1:
        new.S[:] = A1 @ state.first.S[:, rows] @ np.linalg.inv(A1[p.template])[None]
        new.D[:] = np.einsum("knij,knj->kni", A1, state.first.D[:, rows])
    state.fallback.put(rows, new)
    state.link[:, rows] = A1
    state.on_fallback[rows] = True


def _accept(state: _State, nxt, t: int, rows, xy, A, sigma0, M, off, fb,
            p: TrackerParams) -> None:
    """Write the accepted tracks at frame ``t``; re-anchor the fallback templates that are
    due (every accepted track's first templates with ``anchor="previous"``)."""
    state.recovered[t, rows] = state.end[rows] < t - 1
    state.xy[t][:, rows] = xy
    state.end[rows] = t
    state.status[rows] = TrackStatus.ALIVE.value
    state.on_fallback[rows] = fb
    r1, r2 = rows[~fb], rows[fb]
    state.first.A[:, r1] = A[:, ~fb]
    state.fallback.A[:, r2] = A[:, fb]
    state.first.A[:, r2] = A[:, fb] @ state.link[:, r2]
    state.anchor[t, r1] = state.first.frame[r1]
    state.anchor[t, r2] = state.fallback.frame[r2]
    for anchors, r, s in ((state.first, r1, sigma0[:, ~fb]), (state.fallback, r2, sigma0[:, fb])):
        anchors.sigma_ref[:, r] = np.where(np.isnan(anchors.sigma_ref[:, r]), s,
                                           anchors.sigma_ref[:, r])
    if p.anchor == "previous":
        _reanchor(state.first, nxt, t, rows, xy, A, M, off, p)
        return
    Af = A[:, fb]
    grown = (sigma0[:, fb] > p.reanchor_sigma0 * state.fallback.sigma_ref[:, r2]).any(axis=0)
    bent = (np.linalg.norm(Af - np.eye(2), ord=2, axis=(2, 3)) > p.reanchor_distortion).any(0)
    due = grown | bent
    if due.any():
        _reanchor(state.fallback, nxt, t, r2[due], xy[:, fb][:, due], Af[:, due],
                  M[:, fb][:, due], off[:, fb][:, due], p)
        state.link[:, r2[due]] = state.first.A[:, r2[due]]


def _reanchor(anchors: _Anchors, nxt, t: int, rows, xy, A, M, off, p: TrackerParams) -> None:
    """New templates at ``xy`` ``(K, n, 2)`` of frame ``t`` for ``rows`` (matched there with
    the affinities ``A``); the spatial relation follows from the spatial results
    (``S_k = M_k A_tm^-1``, ``D = off``), ``A`` restarts at the identity."""
    new = _Anchors.sampled(nxt, xy, t, p)
    if len(nxt) > 1:
        new.S[:] = M @ np.linalg.inv(A[p.template])[None]
        new.D[:] = off
    anchors.put(rows, new)


# ---------------------------------------------------------------------- one step
@dataclass(frozen=True)
class StepResult:
    """One attempt of one temporal step for n tracks in K cameras (see :func:`track_step`).

    Attributes
    ----------
    ok : (n,) bool array
        Accepted: every temporal LSM passed its thresholds and (K > 1) every spatial LSM
        stayed within ``max_disagreement`` of the temporal result.
    direct : (K, n) bool array
        Matched from the prediction, without the correlation search.
    correlation_xy : (K, n, 2) array
        Best correlation positions in the next frame, px (NaN: not searched, or no peak
        inside the box).
    xy : (K, n, 2) array
        Temporal LSM results, px (NaN where the LSM failed or was not reached).
    temporal_A : (K, n, 2, 2) array
        Affinities of the temporal LSM (anchor template to next frame; NaN where failed).
    spatial_xy : (K, n, 2) array
        Spatial LSM results (template camera matched into camera k), px; NaN for the
        template camera and where not computed.
    spatial_A : (K, n, 2, 2) array
        Spatial affinities of the anchor templates (template camera to camera k) used.
    """

    ok: np.ndarray
    direct: np.ndarray
    correlation_xy: np.ndarray
    xy: np.ndarray
    temporal_A: np.ndarray
    spatial_xy: np.ndarray
    spatial_A: np.ndarray


def track_step(frame, next_frame, xy, predicted, radius, *, params: TrackerParams | None = None,
               direct: bool = True, splines=None) -> StepResult:
    """One temporal step of tracks anchored in ``frame``, exactly as :func:`track_points`
    makes its first step (Fig. 7).

    Templates are anchored at ``xy`` (with the spatial LSM between the cameras); each is
    matched into ``next_frame`` from ``predicted`` (if ``direct``) and, where that fails,
    from the best correlation position in the box of ``radius``; then (K > 1) the spatial
    check. No retry in a bigger box (call again with ``params.retry_radius``).

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
    direct : bool
        Try the anchored LSM from the prediction first (the tracker does for every track
        with a history).
    splines : (frame's, next_frame's) sequences of K SplineImage, optional
        The interpolants of these same images, built by the caller (who calls again with
        an image: each is prefiltered once); built here when None. Interpolants of other
        images of the same size are not detected and give wrong tracks.

    Returns
    -------
    StepResult
    """
    p = params or TrackerParams()
    if len(frame) != len(next_frame):
        raise ValueError(f"next_frame: expected {len(frame)} images (one per camera), got "
                         f"{len(next_frame)}")
    seq = as_sequences([[a, b] for a, b in zip(frame, next_frame)])      # (K, 2, H, W)
    K = seq.shape[0]
    _check_params(p, K)
    cur = as_array(xy, "xy", shape=(K, None, 2))
    pred = as_array(predicted, "predicted", shape=cur.shape)
    n = cur.shape[1]
    r = np.broadcast_to(np.asarray(radius), (n,))
    if r.size and (r.dtype == bool or np.any(r != np.rint(r)) or np.any(r < 1)):
        raise ValueError(f"radius: expected integers >= 1 (pixels), got {radius}")
    if splines is None:
        splines = [SplineImage(seq[k, 0], "frame") for k in range(K)]
        nxt = [SplineImage(seq[k, 1], "next_frame") for k in range(K)]
    else:
        pair = list(splines) if isinstance(splines, (tuple, list)) else []
        if len(pair) == 2 and all(isinstance(s, (tuple, list)) for s in pair):
            splines, nxt = (list(s) for s in pair)
        else:
            splines, nxt = [], []
        if not len(splines) == len(nxt) == K or any(
                not isinstance(s, SplineImage) or s.shape != seq.shape[2:]
                for s in splines + nxt):
            raise ValueError(f"splines: expected two sequences of {K} SplineImage of shape "
                             f"{seq.shape[2:]} (the images'), got {splines!r:.60}, {nxt!r:.60}")
    first = _Anchors.sampled(splines, cur, 0, p)
    _spatial_start(first, splines, cur, p)
    rows = np.arange(n)
    st = _temporal(first, seq, nxt, 1, rows, pred, r.astype(np.int64), p,
                   direct=np.full(n, bool(direct)), box=np.ones(n, bool))
    ok = st.ok.copy()
    sp_xy = np.full((K, n, 2), np.nan)
    if K > 1 and ok.any():
        sel = np.flatnonzero(ok)
        agree, _, sp_xy[:, sel] = _spatial(first, nxt, sel, st.xy[:, sel], st.temporal_A[:, sel],
                                           p)
        ok[sel[~agree]] = False
    return StepResult(ok=ok, direct=st.direct, correlation_xy=st.correlation_xy, xy=st.xy,
                      temporal_A=st.temporal_A, spatial_xy=sp_xy, spatial_A=first.S.copy())
