"""The book: a static site of the executed notebooks, built with Sphinx and MyST-NB.

``lsmta reproduce`` (and ``lsmta book``) writes ``build/book/``: a page per executed
notebook with its outputs (MyST-NB reads them, nothing is re-executed), in the reading
order of ``notebooks/README.md``; a front page stating, per paper and per system, how many
targets are met and which are NOT met, each linked to the cell that computes it; the
records table, sortable and filterable; the interactive 3-D views of :mod:`lsmta.interactive`
after the cells that wrote them; the run's provenance in every page's footer; Sphinx's
search. It builds with no network, and opens from the file system with none: the theme's
assets, MathJax (from ``sphinx-mathjax-offline``) and plotly.js are copied into the book.

A target is a record whose note carries a verdict (:func:`lsmta.report.verdict` writes
"met" / "NOT met"); :func:`verdict_of` reads it back and :func:`group_of` files a record
under its paper or system from its ``figure``.
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from . import report

#: (pattern on a record's figure, group), first match wins
GROUPS = (
    (re.compile(r"system", re.I), None),      # a system: named by its figure, see group_of
    (re.compile(r"\breal\b|AnimFace|Middlebury", re.I), "Real data"),
    (re.compile(r"LSMTA"), "D'Apuzzo, Plänkers & Fua 2000 (LSMTA)"),
    (re.compile(r"Pl(ae|ä)nkers", re.I), "Plänkers, Fua & D'Apuzzo 1999"),
    (re.compile(r"SAPM|Holstein", re.I), "Holstein & Li 2002 (SAPM)"),
    (re.compile(r"Davis"), "Davis 2002"),
)
OTHER = "The generator and other checks"
_NOT_MET = re.compile(r"\bNOT met\b")
_MET = re.compile(r"\bmet\b")
_NB_NAME = re.compile(r"\b(\d\d_[A-Za-z0-9_]+)\.ipynb")


def verdict_of(note: str, *, value=None) -> str | None:
    """``"NOT met"`` if a record's note, or its value when that is a string (a verdict
    recorded as the number), states any target NOT met; ``"met"`` if it states one met;
    else None (the record is not a target)."""
    text = f"{note} {value}" if isinstance(value, str) else note
    if _NOT_MET.search(text):
        return "NOT met"
    if _MET.search(text):
        return "met"
    return None


def group_of(figure: str) -> str:
    """The paper or system a record belongs to, from its ``figure``: a system by its own
    name (the figure up to a parenthesis), real data apart, then the four papers."""
    for pattern, group in GROUPS:
        if pattern.search(figure):
            if group is None:
                return "System: " + figure.split("(")[0].strip()
            return group
    return OTHER


def truth_class(rec: dict) -> str:
    """``"none"`` (also for ``"none (...)"``, :func:`lsmta.report.no_truth`),
    ``"unstated"`` or ``"truth inputs"`` (the record leaned on the generator's truth; its
    words are in ``rec["truth"]``)."""
    truth = rec.get("truth", "unstated")
    if report.no_truth(truth):
        return "none"
    return truth if truth == "unstated" else "truth inputs"


def reading_order(stems, *, readme: Path | None = None) -> list[str]:
    """``stems`` in the order ``readme`` first names them (``NN_name.ipynb``), the others
    after them by number."""
    stems = sorted(stems)
    order = []
    if readme is not None and Path(readme).is_file():
        for name in _NB_NAME.findall(Path(readme).read_text(encoding="utf-8")):
            if name in stems and name not in order:
                order.append(name)
    return order + [s for s in stems if s not in order]


@dataclass(frozen=True)
class BookResult:
    """What :func:`build_book` made: the front page, the seconds it took, and Sphinx's
    warnings and errors (empty when clean); ``ok`` is False if Sphinx failed."""

    index: Path
    seconds: float
    ok: bool
    messages: str


# ------------------------------------------------------------------------------ pages
def _write(path: Path, text: str | bytes) -> None:
    """Write only on change: Sphinx then rebuilds only the pages whose source changed."""
    data = text.encode("utf-8") if isinstance(text, str) else text
    if path.exists() and path.read_bytes() == data:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def _title(nb, stem: str) -> str:
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            hit = re.search(r"^#\s+(.+)$", cell.source, re.MULTILINE)
            if hit:
                return hit.group(1).strip()
    return stem


def _notebook_page(nb, res: dict | None, stem: str):
    """The notebook as the book shows it: an anchor ``cell-N`` before each code cell (N its
    index in the notebook, as errors and the front page name it), the 3-D views after the
    cells that wrote them, a failure stated on top, widget state dropped."""
    import nbformat  # deferred: the notebook machinery is only needed to build

    md = nbformat.v4.new_markdown_cell
    views = {}
    for view in (res or {}).get("views", []):
        views.setdefault(view["cell"], []).append(view["file"])
    cells = []
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "code":
            cells.append(md(f'<div id="cell-{i}" class="lsmta-anchor" data-cell="{i}"></div>'))
        cells.append(cell)
        for name in views.get(i, []):
            src = f"../views3d/{html.escape(name)}"
            cells.append(md(
                f'<div class="lsmta-view3d"><iframe src="{src}" loading="lazy" '
                f'title="interactive 3-D view"></iframe><p>Interactive 3-D view (drag to turn, '
                f'scroll to zoom): <a href="{src}">open it on its own page</a>.</p></div>'))
    if res is not None and not res.get("ok", True):
        warn = md(f"```{{error}}\nThis notebook FAILED at "
                  f"[cell {res['cell']}](#cell-{res['cell']}): {res['error']}\n```")
        first = next((k for k, c in enumerate(cells) if c.cell_type == "markdown"
                      and c.source.lstrip().startswith("# ")), -1)
        cells.insert(first + 1, warn)
    if not any(c.cell_type == "markdown" and c.source.lstrip().startswith("# ") for c in cells):
        cells.insert(0, md(f"# {stem}"))
    nb.cells = cells
    nb.metadata.pop("widgets", None)
    return nb


def _provenance_html(meta: dict) -> str:
    if not meta:
        return "provenance unknown"
    esc = html.escape
    commit = meta.get("git_commit") or "unknown"
    dirty = " (uncommitted changes)" if meta.get("git_dirty") else ""
    versions = ", ".join(f"{k} {v}" for k, v in (meta.get("versions") or {}).items())
    m = meta.get("machine") or {}
    machine = (f"{m.get('system')} {m.get('release')}, {m.get('architecture')}, "
               f"{m.get('cpus')} CPUs, host {m.get('hostname')}")
    return (f'<div class="lsmta-provenance">Run finished {esc(str(meta.get("finished")))}; '
            f"commit <code>{esc(commit[:12])}</code>{esc(dirty)}; {esc(versions)}; "
            f"{esc(machine)}.</div>")


def _cell_link(stem: str, cell, prefix: str = "") -> str:
    anchor = f"#cell-{cell}" if cell is not None else ""
    return f"{prefix}notebooks/{stem}.html{anchor}"


def _records(results: list[dict]) -> list[dict]:
    """Every record with its notebook, cell, verdict, group and truth class."""
    out = []
    for res in results:
        cells = res.get("record_cells") or [None] * len(res.get("records", []))
        for rec, cell in zip(res.get("records", []), cells):
            r = dict(rec)
            r.update(notebook=res["notebook"], cell=cell,
                     verdict=verdict_of(r.get("note", ""), value=r.get("value")),
                     group=group_of(r.get("figure", "")), truth_class=truth_class(r))
            out.append(r)
    return out


def _front_page(results, records, titles, order, meta) -> str:
    esc = html.escape
    targets = [r for r in records if r["verdict"] and r.get("kind") == "result"]
    groups = {}
    for r in targets:
        groups.setdefault(r["group"], []).append(r)
    papers = [g for _, g in GROUPS if g and g != "Real data"]
    ordered = ([g for g in papers if g in groups]
               + sorted(g for g in groups if g.startswith("System: "))
               + [g for g in ("Real data", OTHER) if g in groups])
    rows = []
    for g in ordered:
        recs = groups[g]
        bad = [r for r in recs if r["verdict"] == "NOT met"]
        links = "; ".join(
            f'<a href="{_cell_link(r["notebook"], r["cell"])}">{esc(r["quantity"])}</a> '
            f'<span class="lsmta-nb">({esc(r["notebook"][:2])})</span>' for r in bad)
        rows.append(f"<tr><td>{esc(g)}</td><td>{len(recs)}</td>"
                    f"<td>{len(recs) - len(bad)}</td>"
                    f'<td class="{"lsmta-bad" if bad else ""}">{len(bad)}</td>'
                    f"<td>{links or '—'}</td></tr>")
    n_bad = sum(r["verdict"] == "NOT met" for r in targets)
    by_stem = {res["notebook"]: res for res in results}
    nb_rows = []
    for stem in order:
        res = by_stem.get(stem)
        recs = [r for r in targets if r["notebook"] == stem]
        bad = sum(r["verdict"] == "NOT met" for r in recs)
        if res is None:
            state = "not run"
        elif res.get("ok", True):
            state = "ok"
        else:
            state = (f'<a class="lsmta-bad" href="{_cell_link(stem, res.get("cell"))}">'
                     f"FAILED at cell {res.get('cell')}</a>")
        nb_rows.append(
            f'<tr><td><a href="notebooks/{stem}.html">{esc(titles.get(stem, stem))}</a></td>'
            f"<td>{state}</td><td>{(res or {}).get('seconds', '—')}</td>"
            f"<td>{len((res or {}).get('figures', []))}</td>"
            f"<td>{len((res or {}).get('views', []))}</td>"
            f"<td>{len((res or {}).get('records', []))}</td>"
            f"<td>{len(recs) - bad}</td><td class=\"{'lsmta-bad' if bad else ''}\">{bad}</td>"
            "</tr>")
    failed = [res for res in results if not res.get("ok", True)]
    fail_note = ""
    if failed:
        fail_note = ("<p class=\"lsmta-bad\"><b>Failed notebooks:</b> " + "; ".join(
            f'<a href="{_cell_link(r["notebook"], r.get("cell"))}">{esc(r["notebook"])}, '
            f"cell {r.get('cell')}</a>: {esc(str(r.get('error')))}" for r in failed) + "</p>")
    toc = "\n".join(f"notebooks/{stem}" for stem in order)
    return f"""# lsmta — the reproduced results

