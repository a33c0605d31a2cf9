"""SAPM trials: generated marker poses (or the labelled frames of a recording, e.g. those
of :func:`lsmta.real.marker_captures.clouthier_model`), identified and scored against the
truth.

Notebook 08 and ``experiments/sapm_surface.py`` are built from these functions. A pose is
*fully correct* when every observed point carries its true label (extra points -1); the
*point accuracy* is the share of observed points labelled correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_rng
from ..rigid import apply_rigid, fit_rigid
from ..sapm import MarkerModel, SAPMParams, global_assignment, identify
from ..synth.markers import random_pose


@dataclass(frozen=True)
class Trials:
    """Scores of one method on a set of poses, one entry per pose.

    Attributes
    ----------
    correct : (P,) bool array
        Pose fully correct.
    accuracy : (P,) array
        Share of observed points labelled correctly.
    mislabelled : (P,) array
        Share of observed points given a wrong label (the rest of the errors are points
        left unlabelled).
    seconds : (P,) array
    tables, backtracks : (P,) int arrays
        Search effort (zero for the baseline).
    """

    correct: np.ndarray
    accuracy: np.ndarray
    mislabelled: np.ndarray
    seconds: np.ndarray
    tables: np.ndarray
    backtracks: np.ndarray

    def summary(self) -> dict:
        """Fractions and timing as plain numbers."""
        return {"poses": len(self.correct), "poses_correct": float(self.correct.mean()),
                "points_correct": float(self.accuracy.mean()),
                "points_mislabelled": float(self.mislabelled.mean()),
                "median_s": float(np.median(self.seconds)),
                "p95_s": float(np.percentile(self.seconds, 95))}


def _scored(result, truth):
    """One row of :class:`Trials` from a result of :func:`label_pose`."""
    labels = result.labels
    ok = labels == truth
    return (bool(ok.all()), float(ok.mean()), float(((labels >= 0) & ~ok).mean()),
            result.seconds, getattr(result, "tables", 0), getattr(result, "backtracks", 0))


def _trials(rows) -> Trials:
    cols = list(zip(*rows)) if rows else [[]] * 6
    kinds = (bool, float, float, float, int, int)
    return Trials(*(np.asarray(c, dtype=k) for c, k in zip(cols, kinds)))


def label_pose(model: MarkerModel, observed, *, method: str = "sapm",
               params: SAPMParams | None = None):
    """Label one pose with ``method``: "sapm" (:func:`~lsmta.sapm.identify`, returns an
    ``Identification``, with ``params``) or "baseline"
    (:func:`~lsmta.sapm.global_assignment`)."""
    if method == "sapm":
        return identify(model, observed, params=params)
    if method == "baseline":
        return global_assignment(model, observed)
    raise ValueError(f"method: expected 'sapm' or 'baseline', got {method!r}")


def pose_trials(model: MarkerModel, n_poses: int, *, rng: np.random.Generator | int | None = None,
                level: float = np.pi, distortion: float = 0.0, n_missing: int = 0, n_extra: int = 0,
                methods=("sapm",), params: SAPMParams | None = None) -> dict:
    """Generate ``n_poses`` random poses and score every method on the same poses.

    Returns
    -------
    dict
        method name -> :class:`Trials`.
    """
    rng = as_rng(rng)
    rows = {m: [] for m in methods}
    for _ in range(n_poses):
        pose = random_pose(model, rng=rng, level=level, distortion=distortion, n_missing=n_missing,
                           n_extra=n_extra)
        for m in methods:
            r = label_pose(model, pose.observed, method=m, params=params)
            rows[m].append(_scored(r, pose.truth))
    return {m: _trials(r) for m, r in rows.items()}


@dataclass(frozen=True)
class Surface:
    """Identification over a grid of configuration and distortion levels (paper Fig. 3).

    Attributes
    ----------
    levels : (L,) array
        Configuration levels, rad.
    distortions : (D,) array
        ψ, fraction of l̄_s.
    poses_correct, points_correct : (L, D) arrays
        Mean over the poses of each cell.
    n_poses : int
    """

    levels: np.ndarray
    distortions: np.ndarray
    poses_correct: np.ndarray
    points_correct: np.ndarray
    n_poses: int


def surface_cell(model, seed: int, level: float, distortion: float, n_poses: int, *,
                 params: SAPMParams | None = None) -> tuple[float, float]:
    """One cell of the Fig. 3 grid, from its own seed: (poses correct, points correct)."""
    t = pose_trials(model, n_poses, rng=np.random.default_rng(seed), level=level,
                    distortion=distortion, params=params)["sapm"]
    return float(t.correct.mean()), float(t.accuracy.mean())


def cell_seeds(seed: int, shape) -> np.ndarray:
    """Independent integer seeds for the cells of a grid (NumPy's SeedSequence)."""
    children = np.random.SeedSequence(seed).spawn(int(np.prod(shape)))
    return np.array([c.generate_state(1)[0] for c in children]).reshape(shape)


def identification_surface(model: MarkerModel, seed: int, levels, distortions, n_poses: int,
                           *, progress=None, params: SAPMParams | None = None) -> Surface:
    """Fig. 3 serially: every (level, ψ) cell from its own seed (see ``cell_seeds``), so
    the parallel experiment reproduces the same numbers."""
    levels = np.asarray(levels, float)
    distortions = np.asarray(distortions, float)
    seeds = cell_seeds(seed, (len(levels), len(distortions)))
    poses = np.zeros(seeds.shape)
    points = np.zeros(seeds.shape)
    cells = [(i, j) for i in range(len(levels)) for j in range(len(distortions))]
    for i, j in (progress(cells) if progress else cells):
        poses[i, j], points[i, j] = surface_cell(model, seeds[i, j], levels[i],
                                                 distortions[j], n_poses, params=params)
    return Surface(levels=levels, distortions=distortions, poses_correct=poses,
                   points_correct=points, n_poses=n_poses)


# ---------------------------------------------------------------------- labelled frames
@dataclass(frozen=True)
class FrameTrials:
    """Labelled frames (a real recording's) identified after shuffling and dropping the
    labels.

    Attributes
    ----------
    frames : (F,) int array
    trials : dict
        method -> :class:`Trials`, one entry per frame.
    labels : dict
        method -> (F, M) int array: the label given to each model marker's observed point
        (marker index = correct, -1 = unlabelled, -2 = absent from the frame, other =
        wrong).
    results : dict
        method -> list of the per-frame results (``Identification`` for "sapm").
    """

    frames: np.ndarray
    trials: dict
    labels: dict
    results: dict

    def per_marker_accuracy(self, *, method: str = "sapm") -> np.ndarray:
        """(M,) share of frames in which each present marker was labelled correctly."""
        lab = self.labels[method]
        present = lab != -2
        ok = (lab == np.arange(lab.shape[1])) & present
        return ok.sum(axis=0) / np.maximum(present.sum(axis=0), 1)


def frame_trials(model: MarkerModel, points, frames, *, methods=("sapm",),
                 rng: np.random.Generator | int | None = None,
                 params: SAPMParams | None = None) -> FrameTrials:
    """Identify labelled frames (a real recording's): present markers shuffled, labels
    dropped.

    ``points`` is (T, M, 3) in the model's marker order; in the returned label arrays a
    marker absent from the frame is -2."""
    rng = as_rng(rng)
    rows = {m: [] for m in methods}
    labels = {m: np.full((len(frames), model.n_points), -2) for m in methods}
    results = {m: [] for m in methods}
    for f_i, f in enumerate(frames):
        present = np.flatnonzero(~np.isnan(points[f]).any(axis=1))
        perm = rng.permutation(present)
        for m in methods:
            r = label_pose(model, points[f][perm], method=m, params=params)
            rows[m].append(_scored(r, perm))
            labels[m][f_i, perm] = r.labels
            results[m].append(r)
    return FrameTrials(frames=np.asarray(frames), trials={m: _trials(r) for m, r in rows.items()},
                       labels=labels, results=results)


def segment_fit_errors(model: MarkerModel, points) -> np.ndarray:
    """(S,) ē_s (Eq. 2) of each segment under the *true* correspondence: how far a
    labelled frame ``points`` (M, 3) mm, NaN for gaps, is from rigid per segment (NaN where
    fewer than 3 markers are present). A segment with ē_s above ε cannot pass Eq. 2."""
    out = np.full(model.n_segments, np.nan)
    for s, m in enumerate(model.members):
        q = np.asarray(points, float)[m]
        ok = ~np.isnan(q).any(axis=1)
        if ok.sum() >= 3:
            R, t = fit_rigid(model.points[m][ok], q[ok])
            resid = np.linalg.norm(apply_rigid(R, t, model.points[m][ok]) - q[ok], axis=1)
            out[s] = resid.mean() / model.mean_length[s]
    return out
