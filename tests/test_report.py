import ast
import json
from pathlib import Path

import numpy as np
import pytest

from lsmta import report


def test_record_returns_and_writes_when_asked(tmp_path, monkeypatch):
    monkeypatch.delenv(report.RECORD_ENV, raising=False)
    rec = report.record("Fig. 1", "error", np.float64(0.25), "px", paper=0.3, note="n",
                        truth="none")
    assert rec.value == 0.25 and isinstance(rec.value, float)
    path = tmp_path / "r.jsonl"
    monkeypatch.setenv(report.RECORD_ENV, str(path))
    report.record("Fig. 1", "error", 0.25, "px", paper=0.3, truth="none")
    report.record("Fig. 2", "size", "768x576", truth="none")
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["figure"] for r in rows] == ["Fig. 1", "Fig. 2"]
    assert report.load_records(path)[1].paper is None


def test_table_lists_paper_next_to_ours():
    recs = [report.Record("F", "q", 1.23456, "mm", paper=1.2, note="a|b", truth="none")]
    text = report.table(recs)
    assert "| figure | quantity | paper | ours | unit | truth | note |" in text
    assert "| F | q | 1.2 | 1.235 | mm | none | a\\|b |" in text
    assert "—" in report.table([report.Record("F", "q", 1, "")])


def test_truth_is_stored_and_shown(tmp_path, monkeypatch):
    path = tmp_path / "r.jsonl"
    monkeypatch.setenv(report.RECORD_ENV, str(path))
    report.record("F", "error", 0.5, "mm", truth="true cameras; seeds from truth (one per part)",
                  controlled=True)
    report.record("F", "error", 0.7, "mm", truth="none")
    report.record("F", "image size", "8x8", "px", kind="setting")
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["truth"] for r in rows] == ["true cameras; seeds from truth (one per part)", "none",
                                          "none"]
    assert [r["controlled"] for r in rows] == [True, False, False]
    loaded = report.load_records(path)
    assert loaded[0].truth.startswith("true cameras") and loaded[0].controlled
    text = report.table(loaded)
    assert "| true cameras; seeds from truth (one per part) (controlled) |" in text
    assert "| none |" in text
    # a line written before records had a truth loads as "unstated"
    path.write_text(json.dumps({"figure": "F", "quantity": "q", "value": 1, "unit": "",
                                "paper": None, "note": "", "kind": "result"}) + "\n")
    assert report.load_records(path)[0].truth == "unstated"


@pytest.mark.parametrize("kwargs, exc", [
    (dict(truth=""), ValueError),
    (dict(truth=" "), ValueError),
    (dict(truth=3), TypeError),
    (dict(truth="none", controlled="yes"), TypeError),
])
def test_truth_bad_input(kwargs, exc):
    with pytest.raises(exc, match="truth|controlled"):
        report.record("F", "q", 1.0, **kwargs)


def test_truth_phrases_are_the_common_vocabulary():
    assert len(set(report.TRUTH_PHRASES)) == len(report.TRUTH_PHRASES)
    assert report.CHECK_POINTS in report.TRUTH_PHRASES
    assert all(p == p.strip().lower() and ";" not in p for p in report.TRUTH_PHRASES)


def test_truth_group_and_unsound_verdicts():
    R = report.Record
    recs = {
        "none": R("F", "a", 1, note="target < 2: met", truth="none"),
        "check points": R("F", "b", 1, note="NOT met",
                          truth="aligned on the true check points (held-out bar)"),
        "controlled": R("F", "c", 1, note="target: met", truth="true cameras", controlled=True),
        "truth-fed": R("F", "d", "met", truth="labels from truth (the operator's)"),
        "unstated": R("F", "e", 1, note="NOT met"),
    }
    assert {k: report.truth_group(r) for k, r in recs.items()} == {k: k for k in recs}
    assert report.truth_group(R("F", "f", 1, truth="aligned on the true check points; true "
                                                  "cameras")) == "truth-fed"
    # "none" with a remark in brackets (how a 3-D error was aligned) is still none
    assert report.truth_group(R("F", "j", 1, truth="none (no alignment: the system's own "
                                                  "frame)")) == "none"
    assert report.no_truth(" none (lengths need no alignment) ")
    for other in ("none of the cameras", "nonetheless (true cameras)", "none (", "true cameras",
                  "none (x); true cameras (exact)", "none (true cameras)", "none (a) (b)",
                  "none (a (b))", "none (a; b)"):
        assert not report.no_truth(other), other
        if other.startswith("none"):
            with pytest.raises(ValueError, match="truth"):
                report.record("F", "q", 1.0, truth=other)
    assert report.judged(recs["truth-fed"])                          # the verdict as the value
    assert not report.judged(R("F", "g", 1, note="metres and metadata", truth="none"))
    assert report.unsound_verdicts(recs.values()) == [recs["truth-fed"], recs["unstated"]]
    # without a verdict, or as a setting, a truth-fed record is no unsound verdict
    assert report.unsound_verdicts([R("F", "h", 1, truth="true cameras"),
                                    R("F", "i", 1, note="met", kind="timing")]) == []


@pytest.mark.parametrize("kwargs, exc", [
    (dict(value=float("nan")), ValueError),
    (dict(value=[1, 2]), TypeError),
    (dict(value=True), TypeError),
    (dict(value=1.0, paper=object()), TypeError),
])
def test_record_bad_input(kwargs, exc):
    with pytest.raises(exc):
        report.record("F", "q", unit="", truth="none", **kwargs)


