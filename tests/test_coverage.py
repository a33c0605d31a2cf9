"""notebooks/COVERAGE.md stays in step with the notebooks and the papers.

COVERAGE.md has one table per paper (a ``##`` heading naming the paper's text file, e.g.
``dapuzzo2000_lsmta.txt``) with a row per numbered figure, table and section:

    | item | what the paper shows | status | where |
    | Fig. 1 | ... | reproduced | [01](01_calibration_convergence.ipynb) “Fig. 1 — ...” |

*status* is ``reproduced`` (or ``reproduced: <note>``), ``partly: <what>`` or
``not reproduced: <why>``; *where* names cells by their notebook and the exact text of a
markdown heading in it (curly quotes).

Checked here: every notebook and heading named exists; every notebook is named somewhere;
every figure, table and section a notebook claims — in the first argument of its
``record(...)`` calls and in its markdown headings — has a row naming that notebook; the
rows are exactly the papers' numbered items (``PAPER_ITEMS``, extracted once from the
texts); and, where the paper texts are at hand, ``PAPER_ITEMS`` against them.
"""

import ast
import functools
import json
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
COVERAGE = NOTEBOOK_DIR / "COVERAGE.md"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("[0-9][0-9]_*.ipynb"))

LSMTA = "dapuzzo2000_lsmta.txt"
SAPM = "li_holstein2002_sapm.txt"
DAVIS = "davis2002_mixed_scale_thesis.txt"
PLAENKERS = "plaenkers1999_body_modeling.txt"


def _span(a, b):
    return list(range(a, b + 1))


# Every numbered figure, table and section of the four papers, as extracted from their texts
# by `paper_text_items` (the last test re-extracts them when the texts are at hand). The
# LSMTA paper has no Figure 15: its numbering goes from 14 to 16.
PAPER_ITEMS = {
    LSMTA: {
        "Fig.": _span(1, 14) + [16, 17],
        "Table": [],
        "§": ["1", "2", "2.1", "2.2", "2.3", "2.3.1", "2.3.2", "2.3.3", "3", "4"],
    },
    SAPM: {
        "Fig.": _span(1, 4),
        "Table": [1],
        "§": ["1", "2", "3", "3.1", "3.1.1", "3.1.2", "3.2", "4", "4.1", "4.2", "5"],
    },
    DAVIS: {
        "Fig.": _span(1, 74),
        "Table": [],
        "§": ["1", "1.1", "1.2", "1.3", "1.4", "1.5", "1.6", "1.7",
              "2", "2.1", "2.2", "2.3", "2.4", "2.5",
              "3", "3.1", "3.2", "3.3", "3.4", "3.5", "3.6", "3.7",
              "4", "4.1", "4.2", "4.3", "4.4", "4.5",
              "5", "5.1", "5.2", "5.3", "5.4", "5.5",
              "6", "6.1", "6.2", "6.3"],
    },
    PLAENKERS: {
        "Fig.": _span(1, 11),
        "Table": [],
        "§": ["1", "2", "2.1", "2.2", "3", "3.1", "3.2", "3.3", "3.4", "3.4.1", "3.4.2",
              "3.4.3", "4", "4.1", "4.2", "4.3", "4.4", "5", "6"],
    },
}


def _paper_dir():
    """The papers' texts: $LSMTA_PAPERS, or ../shared/papers beside the checkout (or beside
    the folder holding it, for a git worktree one level down)."""
    candidates = [ROOT.parent / "shared" / "papers", ROOT.parents[1] / "shared" / "papers"]
    if os.environ.get("LSMTA_PAPERS"):
        candidates.insert(0, Path(os.environ["LSMTA_PAPERS"]))
    return next((d for d in candidates if all((d / name).is_file() for name in PAPER_ITEMS)), None)