Four papers on human shape and motion capture, re-implemented and re-run: every number
below was computed by this run of the notebooks (`lsmta reproduce`), next to the papers'.
A *target* is a claim a notebook checks and states as "met" or "NOT met"; the links go to
the cell that computes it. The [records table](records.md) lists all
{len(records)} numbers, sortable and filterable (paper, kind, verdict, ground truth used).

<div class="lsmta-summary"><p><b>{len(targets)} targets: {len(targets) - n_bad} met,
<span class="lsmta-bad">{n_bad} NOT met</span></b>, in {len(results)} notebooks.</p>
{fail_note}</div>

## Targets per paper and system

<table class="lsmta-table lsmta-groups"><thead><tr><th>paper or system</th><th>targets</th>
<th>met</th><th>NOT met</th><th>which are NOT met (notebook)</th></tr></thead><tbody>
{''.join(rows)}
</tbody></table>

## Notebooks, in reading order

<table class="lsmta-table lsmta-notebooks"><thead><tr><th>notebook</th><th>run</th>
<th>seconds</th><th>figures</th><th>3-D views</th><th>numbers</th><th>met</th>
<th>NOT met</th></tr></thead><tbody>
{''.join(nb_rows)}
</tbody></table>

Also in the build folder: `summary.md` and `summary.json` (every number and the provenance),
`notebooks/*.ipynb` (the executed notebooks), `figures/*.png` (every figure, for print).

