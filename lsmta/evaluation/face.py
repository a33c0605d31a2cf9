"""Face-model trials: generated or real face sequences, markers hidden, filled, scored.

Notebook 13 is built from these functions. Errors are distances (mm) between a filled
marker and its true position, over the markers that were missing only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations

import cv2
import numpy as np

from .._validate import as_int, as_rng
from ..face import (
    FaceChoice,
    FaceParams,
    align_sequence,
    build_face_model,
    extreme_basis,
    fill_missing,
    learn,
    pca_basis,
    pca_gap_fill,
)
from ..rigid import apply_rigid, fit_rigid
from ..synth.face import face_cameras, face_sequence, visible
from ..synth.head_surface import self_occlusion
from ..synth.marker_video import render_marker_video
from ..tracking.markers import MarkerStatus, MarkerTrackingParams, track_markers
from ..triangulation import triangulate, triangulate_single_pair

METHODS = ("extremes, w in [0,1]", "extremes, w free", "PCA mean + k, w free",
           "peer: PCA gap filling", "learned default (face.learn)")


@dataclass(frozen=True)
class Observation:
    """A face sequence as the small-scale system measures it.

    Attributes
    ----------
    points : (T, M, 3) array
        Triangulated markers, mm; NaN where the chosen pair does not see a marker.
    pair : (T, 2) int array
        Camera pair used in each frame.
    n_visible : (T, K) int array
        Markers each camera sees.
    seen : (T, K, M) bool array or None
        Which markers each camera sees: not hidden by the head and inside its image
        (:func:`observe_face`; None from :func:`observe_tracked`).
    unhidden : (T, K, M) bool array or None
        Which markers the head does not hide from each camera, whether in its image or not
        (:func:`observe_face`: the surface normal test or the ray casting alone).
    """

    points: np.ndarray
    pair: np.ndarray
    n_visible: np.ndarray
    seen: np.ndarray | None = None
    unhidden: np.ndarray | None = None


def _perturb(cam, rng, deg):
    if deg <= 0:
        return cam
    dR, _ = cv2.Rodrigues(np.radians(rng.normal(0, deg, 3)))
    return cam.replace(R=dR @ cam.R)


def observe_face(seq, *, rng: np.random.Generator | int | None = None,
                 pixel_noise: float = 0.5, pose_noise_deg: float = 0.1, min_cos: float = 0.3,
                 pairing: str = "single", positions=None,
                 occlusion: str = "normals") -> Observation:
    """Image and triangulate a generated face sequence (:mod:`lsmta.synth.face`).

    No marker tracking is simulated here (see :func:`observe_tracked` for the section 5.1
    tracker on rendered video): the tracked image positions are the true projections plus
    Gaussian noise, with every marker correctly identified.

    In every frame four narrow-field cameras aim at the head (:func:`face_cameras`, at
    ``positions`` if given: ``(K, 3)`` camera centres, mm); the
    images come from cameras whose orientation is off by ``pose_noise_deg`` per axis (the
    thesis's 0.1 degree pan-tilt precision) while the triangulation uses the nominal
    ones; tracked image positions carry ``pixel_noise`` px of Gaussian noise; markers
    outside the image are not seen, nor markers hidden by the head: with
    ``occlusion="normals"`` those facing away (:func:`visible` with ``min_cos``), with
    ``occlusion="surface"`` those whose line of sight passes through the head
    (:func:`lsmta.synth.head_surface.self_occlusion`, ray casting; ``min_cos`` unused).

    ``pairing="single"``: all markers of a frame come from the single pair seeing the most
    of them (the thesis's choice). ``pairing="per_marker"``: each marker comes from a pair
    drawn at random among the pairs that see it (what the thesis warns against: each
    pair's pose error then shifts its markers differently). Both modes draw the same
    image noise from ``rng``, so they can be compared on the same images. ``pair`` is
    (-1, -1) for per-marker frames.
    """
    rng = as_rng(rng)
    if pairing not in ("single", "per_marker"):
        raise ValueError(f"pairing: expected 'single' or 'per_marker', got {pairing!r}")
    if occlusion not in ("normals", "surface"):
        raise ValueError(f"occlusion: expected 'normals' or 'surface', got {occlusion!r}")
    choice_rng = np.random.default_rng(rng.integers(2 ** 63))
    T, M, _ = seq.world.shape
    unhidden = None
    if occlusion == "surface":      # camera centres do not depend on where they aim
        centres = np.array([c.C for c in face_cameras(seq.t[0], positions=positions)])
        unhidden = self_occlusion(seq.world, seq.R, seq.t, centres, neutral=seq.neutral)
    pts = np.full((T, M, 3), np.nan)
    pairs = np.zeros((T, 2), dtype=int)
    seen = raw = None
    for f in range(T):
        cams = face_cameras(seq.t[f], positions=positions)
        if seen is None:
            seen = np.zeros((T, len(cams), M), dtype=bool)
            raw = np.zeros((T, len(cams), M), dtype=bool)
        xy = np.full((len(cams), M, 2), np.nan)
        for k, cam in enumerate(cams):
            true_cam = _perturb(cam, rng, pose_noise_deg)
            p = true_cam.project(seq.world[f], behind="nan")
            p = p + rng.normal(0, pixel_noise, p.shape)
            if unhidden is None:
                ok = visible(seq.world[f], seq.normals[f], cam.C, min_cos=min_cos)
            else:
                ok = unhidden[f, k].copy()
            raw[f, k] = ok
            ok &= cam.in_image(p) & np.isfinite(p).all(axis=1)
            xy[k, ok] = p[ok]
            seen[f, k] = ok
        if pairing == "single":
            r = triangulate_single_pair(cams, xy)
            pts[f] = r.intersection.points
            pairs[f] = r.pair
            continue
        pairs[f] = -1
        cand = []
        for i, j in combinations(range(len(cams)), 2):
            cand.append(triangulate([cams[i], cams[j]], xy[[i, j]]).points)
        cand = np.stack(cand)                           # (pairs, M, 3)
        ok = np.isfinite(cand).all(axis=2)
        keys = np.where(ok, choice_rng.random(ok.shape), -1.0)
        pick = keys.argmax(axis=0)
        has = ok.any(axis=0)
        pts[f, has] = cand[pick[has], np.flatnonzero(has)]
    return Observation(points=pts, pair=pairs, n_visible=seen.sum(axis=2), seen=seen,
                       unhidden=raw)


def to_head(points, R, t):
    """World points (T, M, 3) into each frame's head frame (``R``, ``t`` from the
    generator)."""
    return np.einsum("tji,tmj->tmi", R, np.asarray(points) - np.asarray(t)[:, None])


def fill_all(gappy, training, *, n_basis: int, n_components: int,
             peer_components: int | None = None, learned=None) -> dict:
    """Fill ``gappy`` (T, M, 3) with every method of :data:`METHODS`.

    ``n_basis`` extreme faces (constrained and free weights), a PCA basis of
    ``n_components`` (mean + k, free weights), the peer (Gløersen & Federolf's full
    method), which learns from the complete frames of ``training`` (and ``gappy``) with
    ``peer_components`` components (default: as the authors' code chooses), and the
    default model of :func:`lsmta.face.learn` trained on ``training`` (``learned``: that
    model, if already learnt). Returns ``{method: (T, M, 3) filled}``.
    """
    ext = extreme_basis(training, n_basis)
    pca = pca_basis(training, n_components)
    out = {
        METHODS[0]: fill_missing(gappy, ext, constrain=True).frames,
        METHODS[1]: fill_missing(gappy, ext, constrain=False).frames,
        METHODS[2]: fill_missing(gappy, pca).frames,
        METHODS[3]: pca_gap_fill(gappy, training=training,
                                 n_components=peer_components).frames,
        METHODS[4]: (learn(training) if learned is None else learned).fill(gappy).frames,
    }
    return out


@dataclass(frozen=True)
class RemovalTrials:
    """Figs. 65/66: the same markers removed from every frame of a still head, filled by
    every method of :data:`METHODS`, one entry per run.

    Attributes
    ----------
    xy : dict
        Method -> list (one per run) of ``(n, 2)`` errors of the filled markers in the
        head's frontal XY plane (mm), as Fig. 66 plots them.
    removed : list of (n_removed,) int arrays
        The markers removed in each run.
    """

    xy: dict
    removed: list

    @property
    def errors(self) -> dict:
        """Method -> list of ``(n,)`` XY error lengths (mm)."""
        return {m: [np.linalg.norm(d, axis=1) for d in v] for m, v in self.xy.items()}


def removal_trials(model, seeds, *, n_train: int, n_test: int, n_removed: int,
                   n_basis: int, n_components: int, noise_mm: float) -> RemovalTrials:
    """Run the Fig. 65/66 experiment once per entry of ``seeds``.

    Per run, with ``numpy.random.default_rng(seed)``: a still-head training sequence of
    ``n_train`` frames and a test sequence of ``n_test`` frames (``face_sequence``), both
    with Gaussian noise of ``noise_mm`` per axis; ``n_removed`` markers removed from every
    test frame; every method of :func:`fill_all` (``n_basis`` extreme faces,
    ``n_components`` for the PCA basis and the peer) fills them; errors against the
    noise-free test frames.
    """
    xy = {m: [] for m in METHODS}
    removed_all = []
    M = len(model.labels)
    for seed in seeds:
        r = np.random.default_rng(seed)
        tr = face_sequence(model, n_train, rng=r, moving=False).head
        tr = tr + r.normal(0, noise_mm, tr.shape)
        te = face_sequence(model, n_test, rng=r, moving=False).head
        gappy = te + r.normal(0, noise_mm, te.shape)
        removed = r.choice(M, n_removed, replace=False)
        observed = np.ones((n_test, M), bool)
        observed[:, removed] = False
        gappy[~observed] = np.nan
        for name, filled in fill_all(gappy, tr, n_basis=n_basis, n_components=n_components,
                                     peer_components=n_components).items():
            xy[name].append((filled - te)[~observed][:, :2])   # frontal plane of the head
        removed_all.append(removed)
    return RemovalTrials(xy=xy, removed=removed_all)


#: what :func:`held_out_half` compares: the default, plain PCA with its size chosen on the
#: training half (the target's peer), and the fixed models named in ``fixed``
HALF_DEFAULT = "default: learn(training half)"
HALF_PCA = "plain PCA, size chosen on the training half"


@dataclass(frozen=True)
class HeldOutHalf:
    """A face model chosen on the first half of a sequence and scored on the second
    (:func:`held_out_half`).

    Attributes
    ----------
    n_train, n_test : int
        Frames of the training (first) and test (second) half.
    choice : FaceChoice
        The default's cross-validation on the training half (its table and reason).
    pca_size : int
        Components of plain PCA chosen on the training half (the lowest CV error).
    errors : dict
        Method -> (N,) distances of the hidden test markers from their recorded positions,
        pooled over the draws, mm.
    """

    n_train: int
    n_test: int
    choice: FaceChoice
    pca_size: int
    errors: dict

    def summary(self) -> dict:
        """Method -> ``{"median": mm, "mean": mm}``."""
        return {m: {"median": float(np.median(e)), "mean": float(e.mean())}
                for m, e in self.errors.items()}


def held_out_half(sequence, *, n_hidden: int, draws: int = 3,
                  rng: np.random.Generator | int | None = None,
                  params: FaceParams | None = None, fixed=(("pca", 10), ("box", 20))
                  ) -> HeldOutHalf:
    """The protocol of notebook 13 and ``experiments/face_models.py``: choose on the first
    half of a sequence, report on the second.

    The first half in time is the training half: :func:`lsmta.face.learn` (the default,
    ``method="auto"``) and plain PCA with its size chosen by the same cross-validation
    (the lowest-scoring PCA size of the default's table, which is what ``method="pca"``
    chooses) see only it, with ``n_hidden`` markers hidden at random per held-out
    frame, as in the test. In every frame of the second half ``n_hidden`` markers are hidden
    at random (``draws`` independent draws, the same for every method) and filled by each
    model; the errors are pooled over the draws. ``fixed``: further (method, size) models
    built on the training half without a choice (default: plain PCA with 10 components and
    the earlier fixed default, box with 20).

    Parameters
    ----------
    sequence : (T, M, 3) array
        Complete marker positions, mm (the recorded positions serve as the truth).
    n_hidden : int
        Markers hidden per frame, in [1, M - 3].
    draws : int
    rng : numpy.random.Generator, int or None
        The hidden markers of the test half (the cross-validation's own draws are seeded
        by :func:`lsmta.face.learn`).
    params : FaceParams, optional
        The cross-validation's settings; its ``hidden`` is set to ``n_hidden / M``.
    fixed : sequence of (str, int)

    Returns
    -------
    HeldOutHalf
    """
    X = np.asarray(sequence, dtype=float)
    if X.ndim != 3 or X.shape[2] != 3 or not np.isfinite(X).all():
        raise ValueError(f"sequence: expected a complete (T, M, 3) array, got shape {X.shape}")
    T, M, _ = X.shape
    n_hidden = as_int(n_hidden, "n_hidden")
    if not 1 <= n_hidden <= M - 3:
        raise ValueError(f"n_hidden: expected an integer in [1, {M - 3}], got {n_hidden}")
    draws = as_int(draws, "draws")
    rng = as_rng(rng)
    params = replace(FaceParams() if params is None else params, hidden=n_hidden / M)
    train, test = X[:T // 2], X[T // 2:]
    default = learn(train, params=params)
    # plain PCA at the size the same cross-validation scores lowest: what
    # learn(train, method="pca", params=params) chooses (the same blocks and hidden markers)
    pca_size = default.choice.best_pca[1]
    models = {HALF_DEFAULT: default,
              HALF_PCA: build_face_model(train, method="pca", size=pca_size, n_iter=params.n_iter)}
    for m, k in fixed:
        name = f"plain PCA, {k} components" if m == "pca" else f"{m} {k}"
        models[name] = build_face_model(train, method=m, size=k, n_iter=params.n_iter)
    parts = {name: [] for name in models}
    for _ in range(draws):
        vis = random_visibility(len(test), M, M - n_hidden, rng=rng)
        gap = np.where(vis[..., None], test, np.nan)
        for name, model in models.items():
            e = missing_errors(model.fill(gap).frames, test, vis)
            parts[name].append(e[np.isfinite(e)])
    return HeldOutHalf(n_train=len(train), n_test=len(test), choice=default.choice,
                       pca_size=pca_size,
                       errors={k: np.concatenate(v) for k, v in parts.items()})


def missing_errors(filled, truth, observed):
    """Distances (mm) of the filled markers from the truth: (T, M) with NaN where the
    marker was observed."""
    e = np.linalg.norm(np.asarray(filled) - np.asarray(truth), axis=2)
    return np.where(observed, np.nan, e)


def random_visibility(n_frames: int, n_markers: int, n_visible, *,
                      rng: np.random.Generator | int | None = None) -> np.ndarray:
    """(T, M) bool: in each frame ``n_visible`` (scalar or (T,)) markers chosen at random
    are observed."""
    nv = np.broadcast_to(np.asarray(n_visible), (n_frames,))
    keys = as_rng(rng).random((n_frames, n_markers))
    rank = keys.argsort(axis=1).argsort(axis=1)
    return rank < nv[:, None]


def truth_on_measured(truth, measured):
    """The true markers carried rigidly onto each frame's measured (observed) markers.

    The small-scale system is judged on relative geometry (thesis section 5.5): a bias
    shared by the whole face, as from an error in the camera pair's pose, is removed by
    fitting the rigid motion truth -> measured on the markers measured in that frame.

    Parameters
    ----------
    truth : (T, M, 3) array
        Complete true positions, mm.
    measured : (T, M, 3) array
        Measured positions, NaN where missing, mm.

    Returns
    -------
    (T, M, 3) array
        Every true marker in the measured frame's pose (NaN for frames with fewer than 3
        measured markers).
    """
    truth = np.asarray(truth, dtype=float)
    measured = np.asarray(measured, dtype=float)
    ok = np.isfinite(measured).all(axis=2)
    out = np.full_like(truth, np.nan)
    for f in np.flatnonzero(ok.sum(axis=1) >= 3):
        R, t = fit_rigid(truth[f, ok[f]], measured[f, ok[f]])
        out[f] = apply_rigid(R, t, truth[f])
    return out


def binned_median(values, keys, edges):
    """Median of the finite ``values`` (T, M) over frames whose ``keys`` (T,) fall in
    each bin ``[edges[i], edges[i+1])``; NaN for an empty bin."""
    values = np.asarray(values, dtype=float)
    keys = np.asarray(keys)
    out = np.full(len(edges) - 1, np.nan)
    for i in range(len(edges) - 1):
        v = values[(keys >= edges[i]) & (keys < edges[i + 1])]
        v = v[np.isfinite(v)]
        if v.size:
            out[i] = np.median(v)
    return out


def peer_after_alignment(gappy, training, *, n_components: int):
    """The peer (:func:`lsmta.face.pca_gap_fill`) given the same per-frame rigid alignment
    the basis-face fits make: each frame's observed markers are carried rigidly (Kabsch)
    onto the training sequence's mean shape, the gaps are filled there from the aligned
    training frames, and the frame is carried back. No oracle is needed.

    Parameters
    ----------
    gappy : (T, M, 3) array
        Marker positions with NaN gaps, mm. Not modified.
    training : (S, M, 3) array
        Complete training sequence, mm.
    n_components : int

    Returns
    -------
    (T, M, 3) array
        ``gappy`` with its gaps filled (frames with fewer than 3 observed markers keep
        their NaN), mm.
    """
    gappy = np.asarray(gappy, dtype=float)
    train_al, ref = align_sequence(training)
    ok = np.isfinite(gappy).all(axis=2)
    aligned = np.full_like(gappy, np.nan)
    Rs = np.full((len(gappy), 3, 3), np.nan)
    ts = np.full((len(gappy), 3), np.nan)
    for f in np.flatnonzero(ok.sum(axis=1) >= 3):
        Rs[f], ts[f] = fit_rigid(gappy[f, ok[f]], ref[ok[f]])
        aligned[f] = apply_rigid(Rs[f], ts[f], gappy[f])
    filled = pca_gap_fill(aligned, training=train_al, n_components=n_components).frames
    out = gappy.copy()
    for f in np.flatnonzero(ok.sum(axis=1) >= 3):
        back = (filled[f] - ts[f]) @ Rs[f]
        out[f, ~ok[f]] = back[~ok[f]]
    return out


@dataclass(frozen=True)
class TrackedCapture:
    """A face sequence imaged as video and measured by tracking the markers
    (:func:`observe_tracked`).

    Attributes
    ----------
    observation : Observation
        Single-pair triangulation of the tracked positions.
    truth_xy : (K, T, M, 2) array
        True image positions of the drawn markers, px (NaN where not drawn).
    tracked_xy : (K, T, M, 2) array
        Positions the tracker found (first or second search), px; NaN elsewhere (lost,
        blurred frame, or a start position).
    status : (K, T, M) int array
        Tracker status codes (:mod:`lsmta.tracking.markers`).
    images : list of (T, H, W) uint8 arrays, or None
        The rendered videos (``keep_images=True``).
    blurred : (T,) bool array
        Frames rendered with motion blur.
    crowded : (K, T, M) bool array
        Drawn markers with another drawn marker within 6 px in the image (their
        dots merge: e.g. chin markers seen from below).
    seeds : (K, T, M, 2) array
        Start positions given to the tracker (NaN elsewhere).
    """

    observation: Observation
    truth_xy: np.ndarray
    tracked_xy: np.ndarray
    status: np.ndarray
    images: list | None
    blurred: np.ndarray
    crowded: np.ndarray
    seeds: np.ndarray


def crowded_markers(xy, *, crowd_px: float = 6.0) -> np.ndarray:
    """``(..., M)`` bool: image points ``(..., M, 2)`` with another point (not NaN)
    closer than ``crowd_px``."""
    xy = np.asarray(xy, dtype=float)
    d = np.linalg.norm(xy[..., :, None, :] - xy[..., None, :, :], axis=-1)
    d[..., np.arange(xy.shape[-2]), np.arange(xy.shape[-2])] = np.inf
    with np.errstate(invalid="ignore"):
        return np.nan_to_num(d, nan=np.inf).min(axis=-1) < crowd_px


def observe_tracked(seq, *, rng: np.random.Generator | int | None = None,
                    pose_noise_deg: float = 0.1,
                    min_cos: float = 0.3, cameras=None, blur_frames=(),
                    image_noise: float = 2.0, seed_noise: float = 0.5,
                    keep_images: bool = False, tracker: MarkerTrackingParams | None = None,
                    positions=None) -> TrackedCapture:
    """Like :func:`observe_face`, but the image positions come from tracking rendered video.

    Each camera's video is rendered (:func:`lsmta.synth.marker_video.render_marker_video`)
    from cameras aimed at the head in every frame and off by ``pose_noise_deg`` per axis
    and frame (the pan-tilt jitter the tracker's stabilisation removes), with motion blur
    on ``blur_frames``. Markers are tracked with
    :func:`lsmta.tracking.markers.track_markers` (settings ``tracker``); a marker
    is started at its true position plus ``seed_noise`` px of Gaussian noise in frame 0
    and whenever it becomes visible again (a stand-in for identifying it by hand; the
    tracker does not re-acquire markers). Only positions the tracker found are
    triangulated, with the nominal cameras, from the single pair seeing the most.
    ``cameras``: indices of the :func:`face_cameras` used (default all; at ``positions``
    if given, as in :func:`observe_face`).
    """
    rng = as_rng(rng)
    T, M, _ = seq.world.shape
    nominal = [face_cameras(seq.t[f], positions=positions) for f in range(T)]
    ks = list(range(len(nominal[0]))) if cameras is None else list(cameras)
    K = len(ks)
    truth = np.full((K, T, M, 2), np.nan)
    found = np.full((K, T, M, 2), np.nan)
    status = np.zeros((K, T, M), dtype=int)
    images = [] if keep_images else None
    blurred = np.zeros(T, bool)
    all_seeds = np.full((K, T, M, 2), np.nan)
    for i, k in enumerate(ks):
        true_cams = [_perturb(nominal[f][k], rng, pose_noise_deg) for f in range(T)]
        vis = np.stack([visible(seq.world[f], seq.normals[f], nominal[f][k].C,
                                min_cos=min_cos) for f in range(T)])
        video = render_marker_video(true_cams, seq.world, vis, seq.t, rng=rng,
                                    noise=image_noise, blur_frames=blur_frames)
        drawn = np.isfinite(video.xy).all(axis=2)
        start = drawn & ~np.vstack([np.zeros((1, M), bool), drawn[:-1]])
        seeds = np.where(start[..., None], video.xy + rng.normal(0, seed_noise, video.xy.shape),
                         np.nan)
        all_seeds[i] = seeds
        tr = track_markers(video.images, seeds[0], seeds=seeds, params=tracker)
        ok = np.isin(tr.status, (MarkerStatus.TRACKED, MarkerStatus.SECOND_SEARCH))
        ok[0] = False
        found[i][ok] = tr.xy[ok]
        truth[i] = video.xy
        status[i] = tr.status
        blurred = video.blurred
        if keep_images:
            images.append(video.images)
    pts = np.full((T, M, 3), np.nan)
    pairs = np.zeros((T, 2), dtype=int)
    nvis = np.isfinite(found).all(axis=3).sum(axis=2).T
    for f in range(T):
        cams = [nominal[f][k] for k in ks]
        r = triangulate_single_pair(cams, found[:, f])
        pts[f] = r.intersection.points
        pairs[f] = [ks[j] for j in r.pair]
    return TrackedCapture(observation=Observation(points=pts, pair=pairs, n_visible=nvis),
                          truth_xy=truth, tracked_xy=found, status=status, images=images,
                          blurred=blurred, crowded=crowded_markers(truth), seeds=all_seeds)


def tracking_errors(capture: TrackedCapture, *, n_frames: int | None = None,
                    params: MarkerTrackingParams | None = None) -> dict:
    """Track the kept videos of ``capture`` again (first ``n_frames``, same start
    positions) with the tracker's settings ``params`` and score against the truth.

    Returns a dict: ``median``, ``p95`` (px, markers found in frames 1.., crowded markers
    excluded), ``wrong`` (share of those more than 2 px off: jumped to another marker),
    ``found`` (share of drawn, uncrowded marker images in frames 1.. the tracker found).
    Without ``params`` and ``n_frames`` it scores the capture as made.
    """
    if capture.images is None:
        raise ValueError("capture: made without keep_images=True")
    T = capture.truth_xy.shape[1] if n_frames is None else as_int(n_frames, "n_frames")
    errs, found, drawn = [], 0, 0
    for k, images in enumerate(capture.images):
        if params is not None or n_frames is not None:
            tr = track_markers(images[:T], capture.seeds[k, 0],
                               seeds=capture.seeds[k, :T], params=params)
            ok = np.isin(tr.status, (MarkerStatus.TRACKED, MarkerStatus.SECOND_SEARCH))
            xy = np.where(ok[..., None], tr.xy, np.nan)
        else:
            xy = capture.tracked_xy[k]
        e = np.linalg.norm(xy[1:T] - capture.truth_xy[k, 1:T], axis=2)
        sep = ~capture.crowded[k, 1:T] & np.isfinite(capture.truth_xy[k, 1:T, :, 0])
        errs.append(e[sep & np.isfinite(e)])
        found += int((sep & np.isfinite(e)).sum())
        drawn += int(sep.sum())
    e = np.concatenate(errs)
    return dict(median=float(np.median(e)), p95=float(np.percentile(e, 95)),
                wrong=float(np.mean(e > 2.0)), found=found / max(drawn, 1))