# ------------------------------------------------------------------ naming papers and items
# Which paper a name means. Author lists come first, so that a co-author is not taken for the
# first author ("Plänkers, Fua & D'Apuzzo 1999" is Plänkers et al., not D'Apuzzo et al.).
_PAPER_NAMES = [
    (r"Pl(?:ä|ae)nkers(?:,? Fua (?:&|and) D['’]Apuzzo)?", PLAENKERS),
    (r"D['’]Apuzzo(?:,? Pl(?:ä|ae)nkers (?:&|and) Fua)?", LSMTA),
    (r"LSMTA", LSMTA),
    (r"Holstein(?: (?:&|and) Li)?|Li (?:&|and) Holstein|SAPM", SAPM),
    (r"Davis", DAVIS),
]
_NUMS = r"\d+(?:\.\d+)*(?:\s*(?:[–\-/,]|and)\s*\d+(?:\.\d+)*)*"
_KINDS = r"Figs?\.|Figures?|Tables?|§|[Ss]ections?|Secs?\.|ch\.|[Cc]hapters?"
_TOKEN = re.compile(
    "|".join(f"(?P<p{i}>{rx})" for i, (rx, _) in enumerate(_PAPER_NAMES))
    + rf"|(?P<kind>{_KINDS})\s*(?P<nums>{_NUMS})"
)


def _numbers(kind, text):
    """'28–32, 36–39' -> ['28', ..., '32', '36', ..., '39']; '3.3/3.7' -> ['3.3', '3.7']."""
    out, dash = [], False
    for tok in re.findall(r"\d+(?:\.\d+)*|[–\-]", text):
        if tok in "–-":
            dash = True
            continue
        if dash and out and "." not in tok and "." not in out[-1]:
            out.extend(str(n) for n in range(int(out[-1]) + 1, int(tok) + 1))
        else:
            out.append(tok)
        dash = False
    if kind != "§":
        out = [n.split(".")[0] for n in out]
    return out


def parse_refs(text):
    """The items a piece of text names: (paper or None, kind, number), kind one of 'Fig.',
    'Table', '§'. An item takes the paper named last before it in the text (None if none)."""
    refs, paper = [], None
    for m in _TOKEN.finditer(text):
        named = [p for i, (_, p) in enumerate(_PAPER_NAMES) if m.group(f"p{i}")]
        if named:
            paper = named[0]
            continue
        word = m.group("kind")
        kind = "Fig." if word.startswith("Fig") else "Table" if word.startswith("Table") else "§"
        refs += [(paper, kind, n) for n in _numbers(kind, m.group("nums"))]
    return refs


def _papers_named(text):
    return {p for i, (_, p) in enumerate(_PAPER_NAMES)
            for m in _TOKEN.finditer(text) if m.group(f"p{i}")}


# ------------------------------------------------------------------ notebooks
def _cells(path):
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def _source(cell):
    return "".join(cell["source"])


@functools.cache
def headings(path):
    """The text of every markdown heading of a notebook, without its #'s."""
    return [line.lstrip("#").strip() for cell in _cells(path) if cell["cell_type"] == "markdown"
            for line in _source(cell).splitlines() if line.startswith("#")]


def _text_of(node, names):
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value for v in node.values if isinstance(v, ast.Constant))
    if isinstance(node, ast.Name):
        return names.get(node.id)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _text_of(node.left, names), _text_of(node.right, names)
        return None if left is None or right is None else left + right
    return None


def record_figures(path):
    """The first argument of every record(...) / rec(...) call in a notebook's code cells,
    names resolved through the notebook's own string assignments."""
    trees = []
    for cell in _cells(path):
        if cell["cell_type"] == "code":
            code = "\n".join("" if line.lstrip().startswith(("%", "!")) else line
                             for line in _source(cell).splitlines())
            trees.append(ast.parse(code))
    names = {}
    for tree in trees:
        for node in ast.walk(tree):
            if not isinstance(node, ast.Assign):
                continue
            for target in node.targets:
                if isinstance(target, ast.Name):
                    pairs = [(target, node.value)]
                elif isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                    pairs = list(zip(target.elts, node.value.elts))
                else:
                    continue
                for t, v in pairs:
                    if isinstance(t, ast.Name) and _text_of(v, {}) is not None:
                        names[t.id] = _text_of(v, {})
    figures = []
    for tree in trees:
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and node.args):
                continue
            func = getattr(node.func, "id", None) or getattr(node.func, "attr", None)
            if func not in ("record", "rec") or isinstance(node.args[0], ast.Starred):
                continue
            text = _text_of(node.args[0], names)
            assert text is not None, (f"{path.name}: cannot read the figure of "
                                      f"{ast.unparse(node)[:80]}")
            figures.append(text)
    return figures