```{{toctree}}
:hidden:
:caption: Notebooks

{toc}
```

```{{toctree}}
:hidden:
:caption: Tables

records
```
"""


def _records_page(records) -> str:
    esc = html.escape
    cols = ("notebook", "figure", "quantity", "paper", "ours", "unit", "verdict", "kind",
            "truth", "note")
    body = []
    for r in records:
        controlled = " (controlled)" if r.get("controlled") else ""
        cells = [f'<a href="{_cell_link(r["notebook"], r["cell"])}">{esc(r["notebook"][:2])}'
                 f"{'' if r['cell'] is None else ' · ' + str(r['cell'])}</a>",
                 esc(r.get("figure", "")), esc(r.get("quantity", "")),
                 esc(report.format_value(r.get("paper"))),
                 esc(report.format_value(r.get("value"))), esc(r.get("unit", "")),
                 esc(r["verdict"] or ""), esc(r.get("kind", "")),
                 esc(r.get("truth", "")) + controlled, esc(r.get("note", ""))]
        attrs = (f'data-group="{esc(r["group"])}" data-kind="{esc(r.get("kind", ""))}" '
                 f'data-verdict="{esc(r["verdict"] or "no target")}" '
                 f'data-truth="{esc(r["truth_class"])}" '
                 f'data-controlled="{"yes" if r.get("controlled") else "no"}"')
        body.append(f"<tr {attrs}>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")

    def options(name, values):
        opts = "".join(f'<option value="{esc(v)}">{esc(v)}</option>' for v in values)
        return (f'<label>{name} <select data-filter="{name}"><option value="">all</option>'
                f"{opts}</select></label>")

    groups = sorted({r["group"] for r in records})
    filters = (options("group", groups) + options("kind", report.KINDS)
               + options("verdict", ["met", "NOT met", "no target"])
               + options("truth", ["none", "truth inputs", "unstated"])
               + options("controlled", ["yes", "no"])
               + '<label>text <input type="search" data-filter="text" size="18"></label>')
    head = "".join(f'<th data-col="{k}" title="click to sort">{c}</th>'
                   for k, c in enumerate(cols))
    return f"""# Records: every number of the run

