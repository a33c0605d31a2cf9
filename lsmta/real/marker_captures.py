"""SAPM on real marker captures: the marker sets of the bundled recordings as SAPM
segments, a model from the first tenth of a recording, later frames labelled one by one
(notebooks 08 and 18; the recordings are loaded by :func:`lsmta.data.load_recording`).

Protocol: the first ``train_share`` of the frames is the labelled training clip; every
``step``-th later frame is a test frame, its present points shuffled and their labels
dropped, with the gaps it has. A point's truth is its model marker, or -1 for a marker the
model leaves out (a marker absent from the whole training clip). Scores are pooled over the
test frames: *correct* is the share of present model markers given their own label;
*wrong* is the share of present points given another marker's label.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import as_rng
from ..data import Recording
from ..io import read_c3d
from ..sapm import MarkerModel, SAPMParams, identify, identify_instances, suggest_segments
from ..sapm.tracking import TrackParams, label_recording


# ---------------------------------------------------------------------- marker sets
def clouthier_segments(*, acromion: str = "upper_arm") -> dict:
    """The marker set of Clouthier et al. (2021) as SAPM segments: 15 segments, 62 cluster
    markers, no marker shared between segments.

    Parameters
    ----------
    acromion : {"upper_arm", "torso"}
        Where the two acromion markers (RAC, LAC) go. They sit on the shoulder girdle, which
        follows the arm: with the upper arms the segments stay closer to rigid over the
        recording than with the four back markers (notebook 08 measures both).
    """
    if acromion not in ("upper_arm", "torso"):
        raise ValueError(f"acromion: expected 'upper_arm' or 'torso', got {acromion!r}")
    on_arm = acromion == "upper_arm"
    segments = {
        "torso": ["LBUL", "LBLL", "LBUR", "LBLR"] + ([] if on_arm else ["RAC", "LAC"]),
        "head": ["FHD", "RHD", "BHD", "LHD"],
        "pelvis": ["PVUL", "PVLL", "PVLR", "PVUR"],
    }
    for S in "RL":
        segments[f"{S}upper_arm"] = [f"{S}UAPA", f"{S}UAPP", f"{S}UADP", f"{S}UADA"] + (
            [f"{S}AC"] if on_arm else [])
        for name, markers in (("forearm", ("FAPA", "FAPP", "FADP", "FADA")),
                              ("hand", ("RAD", "ULN", "HAND")),
                              ("thigh", ("THPA", "THPP", "THDP", "THDA")),
                              ("shank", ("SHPA", "SHPP", "SHDP", "SHDA")),
                              ("foot", ("ANL", "HEE", "FTB", "FTM", "FTF"))):
            segments[f"{S}{name}"] = [f"{S}{m}" for m in markers]
    return segments


CLOUTHIER_PARENTS = {
    "torso": None, "head": "torso", "pelvis": "torso",
    **{k: v for S in "RL" for k, v in (
        (f"{S}upper_arm", "torso"), (f"{S}forearm", f"{S}upper_arm"),
        (f"{S}hand", f"{S}forearm"), (f"{S}thigh", "pelvis"), (f"{S}shank", f"{S}thigh"),
        (f"{S}foot", f"{S}shank"))},
}



def plug_in_gait() -> tuple[dict, dict]:
    """The tennis marker set (Plug-in-Gait-like, 39 markers) as SAPM segments, as a user
    would write it from anatomy: both wrist markers in forearm and hand, the knee marker in
    thigh and shank, the ankle marker in shank and foot, the anterior iliac spine in pelvis
    and thigh (the thigh has only two markers of its own). Returns (segments, parents)."""
    segments = {"torso": ["C7", "T10", "CLAV", "STRN", "RBAK"],
                "head": ["LFHD", "RFHD", "LBHD", "RBHD"],
                "pelvis": ["LASI", "RASI", "LPSI", "RPSI"]}
    parents = {"torso": None, "head": "torso", "pelvis": "torso"}
    for S in "LR":
        for name, markers, parent in (
                ("upper_arm", ("SHO", "UPA", "ELB"), "torso"),
                ("forearm", ("ELB", "FRM", "WRA", "WRB"), f"{S}upper_arm"),
                ("hand", ("WRA", "WRB", "FIN"), f"{S}forearm"),
                ("thigh", ("ASI", "THI", "KNE"), "pelvis"),
                ("shank", ("KNE", "TIB", "ANK"), f"{S}thigh"),
                ("foot", ("ANK", "HEE", "TOE"), f"{S}shank")):
            segments[f"{S}{name}"] = [f"{S}{m}" for m in markers]
            parents[f"{S}{name}"] = parent
    return segments, parents


def racing_plates(labels) -> dict:
    """The wheelchair recording's rigid groups a user knows: each numbered cluster
    (``Head1..3``, ``ArmL1..3``, ...) and the wheelchair's three markers."""
    groups = {}
    for k in labels:
        m = re.fullmatch(r"(.*?)(\d)", k)
        if m and not k.startswith("Probe"):
            groups.setdefault(m.group(1), []).append(k)
    groups["Wheelchair"] = [k for k in labels if k.startswith("Wheelchair")]
    return groups


