"""Headline numbers over seeds, on Dask: the helper the system experiments share.

An experiment gives a per-seed function (``seed -> {key: value}``) and the headline
numbers it reports (:class:`Headline`: key, label, unit and the truth inputs, worded as the
notebook's record). :func:`map_seeds` runs the function once per seed as one Dask task each
(a local cluster by default, ``--scheduler ADDRESS`` for a running one, whose workers need
lsmta installed); :func:`spread` gives the median, minimum and maximum of every headline
over the seeds; :func:`report` prints one row per seed and the median [min, max] summary
and writes them as JSON and CSV next to the experiment's other outputs.

Not a module of the library: its tests load it from this folder (tests/test_seed_spread.py).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import uuid
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Headline:
    """One headline number of an experiment, as its notebook records it.

    Attributes
    ----------
    key : str
        Key of the number in the per-seed function's dictionary.
    label : str
        What it is, in the notebook record's words.
    unit : str
        Unit ("" for a ratio or a count).
    truth : str
        The truth inputs the number used ("none", or the notebook record's ``truth=``).
    controlled : bool
        A controlled study whose verdict leans on truth inputs on purpose (the record's
        ``controlled=True``).
    """

    key: str
    label: str
    unit: str = ""
    truth: str = "none"
    controlled: bool = False


def add_arguments(parser: argparse.ArgumentParser, *, seed: int, seeds: int = 5) -> None:
    """``--seed`` (first seed), ``--seeds N``, ``--scheduler ADDRESS`` and ``--workers``."""
    parser.add_argument("--seed", type=int, default=seed, help="first seed")
    parser.add_argument("--seeds", type=int, default=seeds,
                        help="number of seeds: --seed, --seed + 1, ... (default %(default)s)")
    parser.add_argument("--scheduler", default=None,
                        help="address of a running Dask scheduler (default: a local cluster)")
    parser.add_argument("--workers", type=int, default=2,
                        help="worker processes of the local cluster (default %(default)s)")


def seed_list(first: int, n: int) -> list[int]:
    """``n`` consecutive seeds from ``first``."""
    if int(n) != n or n < 1:
        raise ValueError(f"seeds: expected a number of seeds >= 1, got {n!r}")
    return [int(first) + i for i in range(int(n))]


def dask_client(scheduler: str | None = None, *, workers: int = 2, processes: bool = True,
                timeout: float = 10.0):
    """A Dask client: of the scheduler at ``scheduler``, or of a new local cluster of
    ``workers`` single-threaded workers (processes, or threads with ``processes=False``).

    Raises
    ------
    ConnectionError
        When no scheduler answers at ``scheduler`` within ``timeout`` seconds, or the
        address cannot be read; the message names the address.
    """
    from dask.distributed import Client

    if scheduler:
        try:
            return Client(scheduler, timeout=timeout)
        except (OSError, ValueError, TypeError) as exc:
            raise ConnectionError(
                f"--scheduler {scheduler!r}: no Dask scheduler answered within {timeout:g} s "
                f"(expected the address a running scheduler prints, e.g. tcp://host:8786; "
                f"{type(exc).__name__}: {exc})") from None
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers: expected a number of workers >= 1, got {workers!r}")
    # the client starts the cluster and so closes it with itself
    return Client(n_workers=int(workers), threads_per_worker=1, processes=processes,
                  dashboard_address=":0")


def map_seeds(fn, seeds, *, client, failures: str = "raise", **kwargs) -> dict[int, dict]:
    """``fn(seed, **kwargs)`` for every seed, one Dask task each, on ``client``.

    Returns ``{seed: result}`` in the order of ``seeds`` whatever order the tasks end in.
    Every call submits its tasks under new keys (so a second call on the same client with
    other ``kwargs`` runs them again). A task's exception is raised here with the seed
    added to its message
    (``failures="raise"``), or, with ``failures="record"``, kept as that seed's result
    ``{"error": "<type>: <message>"}`` (a system that refuses a session is a result too:
    its headlines count as missing).
    """
    if failures not in ("raise", "record"):
        raise ValueError(f"failures: expected 'raise' or 'record', got {failures!r}")
    seeds = [int(s) for s in seeds]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds: expected distinct seeds, got {seeds}")
    # a key of its own per call: a key the client already holds returns that (old) future
    run_id = uuid.uuid4().hex
    futures = [client.submit(fn, s, pure=False, key=f"seed-{s}-{fn.__name__}-{run_id}",
                             **kwargs) for s in seeds]
    out = {}
    for s, fut in zip(seeds, futures):
        try:
            out[s] = fut.result()
        except Exception as exc:
            message = f"{type(exc).__name__}: {exc}"
            if failures == "raise":
                raise RuntimeError(f"seed {s}: {message}") from exc
            print(f"seed {s} failed: {message}")
            out[s] = {"error": message}
    return out


def exit_if_all_failed(results: dict[int, dict]) -> None:
    """Exit with status 1 (``SystemExit``, naming the first error) when every seed failed."""
    if results and all("error" in r for r in results.values()):
        first = next(iter(results.values()))["error"]
        sys.exit(f"every seed failed ({len(results)}); the first: {first}")


def spread(results: dict[int, dict], headlines) -> dict[str, dict]:
    """Median, minimum and maximum of every headline over the seeds.

    Non-finite values (a number a seed could not measure) are left out and counted:
    ``n`` is the number of seeds with a finite value, ``missing`` the others.
    Returns ``{key: {"label", "unit", "truth", "controlled", "median", "min", "max", "n",
    "missing"}}``.
    """
    out = {}
    for h in headlines:
        values = np.array([float(r[h.key]) if r.get(h.key) is not None else np.nan
                           for r in results.values()], float)
        ok = np.isfinite(values)
        stats = ({"median": float(np.median(values[ok])), "min": float(values[ok].min()),
                  "max": float(values[ok].max())} if ok.any()
                 else {"median": math.nan, "min": math.nan, "max": math.nan})
        out[h.key] = {"label": h.label, "unit": h.unit, "truth": h.truth,
                      "controlled": h.controlled, **stats,
                      "n": int(ok.sum()), "missing": int((~ok).sum())}
    return out


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "nan"
    return f"{v:.4g}"


def report(name: str, results: dict[int, dict], headlines, out_dir, *,
           settings: dict | None = None) -> dict:
    """Print one row per seed and the median [min, max] of every headline; write
    ``<out_dir>/<name>_seeds.json`` (the command line and date, settings, headlines,
    per-seed values, spread, and each
    seed's whole result) and
    ``<out_dir>/<name>_seeds.csv`` (one row per seed and three rows median, min, max).
    Returns the spread (:func:`spread`)."""
    headlines = list(headlines)
    table = spread(results, headlines)
    print(f"\n{name}: {len(results)} seeds ({', '.join(map(str, results))})")
    for s, r in results.items():
        if "error" in r:
            print(f"  seed {s} failed: {r['error']}")
    truths = list(dict.fromkeys(h.truth for h in headlines))
    for h in headlines:
        t = table[h.key]
        unit = f" [{h.unit}]" if h.unit else ""
        tag = f"T{truths.index(h.truth)}" + (", controlled study" if h.controlled else "")
        per_seed = "  ".join(f"{s}: {_fmt(r.get(h.key))}" for s, r in results.items())
        missing = f"; {t['missing']} without a value" if t["missing"] else ""
        print(f"  {h.label}{unit} (truth {tag})\n      {per_seed}   median "
              f"{_fmt(t['median'])} [{_fmt(t['min'])}, {_fmt(t['max'])}]{missing}")
    print("  truth inputs: " + "; ".join(f"T{i}: {x}" for i, x in enumerate(truths)))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {"experiment": name, "command": " ".join(["python", *sys.argv]),
           "date": datetime.now(timezone.utc).date().isoformat(),
           "seeds": list(results), "settings": settings or {},
           "headlines": [asdict(h) for h in headlines],
           "failed": {str(s): r["error"] for s, r in results.items() if "error" in r},
           "per_seed": {str(s): {h.key: r.get(h.key) for h in headlines}
                        for s, r in results.items()},
           "spread": table,
           "results": {str(s): r for s, r in results.items()}}
    path = out_dir / f"{name}_seeds.json"
    path.write_text(json.dumps(doc, indent=2, default=_json_default, allow_nan=True) + "\n",
                    encoding="utf-8")
    with open(out_dir / f"{name}_seeds.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["seed"] + [h.key for h in headlines])
        for s, r in results.items():
            w.writerow([s] + [r.get(h.key) for h in headlines])
        for stat in ("median", "min", "max"):
            w.writerow([stat] + [table[h.key][stat] for h in headlines])
    print(f"wrote {path} and {path.with_suffix('.csv')}")
    return table


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def run(name: str, fn, headlines, args, *, out_dir, settings: dict | None = None,
        parser: argparse.ArgumentParser | None = None, connect_timeout: float = 10.0,
        failures: str = "record", **kwargs):
    """The whole sweep of an experiment's ``main``: the seeds from ``args`` (``--seed``,
    ``--seeds``), a client from ``args`` (``--scheduler``, ``--workers``; a bad address is
    reported through ``parser.error``), :func:`map_seeds` with ``kwargs`` (a failing seed
    recorded as missing by default), :func:`report`; exits with status 1 after the report
    when every seed failed (:func:`exit_if_all_failed`).
    Returns ``(results, spread)``."""
    seeds = seed_list(args.seed, args.seeds)
    try:
        client = dask_client(args.scheduler, workers=min(args.workers, len(seeds)),
                             timeout=connect_timeout)
    except ConnectionError as exc:
        if parser is None:
            raise
        parser.error(str(exc))
    with client:
        print(f"Dask: {client}; seeds {seeds}")
        results = map_seeds(fn, seeds, client=client, failures=failures, **kwargs)
    table = report(name, results, headlines, out_dir, settings=settings)
    exit_if_all_failed(results)
    return results, table
