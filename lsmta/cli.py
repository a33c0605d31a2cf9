"""The ``lsmta`` command: ``lsmta reproduce`` re-runs every notebook and gathers the results;
``lsmta capture`` runs the LSMTA system on a user's recording (:mod:`lsmta.capture_command`).

``lsmta reproduce`` executes ``notebooks/NN_*.ipynb`` in order (each with its own folder as
working directory, like nbmake), writes the executed notebooks to ``build/notebooks/``,
every figure to ``build/figures/``, the interactive 3-D views to ``build/views3d/``
(:mod:`lsmta.interactive`), and the headline numbers the notebooks record
(:mod:`lsmta.report`), each with the truth inputs it used and the cell that recorded it, to
``build/summary.md`` and ``build/summary.json``, with the results counted by their truth
inputs and the provenance of the run (git commit and whether the tree had uncommitted
changes, the versions of the main libraries, each notebook's ``SEED``, the machine). Then
it builds the book, ``build/book/`` (:mod:`lsmta.book`); ``build/index.html`` leads to it.
It prints one line per notebook (time, figures, numbers, targets met / NOT met) and where
the book is, and exits with status 1, naming the notebook and cell, if any cell fails.
``lsmta book`` rebuilds the book of an existing build.

The kernels talk to the command over IPC (Unix sockets in a private temporary folder),
not over TCP, so nothing listens on the network. ``LSMTA_BUILD_DIR`` is set to the build
folder while the notebooks run (:func:`lsmta.report.build_dir`), and ``LSMTA_BUILD_CACHE``
to a folder of this run (``build/run-*``, removed when it ends) where notebooks keep arrays
that a later notebook of the same run computes again (:mod:`lsmta.build_cache`).
"""

from __future__ import annotations

import argparse
import ast
import base64
import html
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from importlib import metadata
from pathlib import Path

from . import build_cache, capture_command, interactive, report

OFFSCREEN_ENV = {
    "PYVISTA_OFF_SCREEN": "true",
    "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow",
    "PYDEVD_DISABLE_FILE_VALIDATION": "1",
}


def find_notebooks(folder: Path) -> list[Path]:
    """The numbered notebooks ``NN_name.ipynb`` in ``folder``, in order."""
    return sorted(p for p in folder.glob("[0-9][0-9]_*.ipynb") if p.is_file())


def select(notebooks: list[Path], only: list[str] | None) -> list[Path]:
    """Notebooks whose stem, number or name (without the number) is in ``only``."""
    if not only:
        return notebooks
    chosen = []
    for key in only:
        hits = [p for p in notebooks if key in (p.stem, p.stem[:2], p.stem[3:])]
        if not hits:
            names = ", ".join(p.stem for p in notebooks)
            raise SystemExit(f"lsmta reproduce: --only {key!r} matches no notebook ({names})")
        chosen.extend(h for h in hits if h not in chosen)
    return sorted(chosen)


#: distribution names whose versions go into the provenance, by the name a reader knows
VERSIONS = {"numpy": "numpy", "scipy": "scipy", "OpenCV": "opencv-python-headless",
            "scikit-image": "scikit-image", "numba": "numba", "pyvista": "pyvista",
            "emcee": "emcee", "lsmta": "lsmta"}
SEED_LINE = re.compile(r"^SEED\s*=\s*([^#\n]+?)\s*(?:#.*)?$", re.MULTILINE)


def notebook_seed(nb) -> str | None:
    """The ``SEED = ...`` assignment of a notebook's code cells (as written), or None."""
    for cell in nb.cells:
        if cell.cell_type == "code":
            hit = SEED_LINE.search(cell.source)
            if hit:
                return hit.group(1)
    return None