def clouthier_plates() -> tuple[dict, dict]:
    """The Clouthier recording's rigid groups (the four-marker plates and the shoes) and
    their anatomical tree; the acromion, wrist and hand skin markers are left loose."""
    loose = {"RAC", "LAC", "RRAD", "RULN", "RHAND", "LRAD", "LULN", "LHAND"}
    groups = {k: [m for m in v if m not in loose]
              for k, v in clouthier_segments(acromion="torso").items()}
    groups = {k: v for k, v in groups.items() if len(v) >= 3}
    return groups, {k: v for k, v in CLOUTHIER_PARENTS.items() if k in groups}


# ---------------------------------------------------------------------- models
def clouthier_model(path, *, frame: int = 0,
                    acromion: str = "upper_arm") -> tuple[MarkerModel, np.ndarray]:
    """The model of the Clouthier et al. recording built from one labelled frame (segments
    from :func:`clouthier_segments`), and all its frames.

    Returns
    -------
    model : MarkerModel
    points : (T, M, 3) array
        Every frame, mm, with the model's marker order (NaN for gaps).
    """
    labels, points, _ = read_c3d(Path(path))
    twice = sorted({k for k in labels if labels.count(k) > 1})
    if twice:
        raise ValueError(f"path: labels occur more than once in {path}: {twice}")
    if np.isnan(points[frame]).any():
        raise ValueError(f"frame: frame {frame} has gaps; the model needs a complete frame")
    model = MarkerModel.from_labelled_frame(dict(zip(labels, points[frame])),
                                            clouthier_segments(acromion=acromion),
                                            CLOUTHIER_PARENTS)
    order = [labels.index(k) for k in model.labels]
    return model, points[:, order]


def learned_model(rec: Recording) -> tuple[MarkerModel, dict]:
    """The model of a recording learned from its training clip, with the segments each
    recording gets: the anatomical Plug-in-Gait definition for the tennis files (the clip
    is the player standing: nothing to learn a grouping from), and for the cluster sets
    the plates a user knows with every loose marker placed by :func:`suggest_segments`
    (the racing tree proposed from the clip too). Returns (model, segments)."""
    if rec.name in ("tennis", "two players"):
        segments, parents = plug_in_gait()
        if rec.name == "tennis":
            return MarkerModel.from_labelled_frames(rec.labels, rec.training, segments,
                                                    parents), segments
        # two instances of one marker set: one model learned from both players' clips
        own = [k.split(":")[-1] for k in rec.labels[:39]]
        clip = np.concatenate([rec.training[:, :39], rec.training[:, 39:]])
        return MarkerModel.from_labelled_frames(own, clip, segments, parents), segments
    seen = np.isfinite(rec.training).all(axis=2).any(axis=0)     # markers the clip never
    labels = [k for k, v in zip(rec.labels, seen) if v]            # sees: left out
    clip = rec.training[:, seen]
    if rec.name in ("racing", "racing static"):
        sug = suggest_segments(labels, clip, groups=racing_plates(labels))
    else:
        groups, parents = clouthier_plates()
        sug = suggest_segments(labels, clip, groups=groups, parents=parents)
    keep = [i for i, k in enumerate(labels) if k not in sug.unplaced]
    model = MarkerModel.from_labelled_frames([labels[i] for i in keep], clip[:, keep],
                                             sug.segments, sug.parents)
    return model, sug.segments


def one_frame_model(rec: Recording, segments: dict, parents: dict) -> MarkerModel:
    """The paper's model: the first training frame that sees every marker of ``segments``."""
    names = sorted({k for v in segments.values() for k in v})
    cols = [rec.labels.index(k) for k in names]
    full = np.flatnonzero(np.isfinite(rec.training[:, cols]).all(axis=(1, 2)))
    if not len(full):
        raise ValueError(f"rec: no training frame of {rec.name!r} sees every marker")
    frame = rec.training[full[0]][cols]
    return MarkerModel.from_labelled_frame(dict(zip(names, frame)), segments, parents)


