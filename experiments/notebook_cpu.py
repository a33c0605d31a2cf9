"""CPU time of the notebooks, cell by cell, as ``lsmta reproduce`` runs them (issue #35).

    source scripts/env.sh
    .venv/bin/python experiments/notebook_cpu.py [--only 14 15 ...] [--build build/cpu]
        [--out build/benchmarks/notebook_cpu.json]

Each notebook runs in its own kernel, started as ``lsmta reproduce`` starts it (the same
environment; one run cache folder shared by the notebooks of this call, as in a reproduce
run; ``--no-preamble``: kernels that do not do the notebook's preamble ahead, as before).
After every cell the kernel process's CPU time (user + system, every thread and
waited-for child, read from ``/proc/<pid>/stat``) is read: on a machine loaded by others
this moves far less than wall time (but threads spinning while they wait, OpenBLAS's, count
too: a notebook with threaded BLAS costs more CPU on a loaded machine). ``boot`` is the
CPU the kernel spent before the first cell (Python, ipykernel, the notebook's preamble:
:func:`lsmta.cli.notebook_preamble`). Records go to ``<build>/records`` as under ``lsmta
reproduce``, so two runs' numbers can be compared (``--compare OTHER_BUILD``: every record
but the timings, value by value). Prints one line per notebook and the slowest cells; writes
the JSON (per notebook: boot, per-cell CPU and wall seconds, total).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

from lsmta import cli
from lsmta.cli import find_notebooks, select, start_kernel, stop_kernel
from lsmta.report import write_json

TICK = os.sysconf("SC_CLK_TCK")


def process_cpu(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` and its waited-for children."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(f) for f in fields[11:15]) / TICK   # utime stime cutime cstime


def run_notebook(path: Path, build: Path, cache: Path, timeout: int) -> dict:
    """Run one notebook; per-cell CPU and wall seconds of its kernel."""
    nb = nbformat.read(path, as_version=4)
    records = build / "records" / f"{path.stem}.jsonl"
    records.parent.mkdir(parents=True, exist_ok=True)
    records.unlink(missing_ok=True)
    (build / "views3d").mkdir(parents=True, exist_ok=True)
    kernel = start_kernel(path, build, cache=cache)
    km = kernel[0]
    pid = km.provisioner.process.pid
    cells: list[dict] = []
    mark = {}

    def on_execute(cell, cell_index, **_):
        mark.update(cpu=process_cpu(pid), wall=time.perf_counter())
        if "boot" not in mark:
            mark["boot"] = mark["cpu"]

    def on_executed(cell, cell_index, **_):
        cells.append({"cell": cell_index,
                      "cpu": round(process_cpu(pid) - mark["cpu"], 2),
                      "wall": round(time.perf_counter() - mark["wall"], 2),
                      "first_line": cell.source.splitlines()[0][:60] if cell.source else ""})

    client = NotebookClient(nb, km=km, timeout=timeout, kernel_name="python3",
                            resources={"metadata": {"path": str(path.parent)}},
                            shutdown_kernel="immediate",
                            on_cell_execute=on_execute, on_cell_executed=on_executed)
    start = time.perf_counter()
    ok = True
    try:
        client.execute(cleanup_kc=False)
    except Exception as exc:  # a failing cell: say so, keep the times so far
        print(f"{path.stem}: {type(exc).__name__}: {str(exc).strip().splitlines()[-1:]}",
              file=sys.stderr)
        ok = False
    finally:
        stop_kernel(kernel)
    nbformat.write(nb, build / f"{path.stem}.ipynb")
    return {"notebook": path.stem, "ok": ok, "boot_cpu": round(mark.get("boot", 0.0), 2),
            "cpu": round(mark.get("boot", 0.0) + sum(c["cpu"] for c in cells), 2),
            "wall": round(time.perf_counter() - start, 2), "cells": cells}


def compare_records(build: Path, other: Path, stems: list[str]) -> int:
    """Print the records (but timings) that differ between two builds; returns how many."""
    differ = 0
    for stem in stems:
        runs = []
        for b in (build, other):
            f = b / "records" / f"{stem}.jsonl"
            lines = f.read_text(encoding="utf-8").splitlines() if f.exists() else []
            runs.append([r for r in map(json.loads, filter(None, lines))
                         if r.get("kind") != "timing"])
        same = runs[0] == runs[1]
        differ += not same
        print(f"{stem:<33} {len(runs[0]):3d} records (but timings) "
              + ("identical" if same else f"DIFFER ({len(runs[1])} in {other})"))
    return differ


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="NAME", help="as lsmta reproduce --only")
    parser.add_argument("--notebooks", default="notebooks")
    parser.add_argument("--build", default="build/cpu")
    parser.add_argument("--out", default="build/benchmarks/notebook_cpu.json")
    parser.add_argument("--timeout", type=int, default=1200)
    parser.add_argument("--top", type=int, default=3, help="slowest cells printed per notebook")
    parser.add_argument("--compare", metavar="OTHER_BUILD",
                        help="only compare this build's records with another's")
    parser.add_argument("--no-preamble", action="store_true",
                        help="kernels that do not do the notebook's preamble ahead (as before)")
    args = parser.parse_args(argv)
    if args.no_preamble:
        cli.notebook_preamble = lambda nb: ([], {})
    chosen = select(find_notebooks(Path(args.notebooks)), args.only)
    build = Path(args.build)
    if args.compare:
        return int(compare_records(build, Path(args.compare), [p.stem for p in chosen]) > 0)
    build.mkdir(parents=True, exist_ok=True)
    cache = Path(tempfile.mkdtemp(prefix="run-", dir=build))
    results = []
    try:
        for path in chosen:
            res = run_notebook(path, build, cache, args.timeout)
            results.append(res)
            top = sorted(res["cells"], key=lambda c: -c["cpu"])[:args.top]
            print(f"{res['notebook']:<33} cpu {res['cpu']:6.1f} s (boot {res['boot_cpu']:.1f})"
                  f" wall {res['wall']:6.1f} s  " + "  ".join(
                      f"[{c['cell']}] {c['cpu']:.1f}" for c in top), flush=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    print(f"{len(results)} notebooks: cpu {sum(r['cpu'] for r in results):.1f} s, "
          f"wall {sum(r['wall'] for r in results):.1f} s, load {os.getloadavg()[0]:.2f}")
    write_json(args.out, {"load_average": os.getloadavg(), "notebooks": results})
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