def _git(*args: str, cwd: Path) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True,
                             timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def provenance(repo: Path) -> dict:
    """Where and with what the notebooks ran: git commit and dirty flag of ``repo`` (None
    outside a git checkout), Python and library versions, the machine."""
    versions = {"Python": platform.python_version()}
    for label, dist in VERSIONS.items():
        try:
            versions[label] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[label] = None
    commit = _git("rev-parse", "HEAD", cwd=repo)
    status = _git("status", "--porcelain", "--untracked-files=no", cwd=repo)
    return {
        "git_commit": commit,
        "git_dirty": None if status is None else bool(status),
        "versions": versions,
        "machine": {"system": platform.system(), "release": platform.release(),
                    "architecture": platform.machine(), "processor": platform.processor(),
                    "cpus": os.cpu_count(), "hostname": platform.node()},
    }


def default_notebook_dir() -> Path:
    here = Path.cwd() / "notebooks"
    if here.is_dir():
        return here
    return Path(__file__).resolve().parents[1] / "notebooks"


def notebook_env(path: Path, build: Path, *, cache: Path | None = None) -> dict[str, str]:
    """The environment of the kernel that runs the notebook ``path``: this process's, the
    off-screen rendering settings (where not set), where the notebook writes its records
    and 3-D views under ``build`` and, if given, the run's ``cache`` folder
    (:mod:`lsmta.build_cache`; without it nothing is kept between notebooks)."""
    env = {**OFFSCREEN_ENV, **os.environ}
    env.pop(build_cache.CACHE_ENV, None)
    if cache is not None:
        env[build_cache.CACHE_ENV] = str(cache.resolve())
    env[report.RECORD_ENV] = str((build / "records" / f"{path.stem}.jsonl").resolve())
    env[report.BUILD_ENV] = str(build.resolve())
    env[interactive.VIEWS_ENV] = str((build / "views3d").resolve())
    env[interactive.NOTEBOOK_ENV] = path.stem
    return env


def _setdefault_env(node) -> tuple[str, str] | None:
    """``(name, value)`` of a statement ``os.environ.setdefault("NAME", "value")``, else None."""
    call = node.value if isinstance(node, ast.Expr) else None
    if not (isinstance(call, ast.Call) and ast.unparse(call.func) == "os.environ.setdefault"
            and len(call.args) == 2 and not call.keywords
            and all(isinstance(a, ast.Constant) and isinstance(a.value, str) for a in call.args)):
        return None
    return call.args[0].value, call.args[1].value


