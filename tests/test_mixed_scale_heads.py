"""Any number of pan-tilt heads in the mixed-scale system (issue 39, item 4): each face
marker measured by the best pair of heads that sees it, the four-head scene, and bad input."""

import importlib.util
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from lsmta.camera import Camera
from lsmta.evaluation import mixed_scale as ms
from lsmta.synth.mixed_scale import HEAD_LAYOUTS, mixed_scale_scene
from lsmta.systems import MixedScaleParams, capture_mixed_scale, triangulate_frames
from lsmta.systems.close_up import best_pairs, predicted_pair_error

CENTRES = np.array([[-1000.0, -3000.0, 0.0], [1000.0, -3000.0, 0.0], [-6000.0, -6000.0, 0.0]])


def _cams():
    return [Camera.look_at(c, (0.0, 0.0, 0.0), f=3000.0, width=640, height=480)
            for c in CENTRES]


def test_predicted_error_is_the_depth_error_of_two_rays():
    # two heads at 3 m, rays at right angles: sqrt(2) * 3 m per radian
    X = np.array([[0.0, 0.0, 0.0]])
    e = predicted_pair_error(X, (3000.0, 0.0, 0.0), (0.0, 3000.0, 0.0))
    assert np.allclose(e, np.radians(1.0) * np.sqrt(2) * 3000.0)
    # parallel rays: no depth at all
    assert np.isinf(predicted_pair_error(X, (3000.0, 0.0, 0.0), (6000.0, 0.0, 0.0)))[0]


def test_each_marker_takes_the_usable_pair_with_the_smallest_predicted_error():
    cams = _cams()
    X = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, -8.0], [-12.0, 3.0, 6.0], [5.0, -4.0, 9.0],
                  [0.0, 0.0, 20.0]])
    xy = np.stack([c.project(X) for c in cams])
    xy[0, 1] = np.nan                 # marker 1: not seen by head 0
    xy[1, 2] += (0.0, 10.0)           # marker 2: head 1 tracked it 10 px off (across the
    #                                   epipolar line: a shift along it only moves the depth)
    xy[:2, 4] = np.nan                # marker 4: seen by head 2 only
    r = best_pairs(cams, xy, min_angle_deg=2.0, max_reprojection_px=4.0)
    # pair (1, 2) has the widest angle (63 deg against 37 deg for (0, 1)) but its far head
    # moves the point more per degree: the near pair (0, 1) wins where both see the marker
    near, wide = predicted_pair_error(X[:1], *CENTRES[[0, 1]]), \
        predicted_pair_error(X[:1], *CENTRES[[1, 2]])
    assert near < wide
    assert np.array_equal(r.pair[0], (0, 1)) and np.array_equal(r.pair[3], (0, 1))
    assert np.array_equal(r.pair[1], (1, 2))          # the best pair that sees it
    assert np.array_equal(r.pair[2], (0, 2))          # head 1's image fails the reprojection
    assert np.array_equal(r.pair[4], (-1, -1)) and np.isnan(r.points[4]).all()
    ok = r.pair[:, 0] >= 0
    assert np.allclose(r.points[ok], X[ok], atol=1e-6)
    # the chosen pair's predicted error is the smallest of the usable candidates
    assert np.allclose(r.predicted[ok], np.nanmin(r.candidates[:, ok], axis=0))
    assert np.isnan(r.candidates[list(map(tuple, r.pairs)).index((0, 1)), 2])
    # two heads: the one pair wherever both see the marker (the old two-head rule)
    r2 = best_pairs(cams[:2], xy[:2], max_reprojection_px=4.0)
    assert np.array_equal(r2.pair[[0, 3]], [[0, 1], [0, 1]])
    assert (r2.pair[[1, 2, 4]] == -1).all()
    # nothing passed in was modified
    assert np.isnan(xy[0, 1]).all()


