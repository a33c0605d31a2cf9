"""Headline numbers next to the papers'.

A notebook calls :func:`record` for each number it reproduces. Under ``lsmta reproduce``
the records are appended to the file named by the environment variable
``LSMTA_RECORD_FILE`` (one JSON object per line), and the command gathers them into
``build/summary.md``, ``build/summary.json`` and ``build/index.html``. Run interactively,
:func:`record` only returns the record; :func:`table` shows a list of them.

A record has a ``kind``: ``"result"`` (a measured number, the default), ``"setting"`` (a
number the notebook chose, such as an image size or a noise level picked to match the
paper: not a result, so it stays out of the paper-against-ours table) or ``"timing"`` (a
wall-clock time, which differs from run to run). A result must also say which ground truth
of the generator it leaned on (``truth``): ``"none"`` where the number comes from the
system's own measurements (``"none (...)"`` with a remark in brackets, such as how a 3-D
error was aligned: ``"none (no alignment: the system's own frame)"``), otherwise the truth
inputs in words, the phrases of
:data:`TRUTH_PHRASES` joined by ``"; "`` ("true cameras; seeds from truth"), each with a
few words in brackets where it helps to say which; a target judged on such a record is a
controlled study and says so (``controlled=True``). :func:`truth_group` sorts the results
by it and :func:`unsound_verdicts` lists the targets judged on truth-fed records that are
not controlled studies. :func:`verdict` writes a target's "met" / "NOT met" from a
computed truth value, and :func:`build_dir` says where ``lsmta reproduce`` writes
(``LSMTA_BUILD_DIR``), for a notebook that quotes a benchmark.
"""

from __future__ import annotations

import json
import math
import os
import re
import time
from dataclasses import asdict, dataclass
from numbers import Real
from pathlib import Path

import numpy as np

RECORD_ENV = "LSMTA_RECORD_FILE"
BUILD_ENV = "LSMTA_BUILD_DIR"
KINDS = ("result", "setting", "timing")

#: The common phrases of a record's ``truth`` (others are allowed). A truth input is the
#: generator's truth standing in for what a stage of the system, a device or its data would
#: give; a user's own measurement of the world simulated with the error it has (a
#: tape-measured rig, surveyed points, a bar's length) is not one.
TRUTH_PHRASES = (
    "true cameras",                        # the generator's cameras instead of a calibration
    "projected truth plus noise",          # image observations projected from true points
                                           # (plus noise), not detected in rendered images
    "true points plus noise",              # 3-D measurements sampled from the true points or
                                           # surface (plus noise, outliers), not measured
    "starts from truth",                   # initial positions or values at the truth
    "starts from perturbed truth",         # ... at the truth moved by a set error, standing
                                           # in for a stage's output (tracked joints, a search)
    "seeds from truth",                    # seed points or new points placed from the truth
    "labels from truth",                   # which observation is which (identities,
                                           # segments, body parts) from the true labels
    "noise level from truth",              # a sigma set from the generator or measured
                                           # against the truth (weights, thresholds, limits)
    "true pose",                           # a pose the fit is given (the torso's, the head's)
    "true body model",                     # the generator's body or marker model as the
                                           # method's model of the subject
    "aligned on the true check points",    # scored after a rigid alignment on true points
                                           # (fine for a system's number if named: say which)
    "model learnt from generated shapes",  # a model trained on the generator's shapes
    "camera choice from truth",            # cameras picked by the true path they see
    "mask from truth",                     # an operator's mask drawn where the truth is
    "exact device read-back",              # a device reports the true value (no noise)
    "settings tuned on the scored truth",  # parameters chosen by looking at these scores
)
#: The truth phrase that alone keeps a record a system's own number (name the points).
CHECK_POINTS = "aligned on the true check points"


@dataclass(frozen=True)
class Record:
    """One reproduced number. ``value`` and ``paper`` are numbers or short strings;
    ``kind`` is one of :data:`KINDS`."""

    figure: str
    quantity: str
    value: float | int | str
    unit: str = ""
    paper: float | int | str | None = None
    note: str = ""
    kind: str = "result"
    truth: str = "unstated"
    controlled: bool = False

    def _repr_markdown_(self) -> str:
        return table([self])