def notebook_preamble(nb) -> tuple[list[tuple[str, tuple[str, ...]]], dict[str, str]]:
    """What a notebook does before its first other statement: the imports at the top of its
    first code cell, as ``(module, names from it)``, and the environment variables it sets
    there with ``os.environ.setdefault("NAME", "value")`` (before an import, as notebooks 13,
    15 and 18 limit BLAS threads). :func:`start_kernel` does both ahead, while the previous
    notebook runs; the notebook then finds its modules imported (``[]``, ``{}`` when the
    first code cell does not parse as Python up to its first IPython magic). A setting after
    an import other than ``os`` ends the preamble: in the notebook it comes too late for
    that import, ahead it would not."""
    code = next((c.source for c in nb.cells if c.cell_type == "code"), "")
    head = []
    for line in code.splitlines():
        if line.lstrip().startswith(("%", "!")):
            break
        head.append(line)
    try:
        tree = ast.parse("\n".join(head))
    except SyntaxError:
        return [], {}
    imports, env = [], {}
    for node in tree.body:
        if isinstance(node, ast.Import):
            imports += [(a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            imports.append((node.module, tuple(a.name for a in node.names)))
        elif _setdefault_env(node) is not None and all(m == "os" for m, _ in imports):
            env.setdefault(*_setdefault_env(node))   # set before any import it could affect
        else:
            break
    return imports, env


def _prewarm_line(imports: list[tuple[str, tuple[str, ...]]]) -> str:
    """One line for the kernel's ``exec_lines``: ``imports`` done, no name left behind."""
    calls = "; ".join(f"__import__({m!r}, fromlist={list(names)!r})" for m, names in imports)
    return f"{calls}; None" if calls else ""


def start_kernel(path: Path, build: Path, *, cache: Path | None = None):
    """Start the kernel that will run the notebook ``path`` and return at once (it boots
    while the previous notebook runs); returns ``(kernel manager, its socket folder)``, for
    :func:`execute`. ``cache``: as in :func:`notebook_env`. While it boots the kernel does
    the notebook's preamble (:func:`notebook_preamble`): its environment settings and its
    imports, nothing bound in the notebook's namespace (a second import of a module is a
    look-up), so that the first cell does not wait for them."""
    import nbformat  # deferred: the notebook machinery takes seconds to import
    from jupyter_client.manager import AsyncKernelManager  # deferred: as above
    from jupyter_core.utils import run_sync  # deferred: as above

    try:
        imports, preamble_env = notebook_preamble(nbformat.read(path, as_version=4))
    except Exception:                      # unreadable: :func:`execute` says so in its turn
        imports, preamble_env = [], {}
    env = notebook_env(path, build, cache=cache)
    for name, value in preamble_env.items():   # as the notebook's os.environ.setdefault
        env.setdefault(name, value)
    extra = ["--HistoryManager.hist_file=:memory:"]
    if imports:
        extra.append(f"--IPKernelApp.exec_lines={[_prewarm_line(imports)]!r}")
    # IPC transport: Unix sockets at an absolute path (the kernel runs in the notebook's
    # folder, so a relative one would not meet), in a short private folder
    sockets = Path(tempfile.mkdtemp(prefix="lsmta-ipc-"))
    km = AsyncKernelManager(kernel_name="python3", transport="ipc", ip=str(sockets / "kernel"))
    try:
        run_sync(km.start_kernel)(env=env, cwd=str(path.parent.resolve()),
                                  extra_arguments=extra)
    except BaseException:
        shutil.rmtree(sockets, ignore_errors=True)
        raise
    return km, sockets


def stop_kernel(kernel) -> None:
    """Stop a kernel from :func:`start_kernel` and remove its socket folder (safe to call
    again on a stopped kernel)."""
    from jupyter_core.utils import run_sync  # deferred: seconds to import

    km, sockets = kernel
    try:
        if km.has_kernel:
            run_sync(km.shutdown_kernel)(now=True)
    finally:
        shutil.rmtree(sockets, ignore_errors=True)


def execute(path: Path, build: Path, timeout: int, *, kernel=None) -> dict:
    """Execute one notebook, on ``kernel`` (from :func:`start_kernel`, started for this
    notebook) or on a new kernel; returns a status dict (never raises for a failing cell).
    The kernel is stopped afterwards. The notebook's ``seconds`` exclude a pre-started
    kernel's boot and the preamble it did (:func:`notebook_preamble`; both overlapped the
    notebook before), so they are one to three seconds shorter than in builds made before
    kernels were started ahead."""
    import nbformat  # deferred: the notebook machinery takes seconds to import
    from nbclient import NotebookClient  # deferred: as above
    from nbclient.exceptions import CellExecutionError, CellTimeoutError  # deferred: as above

    nb = nbformat.read(path, as_version=4)
    records_file = build / "records" / f"{path.stem}.jsonl"
    records_file.parent.mkdir(parents=True, exist_ok=True)
    records_file.unlink(missing_ok=True)
    views = build / "views3d"
    views.mkdir(parents=True, exist_ok=True)
    for old in views.glob(f"{path.stem}_*.html"):
        old.unlink()

    current = {"index": None}
    record_cells: list[int] = []   # the cell of each record, in the records' order
    view_cells: list[dict] = []    # the 3-D views and the cells that wrote them

    def on_execute(cell, cell_index, **_):
        current["index"] = cell_index

    def on_executed(cell, cell_index, **_):
        # a cell's records and views are written while it runs: what is new is its own
        if records_file.exists():
            with open(records_file, encoding="utf-8") as fh:
                n = sum(1 for line in fh if line.strip())
            record_cells.extend([cell_index] * (n - len(record_cells)))
        known = {v["file"] for v in view_cells}
        for f in sorted(views.glob(f"{path.stem}_*.html"), key=lambda p: p.stat().st_mtime):
            if f.name not in known:
                view_cells.append({"file": f.name, "cell": cell_index})

    start = time.perf_counter()
    km, sockets = start_kernel(path, build) if kernel is None else kernel
    # shutdown "immediate": the kernel is killed once the last cell has run (every record,
    # view and figure is written by then); a graceful shutdown costs about a second
    client = NotebookClient(nb, km=km, timeout=timeout, kernel_name="python3",
                            resources={"metadata": {"path": str(path.parent)}},
                            shutdown_kernel="immediate",
                            on_cell_execute=on_execute, on_cell_executed=on_executed)
    status = {"notebook": path.stem, "ok": True, "error": None, "cell": None,
              "seed": notebook_seed(nb)}
    try:
        # cleanup_kc: shut the kernel down here (nbclient keeps a kernel it was handed
        # alive, and the kernels would then stop, one warning each, when lsmta exits)
        client.execute(cleanup_kc=True)
    except (CellExecutionError, CellTimeoutError) as exc:
        status.update(ok=False, cell=current["index"],
                      error=str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc))
    except Exception as exc:  # kernel died, etc.
        status.update(ok=False, cell=current["index"], error=f"{type(exc).__name__}: {exc}")
    finally:
        if km.has_kernel:  # e.g. the client failed before it started
            stop_kernel((km, sockets))
        shutil.rmtree(sockets, ignore_errors=True)
    status["seconds"] = round(time.perf_counter() - start, 2)

    out_dir = build / "notebooks"
    out_dir.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, out_dir / path.name)
    status["figures"] = save_figures(nb, path.stem, build / "figures")
    status["records"] = ([asdict(r) for r in report.load_records(records_file)]
                         if records_file.exists() else [])
    # records written after the last cell finished (none expected) get no cell
    status["record_cells"] = (record_cells + [None] * len(status["records"]))[
        :len(status["records"])]
    status["views"] = view_cells
    return status


