"""Tracking trials: rendered walk / arm sequences, start points from truth, scores.

A tracked point starts on a known body surface point; its truth in every frame is that
surface point's projection and 3-D position. A trajectory is *false* from the first frame
where its 3-D position lies more than ``false_mm`` from its true surface point.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from .._validate import as_rng
from ..camera import scaled_camera
from ..synth import Scene, arm_wave, make_body, triplet_rig, walk
from ..synth.face import face_cameras, face_model, face_sequence, visible
from ..synth.marker_video import render_marker_video
from ..synth.sequence import Sequence, render_sequence
from ..tracking.klt import track_klt
from ..tracking.points import Tracks, track_points
from ..tracking.trajectories import Trajectories, trajectories_from_tracks


def walk_sequence(*, seed: int = 2000, n_frames: int = 30, scale: float = 0.5, motion: str = "walk",
                  noise_sigma: float = 2.0, step: int = 4, surface_every: int = 2,
                  speed: float = 700.0) -> Sequence:
    """A rendered triplet sequence of the textured body.

    ``scale`` shrinks the 768 x 576 images of the rig (0.5: 384 x 288, four times faster to
    render); the rig stands 3 m from the subject with a 0.8 m baseline. ``motion`` is
    ``"walk"`` (walking slowly to the right at ``speed`` mm/s) or ``"arm"`` (seated arm
    wave). Surface points are sampled every ``surface_every`` frames (the density check's
    candidates) on a ``step`` pixel grid of the centre image.
    """
    rng = np.random.default_rng(seed)
    cams = [scaled_camera(c, scale) for c in triplet_rig(rng=rng, distance=3000.0, baseline=800.0)]
    if motion == "walk":
        mot = walk(n_frames=n_frames, start=(-250.0, 0.0), speed=speed, stride=1.2e3)
    elif motion == "arm":
        mot = arm_wave(n_frames=n_frames)
    else:
        raise ValueError(f"motion: expected 'walk' or 'arm', got {motion!r}")
    # the texture band is scaled with the image so it stays a few pixels per wavelength
    body = make_body(rng=np.random.default_rng(seed + 1), contrast=0.3,
                     wavelength=(20.0 / scale, 80.0 / scale))
    frames = range(0, n_frames, surface_every)
    return render_sequence(Scene(body=body, motion=mot, background=None), cams, rng=rng,
                           noise_sigma=noise_sigma,
                           surface_frames=frames, step=step)


def start_points(seq: Sequence, n: int, *, rng: np.random.Generator | int | None = None,
                 frame: int = 0):
    """``n`` (or all, if fewer) of frame ``frame``'s visible surface points, spread at random.

    Returns ``(xy (K, n, 2), part (n,), local (n, 3))``.
    """
    rng = as_rng(rng)
    s = seq.surface[frame]
    m = len(s.part)
    pick = np.sort(rng.choice(m, size=min(n, m), replace=False))
    return s.xy[:, pick], s.part[pick], s.local[pick]


def candidates(seq: Sequence):
    """The density check's candidates: ``{frame: (K, M, 2)}`` from the sampled surface."""
    return {t: s.xy for t, s in seq.surface.items()}


def track_identity(seq: Sequence, tracks: Tracks, part0, local0):
    """``(part (N,), local (N, 3))`` of every track: initial points, then added ones."""
    part = np.empty(len(tracks), np.int64)
    local = np.empty((len(tracks), 3))
    n0 = len(part0)
    part[:n0], local[:n0] = part0, local0
    for i in np.flatnonzero(tracks.added):
        s = seq.surface[int(tracks.start[i])]
        part[i], local[i] = s.part[tracks.origin[i]], s.local[tracks.origin[i]]
    return part, local