Each row is one `record(...)` of a notebook: ours next to the paper's, the verdict on its
target (if it is one), its kind (a measured result, a chosen setting, or a timing) and the
generator's ground truth the number leaned on (`none`: the system's own measurements only;
*controlled*: a controlled study that uses truth inputs on purpose). Click a column's
heading to sort by it; the filters combine. The first column links to the cell.

<div class="lsmta-filters">{filters} <span class="lsmta-count"></span></div>
<table class="lsmta-table lsmta-records"><thead><tr>{head}</tr></thead>
<tbody>{''.join(body)}</tbody></table>
"""


RECORDS_JS = r"""// lsmta book: sort and filter the records table (no libraries, works from file://)
document.addEventListener("DOMContentLoaded", function () {
  var table = document.querySelector("table.lsmta-records");
  if (!table) { return; }
  var body = table.tBodies[0];
  var rows = Array.prototype.slice.call(body.rows);
  var controls = document.querySelectorAll("[data-filter]");
  var count = document.querySelector(".lsmta-count");
  function apply() {
    var want = {};
    controls.forEach(function (c) { want[c.dataset.filter] = c.value.toLowerCase(); });
    var shown = 0;
    rows.forEach(function (r) {
      var ok = true;
      ["group", "kind", "verdict", "truth", "controlled"].forEach(function (k) {
        if (want[k] && (r.dataset[k] || "").toLowerCase() !== want[k]) { ok = false; }
      });
      if (want.text && r.textContent.toLowerCase().indexOf(want.text) < 0) { ok = false; }
      r.style.display = ok ? "" : "none";
      if (ok) { shown += 1; }
    });
    if (count) { count.textContent = shown + " of " + rows.length + " rows"; }
    table.dataset.shown = shown;
  }
  controls.forEach(function (c) { c.addEventListener("input", apply); });
  // filters from the address: records.html?verdict=NOT%20met&group=Davis%202002
  var query = new URLSearchParams(window.location.search);
  controls.forEach(function (c) {
    if (query.has(c.dataset.filter)) { c.value = query.get(c.dataset.filter); }
  });
  var order = {};
  table.querySelectorAll("th[data-col]").forEach(function (th) {
    th.addEventListener("click", function () {
      var k = +th.dataset.col, dir = order[k] = -(order[k] || -1);
      function key(r) {
        var t = r.cells[k].textContent.trim(), x = parseFloat(t);
        return isNaN(x) || !/^[-+]?[\d.]/.test(t) ? t.toLowerCase() : x;
      }
      rows.sort(function (a, b) {
        var x = key(a), y = key(b);
        if (typeof x !== typeof y) { return (typeof x === "number" ? -1 : 1) * dir; }
        return (x < y ? -1 : x > y ? 1 : 0) * dir;
      });
      rows.forEach(function (r) { body.appendChild(r); });
    });
  });
  apply();
});
"""

BOOK_CSS = """
.lsmta-bad { color: #b00020; font-weight: 600; }
.lsmta-table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0 1.5em; }
.lsmta-table th, .lsmta-table td { border: 1px solid #ddd; padding: 2px 6px;
  vertical-align: top; }
