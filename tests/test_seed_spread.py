"""The seed-spread helper of the system experiments (experiments/seed_spread.py)."""

import csv
import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

_PATH = Path(__file__).resolve().parents[1] / "experiments" / "seed_spread.py"
_spec = importlib.util.spec_from_file_location("seed_spread", _PATH)
ss = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("seed_spread", ss)       # dataclasses look their module up
_spec.loader.exec_module(ss)


def _per_seed(seed, *, scale):
    """A tiny per-seed 'experiment': numbers known from the seed alone."""
    rng = np.random.default_rng(seed)
    return {"a": scale * seed, "b": float(rng.integers(0, 100)),
            "c": math.nan if seed == 12 else float(seed % 3)}


HEADLINES = [ss.Headline("a", "scaled seed", "mm", "none"),
             ss.Headline("b", "a draw", "", "true cameras", True),
             ss.Headline("c", "seed mod 3", "")]


def test_seeds_on_a_local_cluster_give_median_and_range(tmp_path, capsys):
    seeds = ss.seed_list(10, 5)
    assert seeds == [10, 11, 12, 13, 14]
    with ss.dask_client(workers=1, processes=False) as client:
        results = ss.map_seeds(_per_seed, seeds[::-1], client=client, scale=2.0)
    assert list(results) == seeds[::-1]                 # in the order asked for
    for s in seeds:
        assert results[s] == pytest.approx(_per_seed(s, scale=2.0), nan_ok=True)

    table = ss.report("toy", results, HEADLINES, tmp_path, settings={"scale": 2.0})
    a = table["a"]
    assert (a["median"], a["min"], a["max"], a["n"], a["missing"]) == (24.0, 20.0, 28.0, 5, 0)
    b = np.array([results[s]["b"] for s in seeds])
    assert table["b"]["median"] == np.median(b)
    assert (table["b"]["min"], table["b"]["max"]) == (b.min(), b.max())
    assert (table["b"]["truth"], table["b"]["controlled"]) == ("true cameras", True)
    assert (table["a"]["truth"], table["a"]["controlled"]) == ("none", False)
    # seed 12 has no value for "c": left out and counted; 10, 11, 13, 14 mod 3 = 1, 2, 1, 2
    assert (table["c"]["median"], table["c"]["min"], table["c"]["max"]) == (1.5, 1.0, 2.0)
    assert (table["c"]["n"], table["c"]["missing"]) == (4, 1)

    printed = capsys.readouterr().out
    assert "14: 28  13: 26  12: 24  11: 22  10: 20   median 24 [20, 28]" in printed
    assert "a draw (truth T1, controlled study)" in printed
    assert "scaled seed [mm] (truth T0)" in printed
    assert "truth inputs: T0: none; T1: true cameras" in printed
    doc = json.loads((tmp_path / "toy_seeds.json").read_text(encoding="utf-8"))
    assert doc["seeds"] == seeds[::-1] and doc["settings"] == {"scale": 2.0}
    assert doc["spread"]["a"]["median"] == 24.0
    # the command that made the numbers, and when (a committed copy says what to re-run)
    assert doc["command"].startswith("python ") and len(doc["date"]) == 10
    with open(tmp_path / "toy_seeds.csv", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["seed", "a", "b", "c"]
    assert [r[0] for r in rows[1:]] == [str(s) for s in seeds[::-1]] + ["median", "min", "max"]
    assert float(rows[-3][1]) == 24.0


def test_a_failing_seed_is_named():
    def boom(seed):
        if seed == 3:
            raise ValueError("no walk")
        return {"a": 1.0}

    with ss.dask_client(workers=1, processes=False) as client:
        with pytest.raises(RuntimeError, match="seed 3: ValueError: no walk"):
            ss.map_seeds(boom, [2, 3], client=client)
        with pytest.raises(ValueError, match="distinct"):
            ss.map_seeds(boom, [2, 2], client=client)
        kept = ss.map_seeds(boom, [2, 3, 4], client=client, failures="record")
    assert kept == {2: {"a": 1.0}, 3: {"error": "ValueError: no walk"}, 4: {"a": 1.0}}
    table = ss.spread(kept, [ss.Headline("a", "one")])
    assert (table["a"]["median"], table["a"]["n"], table["a"]["missing"]) == (1.0, 2, 1)


def test_a_second_map_on_the_same_client_runs_again():
    # the same seeds and function with other kwargs: new results, not the first map's
    with ss.dask_client(workers=1, processes=False) as client:
        first = ss.map_seeds(_per_seed, [1, 2], client=client, scale=2.0)
        second = ss.map_seeds(_per_seed, [1, 2], client=client, scale=3.0)
    assert (first[2]["a"], second[2]["a"]) == (4.0, 6.0)


def test_every_seed_failing_exits_non_zero():
    ss.exit_if_all_failed({1: {"error": "x"}, 2: {"a": 1.0}})          # one left: no exit
    with pytest.raises(SystemExit, match="every seed failed \\(2\\); the first: ValueError: a"):
        ss.exit_if_all_failed({1: {"error": "ValueError: a"}, 2: {"error": "ValueError: b"}})


def test_bad_arguments_are_refused_clearly():
    with pytest.raises(ValueError, match="seeds: expected a number of seeds >= 1"):
        ss.seed_list(1, 0)
    with pytest.raises(ValueError, match="workers"):
        ss.dask_client(workers=0)


def test_a_bad_scheduler_address_gives_a_clear_error():
    # nothing listens on port 1 of this machine; and an address that is not one
    for address in ("tcp://127.0.0.1:1", "no-such-scheme://x"):
        with pytest.raises(ConnectionError, match=r"--scheduler .*no Dask scheduler answered"):
            ss.dask_client(address, timeout=2.0)


def test_the_command_line_reports_a_bad_scheduler_and_exits(capsys):
    import argparse

    parser = argparse.ArgumentParser()
    ss.add_arguments(parser, seed=1)
    args = parser.parse_args(["--seeds", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert (args.seed, args.seeds, args.workers) == (1, 2, 2)
    with pytest.raises(SystemExit) as exc:
        ss.run("toy", _per_seed, HEADLINES, args, out_dir=".", parser=parser,
               connect_timeout=2.0)
    assert exc.value.code == 2
    assert "no Dask scheduler answered" in capsys.readouterr().err