@dataclass(frozen=True)
class TrackScore:
    """Errors of N tracks against their true surface points.

    Attributes
    ----------
    image_error : (T, K, N) array
        Distance to the true image position, px (NaN where untracked).
    step_error : (T, K, N) array
        Error of the frame-to-frame motion, ``|(x_t - x_{t-1}) - (true_t - true_{t-1})|``,
        px per frame.
    error_3d : (T, N) array
        3-D distance to the true surface point, mm (NaN without trajectory).
    false_from : (N,) int array
        First frame whose 3-D error exceeds the threshold (-1: never).
    truth_xy : (T, K, N, 2) array
    truth_xyz : (T, N, 3) array
    visible : (T, K, N) bool array
    """

    image_error: np.ndarray
    step_error: np.ndarray
    error_3d: np.ndarray
    false_from: np.ndarray
    truth_xy: np.ndarray
    truth_xyz: np.ndarray
    visible: np.ndarray

    @property
    def false(self) -> np.ndarray:
        return self.false_from >= 0

    def false_frames(self, present) -> np.ndarray:
        """``(T, N)`` bool: frames from ``false_from`` on that are still ``present``."""
        T = present.shape[0]
        f = np.where(self.false_from >= 0, self.false_from, T)
        return present & (np.arange(T)[:, None] >= f[None, :])


def score_tracks(seq: Sequence, tracks: Tracks, part, local, *, traj: Trajectories | None = None,
                 false_mm: float = 10.0, false_px: float = 2.0) -> TrackScore:
    """Score tracks (and their trajectories) against the generator's truth.

    Without trajectories (2-D mode) a track is false from the first frame whose image error
    exceeds ``false_px`` pixels.
    """
    proj = seq.truth(part, local)
    truth_xy = proj.xy                                   # (T, K, N, 2)
    err = np.linalg.norm(tracks.xy - truth_xy, axis=3)
    d = tracks.xy[1:] - tracks.xy[:-1]
    dt = truth_xy[1:] - truth_xy[:-1]
    step = np.full(err.shape, np.nan)
    step[1:] = np.linalg.norm(d - dt, axis=3)
    T = err.shape[0]
    if traj is not None:
        e3 = np.linalg.norm(traj.xyz - proj.world, axis=2)
        bad = e3 > false_mm
    else:
        e3 = np.full((T, len(part)), np.nan)
        bad = (err > false_px).any(axis=1)
    false_from = np.where(bad.any(axis=0), bad.argmax(axis=0), -1)
    return TrackScore(image_error=err, step_error=step, error_3d=e3, false_from=false_from,
                      truth_xy=truth_xy, truth_xyz=proj.world, visible=proj.visible)


def by_age(values, start, *, reduce=np.nanmedian, min_count: int = 5):
    """Reduce ``(T, N)`` values over the tracks by track age (frames since each track's start).

    Returns ``(age (A,), value (A,), count (A,))``; ages with fewer than ``min_count``
    finite values give NaN.
    """
    values = np.asarray(values, float)
    T, N = values.shape
    age = np.arange(T)[:, None] - np.asarray(start)[None, :]
    ages = np.arange(T)
    out = np.full(T, np.nan)
    count = np.zeros(T, np.int64)
    for a in ages:
        v = values[(age == a) & np.isfinite(values)]
        count[a] = v.size
        if v.size >= min_count:
            out[a] = reduce(v)
    return ages, out, count


@dataclass(frozen=True)
class Trial:
    """Both trackers on one sequence from the same start points (see :func:`run_tracking_trial`);
    ``seconds`` are wall-clock, ``cpu_seconds`` the process's CPU time (every thread)."""

    sequence: Sequence
    tracks: Tracks
    traj: Trajectories
    score: TrackScore
    klt: Tracks | None
    klt_traj: Trajectories | None
    klt_score: TrackScore | None
    seconds: float
    klt_seconds: float | None
    part: np.ndarray
    local: np.ndarray
    cpu_seconds: float = float("nan")
    klt_cpu_seconds: float | None = None


def run_tracking_trial(seq: Sequence, n_points: int, *,
                       rng: np.random.Generator | int | None = None, params=None,
                       density: bool = True, false_mm: float = 10.0, klt: bool = True,
                       geometric: bool = False) -> Trial:
    """Track ``n_points`` of frame 0's surface with LSMTA (with the density check unless
    ``density`` is False; with the geometric check through the sequence's true cameras if
    ``geometric``) and, if ``klt``, with KLT; score both."""
    rng = as_rng(rng)
    xy0, part0, local0 = start_points(seq, n_points, rng=rng)
    t0, c0 = time.perf_counter(), time.process_time()
    tracks = track_points(seq.images, xy0, params=params,
                          new_points=candidates(seq) if density else None,
                          cameras=seq.cameras if geometric else None)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    part, local = track_identity(seq, tracks, part0, local0)
    traj = trajectories_from_tracks(seq.cameras, tracks, seq.fps)
    score = score_tracks(seq, tracks, part, local, traj=traj, false_mm=false_mm)
    peer = peer_traj = peer_score = peer_seconds = peer_cpu = None
    if klt:
        t0, c0 = time.perf_counter(), time.process_time()
        peer = track_klt(seq.images, xy0)
        peer_seconds, peer_cpu = time.perf_counter() - t0, time.process_time() - c0
        peer_traj = trajectories_from_tracks(seq.cameras, peer, seq.fps)
        peer_score = score_tracks(seq, peer, part0, local0, traj=peer_traj, false_mm=false_mm)
    return Trial(sequence=seq, tracks=tracks, traj=traj, score=score, klt=peer,
                 klt_traj=peer_traj, klt_score=peer_score, seconds=seconds,
                 klt_seconds=peer_seconds, part=part, local=local, cpu_seconds=cpu,
                 klt_cpu_seconds=peer_cpu)


