"""The committed whole-walk fit results read back (notebook 22): the verdicts computed again
from the per-frame numbers agree with the experiment's own, and bad files are refused."""

import json

import numpy as np
import pytest

from lsmta.evaluation import walk_fit_results as wr
from lsmta.evaluation import walk_full_fit as wf
from lsmta.evaluation.full_body import MAJOR

SKIN_RECORDS = {"skin_to_truth": "fitted skin -> true skin, median, seen side",
                "skin_from_truth": "true skin -> fitted skin, median, seen side"}


@pytest.mark.parametrize("rig", ["studio", "triplet"])
def test_committed_results_judged_again(rig):
    res = wr.read_walk_fit_result(wr.WALK_FIT_RESULTS[rig])
    assert rig in res["rigs"]
    raw = json.loads(wr.WALK_FIT_RESULTS[rig].read_text(encoding="utf-8"))["rigs"][rig]
    r = res["rigs"][rig]
    assert r["chosen"] in r["variants"] and "walk alone" in r["variants"]
    for name, v in r["variants"].items():
        assert set(MAJOR) <= set(v["joints_deg"])
        assert all(a.shape == v["frames"].shape for a in v["joints_deg"].values())
        ours, theirs = wr.result_verdicts(v, rig), v["file_verdicts"]
        # joints and lengths: judged here from the per-frame angles and the lengths in mm,
        # against the experiment's own verdicts
        for key in ("joints", "lengths"):
            assert ours[key]["met"] == theirs[key]["met"], (name, key)
            # lengths: the file keeps them to 0.1 mm, so the % differs in the second decimal
            assert ours[key]["value"] == pytest.approx(theirs[key]["value"], abs=0.05)
        assert ours["joints"]["failing"] == sorted(theirs["joints"]["failing"])
        # the skin medians are read from the verdicts: check them against the file's records
        # (written separately by the experiment) and the limit
        limit = wf.TARGETS[rig][2]
        for key, quantity in SKIN_RECORDS.items():
            rec = [x for x in raw["records"] if x["quantity"] == quantity
                   and x.get("variant", "walk alone").removesuffix(" (chosen)") == name]
            assert len(rec) == 1, (name, quantity)
            assert ours[key]["value"] == pytest.approx(rec[0]["value"], rel=1e-9)
            assert ours[key]["met"] == (rec[0]["value"] <= limit)


def test_times_per_variant():
    r = wr.read_walk_fit_result(wr.WALK_FIT_RESULTS["studio"])["rigs"]["studio"]
    raw = json.loads(wr.WALK_FIT_RESULTS["studio"].read_text(encoding="utf-8"))
    n = sum(x["unit"] == "s" for x in raw["rigs"]["studio"]["records"])
    assert sum(len(t) for t in r["times"].values()) == n
    assert f"{r['chosen']} (chosen)" in r["times"] and "range-of-motion clip" in r["times"]
    assert "system time, all stages" in r["times"]["walk alone"]


def test_ladder_rungs():
    lad = wr.read_ladder(wr.LADDER_RESULTS[0])
    assert {"a", "b", "c", "d"} <= set(lad["rungs"])
    raw = json.loads(wr.LADDER_RESULTS[0].read_text(encoding="utf-8"))["rungs"]
    for rung, r in lad["rungs"].items():
        # against the experiment's own summary of the rung, written separately
        assert r["worst_joint"] == pytest.approx(raw[rung]["skin"]["worst_joint_deg"])
        assert r["worst_length"] == pytest.approx(raw[rung]["skin"]["worst_length_pct"])
        assert r["truth"]
    assert lad["frames"] == list(range(8))


def test_target_verdicts_at_the_limits():
    joints = {k: 1.0 for k in MAJOR}
    v = wf.target_verdicts(joints | {"knee_r": 3.0}, {"thigh": -2.0}, 2.0, 1.5, "studio")
    assert v["joints"]["met"] and v["lengths"]["met"] and v["skin_to_truth"]["met"]
    v = wf.target_verdicts(joints | {"knee_r": np.nan}, {"thigh": -2.01}, 2.01, 1.5, "studio")
    assert not v["joints"]["met"] and v["joints"]["failing"] == ["knee_r"]
    assert not v["lengths"]["met"] and v["lengths"]["failing"] == ["thigh"]
    assert not v["skin_to_truth"]["met"] and v["skin_from_truth"]["met"]
    assert wf.target_verdicts(joints | {"knee_r": 4.0}, {"thigh": 2.5}, 3.0, 3.0,
                              "triplet")["joints"]["met"]
    with pytest.raises(ValueError, match="rig"):
        wf.target_verdicts(joints, {"thigh": 0.0}, 1.0, 1.0, "dome")
    with pytest.raises(ValueError, match="worst_joints"):
        wf.target_verdicts({}, {"thigh": 0.0}, 1.0, 1.0, "studio")


