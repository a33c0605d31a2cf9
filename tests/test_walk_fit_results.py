"""The committed whole-walk fit results read back (notebook 22): the verdicts computed again
from the per-frame numbers agree with the experiment's own, and bad files are refused."""

import json

import numpy as np
import pytest

from lsmta.evaluation import walk_fit_results as wr
from lsmta.evaluation import walk_full_fit as wf
from lsmta.evaluation.full_body import MAJOR


@pytest.mark.parametrize("rig", ["studio", "triplet"])
def test_committed_results_judged_again(rig):
    res = wr.read_walk_fit_result(wr.WALK_FIT_RESULTS[rig])
    assert res is not None and rig in res["rigs"]
    r = res["rigs"][rig]
    assert r["chosen"] in r["variants"] and "walk alone" in r["variants"]
    for name, v in r["variants"].items():
        assert set(MAJOR) <= set(v["joints_deg"])
        assert all(a.shape == v["frames"].shape for a in v["joints_deg"].values())
        ours, theirs = wr.result_verdicts(v, rig), v["file_verdicts"]
        for key in ("joints", "lengths", "skin_to_truth", "skin_from_truth"):
            assert ours[key]["met"] == theirs[key]["met"], (name, key)
            # lengths: the file keeps them to 0.1 mm, so the % differs in the second decimal
            assert ours[key]["value"] == pytest.approx(theirs[key]["value"], abs=0.05)
        assert ours["joints"]["failing"] == sorted(theirs["joints"]["failing"])


def test_ladder_rungs():
    lad = wr.read_ladder(wr.LADDER_RESULTS[0])
    assert {"a", "b", "c", "d"} <= set(lad["rungs"])
    for r in lad["rungs"].values():
        assert r["worst_joint"] == max(r["worst_joint_deg"].values())
        assert r["worst_length"] == max(abs(x) for x in r["length_error_pct"].values())
        assert r["truth"]
    assert wr.read_ladder(wr.RESULTS_DIR / "no_such_file.json") is None


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


def test_bad_files(tmp_path):
    assert wr.read_walk_fit_result(tmp_path / "absent.json") is None
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
    with pytest.raises(ValueError, match="rig"):
        wr.result_verdicts({}, "dome")