def test_kind_marks_settings_and_old_files_still_load(tmp_path, monkeypatch):
    path = tmp_path / "r.jsonl"
    monkeypatch.setenv(report.RECORD_ENV, str(path))
    assert report.record("F", "q", 1.0, truth="none").kind == "result"
    report.record("F", "image size", "8x8", "px", kind="setting")
    assert [r.kind for r in report.load_records(path)] == ["result", "setting"]
    # a JSON line written before records had a kind still loads, as a result
    path.write_text(json.dumps({"figure": "F", "quantity": "q", "value": 1, "unit": "",
                                "paper": None, "note": ""}) + "\n")
    assert report.load_records(path)[0].kind == "result"
    assert "(setting) chosen" in report.table([report.Record("F", "q", 1, kind="setting",
                                                             note="chosen")])
    with pytest.raises(ValueError, match="kind"):
        report.record("F", "q", 1.0, kind="guess", truth="none")


def test_a_result_must_state_its_truth(tmp_path, monkeypatch):
    path = tmp_path / "r.jsonl"
    monkeypatch.setenv(report.RECORD_ENV, str(path))
    with pytest.raises(TypeError, match="truth"):
        report.record("F", "error", 0.5, "mm")
    with pytest.raises(TypeError, match="truth"):
        report.record("F", "error", 0.5, "mm", kind="result", controlled=True)
    assert not path.exists()                                       # nothing written
    # settings and timings need none: they default to "none"
    assert report.record("F", "image size", "8x8", "px", kind="setting").truth == "none"
    assert report.record("F", "time", 1.5, "s", kind="timing").truth == "none"


def test_verdict_is_computed_from_a_truth_value():
    assert report.verdict(True) == "met"
    assert report.verdict(np.float64(0.2) < 0.1) == "NOT met"
    assert report.verdict(3 > 2, "> 2 px") == "target > 2 px: met"
    with pytest.raises(TypeError, match="ok"):
        report.verdict("met")
    with pytest.raises(TypeError, match="ok"):
        report.verdict(np.array([True, False]))
    with pytest.raises(TypeError, match="target"):
        report.verdict(True, 0.1)


def test_build_dir(tmp_path, monkeypatch):
    monkeypatch.setenv(report.BUILD_ENV, str(tmp_path / "out"))
    assert report.build_dir() == (tmp_path / "out").resolve()
    monkeypatch.delenv(report.BUILD_ENV)
    (tmp_path / "repo" / "notebooks").mkdir(parents=True)
    (tmp_path / "repo" / "pyproject.toml").write_text("")
    monkeypatch.chdir(tmp_path / "repo" / "notebooks")
    assert report.build_dir() == (tmp_path / "repo" / "build").resolve()


# ------------------------------------------------------------- the notebooks' record calls
NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("[0-9][0-9]_*.ipynb"))


def _code_cells(path):
    """``(cell index, source)`` of a notebook's code cells, magics and shell lines commented."""
    nb = json.loads(path.read_text(encoding="utf-8"))
    for i, cell in enumerate(nb["cells"]):
        if cell["cell_type"] == "code":
            src = "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]
            yield i, "\n".join("# " + line if line.lstrip().startswith(("%", "!")) else line
                               for line in src.split("\n"))


def _result_calls(path):
    """``(cell, line, call)`` of every call of ``record`` or of a notebook function that
    forwards its keywords to it (``def rec(*args, **kwargs): ... record(*args, **kwargs)``),
    except settings, timings and the forwarding call itself."""
    trees = [(i, ast.parse(src)) for i, src in _code_cells(path)]

    def forwards(call, names):
        return (isinstance(call, ast.Call) and isinstance(call.func, ast.Name)
                and call.func.id in names and any(k.arg is None for k in call.keywords))

    names = {"record"}
    for _, tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and any(forwards(c, {"record"})
                                                         for c in ast.walk(node)):
                names.add(node.name)
    for i, tree in trees:
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in names) or forwards(node, names):
                continue
            kind = {k.arg: k.value for k in node.keywords}.get("kind")
            if isinstance(kind, ast.Constant) and kind.value in ("setting", "timing"):
                continue
            yield i, node.lineno, node


def test_the_notebook_scan_finds_forwarded_calls(tmp_path):
    import nbformat

    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(
        "%matplotlib inline\n"
        "def rec(*args, **kwargs):\n    RECORDS.append(record(*args, **kwargs))\n"
        "rec('F', 'a', 1, truth='none')\nrec('F', 'b', 2)\n"
        "record('F', 'c', 3, kind='setting')\nrecord('F', 'd', 4, kind='result')")]
    path = tmp_path / "00_x.ipynb"
    nbformat.write(nb, path)
    found = [(call.args[1].value, any(k.arg == "truth" for k in call.keywords))
             for _, _, call in _result_calls(path)]
    assert sorted(found) == [("a", True), ("b", False), ("d", False)]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_result_record_in_the_notebooks_states_its_truth(path):
    calls = list(_result_calls(path))
    missing = [f"cell {i}, line {line}" for i, line, call in calls
               if not any(k.arg == "truth" for k in call.keywords)]
    assert not missing, f"{path.name}: record(...) of a result without truth= at {missing}"