def save_figures(nb, stem: str, folder: Path) -> list[str]:
    """Write every PNG output of ``nb`` to ``folder``; returns the file names."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob(f"{stem}_cell*.png"):
        old.unlink()
    names = []
    for i, cell in enumerate(nb.cells):
        k = 0
        for output in cell.get("outputs", []):
            data = output.get("data", {})
            if "image/png" in data:
                name = f"{stem}_cell{i:02d}_{k}.png"
                (folder / name).write_bytes(base64.b64decode(data["image/png"]))
                names.append(name)
                k += 1
    return names


TRUTH_GROUPS = {
    "none": "none: the system's own measurements",
    "check points": "aligned on named true check points only",
    "controlled": "truth-fed, controlled studies",
    "truth-fed": "truth-fed, not controlled studies",
    "unstated": "truth inputs unstated",
}


def truth_summary(records) -> tuple[list[tuple[str, int, int]], list]:
    """The results among ``records`` counted by their truth inputs
    (:func:`lsmta.report.truth_group`): ``(label, results, of them judged on a target)`` per
    group of :data:`TRUTH_GROUPS`, and the records whose target verdicts lean on truth
    inputs without being controlled studies (:func:`lsmta.report.unsound_verdicts`)."""
    results = [r for r in records if r.kind == "result"]
    rows = []
    for group, label in TRUTH_GROUPS.items():
        members = [r for r in results if report.truth_group(r) == group]
        rows.append((label, len(members), sum(report.judged(r) for r in members)))
    return rows, report.unsound_verdicts(results)


def write_summary(build: Path, results: list[dict], *, meta: dict | None = None) -> None:
    """``summary.json``, ``summary.md`` and ``index.html`` from the notebooks' results.

    ``index.html`` is a plain page of the same tables and every figure, until
    :func:`write_index` makes it lead to the book. Results and timings stand next to the
    papers' numbers, each with its truth inputs; settings (numbers the notebooks chose)
    are listed apart. A section counts the results by their truth inputs and lists the
    target verdicts judged on truth-fed records that are not controlled studies (there
    should be none). ``meta``: the run's :func:`provenance` (computed if not given)."""
    records = [report.Record(**r) for res in results for r in res["records"]]
    compared = [r for r in records if r.kind != "setting"]
    settings = [r for r in records if r.kind == "setting"]
    meta = dict(provenance(Path.cwd()) if meta is None else meta)
    meta.update(python=platform.python_version(), finished=time.strftime("%Y-%m-%d %H:%M:%S"),
                seeds={res["notebook"]: res.get("seed") for res in results})
    (build / "summary.json").write_text(json.dumps(
        {"meta": meta, "notebooks": results, "records": [asdict(r) for r in records]},
        indent=2), encoding="utf-8")
    prov = _provenance_lines(meta)
    groups, unsound = truth_summary(records)
    lines = ["# lsmta — reproduced numbers next to the papers'", "",
             report.table(compared), "", "## Truth inputs of the results", "",
             "| truth inputs | results | of them judged on a target |", "|---|---|---|"]
    lines += [f"| {label} | {n} | {k} |" for label, n, k in groups]
    lines += ["", "Target verdicts judged on truth-fed records that are not controlled studies:"
              + ("" if unsound else " none."), ""]
    if unsound:
        lines += [report.table(unsound), ""]
    lines += ["## Settings (chosen, not measured)", "",
              report.table(settings), "", "## Notebooks", "",
             "| notebook | status | seconds | seed | figures |", "|---|---|---|---|---|"]
    for res in results:
        state = "ok" if res["ok"] else f"FAILED at cell {res['cell']}: {res['error']}"
        lines.append(f"| {res['notebook']} | {state} | {res['seconds']} | "
                     f"{res.get('seed') or '—'} | {len(res['figures'])} |")
    lines += ["", "## Provenance", ""] + [f"- {k}: {v}" for k, v in prov]
    (build / "summary.md").write_text("\n".join(lines) + "\n", encoding="utf-8")

    esc = html.escape

    def rows(recs):
        return "".join(
            "<tr>" + "".join(f"<td>{esc(report.format_value(v))}</td>" for v in
                             (r.figure, r.quantity, r.paper, r.value, r.unit,
                              report.truth_cell(r),
                              r.note if r.kind == "result" else f"({r.kind}) {r.note}"))
            + "</tr>" for r in recs)

    header = ("<tr><th>figure</th><th>quantity</th><th>paper</th><th>ours</th><th>unit</th>"
              "<th>truth</th><th>note</th></tr>")
    unsound_text = ("Target verdicts judged on truth-fed records that are not controlled "
                    "studies:" + ("" if unsound else " none."))
    truth_html = ("<table><tr><th>truth inputs</th><th>results</th>"
                  "<th>of them judged on a target</th></tr>"
                  + "".join(f"<tr><td>{esc(label)}</td><td>{n}</td><td>{k}</td></tr>"
                            for label, n, k in groups)
                  + f"</table><p>{esc(unsound_text)}</p>"
                  + (f"<table>{header}{rows(unsound)}</table>" if unsound else ""))
    sections = []
    for res in results:
        link = f'<a href="notebooks/{esc(res["notebook"])}.ipynb">{esc(res["notebook"])}</a>'
        state = "ok" if res["ok"] else f"<b>FAILED</b> at cell {res['cell']}: {esc(res['error'])}"
        seed = f", seed {esc(str(res['seed']))}" if res.get("seed") else ""
        figs = "".join(f'<img src="figures/{esc(f)}" loading="lazy">' for f in res["figures"])
        sections.append(f"<h2>{link}</h2><p>{state} — {res['seconds']} s{seed}</p>{figs}")
    prov_html = "".join(f"<li>{esc(k)}: {esc(str(v))}</li>" for k, v in prov)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>lsmta results</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px}}