def score_filter(before: Trajectories, after: Trajectories, score: TrackScore) -> dict:
    """How well a filtering removed false trajectories.

    A trajectory is *false* when some frame of it lies more than the score's threshold from
    its true surface point; it is *caught* when none of its false frames is left; it is
    *touched* when the filtering removed any of its frames. Returns ``recall`` (caught /
    false), ``precision`` (false / touched), ``correct_length_removed`` (share of the
    correct frames removed), ``false_length_left`` (share of the remaining frames that are
    false) and the counts.
    """
    pb, pa = before.present, after.present
    false_b = score.false_frames(pb)
    false_a = score.false_frames(pa)
    is_false = false_b.any(axis=0)
    caught = is_false & ~false_a.any(axis=0)
    touched = (pb & ~pa).any(axis=0)
    correct_b = pb & ~false_b
    n_false, n_touched = int(is_false.sum()), int(touched.sum())
    return {
        "n_trajectories": int(pb.any(axis=0).sum()), "n_false": n_false,
        "n_touched": n_touched, "n_caught": int(caught.sum()),
        "recall": float(caught.sum() / n_false) if n_false else float("nan"),
        "precision": float((touched & is_false).sum() / n_touched) if n_touched
        else float("nan"),
        "correct_length_removed": float((correct_b & ~pa).sum() / max(correct_b.sum(), 1)),
        "false_length_left": float(false_a.sum() / max(pa.sum(), 1)),
    }


@dataclass(frozen=True)
class FaceVideo:
    """A single-camera face video (2-D mode) and its truth.

    Attributes
    ----------
    images : (T, H, W) uint8 array
    truth_xy : (T, M, 2) array
        True image positions of the key points (NaN where not visible).
    edges : (E, 2) int array
        Lines joining neighbouring key points (Delaunay triangulation of frame 0).
    """

    images: np.ndarray
    truth_xy: np.ndarray
    edges: np.ndarray


def face_video(*, seed: int = 14, n_frames: int = 40, dot_amplitude: float = 40.0,
               noise: float = 2.0, hold: float = 12.0) -> FaceVideo:
    """One fixed camera (a camcorder) filming a still head making expressions.

    The key points are the 76 points of the face model, drawn as soft dots of
    ``dot_amplitude`` grey levels on a skin texture (the generator's marker video; the
    texture moves with the head only, not with the expressions).
    """
    rng = np.random.default_rng(seed)
    seq = face_sequence(face_model(), n_frames, rng=rng, moving=False, hold=hold)
    cam = face_cameras(seq.t[0])[1]
    vis = np.stack([visible(seq.world[f], seq.normals[f], cam.C) for f in range(n_frames)])
    video = render_marker_video([cam] * n_frames, seq.world, vis, seq.t, rng=rng,
                                dot_amplitude=dot_amplitude, noise=noise)
    seen = np.isfinite(video.xy[0]).all(axis=1)
    tri = Delaunay(video.xy[0, seen])
    idx = np.flatnonzero(seen)
    e = np.concatenate([tri.simplices[:, [0, 1]], tri.simplices[:, [1, 2]],
                        tri.simplices[:, [2, 0]]])
    e = np.unique(np.sort(idx[e], axis=1), axis=0)
    length = np.linalg.norm(video.xy[0, e[:, 0]] - video.xy[0, e[:, 1]], axis=1)
    e = e[length < 2.5 * np.median(length)]
    return FaceVideo(images=video.images, truth_xy=video.xy, edges=e)
