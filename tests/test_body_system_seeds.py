"""The committed sweep of notebook 14's system over seeds, as notebook 14 reads it."""

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


def test_system_seeds_missing_or_short(tmp_path):
    assert bs.read_system_seeds(path=tmp_path / "none.json") is None
    bad = tmp_path / "short.json"
    bad.write_text('{"command": "x", "date": "d", "seeds": [1], "settings": {}, "results": {}}')
    with pytest.raises(ValueError, match="has no 'per_seed'"):
        bs.read_system_seeds(path=bad)
    bad.write_text('{"command": "x", "date": "d", "seeds": [1], "settings": {}, '
                   '"per_seed": {"1": {"track_ratio": 2.0}}, "results": {"1": {}}}')
    with pytest.raises(ValueError, match="no values or no detail for seed 1"):
        bs.read_system_seeds(path=bad)
    bad.write_text('{"command": "x", "date": "d", "seeds": [1], "settings": {}, '
                   '"per_seed": {"1": {"track_ratio": null}}, "results": {"1": {"detail": {}}}}')
    run = bs.read_system_seeds(path=bad)
    assert np.isnan(run["values"]["track_ratio"]).all() and run["seeds"].tolist() == [1]