.lsmta-table th { background: #f4f4f4; position: sticky; top: 0; }
.lsmta-records th { cursor: pointer; }
.lsmta-filters { display: flex; flex-wrap: wrap; gap: 0.4em 1.2em; margin: 0.5em 0; }
.lsmta-filters select, .lsmta-filters input { font-size: 0.9em; }
.lsmta-view3d iframe { width: 100%; height: 540px; border: 1px solid #ddd; }
.lsmta-anchor:target + div.cell { outline: 3px solid #f0b400; }
.lsmta-provenance { font-size: 0.8em; color: #555; }
.bd-page-width { max-width: 100rem; }
"""

def _copy_mathjax(static: Path) -> None:
    """MathJax 3's ``tex-svg-full.js`` from the ``sphinx-mathjax-offline`` package: one file
    with every TeX extension, TeX in, SVG out, so no web fonts (which Chromium would not
    load from the file system)."""
    target = static / "mathjax" / "tex-svg-full.js"
    if target.exists():
        return
    from importlib import metadata  # deferred: only to find the package's files

    try:
        dist = metadata.distribution("sphinx-mathjax-offline")
    except metadata.PackageNotFoundError:  # pragma: no cover - a dependency
        return
    src = Path(dist.locate_file("sphinx-mathjax-offline/static/mathjax/tex-svg-full.js"))
    if src.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target)


CONF = '''# written by lsmta.book: the book's Sphinx configuration (regenerated on every build)
project = "lsmta"
author = "lsmta contributors"
extensions = ["myst_nb"]
nb_execution_mode = "off"               # the notebooks ran in lsmta reproduce
nb_ipywidgets_js = {{}}                   # no widget manager from a CDN
nb_mime_priority_overrides = [
    ("html", "application/vnd.jupyter.widget-view+json", None),
    ("html", "application/vnd.jupyter.widget-state+json", None),
]
nb_merge_streams = True
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_dmath_double_inline = True       # $$...$$ inside a paragraph, as Jupyter shows it
suppress_warnings = ["mystnb.unknown_mime_type", "myst.header", "misc.highlighting_failure",
                     "mystnb.mime_priority"]
html_theme = "sphinx_book_theme"
html_title = "lsmta — reproduced results"
html_static_path = ["_static"]
html_css_files = ["lsmta.css"]
html_js_files = ["records.js"]
html_extra_path = ["extra"]
html_copy_source = False
html_show_sourcelink = False
html_last_updated_fmt = None
mathjax_path = "mathjax/tex-svg-full.js"
mathjax3_config = {{"svg": {{"fontCache": "global"}}}}
html_show_search_summary = False        # summaries are fetched: not from file://
html_context = {{"default_mode": "light"}}
html_theme_options = {{
    "extra_footer": {footer!r},
    "home_page_in_toc": True,
    "show_navbar_depth": 1,
    "use_download_button": False,
    "use_fullscreen_button": False,
}}
'''


def build_book(build, *, readme=None, jobs: int = 1, quiet: bool = True) -> BookResult:
    """Build ``build/book/`` from what ``lsmta reproduce`` wrote to ``build``.

    Parameters
    ----------
    build : str or Path
        The build folder: ``summary.json``, ``notebooks/*.ipynb``, ``views3d/``.
    readme : str or Path, optional
        ``notebooks/README.md``, whose order of the notebooks the book follows (default:
        the notebooks' numbers).
    jobs : int
        Sphinx's parallel processes.
    quiet : bool
        Keep Sphinx's progress off the terminal (warnings and errors are returned).

    Returns
    -------
    BookResult
    """
    import nbformat  # deferred: as above

    start = time.perf_counter()
    build = Path(build)
    summary = build / "summary.json"
    if not summary.is_file():
        raise FileNotFoundError(f"build: no summary.json in {build} (run lsmta reproduce)")
    data = json.loads(summary.read_text(encoding="utf-8"))
    results, meta = data.get("notebooks", []), data.get("meta", {})
    work = build / ".book"
    src = work / "src"
    present = {p.stem: p for p in sorted((build / "notebooks").glob("[0-9][0-9]_*.ipynb"))}
    by_stem = {res["notebook"]: res for res in results}
    order = reading_order(set(present) | set(by_stem), readme=readme)
    order = [s for s in order if s in present]
    titles = {}
    for stem in order:
        nb = nbformat.read(present[stem], as_version=4)
        titles[stem] = _title(nb, stem)
        page = _notebook_page(nb, by_stem.get(stem), stem)
        _write(src / "notebooks" / f"{stem}.ipynb", nbformat.writes(page))
    for old in (src / "notebooks").glob("*.ipynb"):
        if old.stem not in present:
            old.unlink()
    records = _records([by_stem[s] for s in order if s in by_stem])
    _write(src / "index.md", _front_page([by_stem[s] for s in order if s in by_stem],
                                         records, titles, order, meta))
    _write(src / "records.md", _records_page(records))
    _write(src / "_static" / "records.js", RECORDS_JS)
    _write(src / "_static" / "lsmta.css", BOOK_CSS)
    _copy_mathjax(src / "_static")
    extra = src / "extra" / "views3d"
    if extra.exists():
        shutil.rmtree(extra)
    extra.mkdir(parents=True)
    views = build / "views3d"
    if views.is_dir():
        for f in views.iterdir():
            if f.suffix in (".html", ".js"):
                try:
                    (extra / f.name).hardlink_to(f)
                except OSError:
                    shutil.copy2(f, extra / f.name)
    _write(src / "conf.py", CONF.format(footer=_provenance_html(meta)))
    out = build / "book"
    cmd = [sys.executable, "-m", "sphinx", "-b", "html", "-d", str(work / "doctrees"),
           "-j", str(max(1, int(jobs))), "-w", str(work / "warnings.txt")]
    if quiet:
        cmd.append("-q")
    proc = subprocess.run(cmd + [str(src), str(out)], capture_output=quiet, text=True,
                          check=False)
    messages = (work / "warnings.txt").read_text(encoding="utf-8").strip() \
        if (work / "warnings.txt").exists() else ""
    if proc.returncode != 0 and quiet:
        messages = (messages + "\n" + (proc.stderr or "")).strip()
    return BookResult(index=out / "index.html", seconds=round(time.perf_counter() - start, 2),
                      ok=proc.returncode == 0, messages=messages)