# ---------------------------------------------------------------------- trials
@dataclass(frozen=True)
class RecordingTrials:
    """Scores of one method on the test frames of a recording.

    Attributes
    ----------
    frames : (F,) int array
    correct, wrong : (F,) int arrays
        Present model markers given their own label; present points given another's.
    markers, points : (F,) int arrays
        Present model markers; present points.
    seconds : (F,) array
    given : (F, L) int array
        Label index (into the recording's labels) given to each present marker, -1
        unlabelled, -2 absent.
    """

    frames: np.ndarray
    correct: np.ndarray
    wrong: np.ndarray
    markers: np.ndarray
    points: np.ndarray
    seconds: np.ndarray
    given: np.ndarray

    def summary(self) -> dict:
        """Pooled shares and timing as plain numbers."""
        return {"frames": len(self.frames),
                "correct": float(self.correct.sum() / max(self.markers.sum(), 1)),
                "wrong": float(self.wrong.sum() / max(self.points.sum(), 1)),
                "unlabelled": float(1 - (self.correct.sum() + self.wrong.sum())
                                    / max(self.points.sum(), 1)),
                "frames_correct": float(np.mean(self.correct == self.markers)),
                "median_ms": float(1000 * np.median(self.seconds)),
                "p95_ms": float(1000 * np.percentile(self.seconds, 95))}


def _score(labels_rec, model_labels, present, given_model):
    """(correct, wrong, markers, given as recording indices) of one frame."""
    truth = np.array([model_labels.index(labels_rec[i]) if labels_rec[i] in model_labels
                      else -1 for i in present])
    ok = given_model == truth
    to_rec = np.array([labels_rec.index(k) for k in model_labels])
    given = np.where(given_model >= 0, to_rec[np.maximum(given_model, 0)], -1)
    return (int((ok & (truth >= 0)).sum()), int(((given_model >= 0) & ~ok).sum()),
            int((truth >= 0).sum()), given)


def recording_trials(model: MarkerModel, rec: Recording, *, params: SAPMParams | None = None,
                     rng: np.random.Generator | int | None = None,
                     frames=None) -> RecordingTrials:
    """Identify the test frames of ``rec`` (or ``frames``) with ``model`` and ``params``
    (:func:`lsmta.sapm.identify`), present points shuffled."""
    rng = as_rng(rng)
    frames = rec.frames if frames is None else np.asarray(frames)
    L = len(rec.labels)
    rows = []
    given = np.full((len(frames), L), -2)
    for k, f in enumerate(frames):
        present = np.flatnonzero(np.isfinite(rec.points[f]).all(axis=1))
        perm = rng.permutation(present)
        r = identify(model, rec.points[f, perm], params=params)
        c, w, m, g = _score(rec.labels, model.labels, perm, r.labels)
        given[k, perm] = g
        rows.append((c, w, m, len(perm), r.seconds))
    c, w, m, n, s = (np.array(x) for x in zip(*rows))
    return RecordingTrials(frames=frames, correct=c, wrong=w, markers=m, points=n, seconds=s,
                           given=given)


@dataclass(frozen=True)
class PlayerTrials:
    """Two instances of one model in each test frame (:func:`player_trials`).

    Attributes
    ----------
    correct, wrong : (F, P) int arrays
        Per player: markers given their own label *and* their own player's instance;
        points given a wrong label or the other player's instance.
    markers : (F, P) int array
    seconds : (F,) array
    instances : (F,) int array
        Instances found.
    """

    correct: np.ndarray
    wrong: np.ndarray
    markers: np.ndarray
    seconds: np.ndarray
    instances: np.ndarray

    def summary(self) -> list[dict]:
        """Per player: pooled shares; the timing is per frame (both players)."""
        return [{"correct": float(self.correct[:, p].sum() / self.markers[:, p].sum()),
                 "wrong": float(self.wrong[:, p].sum() / self.markers[:, p].sum()),
                 "median_ms": float(1000 * np.median(self.seconds))}
                for p in range(self.correct.shape[1])]


