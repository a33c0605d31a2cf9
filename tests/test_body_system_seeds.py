"""The committed sweep of notebook 14's system over seeds, as notebook 14 reads it."""

import importlib.util
import json

import numpy as np
import pytest

from lsmta.evaluation import body_system as bs


def test_the_committed_system_seeds_have_what_notebook_14_reads():
    # experiments/lsmta_system.py --seeds 5 --frames 20 --first 14 --width 576 --height 432
    run = bs.read_system_seeds()
    assert run is not None, f"no committed {bs.SYSTEM_SEEDS_RESULT}"
    assert "experiments/lsmta_system.py" in run["command"] and "--seeds 5" in run["command"]
    assert "--out" not in run["command"] and len(run["date"]) == 10
    assert {k: run["settings"][k] for k in ("frames", "first", "width", "height", "every")} == \
        {"frames": 20, "first": 14, "width": 576, "height": 432, "every": 4}
    assert run["settings"]["truth_fed"] and len(run["seeds"]) >= 5 and 1998 in run["seeds"]
    for key in ("track_ratio", "track_carried_ratio", "track_carried_tracks_ratio",
                "angle_full_own_deg", "angle_full_deg"):
        v = run["values"][key]
        assert v.shape == run["seeds"].shape and np.isfinite(v).all() and (v > 0).all()
    for s in run["seeds"]:
        d = run["detail"][int(s)]
        own = d["arm_system_own"]["full"]
        assert np.shape(own["angle_err_deg"]) == (len(own["frames"]), 4)
        assert len(d["arm_points"]["hand_r"]) == run["settings"]["frames"]
    assert bs.SYSTEM_SEEDS_RESULT.read_text(encoding="utf-8").endswith("}\n")


def _doc(**change):
    # a minimal sweep file as experiments/seed_spread.py writes it: seeds 1 and 2
    doc = {"experiment": "lsmta_system", "command": "x", "date": "d", "seeds": [1, 2],
           "settings": {}, "failed": {},
           "per_seed": {"1": {"track_ratio": 2.0, "arm_frames": 18},
                        "2": {"track_ratio": None, "arm_frames": 17}},
           "results": {"1": {"detail": {"a": 1}}, "2": {"detail": {"a": 2}}}}
    return doc | change


def _read(tmp_path, doc):
    path = tmp_path / "seeds.json"
    path.write_text(json.dumps(doc))
    return bs.read_system_seeds(path=path)


def test_system_seeds_missing_or_short(tmp_path):
    assert bs.read_system_seeds(path=tmp_path / "none.json") is None
    doc = _doc()
    del doc["per_seed"]
    with pytest.raises(ValueError, match="seeds.json has no 'per_seed'"):
        _read(tmp_path, doc)
    with pytest.raises(ValueError, match="no values or no detail for seed 2"):
        _read(tmp_path, _doc(results={"1": {"detail": {}}, "2": {}}))
    run = _read(tmp_path, _doc())
    assert run["seeds"].tolist() == [1, 2] and run["failed"] == {}
    np.testing.assert_array_equal(run["values"]["track_ratio"], [2.0, np.nan])
    np.testing.assert_array_equal(run["values"]["arm_frames"], [18.0, 17.0])
    assert run["detail"] == {1: {"a": 1}, 2: {"a": 2}}


def test_system_seeds_a_failed_seed_is_nan_with_its_error(tmp_path):
    # as seed_spread.py records it: no detail, every headline null, the error under "failed"
    error = "ValueError: only 2 rigid groups"
    doc = _doc(failed={"2": error},
               per_seed={"1": {"track_ratio": 2.0, "arm_frames": 18},
                         "2": {"track_ratio": None, "arm_frames": None}},
               results={"1": {"detail": {"a": 1}}, "2": {"error": error}})
    run = _read(tmp_path, doc)
    assert run["failed"] == {2: error}
    assert np.isnan(run["values"]["arm_frames"][1]) and run["values"]["arm_frames"][0] == 18
    assert list(run["detail"]) == [1]


def test_system_seeds_refuses_another_experiment_no_seeds_other_keys_or_text(tmp_path):
    with pytest.raises(ValueError, match="seeds.json is the 'walk_system' experiment's"):
        _read(tmp_path, _doc(experiment="walk_system"))
    with pytest.raises(ValueError, match="seeds.json has no seeds"):
        _read(tmp_path, _doc(seeds=[]))
    doc = _doc()
    del doc["experiment"]
    with pytest.raises(ValueError, match="has no 'experiment'"):
        _read(tmp_path, doc)
    other = {"1": {"track_ratio": 2.0, "arm_frames": 18}, "2": {"track_ratio": 2.1}}
    with pytest.raises(ValueError, match=r"seed 2's headline keys differ .*\['arm_frames'\]"):
        _read(tmp_path, _doc(per_seed=other))
    for bad in ("2.1", True, [2.1]):
        text = {"1": {"track_ratio": 2.0, "arm_frames": 18}, "2": {"track_ratio": bad,
                                                                   "arm_frames": 17}}
        with pytest.raises(ValueError, match="seeds.json: seed 2's 'track_ratio' is"):
            _read(tmp_path, _doc(per_seed=text))


def test_the_committed_system_seeds_name_the_experiments_truth_inputs(monkeypatch):
    # the file's labels and truth texts are those experiments/lsmta_system.py writes now
    # (the carried-along ratios: the twin's tracking error in quadrature, not divided by it)
    pytest.importorskip("dask.distributed")
    folder = bs.SYSTEM_SEEDS_RESULT.parents[1]
    monkeypatch.syspath_prepend(str(folder))
    spec = importlib.util.spec_from_file_location("lsmta_system", folder / "lsmta_system.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    doc = json.loads(bs.SYSTEM_SEEDS_RESULT.read_text(encoding="utf-8"))
    want = {h.key: (h.label, h.truth) for h in module.HEADLINES}
    assert {h["key"]: (h["label"], h["truth"]) for h in doc["headlines"]} == want
    assert {k: (v["label"], v["truth"]) for k, v in doc["spread"].items()} == want
    assert "quadrature, not divided" in want["track_carried_ratio"][1]
    assert doc["failed"] == {} and bs.read_system_seeds()["failed"] == {}
