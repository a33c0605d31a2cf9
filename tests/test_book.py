"""The book (lsmta.book), built from tiny executed notebooks and opened in headless Chromium."""

import json
import shutil

import nbformat
import numpy as np
import pytest
from chromium_cdp import CHROMIUM, Chromium  # tests/chromium_cdp.py

from lsmta import book, cli, interactive


def _notebook(path, cells):
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_markdown_cell(c[3:]) if c.startswith("md:")
                else nbformat.v4.new_code_cell(c) for c in cells]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nbformat.write(nb, path)


VIEW = """import numpy as np
from lsmta.viz import Lines, Mesh, Points, export_3d_html
t = np.linspace(0, 2 * np.pi, 40)
v = np.array([[0, 0, 0], [400, 0, 0], [0, 400, 0], [0, 0, 400.0]])
export_3d_html(Mesh(v, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], color="orange"),
               Points(np.c_[200 * np.cos(t), 200 * np.sin(t), t * 50], values=t, label="t"),
               Lines([np.c_[t * 60, 0 * t, 100 * np.sin(t)]]), title="a test scene")"""


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Three tiny notebooks run by lsmta reproduce (which builds the book)."""
    root = tmp_path_factory.mktemp("book")
    folder = root / "notebooks"
    folder.mkdir()
    (folder / "README.md").write_text(   # the reading order: 02 before 01
        "Read [00](00_first.ipynb), then [02](02_third.ipynb), then [01](01_second.ipynb).\n")
    _notebook(folder / "00_first.ipynb", [
        "md:# First notebook\n\nWith an equation $E = m c^2$ and $$\\int_0^1 x\\,dx$$.",
        "import matplotlib.pyplot as plt\n%matplotlib inline",
        "from lsmta.report import record, verdict\n"
        "record('LSMTA Fig. 2', 'precision', 0.05, 'px', paper=0.1, truth='none',\n"
        "       note=verdict(0.05 < 0.1, '< 0.1 px'))\n"
        "record('LSMTA Fig. 2', 'image size', 64, 'px', kind='setting')",
        "plt.figure(figsize=(4, 3)); plt.plot([0, 1], [1, 0]); plt.show()",
        "from lsmta.report import record, verdict\n"
        "record('Davis Fig. 25', 'scale error', 3.0, '%', paper=1.0, truth='true cameras',\n"
        "       controlled=True, note=verdict(3.0 < 1.0, '< 1 %'))",
    ])
    _notebook(folder / "01_second.ipynb", [
        "md:# Second notebook",
        VIEW,
        "from lsmta.report import record, verdict\n"
        "record('LSMTA system (ours)', 'arm length error', 12.0, 'mm', truth='none',\n"
        "       note=verdict(12.0 < 10.0, '< 10 mm'))",
    ])
    _notebook(folder / "02_third.ipynb", ["md:# Third notebook", "x = 1"])
    build = root / "build"
    code = cli.main(["reproduce", "--notebooks", str(folder), "--build", str(build)])
    return build, code


def test_reproduce_builds_the_book(built, capsys):
    build, code = built
    assert code == 0
    assert (build / "book" / "index.html").is_file()
    for stem in ("00_first", "01_second", "02_third"):
        assert (build / "book" / "notebooks" / f"{stem}.html").is_file()
    assert (build / "book" / "records.html").is_file()
    assert (build / "book" / "searchindex.js").is_file()
    assert (build / "book" / "views3d" / "01_second_view00.html").is_file()
    assert (build / "book" / "views3d" / "plotly.min.js").is_file()
    assert (build / "book" / "_static" / "mathjax" / "tex-svg-full.js").is_file()
    # build/index.html leads to the book
    assert 'url=book/index.html' in (build / "index.html").read_text()
    summary = json.loads((build / "summary.json").read_text())
    nbs = {n["notebook"]: n for n in summary["notebooks"]}
    # each record knows its cell; each view the cell that wrote it
    assert nbs["00_first"]["record_cells"] == [2, 2, 4]
    assert nbs["01_second"]["views"] == [{"file": "01_second_view00.html", "cell": 1}]
    # the provenance is on every page, and nothing is fetched from the network
    for page in (build / "book").rglob("*.html"):
        if page.parent.name in ("views3d", "_static") or "_static" in page.parts:
            continue
        text = page.read_text(encoding="utf-8")
        assert "lsmta-provenance" in text, page
        assert "https://cdn" not in text and "unpkg.com" not in text, page


def test_reproduce_prints_one_line_per_notebook(tmp_path, capsys):
    folder = tmp_path / "notebooks"
    folder.mkdir()
    _notebook(folder / "00_one.ipynb", [
        "from lsmta.report import record, verdict\n"
        "record('F', 'q', 1.0, truth='none', note=verdict(True, '> 0'))\n"
        "record('F', 'r', 2.0, truth='none', note=verdict(False, '< 0'))"])
    _notebook(folder / "01_two.ipynb", ["a = 1", "raise ValueError('broken here')"])
    code = cli.main(["reproduce", "--notebooks", str(folder), "--build", str(tmp_path / "b"),
                     "--no-book"])
    assert code == 1
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[0].startswith("00_one ") and " ok " in lines[0]
    assert "2 numbers" in lines[0] and "1 met" in lines[0] and "1 NOT met" in lines[0]
    assert lines[1].startswith("01_two ") and "FAILED at cell 1" in lines[1]
    assert len(lines) == 4        # two notebooks, the totals, where the numbers are
    assert "01_two.ipynb failed at cell 1" in err and "broken here" in err
    assert "Warning" not in out + err and "warning" not in out + err


def test_front_page_counts(built):
    build, _ = built
    src = (build / ".book" / "src" / "index.md").read_text(encoding="utf-8")
    assert "3 targets: 1 met" in src and "2 NOT met" in src
    # the NOT met target links to the cell that computes it
    assert 'href="notebooks/00_first.html#cell-4"' in src
    assert 'href="notebooks/01_second.html#cell-2"' in src
    # the notebooks' table and the sidebar follow the README's reading order: 00, 02, 01
    for part in (src[src.index("## Notebooks"):], src[src.index("{toctree}"):]):
        assert part.index("notebooks/00_first") < part.index("notebooks/02_third") \
            < part.index("notebooks/01_second")


def test_verdicts_and_groups():
    assert book.verdict_of("target < 1: met") == "met"
    assert book.verdict_of("target < 1: NOT met; close") == "NOT met"
    assert book.verdict_of("a: met; b: NOT met") == "NOT met"
    assert book.verdict_of("metres") is None and book.verdict_of("") is None
    # a verdict recorded as the value (notebooks 17 and 20), not in the note
    assert book.verdict_of("worst 3.1 deg", value="NOT met") == "NOT met"
    assert book.verdict_of("", value="met") == "met" and book.verdict_of("", value=3.0) is None
    assert book.group_of("LSMTA Figs. 3-5 (surface)").endswith("(LSMTA)")
    assert book.group_of("Plaenkers 1999 Figs. 7-11").startswith("Plänkers")
    assert book.group_of("SAPM Fig. 3").startswith("Holstein")
    assert book.group_of("Davis Fig. 25") == "Davis 2002"
    assert book.group_of("LSMTA system (D'Apuzzo et al.)") == "System: LSMTA system"
    assert book.group_of("17 real video") == "Real data"
    assert book.group_of("00 synthetic world") == book.OTHER
    assert book.reading_order(["01_b", "00_a", "02_c"]) == ["00_a", "01_b", "02_c"]


def test_export_3d_html_checks_its_input(tmp_path):
    with pytest.raises(ValueError, match="xyz"):
        interactive.Points(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="faces"):
        interactive.Mesh(np.zeros((3, 3)), [[0, 1, 5]])
    with pytest.raises(ValueError, match="items"):
        interactive.export_3d_html(path=tmp_path / "x.html")
    with pytest.raises(ValueError, match="name"):
        interactive.export_3d_html(interactive.Points(np.zeros((2, 3))), name="../x")
    xyz = np.arange(9.0).reshape(3, 3)
    before = xyz.copy()
    out = interactive.export_3d_html(interactive.Points(xyz), path=tmp_path / "v" / "p.html")
    assert out.is_file() and (tmp_path / "v" / "plotly.min.js").is_file()
    assert np.array_equal(xyz, before)


needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (apt.txt; scripts/bootstrap.sh "
    "installs it)")


@pytest.mark.slow
@needs_chromium
def test_the_book_in_chromium(built):
    build, _ = built
    root = (build / "book").resolve().as_uri()
    with Chromium() as browser:
        # the front page: every notebook, the verdict counts, no console error, no network
        browser.open(f"{root}/index.html")
        assert browser.errors() == [] and browser.remote_requests() == []
        text = browser.eval("document.querySelector('main').innerText")
        for title in ("First notebook", "Second notebook", "Third notebook"):
            assert title in text
        assert "3 targets: 1 met, 2 NOT met" in text
        links = browser.eval("Array.from(document.querySelectorAll('main a'))"
                             ".map(a => a.getAttribute('href'))")
        for stem in ("00_first", "01_second", "02_third"):   # one click from the front page
            assert f"notebooks/{stem}.html" in links

        # a notebook page: its figure loaded, with a size; its equations typeset
        browser.open(f"{root}/notebooks/00_first.html", settle=2.0)
        assert browser.errors() == [] and browser.remote_requests() == []
        sizes = browser.eval("Array.from(document.querySelectorAll('main img'))"
                             ".map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
        assert sizes and all(ok and w > 0 and h > 0 for ok, w, h in sizes)
        assert browser.eval("document.querySelectorAll('mjx-container svg').length") >= 2
        assert browser.eval("!!document.getElementById('cell-4')")

        # the records table filters (from the address, as the front page's links do)
        browser.open(f"{root}/records.html")
        assert browser.eval("document.querySelectorAll('table.lsmta-records tbody tr')"
                            ".length") == 4
        assert browser.eval("document.querySelector('table.lsmta-records').dataset.shown") \
            == "4"
        browser.open(f"{root}/records.html?verdict=NOT%20met")
        assert browser.eval("document.querySelector('table.lsmta-records').dataset.shown") \
            == "2"
        browser.eval("(() => { const s = document.querySelector('[data-filter=kind]');"
                     " s.value = 'setting'; s.dispatchEvent(new Event('input')); })()")
        assert browser.eval("document.querySelector('table.lsmta-records').dataset.shown") \
            == "0"
        browser.open(f"{root}/records.html?truth=truth%20inputs")
        visible = browser.eval("Array.from(document.querySelectorAll("
                               "'table.lsmta-records tbody tr')).filter(r => "
                               "r.style.display !== 'none').map(r => r.innerText)")
        assert len(visible) == 1 and "scale error" in visible[0]
        assert browser.errors() == []

        # search finds a notebook
        browser.open(f"{root}/search.html?q=Third", settle=2.0)
        assert browser.eval("document.querySelectorAll('#search-results li').length") >= 1
        assert browser.errors() == []

        # the interactive 3-D view: a WebGL canvas with non-blank pixels
        browser.open(f"{root}/views3d/01_second_view00.html", settle=3.0)
        assert browser.errors() == [] and browser.remote_requests() == []
        assert browser.eval("document.querySelectorAll('canvas').length") >= 1
        png = browser.screenshot()
        # and the same view inside its notebook page
        browser.open(f"{root}/notebooks/01_second.html", settle=1.0)
        assert browser.eval("document.querySelectorAll('iframe[src*=view00]').length") == 1
        assert browser.errors() == []
    from io import BytesIO

    from PIL import Image

    pixels = np.asarray(Image.open(BytesIO(png)).convert("RGB"), float)
    middle = pixels[150:-150, 150:-150]
    # the scene's colours (orange mesh, coloured points) and not a blank page
    assert middle.std() > 10
    orange = (middle[..., 0] > 200) & (middle[..., 1] > 100) & (middle[..., 1] < 200) & (
        middle[..., 2] < 80)
    assert orange.sum() > 200


def test_book_command_needs_a_build(tmp_path, capsys):
    assert cli.main(["book", "--build", str(tmp_path)]) == 2
    assert "no summary.json" in capsys.readouterr().err


def test_book_rebuilds_from_a_build(built, tmp_path):
    build, _ = built
    copy = tmp_path / "b"
    shutil.copytree(build, copy, ignore=shutil.ignore_patterns("book", ".book"))
    result = book.build_book(copy)
    assert result.ok, result.messages
    assert (copy / "book" / "notebooks" / "02_third.html").is_file()