def player_trials(model: MarkerModel, rec: Recording, *, n_players: int = 2,
                  params: SAPMParams | None = None,
                  rng: np.random.Generator | int | None = None) -> PlayerTrials:
    """Label both players of each test frame of the two-player file at once
    (:func:`lsmta.sapm.identify_instances`). Instances are matched to players by the
    majority of their points; a point counts as correct when its label and its player are."""
    rng = as_rng(rng)
    M = len(rec.labels) // n_players
    own = [k.split(":")[-1] for k in rec.labels]
    truth = np.array([model.labels.index(k) for k in own])
    player = np.repeat(np.arange(n_players), M)
    rows = []
    for f in rec.frames:
        present = np.flatnonzero(np.isfinite(rec.points[f]).all(axis=1))
        perm = rng.permutation(present)
        r = identify_instances(model, rec.points[f, perm], n_instances=n_players, params=params)
        who = player[perm]
        votes = np.array([[((r.instance == i) & (who == p)).sum() for p in range(n_players)]
                          for i in range(r.n_instances)]).reshape(-1, n_players)
        owner = votes.argmax(axis=1) if len(votes) else np.zeros(0, int)
        inst_player = np.where(r.instance >= 0, owner[np.maximum(r.instance, 0)]
                               if len(owner) else -1, -1)
        ok = (r.labels == truth[perm]) & (inst_player == who)
        bad = (r.labels >= 0) & ~ok
        rows.append(([int((ok & (who == p)).sum()) for p in range(n_players)],
                     [int((bad & (who == p)).sum()) for p in range(n_players)],
                     [int((who == p).sum()) for p in range(n_players)],
                     r.seconds, r.n_instances))
    c, w, m, s, i = (np.array(x) for x in zip(*rows))
    return PlayerTrials(correct=c, wrong=w, markers=m, seconds=s, instances=i)


# ---------------------------------------------------------------------- whole recordings
@dataclass(frozen=True)
class WholeTrials:
    """Every frame after the training clip labelled with carried labels
    (:func:`whole_trials`; :func:`lsmta.sapm.tracking.label_recording`).

    Attributes
    ----------
    correct, wrong, markers, points : (F,) int arrays
        Per frame, as in :class:`RecordingTrials` (for several players a label counts as
        correct only with its player).
    sapm_frames : int
        Frames on which SAPM was called.
    seconds : (F,) array
    """

    correct: np.ndarray
    wrong: np.ndarray
    markers: np.ndarray
    points: np.ndarray
    sapm_frames: int
    seconds: np.ndarray

    def summary(self) -> dict:
        return {"frames": len(self.correct),
                "correct": float(self.correct.sum() / max(self.markers.sum(), 1)),
                "wrong": float(self.wrong.sum() / max(self.points.sum(), 1)),
                "unlabelled": float(1 - (self.correct.sum() + self.wrong.sum())
                                    / max(self.points.sum(), 1)),
                "sapm_share": self.sapm_frames / max(len(self.correct), 1),
                "median_ms": float(1000 * np.median(self.seconds))}


def whole_trials(model: MarkerModel, rec: Recording, *, params: SAPMParams | None = None,
                 track: TrackParams | None = None, n_players: int | None = None,
                 rng: np.random.Generator | int | None = None) -> WholeTrials:
    """Label every frame after ``rec``'s training clip at once, points shuffled in every
    frame, labels carried where the markers move continuously. ``n_players``: the
    two-player file (labels instance · M + marker, instances matched to players by the
    majority of their points)."""
    rng = as_rng(rng)
    X = rec.points[rec.n_train:]
    T, L = X.shape[:2]
    perms = np.array([rng.permutation(L) for _ in range(T)])
    shuffled = np.take_along_axis(X, perms[..., None], axis=1)
    out = label_recording(model, shuffled, params=params, track=track, n_instances=n_players)
    M = model.n_points
    if n_players:
        own = [k.split(":")[-1] for k in rec.labels]
        truth_rec = np.array([p * M + model.labels.index(k)
                              for p, k in zip(np.repeat(np.arange(n_players), L // n_players),
                                              own)])
        # instances to players by the majority of their points over the recording
        lab = out.labels
        inst = np.where(lab >= 0, lab // M, -1)
        who = truth_rec[perms] // M
        votes = np.array([[((inst == i) & (who == p)).sum() for p in range(n_players)]
                          for i in range(n_players)])
        owner = votes.argmax(axis=1)
        given = np.where(lab >= 0, owner[np.maximum(inst, 0)] * M + lab % M, -1)
    else:
        truth_rec = np.array([model.labels.index(k) if k in model.labels else -1
                              for k in rec.labels])
        given = out.labels
    truth = truth_rec[perms]
    present = np.isfinite(shuffled).all(axis=2)
    ok = (given == truth) & present
    return WholeTrials(correct=(ok & (truth >= 0)).sum(axis=1),
                       wrong=((given >= 0) & ~ok & present).sum(axis=1),
                       markers=((truth >= 0) & present).sum(axis=1),
                       points=present.sum(axis=1), sapm_frames=len(out.sapm_frames),
                       seconds=out.seconds)
