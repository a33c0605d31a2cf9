import json
from pathlib import Path

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
        "import matplotlib\nimport matplotlib.pyplot as plt\n%matplotlib inline\n"
        "SEED = 7   # the notebook's seed",
        "from lsmta.report import build_dir, record\n"
        "record('F0', 'answer', 42, 'units', paper=41, note='close', truth='none')\n"
        "record('F0', 'image size', '8x8', 'px', paper='8x8', kind='setting')\n"
        "record('F0', 'error', 1.5, 'mm', note='target < 2: met', truth='true cameras',\n"
        "       controlled=True)\n"
        "record('F0', 'fit', 3.5, 'mm', note='target < 2: NOT met', truth='labels from truth')\n"
        "open('build.txt', 'w').write(str(build_dir()))",
        "plt.plot([0, 1], [1, 0]); plt.xlabel('x [px]'); plt.show()",
        "import os; open('cwd.txt', 'w').write(os.getcwd())",
    ])
    # the second notebook runs on a kernel started while the first ran: its own records, name
    # and folder
    _notebook(folder / "01_second.ipynb", [
        "import os\nfrom lsmta.report import record\n"
        "record('F1', 'second', 2, kind='setting')\n"
        "open('second.txt', 'w').write(os.environ['LSMTA_NOTEBOOK'] + ' ' + os.getcwd())"])
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


def test_reproduce_writes_summary_and_figures(notebooks, tmp_path, capfd):
    build = tmp_path / "build"
    assert cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build),
                     "--no-book"]) == 0     # the book: tests/test_book.py
    summary = json.loads((build / "summary.json").read_text())
    assert summary["records"][:2] == [
        {"figure": "F0", "quantity": "answer", "value": 42, "unit": "units", "paper": 41,
         "note": "close", "kind": "result", "truth": "none", "controlled": False},
        {"figure": "F0", "quantity": "image size", "value": "8x8", "unit": "px",
         "paper": "8x8", "note": "", "kind": "setting", "truth": "none", "controlled": False}]
    assert [(r["truth"], r["controlled"]) for r in summary["records"][2:4]] == [
        ("true cameras", True), ("labels from truth", False)]
    md = (build / "summary.md").read_text()
    assert "| F0 | answer | 41 | 42 | units | none | close |" in md
    assert "| F0 | error | — | 1.5 | mm | true cameras (controlled) | target < 2: met |" in md
    # a setting is listed apart, after the paper-against-ours table
    assert md.index("image size") > md.index("## Settings") > md.index("answer")
    # the results counted by their truth inputs; the verdict on a truth-fed record that is
    # not a controlled study listed, and only that one
    truth = md[md.index("## Truth inputs"):md.index("## Settings")]
    assert "| none: the system's own measurements | 1 | 0 |" in truth
    assert "| truth-fed, controlled studies | 1 | 1 |" in truth
    assert "| truth-fed, not controlled studies | 1 | 1 |" in truth
    assert "| F0 | fit | — | 3.5 | mm | labels from truth | target < 2: NOT met |" in truth
    assert "error" not in truth and "answer" not in truth
    figures = list((build / "figures").glob("00_first_cell*.png"))
    assert len(figures) == 1
    page = (build / "index.html").read_text()
    assert figures[0].name in page and "notebooks/00_first.ipynb" in page
    assert "<th>truth</th>" in page and "<td>true cameras (controlled)</td>" in page
    assert "Truth inputs of the results" in page and "<td>labels from truth</td>" in page
    assert summary["notebooks"][0]["record_cells"] == [2, 2, 2, 2]    # the cell of each record
    assert (build / "notebooks" / "01_second.ipynb").exists()
    lines = (build / "records" / "01_second.jsonl").read_text().splitlines()
    second = [json.loads(line) for line in lines]
    assert [r["quantity"] for r in second] == ["second"]
    assert "second" not in (build / "records" / "00_first.jsonl").read_text()
    assert (notebooks / "second.txt").read_text() == f"01_second {notebooks}"
    # each notebook runs in its own folder, as under nbmake, told where the build is
    assert (notebooks / "cwd.txt").read_text() == str(notebooks)
    assert (notebooks / "build.txt").read_text() == str(build.resolve())
    # provenance: seeds, versions, machine (no git repository here)
    meta = summary["meta"]
    assert meta["seeds"] == {"00_first": "7", "01_second": None}
    assert [n["seed"] for n in summary["notebooks"]] == ["7", None]
    for name in ("Python", "numpy", "scipy", "OpenCV", "scikit-image", "numba", "pyvista",
                 "emcee"):
        assert meta["versions"][name], name
    assert meta["git_commit"] is None and meta["git_dirty"] is None
    assert meta["machine"]["cpus"] >= 1
    assert f"numpy {meta['versions']['numpy']}" in page and "00_first 7" in md
    # the kernels run over IPC: no warning about unencrypted TCP
    assert "without encryption" not in capfd.readouterr().err
    # and are shut down after their notebook (none left to stop, with a warning, at exit)
    assert not _kernels_left()


