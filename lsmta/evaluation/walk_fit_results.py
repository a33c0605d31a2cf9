"""The committed results of the experiments' 8-frame walk full-body fits (issue 36), read back
for notebook 22.

The 8-frame walk takes minutes to tens of minutes, so the notebook quotes what
``experiments/walk_full_fit.py`` and ``experiments/walk_full_fit_ladder.py`` wrote to
``experiments/results/``:

- :func:`read_walk_fit_result`: per rig and variant (``"walk alone"``, and with
  ``--rom-per-phase`` the walk fitted from the range-of-motion clip's build) each major
  joint's angle error per frame, the segment lengths, the skin medians both ways and the
  open edges per frame; :func:`result_verdicts` judges them against issue 36's targets with
  :func:`~lsmta.evaluation.walk_full_fit.target_verdicts` (computed again from the per-frame
  numbers, not read from the file's own verdicts; the skin's median over all frames is the
  one number taken as the file holds it);
- :func:`read_ladder`: the controlled ladder's rungs (truth stated per rung), each rung's
  worst joint, lengths and skin.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .full_body import MAJOR
from .walk_full_fit import TARGETS, target_verdicts

RESULTS_DIR = Path(__file__).resolve().parents[2] / "experiments" / "results"
# the committed runs notebook 22 quotes (the commands are in each file)
WALK_FIT_RESULTS = {"studio": RESULTS_DIR / "walk_full_fit_studio_rom_walking.json",
                    "triplet": RESULTS_DIR / "walk_full_fit_triplet_temporal.json"}
LADDER_RESULTS = (RESULTS_DIR / "walk_full_fit_ladder_studio.json",
                  RESULTS_DIR / "walk_full_fit_ladder_studio_coverage.json")

_VARIANT_KEYS = ("frames_fitted", "joints_deg_per_frame", "lengths_mm", "verdicts",
                 "skin_to_truth_seen_per_frame_mm", "skin_from_truth_seen_per_frame_mm",
                 "open_edges")
_RUNG_KEYS = ("truth", "worst_joint_deg", "length_error_pct", "skin")


def _load(path, keys) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: expected a committed result file, {path} does not "
                                "exist")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"path: {path} is not valid JSON ({err})") from err
    if not isinstance(data, dict):
        raise ValueError(f"path: {path} holds a {type(data).__name__}, expected a JSON object")
    for key in keys:
        if key not in data:
            raise ValueError(f"path: {path.name} has no {key!r}")
    return data


def _variant(detail: dict, where: str) -> dict:
    for key in _VARIANT_KEYS:
        if key not in detail:
            raise ValueError(f"path: {where} has no {key!r}")
    frames = np.asarray(detail["frames_fitted"], int)
    joints = {k: np.array([np.nan if x is None else x for x in v], float)
              for k, v in detail["joints_deg_per_frame"].items()}
    for k, v in joints.items():
        if v.shape != frames.shape:
            raise ValueError(f"path: {where}'s joints_deg_per_frame[{k!r}] has {v.size} "
                             f"values; expected one per fitted frame ({frames.size})")
    missing = sorted(set(MAJOR) - set(joints))
    if missing:
        raise ValueError(f"path: {where} has no angle errors of {missing}")
    return {"frames": frames, "joints_deg": joints,
            "lengths_mm": {k: (float(a), float(b)) for k, (a, b) in detail["lengths_mm"].items()},
            "skin_to_truth_mm": float(detail["verdicts"]["skin_to_truth"]["value"]),
            "skin_from_truth_mm": float(detail["verdicts"]["skin_from_truth"]["value"]),
            "skin_to_per_frame_mm": np.asarray(detail["skin_to_truth_seen_per_frame_mm"], float),
            "skin_from_per_frame_mm": np.asarray(detail["skin_from_truth_seen_per_frame_mm"],
                                                 float),
            "open_edges": np.asarray(detail["open_edges"], int),
            "file_verdicts": detail["verdicts"]}


def read_walk_fit_result(path) -> dict:
    """A committed ``experiments/walk_full_fit.py`` result.

    Parameters
    ----------
    path : str or Path
        E.g. ``WALK_FIT_RESULTS["studio"]``.

    Returns
    -------
    dict
        ``command``, ``date``, ``settings``, ``note`` (``""`` if none) and ``rigs``: per rig
        ``{"variants": {name: variant}, "chosen": name, "times": {variant: {quantity: s}}}``. A
        variant holds ``frames`` (T,) int, ``joints_deg`` (major joint -> (T,) deg, NaN: a frame
        not scored), ``lengths_mm`` (name -> (fitted, true) mm), ``skin_to_truth_mm`` and
        ``skin_from_truth_mm`` (medians over all frames, seen side), their per-frame medians
        ``skin_to_per_frame_mm`` / ``skin_from_per_frame_mm`` (T,), ``open_edges`` (T,) and the
        file's own ``file_verdicts``. ``"walk alone"`` is the fit without the clip; ``chosen``
        the variant the experiment reported (its rule: the fit's own cost). ``times`` maps each
        record's variant (``"walk alone"`` when the record names none; ``"range-of-motion
        clip"``; a walk variant with `` (chosen)`` when chosen) to its records in seconds,
        ``{quantity: s}`` (wall, as the file records them; its ``note`` says whether they are
        comparable).

    Raises
    ------
    FileNotFoundError
        When there is no file at ``path``.
    ValueError
        When the file is not JSON, a field is missing or a joint's list is not one value per
        fitted frame (naming the file and the field).
    """
    data = _load(path, ("command", "date", "settings", "rigs"))
    name = Path(path).name
    rigs = {}
    for rig, r in data["rigs"].items():
        if "detail" not in r or "records" not in r:
            raise ValueError(f"path: {name}'s rig {rig!r} has no 'detail' or 'records'")
        variants = {"walk alone": _variant(r["detail"], f"{name}[{rig}]")}
        chosen = "walk alone"
        for v, d in r.get("rom_detail", {}).items():
            if "joints_deg_per_frame" in d and "frames_fitted" in d:
                variants[v] = _variant(d, f"{name}[{rig}][{v}]")
            chosen = d.get("chosen", chosen)
        times = {}
        for x in r["records"]:
            if x.get("unit") == "s":
                times.setdefault(x.get("variant", "walk alone"), {})[x["quantity"]] = \
                    float(x["value"])
        rigs[rig] = {"variants": variants, "chosen": chosen, "times": times}
    return {"command": data["command"], "date": data["date"], "settings": data["settings"],
            "note": data.get("note", ""), "rigs": rigs}


def length_pct(variant: dict) -> dict:
    """Signed length errors of a variant.

    Parameters
    ----------
    variant : dict
        A variant of :func:`read_walk_fit_result`; its ``lengths_mm`` maps a segment's name
        to (fitted, true) lengths in mm.

    Returns
    -------
    dict
        Segment name -> (fitted / true - 1) in % of the true length (signed: + too long).
    """
    _require(variant, ("lengths_mm",))
    return {k: 100.0 * (a / b - 1.0) for k, (a, b) in variant["lengths_mm"].items()}


def _require(variant, keys) -> None:
    if not isinstance(variant, dict):
        raise ValueError(f"variant: expected a dict of read_walk_fit_result, got "
                         f"{type(variant).__name__}")
    missing = [k for k in keys if k not in variant]
    if missing:
        raise ValueError(f"variant: expected a variant of read_walk_fit_result, it has no "
                         f"{missing}")


def result_verdicts(variant: dict, rig: str) -> dict:
    """Issue 36's targets for ``rig`` against a variant of :func:`read_walk_fit_result`.

    Parameters
    ----------
    variant : dict
        A variant of :func:`read_walk_fit_result`: ``joints_deg`` (major joint -> (T,) angle
        errors, deg; NaN: a frame not scored), ``lengths_mm`` (name -> (fitted, true) mm),
        ``skin_to_truth_mm`` and ``skin_from_truth_mm`` (medians, mm).
    rig : {"triplet", "studio"}
        Whose targets (:data:`~lsmta.evaluation.walk_full_fit.TARGETS`).

    Returns
    -------
    dict
        :func:`~lsmta.evaluation.walk_full_fit.target_verdicts` of the worst angle per major
        joint over the frames (deg; a NaN frame fails, as inf), the signed lengths (%) and
        the skin medians (mm): per target ``value``, ``limit``, ``unit``, ``met`` and for the
        joints and lengths the ``failing`` names.

    Raises
    ------
    ValueError
        When ``rig`` is not one of the targets' rigs, or ``variant`` lacks a key (named).
    """
    if rig not in TARGETS:
        raise ValueError(f"rig: expected one of {tuple(TARGETS)}, got {rig!r}")
    _require(variant, ("joints_deg", "lengths_mm", "skin_to_truth_mm", "skin_from_truth_mm"))
    worst = {k: float(np.nan_to_num(v, nan=np.inf, posinf=np.inf).max())
             for k, v in variant["joints_deg"].items() if k in MAJOR}
    return target_verdicts(worst, length_pct(variant), variant["skin_to_truth_mm"],
                           variant["skin_from_truth_mm"], rig)


def read_ladder(path) -> dict:
    """A committed ``experiments/walk_full_fit_ladder.py`` result.

    Parameters
    ----------
    path : str or Path
        E.g. ``LADDER_RESULTS[0]``.

    Returns
    -------
    dict
        ``command``, ``date``, ``note``, ``frames`` (list of int, the walk frames fitted) and
        ``rungs``: per rung ``truth`` (the truth in its fit's input, in words),
        ``worst_joint_deg`` (major joint -> its worst frame, deg), ``length_error_pct``
        (segment -> signed error, % of the true length), ``skin`` (the experiment's score
        summary as the file holds it: ``skin_to_truth_mm`` / ``skin_from_truth_mm`` medians
        in mm, ``worst_joint_deg``, ``worst_length_pct`` and their names), and
        ``worst_joint`` (deg) / ``worst_length`` (|%|): the largest of each, computed here.

    Raises
    ------
    FileNotFoundError
        When there is no file at ``path``.
    ValueError
        When the file is not JSON, a field is missing or a rung has no major joint or length
        (naming the file, the rung and the field).
    """
    data = _load(path, ("command", "date", "note", "frames", "rungs"))
    name = Path(path).name
    rungs = {}
    for rung, r in data["rungs"].items():
        for key in _RUNG_KEYS:
            if key not in r:
                raise ValueError(f"path: {name}'s rung {rung!r} has no {key!r}")
        joints = {k: float(v) for k, v in r["worst_joint_deg"].items() if k in MAJOR}
        pct = {k: float(v) for k, v in r["length_error_pct"].items()}
        if not joints or not pct:
            raise ValueError(f"path: {name}'s rung {rung!r} has no major joint or length")
        rungs[rung] = {"truth": r["truth"], "worst_joint_deg": joints, "length_error_pct": pct,
                       "skin": r["skin"], "worst_joint": max(joints.values()),
                       "worst_length": max(abs(v) for v in pct.values())}
    return {"command": data["command"], "date": data["date"], "note": data["note"],
            "frames": list(data["frames"]), "rungs": rungs}