def test_a_nan_frame_fails():
    v = wr.read_walk_fit_result(wr.WALK_FIT_RESULTS["studio"])["rigs"]["studio"]["variants"][
        "walk alone"]
    ok = {k: np.zeros_like(a) for k, a in v["joints_deg"].items()}
    ok["trunk"][3] = np.nan   # a frame not scored: it fails, even when the others are exact
    out = wr.result_verdicts(v | {"joints_deg": ok}, "triplet")
    assert not out["joints"]["met"] and out["joints"]["failing"] == ["trunk"]
    assert out["joints"]["value"] == np.inf
    assert wr.result_verdicts(v | {"joints_deg": ok | {"trunk": np.zeros(8)}},
                              "triplet")["joints"]["met"]
    assert np.isnan(ok["trunk"][3]), "the input is not modified"


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="absent.json"):
        wr.read_walk_fit_result(tmp_path / "absent.json")
    with pytest.raises(FileNotFoundError, match="no_such_file.json"):
        wr.read_ladder(wr.RESULTS_DIR / "no_such_file.json")
    broken = tmp_path / "broken.json"
    broken.write_text('{"command": ')
    for read in (wr.read_walk_fit_result, wr.read_ladder):
        with pytest.raises(ValueError, match="broken.json.*not valid JSON"):
            read(broken)
    broken.write_text("[1, 2]")
    with pytest.raises(ValueError, match="broken.json.*JSON object"):
        wr.read_ladder(broken)
    good = json.loads(wr.WALK_FIT_RESULTS["triplet"].read_text(encoding="utf-8"))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({k: v for k, v in good.items() if k != "rigs"}))
    with pytest.raises(ValueError, match="rigs"):
        wr.read_walk_fit_result(bad)
    short = json.loads(json.dumps(good))
    short["rigs"]["triplet"]["detail"]["joints_deg_per_frame"]["knee_r"].pop()
    bad.write_text(json.dumps(short))
    with pytest.raises(ValueError, match="knee_r"):
        wr.read_walk_fit_result(bad)
    gone = json.loads(json.dumps(good))
    del gone["rigs"]["triplet"]["detail"]["lengths_mm"]
    bad.write_text(json.dumps(gone))
    with pytest.raises(ValueError, match="lengths_mm"):
        wr.read_walk_fit_result(bad)
    lad = json.loads(wr.LADDER_RESULTS[0].read_text(encoding="utf-8"))
    del lad["rungs"]["a"]["skin"]
    bad.write_text(json.dumps(lad))
    with pytest.raises(ValueError, match="rung 'a'"):
        wr.read_ladder(bad)
    no_joint = json.loads(wr.LADDER_RESULTS[0].read_text(encoding="utf-8"))
    no_joint["rungs"]["b"]["worst_joint_deg"] = {"pelvis (orientation)": 1.0}
    bad.write_text(json.dumps(no_joint))
    with pytest.raises(ValueError, match="rung 'b' has no major joint or length"):
        wr.read_ladder(bad)
    no_joint["rungs"]["b"]["worst_joint_deg"] = {"knee_r": 1.0}
    no_joint["rungs"]["b"]["length_error_pct"] = {}
    bad.write_text(json.dumps(no_joint))
    with pytest.raises(ValueError, match="rung 'b' has no major joint or length"):
        wr.read_ladder(bad)
    with pytest.raises(ValueError, match="rig"):
        wr.result_verdicts({}, "dome")
    with pytest.raises(ValueError, match="skin_to_truth_mm"):
        wr.result_verdicts({"joints_deg": {}, "lengths_mm": {}, "skin_from_truth_mm": 1.0},
                           "studio")
    with pytest.raises(ValueError, match="lengths_mm"):
        wr.length_pct({})
    with pytest.raises(ValueError, match="variant"):
        wr.result_verdicts(None, "studio")