img{{max-width:100%;margin:6px 0;border:1px solid #eee}}</style></head><body>
<h1>lsmta — reproduced numbers next to the papers'</h1>
<table>{header}{rows(compared)}</table>
<h2>Truth inputs of the results</h2>{truth_html}
<h2>Settings (chosen, not measured)</h2><table>{header}{rows(settings)}</table>
{''.join(sections)}
<h2>Provenance</h2><ul>{prov_html}</ul>
</body></html>"""
    (build / "index.html").write_text(page, encoding="utf-8")


def _provenance_lines(meta: dict) -> list[tuple[str, str]]:
    """(label, text) pairs of the provenance for summary.md and index.html."""
    dirty = " (uncommitted changes)" if meta["git_dirty"] else ""
    m = meta["machine"]
    machine = (f"{m['system']} {m['release']}, {m['architecture']}, {m['cpus']} CPUs, "
               f"host {m['hostname']}")
    versions = ", ".join(f"{k} {v}" for k, v in meta["versions"].items())
    seeds = ", ".join(f"{k} {v}" for k, v in meta["seeds"].items())
    return [("git commit", f"{meta['git_commit'] or 'unknown'}{dirty}"),
            ("versions", versions), ("seeds", seeds or "—"), ("machine", machine),
            ("finished", meta["finished"])]


def write_index(build: Path) -> None:
    """``build/index.html``: a page that leads to the book (``book/index.html``)."""
    (build / "index.html").write_text(
        '<!doctype html><html><head><meta charset="utf-8"><title>lsmta results</title>'
        '<meta http-equiv="refresh" content="0; url=book/index.html"></head><body>'
        '<p>The results are in <a href="book/index.html">the book</a>; every number is '
        'also in <a href="summary.md">summary.md</a>.</p></body></html>\n', encoding="utf-8")


def _targets(res: dict) -> tuple[int, int]:
    """(met, NOT met) among a notebook's result records."""
    from .book import verdict_of  # deferred: the book module is only needed here

    verdicts = [verdict_of(r.get("note", ""), value=r.get("value"))
                for r in res.get("records", []) if r.get("kind") == "result"]
    return verdicts.count("met"), verdicts.count("NOT met")


def notebook_line(res: dict) -> str:
    """One line for a notebook that ran: name, state, time, figures, numbers, targets."""
    state = "ok" if res["ok"] else f"FAILED at cell {res['cell']}"
    met, not_met = _targets(res)
    return (f"{res['notebook']:<33} {state:<6} {res['seconds']:6.1f} s "
            f"{len(res['figures']):3d} fig {len(res.get('views', [])):2d} 3-D "
            f"{len(res['records']):3d} numbers {met:3d} met {not_met:2d} NOT met")


def make_book(build: Path, readme: Path | None) -> int:
    """Build the book and say where it is (or what went wrong); returns 0 or 1."""
    from . import book  # deferred: Sphinx is only needed here

    result = book.build_book(build, readme=readme, jobs=min(2, os.cpu_count() or 1))
    if not result.ok:
        print(f"lsmta: the book failed to build ({result.seconds:.0f} s):", file=sys.stderr)
        print("\n".join(result.messages.splitlines()[-15:]), file=sys.stderr)
        return 1
    write_index(build)
    n_warn = len([m for m in result.messages.splitlines() if "WARNING" in m])
    warned = (f" ({n_warn} Sphinx warnings in {build / '.book' / 'warnings.txt'})"
              if n_warn else "")
    print(f"the book ({result.seconds:.0f} s): {result.index}{warned}")
    print("  open it with: bash scripts/open_book.sh"
          + ("" if build.resolve() == (Path.cwd() / "build").resolve() else f" {build}"))
    return 0


def reproduce(args) -> int:
    folder = Path(args.notebooks) if args.notebooks else default_notebook_dir()
    notebooks = find_notebooks(folder)
    if not notebooks:
        print(f"lsmta reproduce: no notebooks NN_*.ipynb in {folder}", file=sys.stderr)
        return 2
    chosen = select(notebooks, args.only)
    if args.list:
        for p in chosen:
            print(p.stem)
        return 0
    build = Path(args.build)
    build.mkdir(parents=True, exist_ok=True)
    # arrays kept between this run's notebooks only (lsmta.build_cache), removed at its end
    cache = Path(tempfile.mkdtemp(prefix="run-", dir=build))
    results = []
    tty = sys.stdout.isatty()
    start = time.perf_counter()
    # each notebook's kernel is started while the one before runs (its boot, about a second,
    # overlaps that notebook's work); each runs in a fresh kernel as before
    kernels = {0: start_kernel(chosen[0], build, cache=cache)}
    try:
        for i, path in enumerate(chosen):
            if i + 1 < len(chosen):
                kernels[i + 1] = start_kernel(chosen[i + 1], build, cache=cache)
            if tty:
                print(f"{path.stem:<33} running ...", end="\r", flush=True)
            res = execute(path, build, args.timeout, kernel=kernels[i])
            del kernels[i]   # stopped by execute; kept until then so the finally stops it
            results.append(res)
            print(notebook_line(res) + (" " * 8 if tty else ""), flush=True)
    finally:
        for kernel in kernels.values():  # only if a notebook's run raised (or Ctrl-C)
            stop_kernel(kernel)
        shutil.rmtree(cache, ignore_errors=True)
    ran = results
    if args.only:  # keep the other notebooks' earlier results in the summary
        old = build / "summary.json"
        if old.exists():
            previous = json.loads(old.read_text(encoding="utf-8")).get("notebooks", [])
            done = {r["notebook"] for r in results}
            results = sorted([r for r in previous if r["notebook"] not in done] + results,
                             key=lambda r: r["notebook"])
    write_summary(build, results, meta=provenance(folder.resolve().parent))
    totals = [_targets(r) for r in results]
    met, not_met = sum(t[0] for t in totals), sum(t[1] for t in totals)
    failed = [r for r in ran if not r["ok"]]
    print(f"{len(ran)} notebook(s) in {time.perf_counter() - start:.0f} s, {len(failed)} failed;"
          f" targets of the {len(results)} in the build: {met} met, {not_met} NOT met")
    print(f"every number: {build / 'summary.md'}")
    book_failed = make_book(build, folder / "README.md") if not args.no_book else 0
    for r in failed:
        print(f"lsmta reproduce: {r['notebook']}.ipynb failed at cell {r['cell']}: {r['error']}",
              file=sys.stderr)
    return 1 if failed or book_failed else 0


def book_command(args) -> int:
    build = Path(args.build)
    if not (build / "summary.json").is_file():
        print(f"lsmta book: no summary.json in {build} (run lsmta reproduce first)",
              file=sys.stderr)
        return 2
    folder = Path(args.notebooks) if args.notebooks else default_notebook_dir()
    return make_book(build, folder / "README.md")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="lsmta", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("reproduce", help="execute the notebooks and gather figures and numbers")
    rep.add_argument("--only", nargs="+", metavar="NAME",
                     help="notebooks to run, by number (00), name or stem (00_synthetic_world)")
    rep.add_argument("--list", action="store_true", help="list the notebooks and exit")
    rep.add_argument("--build", default="build", help="output folder (default: build)")
    rep.add_argument("--notebooks", default=None, help="folder of the notebooks")
    rep.add_argument("--timeout", type=int, default=1200, help="seconds allowed per cell")
    rep.add_argument("--no-book", action="store_true", help="do not build the book")
    bk = sub.add_parser("book", help="build the book (build/book/) from an earlier reproduce")
    bk.add_argument("--build", default="build", help="the build folder (default: build)")
    bk.add_argument("--notebooks", default=None,
                    help="folder of the notebooks (its README.md gives the reading order)")
    capture_command.add_parser(sub)
    args = parser.parse_args(argv)
    if args.command == "reproduce":
        return reproduce(args)
    if args.command == "book":
        return book_command(args)
    if args.command == "capture":
        return capture_command.run(args)
    return 2  # pragma: no cover


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