def test_best_pairs_bad_input():
    cams = _cams()
    xy = np.zeros((3, 4, 2))
    with pytest.raises(TypeError, match="cameras"):
        best_pairs(cams[:1], xy[:1])
    with pytest.raises(ValueError, match="xy"):
        best_pairs(cams, xy[:2])
    with pytest.raises(ValueError, match="max_reprojection_px"):
        best_pairs(cams, xy, max_reprojection_px=0.0)
    with pytest.raises(TypeError, match="heads"):
        triangulate_frames(np.zeros((1, 2, 4, 2)), [], np.zeros((1, 2, 2)))
    with pytest.raises(ValueError, match="heads: expected one of"):
        mixed_scale_scene(rng=1, travel=500.0, stand=0.2, n_ceiling=2, heads=3)


@pytest.fixture(scope="module")
def four():
    """A tiny walk seen by the four heads of HEAD_LAYOUTS[4], the system run with the first
    two and with all four (the markers identified by the system itself)."""
    scene = mixed_scale_scene(rng=5, travel=700.0, stand=0.8, n_ceiling=4, heads=4)
    cal = ms.calibrate_scene(scene, rng=6)
    inputs = ms.walk_inputs(scene, cal, rng=7, n_train=120)
    params = MixedScaleParams(start=0.7, reacquire=1)
    out = {}
    for K in (2, 4):
        devices, _ = ms.head_devices(scene, heads=scene.heads[:K], rng=8 + K)
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)      # a refused identification
            cap = capture_mixed_scale(inputs.ceiling, cal.heads[:K], devices, None,
                                      inputs.face_model, params=params, progress=False,
                                      keep_images=False)
        out[K] = cap, ms.score_capture(cap, scene, devices), devices
    return scene, cal, inputs, out


def test_four_heads_on_a_tiny_walk(four):
    scene, cal, inputs, out = four
    assert len(scene.heads) == 4 and np.allclose(
        [h.camera.C for h in scene.heads], HEAD_LAYOUTS[4], atol=1.0)
    for K, (cap, sc, devices) in out.items():
        F, M = cap.points.shape[:2]
        assert cap.settings.shape == (K, F, 2) and cap.xy.shape[:2] == (K, F)
        assert cap.pairs.shape == (F, M, 2)
        measured = np.isfinite(cap.points).all(axis=2)
        # a marker is measured exactly where a pair is named, and the pair is of two heads
        assert np.array_equal(measured, cap.pairs[..., 0] >= 0)
        p = cap.pairs[measured]
        assert ((p[:, 0] < p[:, 1]) & (p[:, 1] < K)).all()
        # every head labelled by the identification, and the labels right
        labels = ms.label_score(cap.identification.xy, devices, cap.times[cap.first])
        assert cap.identification.labelled.any(axis=1).all()
        assert labels.share_correct >= 0.99, labels
        assert cap.face.fitted.mean() > 0.9
        assert sc.face_median_mm < 5.0
    cap2, sc2, _ = out[2]
    cap4, sc4, _ = out[4]
    assert (cap2.pairs[np.isfinite(cap2.points).all(axis=2)] == (0, 1)).all()
    # with four heads more than one pair is used, and more markers are measured
    used = {tuple(p) for p in cap4.pairs.reshape(-1, 2) if p[0] >= 0}
    assert len(used) >= 2, used
    assert sc4.measured.mean() > sc2.measured.mean()


def test_heads_and_devices_must_match(four):
    scene, cal, inputs, out = four
    devices, identify = ms.head_devices(scene, rng=1)

    def call(heads, devs, ident=None):
        return capture_mixed_scale(inputs.ceiling, heads, devs, ident, inputs.face_model,
                                   progress=False)

    with pytest.raises(TypeError, match="heads: expected at least 2"):
        call(cal.heads[:1], devices[:1])
    with pytest.raises(ValueError, match=r"devices: expected one per head \(4\), got 2"):
        call(cal.heads, devices[:2])
    with pytest.raises(ValueError, match=r"identify: expected one per head \(2\), got 4"):
        call(cal.heads[:2], devices[:2], identify)