def _kernels_left() -> list[str]:
    """Command lines of this process's child processes that are Jupyter kernels (Linux)."""
    from pathlib import Path

    kids = []
    for task in Path("/proc/self/task").glob("*/children"):
        kids += task.read_text().split()
    lines = []
    for pid in kids:
        try:
            lines.append(Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode())
        except OSError:       # gone meanwhile
            pass
    return [c for c in lines if "ipykernel" in c]


def test_provenance_of_a_git_checkout(tmp_path):
    import subprocess

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
                       cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "a.txt").write_text("1")
    git("add", "a.txt")
    git("commit", "-qm", "one")
    meta = cli.provenance(tmp_path)
    assert len(meta["git_commit"]) == 40 and meta["git_dirty"] is False
    (tmp_path / "a.txt").write_text("2")
    assert cli.provenance(tmp_path)["git_dirty"] is True


def test_failing_cell_is_named(notebooks, tmp_path, capsys):
    _notebook(notebooks / "02_broken.ipynb", ["a = 1", "raise RuntimeError('boom')"])
    build = tmp_path / "build"
    code = cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build),
                     "--only", "02", "--no-book"])
    assert code == 1
    err = capsys.readouterr().err
    assert "02_broken.ipynb failed at cell 2" in err and "boom" in err
    assert not _kernels_left()


def test_unreadable_notebook_leaves_no_kernel(notebooks, tmp_path):
    (notebooks / "02_bad.ipynb").write_text("not json")
    from nbformat.reader import NotJSONError

    with pytest.raises(NotJSONError):
        cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(tmp_path / "b"),
                  "--only", "01", "02", "--no-book"])
    assert not _kernels_left()


def test_two_runs_of_a_notebook_give_identical_records(tmp_path):
    """Reproducibility: every record of a (fast) notebook but its timings is the same in two
    executions, to the last digit."""
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "notebooks"
    runs = []
    for name in ("a", "b"):
        build = tmp_path / name
        assert cli.main(["reproduce", "--notebooks", str(folder), "--build", str(build),
                         "--only", "09", "--no-book"]) == 0
        runs.append([r for r in json.loads((build / "summary.json").read_text())["records"]
                     if r["kind"] != "timing"])
    assert len(runs[0]) >= 5
    assert runs[0] == runs[1]


def test_summary_counts_results_by_their_truth_inputs(tmp_path):
    """Settings and timings stay out of the counts; check-point alignment alone keeps a
    verdict sound, and with no unsound verdict the summary says "none"."""
    from dataclasses import asdict

    from lsmta import report

    recs = [report.Record("F", "a", 1.0, note="target: met", truth="none"),
            report.Record("F", "b", 2.0, note="target: NOT met",
                          truth="aligned on the true check points (held-out bar)"),
            report.Record("F", "c", 3.0, truth="true cameras"),
            report.Record("F", "d", 4.0, note="met", kind="timing"),
            report.Record("F", "e", 5.0, kind="setting")]
    results = [{"notebook": "00_first", "ok": True, "cell": None, "error": None, "seconds": 1.0,
                "seed": None, "figures": [], "html": None, "records": [asdict(r) for r in recs]}]
    cli.write_summary(tmp_path, results, meta=cli.provenance(tmp_path))
    md = (tmp_path / "summary.md").read_text()
    truth = md[md.index("## Truth inputs"):md.index("## Settings")]
    assert "| none: the system's own measurements | 1 | 1 |" in truth
    assert "| aligned on named true check points only | 1 | 1 |" in truth
    assert "| truth-fed, not controlled studies | 1 | 0 |" in truth
    assert "| truth inputs unstated | 0 | 0 |" in truth
    assert "not controlled studies: none." in truth
    assert "studies: none." in (tmp_path / "index.html").read_text()
    assert json.loads((tmp_path / "summary.json").read_text())["records"][2]["truth"] == \
        "true cameras"


