"""Headline numbers next to the papers'.

A notebook calls :func:`record` for each number it reproduces. Under ``lsmta reproduce``
the records are appended to the file named by the environment variable
``LSMTA_RECORD_FILE`` (one JSON object per line), and the command gathers them into
``build/summary.md``, ``build/summary.json`` and ``build/index.html``. Run interactively,
:func:`record` only returns the record; :func:`table` shows a list of them.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from numbers import Real
from pathlib import Path

RECORD_ENV = "LSMTA_RECORD_FILE"


@dataclass(frozen=True)
class Record:
    """One reproduced number. ``value`` and ``paper`` are numbers or short strings."""

    figure: str
    quantity: str
    value: float | int | str
    unit: str = ""
    paper: float | int | str | None = None
    note: str = ""

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
           note: str = "") -> Record:
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

    Returns
    -------
    Record
    """
    for name, text in (("figure", figure), ("quantity", quantity), ("unit", unit),
                       ("note", note)):
        if not isinstance(text, str):
            raise TypeError(f"{name}: expected a string, got {type(text).__name__}")
    rec = Record(figure, quantity, _check_value(value, "value"), unit,
                 None if paper is None else _check_value(paper, "paper"), note)
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
                out.append(Record(**json.loads(line)))
    return out


def format_value(value) -> str:
    """Numbers to four significant digits; strings as they are; None as an em dash."""
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def table(records) -> str:
    """A Markdown table (figure, quantity, paper, ours, unit, note) of ``records``."""
    rows = ["| figure | quantity | paper | ours | unit | note |",
            "|---|---|---|---|---|---|"]
    for r in records:
        cells = [r.figure, r.quantity, format_value(r.paper), format_value(r.value), r.unit,
                 r.note]
        rows.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


def show(records):
    """Display ``records`` as a table in a notebook (returns an IPython Markdown object)."""
    from IPython.display import Markdown

    return Markdown(table(records))


def write_json(path, data) -> Path:
    """Write ``data`` as indented JSON to ``path`` (folders made as needed), say so, and
    return the path; used by the benchmarks in ``experiments/``."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2), encoding="utf-8")
    print(f"wrote {out}")
    return out


def best_time(fn, repeats: int = 3):
    """Call ``fn()`` ``repeats`` times; return the shortest wall time (s) and the last
    result. Used by the benchmarks in ``experiments/``."""
    import time

    times, out = [], None
    for _ in range(max(1, int(repeats))):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out