def test_the_committed_heads_result_has_what_notebook_15_reads():
    # experiments/mixed_scale_system.py --heads 2 4 wrote it; notebook 15 quotes these fields
    run = ms.read_heads_result()
    assert run is not None, f"no committed {ms.HEADS_RESULT}"
    assert "experiments/mixed_scale_system.py" in run["command"] and "--heads 2 4" in run["command"]
    assert len(run["date"]) == 10 and len(run["seeds"]) >= 5
    assert set(run["heads"]) >= {"2", "4"} and run["settings"]["heads"] == [2, 4]
    for K in ("2", "4"):
        for key in ms.HEADS_FIELDS:
            v = run["heads"][K][key]
            assert v.shape == (len(run["seeds"]),)
        assert (run["heads"][K]["tries"] >= 1).all()
        assert ((run["heads"][K]["covered"] >= 0) & (run["heads"][K]["covered"] <= 1)).all()
    assert all(0.0 <= v <= 1.0 for v in run["seeds_met"].values())
    # the command says what made the numbers, not where the files went
    assert "--out" not in run["command"] and "--results" not in run["command"]
    assert ms.HEADS_RESULT.read_text(encoding="utf-8").endswith("}\n")


def test_the_committed_motor_fit_result_has_what_notebook_15_reads():
    # experiments/mixed_scale_system.py --seed 18 --seeds 10 --no-baseline wrote it
    run = ms.read_motor_fit_result()
    assert run is not None, f"no committed {ms.MOTOR_FIT_RESULT}"
    assert "--seeds 10" in run["command"] and "--out" not in run["command"]
    assert run["motor_fit"] and len(run["date"]) == 10
    assert {18, 20} <= set(run["seeds"].tolist()) and len(run["seeds"]) == 10
    for key in ("face_median_mm", "readback_face_mm", "true_angles_face_mm"):
        assert run[key].shape == run["seeds"].shape and (run[key] > 0).all()
    assert ms.MOTOR_FIT_RESULT.read_text(encoding="utf-8").endswith("}\n")
    assert ms.read_motor_fit_result(path=ms.MOTOR_FIT_RESULT.with_name("none.json")) is None


def _experiment():
    """experiments/mixed_scale_system.py as a module (its seed_spread import from there)."""
    pytest.importorskip("dask.distributed")
    folder = Path(__file__).resolve().parents[1] / "experiments"
    mods = {}
    for name in ("seed_spread", "mixed_scale_system"):
        spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
        mods[name] = importlib.util.module_from_spec(spec)
        sys.modules.setdefault(name, mods[name])
        spec.loader.exec_module(mods[name])
    return mods["mixed_scale_system"]


def test_the_face_truth_names_the_view_gates_design_when_it_is_on():
    exp = _experiment()
    assert "min_view_cos designed on seeds 18 and 20" in exp.face_in(0.4)
    assert "min_view_cos" not in exp.face_in(-1.0) and exp.FACE_IN == exp.face_in(-1.0)
    # the committed runs' face truth is what the experiment writes for their gate
    for path in (ms.OCCLUSION_RESULT, ms.OCCLUSION_NO_GATE_RESULT, ms.MOTOR_FIT_RESULT):
        data = json.loads(path.read_text(encoding="utf-8"))
        gate = float(data.get("min_view_cos", -1.0))
        assert data["spread"]["face_median_mm"]["truth"] == exp.face_in(gate), path.name


def test_the_recorded_command_leaves_out_where_the_files_go():
    exp = _experiment()
    argv = ["--heads", "2", "4", "--out", "/tmp/a.json", "--seeds", "5",
            "--results=/tmp/b.json", "--no-baseline"]
    before = list(argv)
    assert exp.recorded_command(argv) == ("python experiments/mixed_scale_system.py --heads 2 4 "
                                          "--seeds 5 --no-baseline")
    assert argv == before


def test_heads_result_missing_or_short(tmp_path):
    assert ms.read_heads_result(path=tmp_path / "none.json") is None
    bad = tmp_path / "short.json"
    bad.write_text('{"command": "x", "date": "2026-01-01", "seeds": [1, 2], "settings": {}, '
                   '"seeds_met": {}, "heads": {"2": {"measured": [0.5]}}}')
    with pytest.raises(ValueError, match=r"heads\['2'\]\['measured'\] has 1 values; expected "
                       r"one per seed \(2\)"):
        ms.read_heads_result(path=bad)
    with pytest.raises(ValueError, match="has no 'seeds_met'"):
        bad.write_text('{"command": "x", "date": "d", "seeds": [], "settings": {}, "heads": {}}')
        ms.read_heads_result(path=bad)