def test_reproduce_keeps_arrays_for_its_own_run_only(notebooks, tmp_path):
    """The notebooks of one run share a cache folder; it is gone when the run ends."""
    _notebook(notebooks / "02_third.ipynb", [
        "import os\nfrom pathlib import Path\n"
        "Path('cache.txt').write_text(os.environ.get('LSMTA_BUILD_CACHE', ''))"])
    build = tmp_path / "build"
    assert cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build),
                     "--only", "third", "--no-book"]) == 0
    used = Path((notebooks / "cache.txt").read_text())
    assert used.parent == build.resolve() and used.name.startswith("run-")
    assert not used.exists()


def test_preamble_of_a_notebook():
    """The top of the first code cell: its imports and os.environ.setdefault, up to the first
    other statement or magic."""
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_markdown_cell("import nothing"), nbformat.v4.new_code_cell(
        "import os\n\nos.environ.setdefault('OPENBLAS_NUM_THREADS', '1')  # BLAS\n"
        "import json, time\nfrom pathlib import Path\n"
        "from lsmta import (\n    cli,\n    report,\n)\n"
        "\n%matplotlib inline\nimport numba\n")]
    imports, env = cli.notebook_preamble(nb)
    assert imports == [("os", ()), ("json", ()), ("time", ()), ("pathlib", ("Path",)),
                       ("lsmta", ("cli", "report"))]
    assert env == {"OPENBLAS_NUM_THREADS": "1"}
    nb.cells[1].source = "import os\nx = 1\nimport numba\nos.environ.setdefault('A', 'b')"
    assert cli.notebook_preamble(nb) == ([("os", ())], {})
    nb.cells[1].source = "import os\nos.environ.setdefault('A', name)\nimport numba"
    assert cli.notebook_preamble(nb) == ([("os", ())], {})
    nb.cells[1].source = "import (\n"
    assert cli.notebook_preamble(nb) == ([], {})


def test_kernel_does_the_preamble_ahead_and_binds_nothing(notebooks, tmp_path):
    """The kernel imports the notebook's first modules and sets its environment while it
    boots; the notebook still starts at execution count 1 with only its own names."""
    # imported while the kernel boots: before any cell (IPython counts 1 until the first)
    (notebooks / "probe_import.py").write_text(
        "from IPython import get_ipython\n"
        "open('probe.txt', 'w').write(str(get_ipython().execution_count))\n")
    _notebook(notebooks / "02_third.ipynb", [
        "import os\n\nos.environ.setdefault('LSMTA_TEST_PREAMBLE', 'from the notebook')\n"
        "import json\nfrom probe_import import get_ipython\n%matplotlib inline\n"
        "open('third.txt', 'w').write(json.dumps([os.environ['LSMTA_TEST_PREAMBLE'],\n"
        "                                         'pathlib' in dir()]))",
        "import pathlib  # not in the preamble"])
    build = tmp_path / "build"
    assert cli.main(["reproduce", "--notebooks", str(notebooks), "--build", str(build),
                     "--only", "third", "--no-book"]) == 0
    env_value, leaked = json.loads((notebooks / "third.txt").read_text())
    assert env_value == "from the notebook" and not leaked
    assert (notebooks / "probe.txt").read_text() == "1"
    ran = nbformat.read(build / "notebooks" / "02_third.ipynb", 4)
    assert [c.execution_count for c in ran.cells if c.cell_type == "code"] == [1, 2]


def test_preamble_keeps_no_setting_after_an_import():
    """A setting after an import other than os comes too late in the notebook for that
    import, so the preamble stops there (ahead it would not be too late)."""
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(
        "import os\nimport numpy as np\nos.environ.setdefault('OPENBLAS_NUM_THREADS', '1')\n"
        "import scipy\n")]
    assert cli.notebook_preamble(nb) == ([("os", ()), ("numpy", ())], {})