def _check_value(value, name: str):
    if isinstance(value, bool) or not isinstance(value, (Real, str)):
        raise TypeError(f"{name}: expected a number or a short string, got {type(value).__name__}")
    if isinstance(value, Real):
        value = value.item() if hasattr(value, "item") else value
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{name}: expected a finite number, got {value}")
    return value


def record(figure: str, quantity: str, value, unit: str = "", *, paper=None,
           note: str = "", kind: str = "result", truth: str | None = None,
           controlled: bool = False) -> Record:
    """Record one headline number of a figure next to the paper's.

    Parameters
    ----------
    figure : str
        Which figure or table, e.g. ``"LSMTA Fig. 2"`` or ``"00 synthetic world"``.
    quantity : str
        What is measured, e.g. ``"median matching error"``.
    value : float, int or str
        Our number.
    unit : str
        Unit of ``value`` and ``paper``.
    paper : float, int, str or None
        The paper's number, or None where the paper gives none.
    note : str
        Where and why we differ, in a few words.
    kind : {"result", "setting", "timing"}
        ``"setting"`` for a number the notebook chose rather than measured (kept out of
        the paper-against-ours table), ``"timing"`` for a wall-clock time.
    truth : str
        The generator's ground truth the number leaned on, besides scoring against it:
        ``"none"`` (the system's own measurements only; ``"none (...)"`` with a remark, e.g.
        how a 3-D error was aligned), or the truth inputs in a few
        words, the phrases of :data:`TRUTH_PHRASES` joined by ``"; "``, e.g.
        ``"true cameras; seeds from truth"``. Required for a result (a ``TypeError``
        otherwise); settings and timings default to ``"none"``. (``"unstated"`` is left for
        records read from files written before results had to say it.)
    controlled : bool
        The record is a controlled study: truth inputs on purpose, to isolate one stage.

    Returns
    -------
    Record
    """
    if truth is None:
        if kind == "result":
            raise TypeError("truth: a result must say which of the generator's truth it "
                            "leaned on: truth='none', or the truth inputs in words "
                            "(lsmta.report.TRUTH_PHRASES)")
        truth = "none"
    for name, text in (("figure", figure), ("quantity", quantity), ("unit", unit),
                       ("note", note), ("kind", kind), ("truth", truth)):
        if not isinstance(text, str):
            raise TypeError(f"{name}: expected a string, got {type(text).__name__}")
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    if not truth.strip():
        raise ValueError("truth: expected 'none' or the truth inputs in words, got ''")
    if truth.strip().startswith("none") and not no_truth(truth):
        raise ValueError("truth: expected 'none', 'none (<remark>)' (one bracket at the end, "
                         "no ';', none of TRUTH_PHRASES) or the truth inputs in words, got "
                         f"{truth!r}")
    if not isinstance(controlled, (bool, np.bool_)):
        raise TypeError(f"controlled: expected a bool, got {type(controlled).__name__}")
    rec = Record(figure=figure, quantity=quantity, value=_check_value(value, "value"),
                 unit=unit, paper=None if paper is None else _check_value(paper, "paper"),
                 note=note, kind=kind, truth=truth, controlled=bool(controlled))
    path = os.environ.get(RECORD_ENV)
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(asdict(rec)) + "\n")
    return rec


def load_records(path) -> list[Record]:
    """Records from a JSON-lines file written by :func:`record`."""
    out = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.strip():
                out.append(Record(**json.loads(line)))   # older files: truth "unstated"
    return out


def verdict(ok, target: str | None = None) -> str:
    """``"met"`` or ``"NOT met"`` from a computed truth value, optionally after the target.

    Parameters
    ----------
    ok : bool or numpy.bool_
        Whether the target holds, computed from the numbers (never typed).
    target : str, optional
        The target in words, e.g. ``"< 0.1 px"``; gives ``"target < 0.1 px: met"``.

    Examples
    --------
    >>> verdict(0.05 < 0.1, "< 0.1 px")
    'target < 0.1 px: met'
    """
    if not isinstance(ok, (bool, np.bool_)):
        raise TypeError(f"ok: expected a bool, got {type(ok).__name__}")
    if target is not None and not isinstance(target, str):
        raise TypeError(f"target: expected a string, got {type(target).__name__}")
    word = "met" if ok else "NOT met"
    return word if target is None else f"target {target}: {word}"


