import numpy as np
import pytest

from lsmta.evaluation.matching import METHODS, honesty, noise_sweep, run_trial, success_rate
from lsmta.matching import peers
from lsmta.synth.patches import warped_pair


@pytest.fixture(scope="module")
def shifted():
    return warped_pair(rng=np.random.default_rng(3), shape=(128, 128), c=(1.6, -0.8),
                       noise_sigma=1.0)


@pytest.mark.parametrize("name", ["ecc", "klt", "ilk"])
def test_peers_find_a_shift(shifted, name):
    rng = np.random.default_rng(0)
    pts = np.rint(rng.uniform(30, 98, (20, 2)))
    truth = shifted.true_xy(pts)
    res = getattr(peers, name)(shifted.template, shifted.search, pts, truth + 0.4)
    assert res.ok.mean() > 0.9
    assert np.median(np.linalg.norm(res.xy[res.ok] - truth[res.ok], axis=1)) < 0.15


def test_phase_correlation_returns_integer_scale_answers(shifted):
    pts = np.array([[60.0, 60.0]])
    res = peers.phase_correlation(shifted.template, shifted.search, pts, shifted.true_xy(pts))
    assert res.ok.all() and np.isfinite(res.xy).all()


def test_peers_refuse_bad_input(shifted):
    with pytest.raises(ValueError, match="motion"):
        peers.ecc(shifted.template, shifted.search, [[60, 60]], [[60, 60]], motion="perspective")
    with pytest.raises(ValueError, match="search_xy"):
        peers.klt(shifted.template, shifted.search, [[60, 60]], np.zeros((2, 2)))


def test_trial_scores_every_method_on_the_same_starts(shifted):
    rng = np.random.default_rng(1)
    trial = run_trial(shifted, rng=rng, methods=list(METHODS), n_points=12, margin=25)
    assert set(trial.errors) == set(METHODS)
    assert trial.crb.shape == (12, 2, 2)
    s = trial.summary("lsm")
    assert s["failure_rate"] == 0 and s["median_px"] < 0.1
    h = honesty(trial)
    assert 0 < h["rms_ratio"] < 5 and 0 <= h["coverage_95"] <= 1


def test_noise_sweep_and_success_rate(shifted):
    rng = np.random.default_rng(2)
    sweep = noise_sweep(shifted, [0.0, 2.0], rng=rng, n_points=30, geometry="shift",
                        radiometry="none")
    assert np.isnan(sweep["bound_median_px"][0]) and sweep["bound_median_px"][1] > 0
    assert sweep["median_px"][1] > sweep["median_px"][0]
    near = success_rate(shifted, rng=rng, start_distance=0.5, geometry="shift", radiometry="none",
                        n_points=30, margin=20)
    far = success_rate(shifted, rng=rng, start_distance=8.0, geometry="shift", radiometry="none",
                       n_points=30, margin=20)
    assert near > 0.9 and far < near
