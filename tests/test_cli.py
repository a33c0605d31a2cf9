import json

import nbformat
import pytest

from lsmta import cli


def _notebook(path, sources):
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_markdown_cell("# test")] + [
        nbformat.v4.new_code_cell(s) for s in sources]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nbformat.write(nb, path)


@pytest.fixture
def notebooks(tmp_path):
    folder = tmp_path / "notebooks"
    folder.mkdir()
    _notebook(folder / "00_first.ipynb", [
        "import matplotlib\nimport matplotlib.pyplot as plt\n%matplotlib inline",
        "from lsmta.report import record\n"
        "record('F0', 'answer', 42, 'units', paper=41, note='close')",
        "plt.plot([0, 1], [1, 0]); plt.xlabel('x [px]'); plt.show()",
        "import os; open('cwd.txt', 'w').write(os.getcwd())",
    ])
    _notebook(folder / "01_second.ipynb", ["x = 1"])
    (folder / "notes.ipynb").write_text("{}")  # not numbered: ignored
    return folder


def test_list(notebooks, capsys):
    assert cli.main(["reproduce", "--list", "--notebooks", str(notebooks)]) == 0
    assert capsys.readouterr().out.split() == ["00_first", "01_second"]
    assert cli.main(["reproduce", "--list", "--notebooks", str(notebooks),
                     "--only", "second"]) == 0
    assert capsys.readouterr().out.split() == ["01_second"]
    with pytest.raises(SystemExit, match="matches no notebook"):
        cli.main(["reproduce", "--list", "--notebooks", str(notebooks), "--only", "99"])


def test_reproduce_writes_summary_and_figures(notebooks, tmp_path):
    build = tmp_path / "build"
    assert cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build)]) == 0
    summary = json.loads((build / "summary.json").read_text())
    assert summary["records"] == [{"figure": "F0", "quantity": "answer", "value": 42,
                                   "unit": "units", "paper": 41, "note": "close"}]
    assert "| F0 | answer | 41 | 42 | units | close |" in (build / "summary.md").read_text()
    figures = list((build / "figures").glob("00_first_cell*.png"))
    assert len(figures) == 1
    page = (build / "index.html").read_text()
    assert figures[0].name in page and "notebooks/00_first.html" in page
    assert (build / "notebooks" / "01_second.ipynb").exists()
    # each notebook runs in its own folder, as under nbmake
    assert (notebooks / "cwd.txt").read_text() == str(notebooks)


def test_failing_cell_is_named(notebooks, tmp_path, capsys):
    _notebook(notebooks / "02_broken.ipynb", ["a = 1", "raise RuntimeError('boom')"])
    build = tmp_path / "build"
    code = cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build),
                     "--only", "02"])
    assert code == 1
    err = capsys.readouterr().err
    assert "02_broken.ipynb failed at cell 2" in err and "boom" in err