def notebook_claims(path):
    """(paper or None, kind, number, where) for every item the notebook's records and
    headings name; None: the heading names no paper (any paper of the notebook will do)."""
    claims = []
    for figure in sorted(set(record_figures(path))):
        claims += [(p, k, n, f"record({figure!r})") for p, k, n in parse_refs(figure)]
    for heading in headings(path):
        claims += [(p, k, n, f"heading {heading!r}") for p, k, n in parse_refs(heading)]
    return claims


def notebook_papers(path):
    """The papers a notebook's first cell names."""
    return _papers_named(_source(_cells(path)[0]))


# ------------------------------------------------------------------ COVERAGE.md
_ROW_ITEM = re.compile(r"^(Fig\.|Table|§)\s*(\d+(?:\.\d+)*)$")
_ANCHOR = re.compile(r"\[(\d\d)\]\((\d\d_[A-Za-z0-9_]+\.ipynb)\)\s*“([^”]+)”")
_STATUS = re.compile(r"^(reproduced(: \S.*)?|partly: \S.*|not reproduced: \S.*)$")


def coverage_tables():
    """{paper file: {(kind, number): row}}, row a dict of item, shows, status, anchors."""
    tables, paper = {}, None
    for n, line in enumerate(COVERAGE.read_text(encoding="utf-8").splitlines(), 1):
        if line.startswith("## "):
            named = [p for p in PAPER_ITEMS if p in line]
            paper = named[0] if named else None
            if paper:
                assert paper not in tables, f"COVERAGE.md line {n}: a second table for {paper}"
                tables[paper] = {}
            continue
        if paper is None or not line.startswith("|"):
            continue
        cols = [c.strip() for c in line.strip().strip("|").split("|")]
        if cols[0] in ("item", "") or set(cols[0]) <= set("-: "):
            continue
        assert len(cols) == 4, f"COVERAGE.md line {n}: {len(cols)} columns, not 4: {line}"
        m = _ROW_ITEM.match(cols[0])
        assert m, f"COVERAGE.md line {n}: item {cols[0]!r} is not 'Fig. N', 'Table N' or '§N.N'"
        key = (m.group(1), m.group(2))
        assert key not in tables[paper], f"COVERAGE.md line {n}: {cols[0]} twice for {paper}"
        tables[paper][key] = {"line": n, "item": cols[0], "shows": cols[1], "status": cols[2],
                              "anchors": _ANCHOR.findall(cols[3]), "where": cols[3]}
    return tables


def _expected_rows(paper):
    items = PAPER_ITEMS[paper]
    return {(kind, str(n)) for kind in ("Fig.", "Table", "§") for n in items[kind]}


# ------------------------------------------------------------------ the tests
def test_the_parser_reads_figure_strings():
    assert parse_refs("Plänkers, Fua & D'Apuzzo 1999, Figs. 7–11") == [
        (PLAENKERS, "Fig.", str(n)) for n in range(7, 12)]
    assert parse_refs("LSMTA Fig. 16 / Plänkers Figs. 6, 11") == [
        (LSMTA, "Fig.", "16"), (PLAENKERS, "Fig.", "6"), (PLAENKERS, "Fig.", "11")]
    assert parse_refs("Davis §3.3/3.7 (LED detection)") == [
        (DAVIS, "§", "3.3"), (DAVIS, "§", "3.7")]
    assert parse_refs("LSMTA system (D'Apuzzo et al. 2000 Secs. 2-3; "
                      "Plaenkers et al. 1999 Sec. 4)") == [
        (LSMTA, "§", "2"), (LSMTA, "§", "3"), (PLAENKERS, "§", "4")]
    assert parse_refs("Davis 2002, ch. 3, Figs. 33, 35, 40–42, §3.6") == [
        (DAVIS, "§", "3")] + [(DAVIS, "Fig.", n) for n in ("33", "35", "40", "41", "42")] + [
        (DAVIS, "§", "3.6")]
    assert parse_refs("Fig. 59/60: the most occluded frame") == [
        (None, "Fig.", "59"), (None, "Fig.", "60")]
    assert parse_refs("The method (Gruen 1985; LSMTA paper Section 2.2 and Fig. 2)") == [
        (LSMTA, "§", "2.2"), (LSMTA, "Fig.", "2")]
    assert parse_refs("Table 1: the effect of ε and β") == [(None, "Table", "1")]


