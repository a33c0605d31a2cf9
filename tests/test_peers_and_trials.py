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


def test_phase_correlation_exact_for_whole_pixel_shifts_within_a_pixel_otherwise(shifted):
    # a whole-pixel shift is found to a few hundredths of a pixel; a fractional one (the
    # fixture's 1.6, -0.8) only to within a pixel: on small, unwindowed patches the phase
    # correlation peak is biased (notebook 02: the peer's large median error)
    whole = warped_pair(rng=np.random.default_rng(3), shape=(128, 128), c=(2.0, -1.0),
                        noise_sigma=1.0)
    pts = np.rint(np.random.default_rng(0).uniform(35, 93, (20, 2)))
    for pair, tol in ((whole, 0.1), (shifted, 1.0)):
        truth = pair.true_xy(pts)
        res = peers.phase_correlation(pair.template, pair.search, pts, truth + 0.4, patch=31)
        assert res.ok.all()
        assert np.abs(res.xy - truth).max() < tol
    assert np.median(np.linalg.norm(res.xy - truth, axis=1)) > 0.1   # the bias is real


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
    # LSM's own precision estimate is about right: on 100 patches the RMS error is within
    # 0.8-1.5 times the predicted one and most true positions lie in the 95 % ellipses
    h = honesty(run_trial(shifted, rng=rng, methods=["lsm"], n_points=100, margin=25))
    assert 0.8 < h["rms_ratio"] < 1.5 and h["coverage_95"] > 0.8


def test_noise_sweep_and_success_rate(shifted):
    rng = np.random.default_rng(2)
    sweep = noise_sweep(shifted, [0.0, 2.0], rng=rng, n_points=30, geometry="shift",
                        radiometry="none")
    assert np.isnan(sweep["bound_median_px"][0]) and sweep["bound_median_px"][1] > 0
    assert sweep["median_px"][1] > sweep["median_px"][0]
    assert 0.5 < sweep["error_ratio"][1] < 2, "the shift-only model near its Cramér-Rao bound"
    near = success_rate(shifted, rng=rng, start_distance=0.5, geometry="shift", radiometry="none",
                        n_points=30, margin=20)
    far = success_rate(shifted, rng=rng, start_distance=8.0, geometry="shift", radiometry="none",
                       n_points=30, margin=20)
    assert near > 0.9 and far < near