def build_dir() -> Path:
    """The folder ``lsmta reproduce`` writes to, for notebooks that read what it wrote
    (e.g. ``build/benchmarks/`` from ``experiments/``).

    ``LSMTA_BUILD_DIR`` if set (``lsmta reproduce`` sets it to its ``--build``); otherwise
    ``build/`` in the nearest folder at or above the working directory that holds a
    ``pyproject.toml`` (the repository, from a notebook's own folder); otherwise
    ``build/`` in the working directory. The folder need not exist.
    """
    env = os.environ.get(BUILD_ENV)
    if env:
        return Path(env).resolve()
    here = Path.cwd().resolve()
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file():
            return folder / "build"
    return here / "build"


def no_truth(truth: str) -> bool:
    """Whether a record's ``truth`` says it used none of the generator's truth: ``"none"``,
    or ``"none"`` followed by one remark in brackets (``"none (no alignment: the system's own
    frame)"``). The remark is a single balanced bracket closing at the very end, holds no
    ``";"`` and none of :data:`TRUTH_PHRASES` (``"none (x); true cameras"`` and ``"none (true
    cameras)"`` are not none)."""
    truth = truth.strip()
    if truth == "none":
        return True
    if not (truth.startswith("none (") and truth.endswith(")")):
        return False
    remark = truth[len("none ("):-1]
    if "(" in remark or ")" in remark or ";" in remark:
        return False
    return not any(phrase in remark for phrase in TRUTH_PHRASES)


def truth_group(rec: Record) -> str:
    """Where a result stands by its truth inputs: ``"none"`` (the system's own
    measurements), ``"check points"`` (those, scored after an alignment on named true check
    points only), ``"controlled"`` (truth-fed, a controlled study), ``"truth-fed"`` (truth
    inputs, not a controlled study) or ``"unstated"``. Settings and timings are ``"none"``
    unless they say otherwise."""
    truth = rec.truth.strip()
    if no_truth(truth):
        return "none"
    if truth == "unstated":
        return truth
    if all(part.strip().startswith(CHECK_POINTS) for part in truth.split(";")):
        return "check points"
    return "controlled" if rec.controlled else "truth-fed"


def judged(rec: Record) -> bool:
    """Whether ``rec`` carries a target's verdict (:func:`verdict`'s "met" / "NOT met", in
    its note or as its value)."""
    text = f"{rec.note} {rec.value if isinstance(rec.value, str) else ''}"
    return re.search(r"\bmet\b", text) is not None


def unsound_verdicts(records) -> list[Record]:
    """The results among ``records`` whose target verdict leans on truth inputs without
    being a controlled study, or whose truth inputs are unstated."""
    return [r for r in records if r.kind == "result" and judged(r)
            and truth_group(r) in ("truth-fed", "unstated")]


def format_value(value) -> str:
    """Numbers to four significant digits; strings as they are; None as an em dash."""
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def truth_cell(rec: Record) -> str:
    """A record's truth inputs as a table shows them, "(controlled)" after a controlled
    study's."""
    return f"{rec.truth} (controlled)" if rec.controlled else rec.truth


def table(records) -> str:
    """A Markdown table (figure, quantity, paper, ours, unit, truth, note) of ``records``;
    a setting or timing says so in its note."""
    rows = ["| figure | quantity | paper | ours | unit | truth | note |",
            "|---|---|---|---|---|---|---|"]
    for r in records:
        note = r.note if r.kind == "result" else f"({r.kind}) {r.note}".strip()
        cells = [r.figure, r.quantity, format_value(r.paper), format_value(r.value), r.unit,
                 truth_cell(r), note]
        rows.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


def show(records):
    """Display ``records`` as a table in a notebook (returns an IPython Markdown object)."""
    from IPython.display import Markdown  # deferred: only in a notebook

    return Markdown(table(records))


def write_json(path, data) -> Path:
    """Write ``data`` as indented JSON to ``path`` (folders made as needed), say so, and
    return the path; used by the benchmarks in ``experiments/``."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return out


def best_time(fn, *, repeats: int = 3):
    """Call ``fn()`` ``repeats`` times; return the shortest wall time (s) and the last
    result. Used by the benchmarks in ``experiments/``."""
    times, out = [], None
    for _ in range(max(1, int(repeats))):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out
