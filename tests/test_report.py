import json

import numpy as np
import pytest

from lsmta import report


def test_record_returns_and_writes_when_asked(tmp_path, monkeypatch):
    monkeypatch.delenv(report.RECORD_ENV, raising=False)
    rec = report.record("Fig. 1", "error", np.float64(0.25), "px", paper=0.3, note="n")
    assert rec.value == 0.25 and isinstance(rec.value, float)
    path = tmp_path / "r.jsonl"
    monkeypatch.setenv(report.RECORD_ENV, str(path))
    report.record("Fig. 1", "error", 0.25, "px", paper=0.3)
    report.record("Fig. 2", "size", "768x576")
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["figure"] for r in rows] == ["Fig. 1", "Fig. 2"]
    assert report.load_records(path)[1].paper is None


def test_table_lists_paper_next_to_ours():
    recs = [report.Record("F", "q", 1.23456, "mm", paper=1.2, note="a|b")]
    text = report.table(recs)
    assert "| F | q | 1.2 | 1.235 | mm | a\\|b |" in text
    assert "—" in report.table([report.Record("F", "q", 1, "")])


@pytest.mark.parametrize("kwargs, exc", [
    (dict(value=float("nan")), ValueError),
    (dict(value=[1, 2]), TypeError),
    (dict(value=True), TypeError),
    (dict(value=1.0, paper=object()), TypeError),
])
def test_record_bad_input(kwargs, exc):
    with pytest.raises(exc):
        report.record("F", "q", unit="", **kwargs)