def test_every_paper_has_a_table_with_a_row_per_item():
    tables = coverage_tables()
    assert set(tables) == set(PAPER_ITEMS), f"tables for {sorted(tables)}"
    for paper, rows in tables.items():
        missing = sorted(_expected_rows(paper) - set(rows))
        extra = sorted(set(rows) - _expected_rows(paper))
        assert not missing, f"{paper}: no row for {missing}"
        assert not extra, f"{paper}: rows for items the paper does not number: {extra}"


def test_every_row_says_how_it_stands():
    for paper, rows in coverage_tables().items():
        for row in rows.values():
            where = f"COVERAGE.md line {row['line']} ({paper} {row['item']})"
            assert row["shows"], f"{where}: say what the paper shows"
            assert _STATUS.match(row["status"]), (
                f"{where}: status {row['status']!r} is not 'reproduced[: <note>]', "
                "'partly: <what>' or 'not reproduced: <why>'")
            if not row["status"].startswith("not reproduced"):
                assert row["anchors"], f"{where}: {row['status'].split(':')[0]} but names no cell"


def test_every_notebook_and_heading_named_exists():
    text = COVERAGE.read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(([^)#]+\.ipynb)[^)]*\)", text))
    missing = sorted(name for name in linked if not (NOTEBOOK_DIR / name).is_file())
    assert not missing, f"COVERAGE.md links notebooks that do not exist: {missing}"
    for paper, rows in coverage_tables().items():
        for row in rows.values():
            for number, name, heading in row["anchors"]:
                where = f"COVERAGE.md line {row['line']} ({paper} {row['item']})"
                assert name.startswith(number + "_"), f"{where}: [{number}] links {name}"
                assert heading in headings(NOTEBOOK_DIR / name), (
                    f"{where}: {name} has no heading {heading!r}")


def test_every_notebook_is_in_coverage():
    text = COVERAGE.read_text(encoding="utf-8")
    absent = [p.name for p in NOTEBOOKS if f"({p.name})" not in text]
    assert not absent, f"COVERAGE.md never names {absent}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_every_item_a_notebook_claims_is_in_coverage(path):
    tables = coverage_tables()
    own = notebook_papers(path)
    missing = []
    for paper, kind, number, source in notebook_claims(path):
        papers = [paper] if paper else sorted(own)
        assert papers, f"{path.name}: {source} names {kind} {number}, and no paper"
        rows = [tables[p].get((kind, number)) for p in papers]
        if not any(row and path.name in {a[1] for a in row["anchors"]} for row in rows):
            missing.append(f"{kind} {number} of {' or '.join(papers)} ({source})")
    assert not missing, (f"{path.name} claims items whose COVERAGE.md row does not name it: "
                         + "; ".join(sorted(set(missing))))


def paper_text_items(text):
    """Figures and tables from caption lines ('Figure 12. ...', 'Table 1: ...', and the thesis's
    list of illustrations), sections from numbered heading lines ('2.3.1 Tracking ...')."""
    items = {"Fig.": set(), "Table": set(), "§": set()}
    for line in text.splitlines():
        m = re.match(r"^(?:#+\s+)?(Figure|Table)\s+(\d+)\b", line)
        if m:
            items["Fig." if m.group(1) == "Figure" else "Table"].add(int(m.group(2)))
        m = re.match(r"^(?:#+\s+)?(\d+(?:\.\d+)*)\s+[A-Z]", line)
        if m:
            items["§"].add(m.group(1))
    return items


def test_paper_items_match_the_paper_texts():
    folder = _paper_dir()
    if folder is None:
        pytest.skip("the papers' texts are not at hand (../shared/papers or $LSMTA_PAPERS); "
                    "PAPER_ITEMS was extracted from them once")
    for paper, items in PAPER_ITEMS.items():
        found = paper_text_items((folder / paper).read_text(encoding="utf-8"))
        assert found["Fig."] == set(items["Fig."]), f"{paper}: figures {sorted(found['Fig.'])}"
        assert found["Table"] == set(items["Table"]), f"{paper}: tables {sorted(found['Table'])}"
        assert found["§"] == set(items["§"]), f"{paper}: sections {sorted(found['§'])}"
