"""The zero-lag Butterworth low-pass of trajectories with gaps (lsmta.tracking.lowpass)."""

import numpy as np
import pytest
from scipy import signal

from lsmta.tracking import lowpass_trajectories
from lsmta.tracking.lowpass import min_run


def _noisy_sines(seed=3):
    """Two markers' 1-Hz sines (60 fps, 4 s, mm) plus white noise of 2 mm, and the truth."""
    rng = np.random.default_rng(seed)
    fps, T = 60.0, 240
    t = np.arange(T) / fps
    truth = np.zeros((T, 2, 3))
    truth[:, 0, 0] = 100.0 * np.sin(2 * np.pi * 1.0 * t)
    truth[:, 0, 1] = 50.0 * np.cos(2 * np.pi * 0.5 * t)
    truth[:, 1, 2] = 1000.0 + 80.0 * np.sin(2 * np.pi * 1.5 * t + 1.0)
    return fps, truth, truth + rng.normal(0.0, 2.0, truth.shape)


def test_noise_reduced_signal_kept_gaps_preserved():
    fps, truth, noisy = _noisy_sines()
    X = noisy.copy()
    X[100:105, 0] = np.nan                      # a gap of 5 frames
    X[150, 1, 2] = np.nan                       # one coordinate missing: the sample is missing
    X[200:212, 1, 0] = np.nan
    given = X.copy()
    lp = lowpass_trajectories(X, fps, cutoff_hz=6.0, order=4)
    assert np.array_equal(X, given, equal_nan=True)                   # input unchanged
    missing = ~np.isfinite(X).all(axis=2)
    assert np.array_equal(~np.isfinite(lp.xyz).all(axis=2), missing)  # gaps kept, not bridged
    ok = ~missing & ~lp.raw
    err_raw = np.std((X - truth)[ok])
    err_filtered = np.std((lp.xyz - truth)[ok])
    assert err_raw == pytest.approx(2.0, rel=0.1)
    # 6 Hz of a 30-Hz band keeps ~ sqrt(6 / 30) of white noise (the passes' roll-off aside)
    assert err_filtered < 0.6 * err_raw
    # the signal kept: amplitude of the 1-Hz sine within 2 % (the noise left moves its
    # extremes), no lag
    amp = np.ptp(lp.xyz[20:100, 0, 0])
    assert amp == pytest.approx(np.ptp(truth[20:100, 0, 0]), rel=0.02)
    lag = np.argmax(np.correlate(lp.xyz[:100, 0, 0], truth[:100, 0, 0], "full")) - 99
    assert lag == 0
    assert lp.short_runs == 0 and lp.runs == 2 + 3 and not lp.raw.any()


def test_short_runs_left_raw_and_counted():
    fps, truth, noisy = _noisy_sines(seed=5)
    X = noisy[:40].copy()
    n = min_run(4)
    assert n == 10                                   # sosfiltfilt's padding (9) plus one
    X[n - 1, 0] = np.nan                             # marker 0: run of n - 1, then the rest
    X[[n, 2 * n], 1] = np.nan                        # marker 1: runs of n, n - 1 and 19
    lp = lowpass_trajectories(X, fps, cutoff_hz=6.0)
    assert lp.short_runs == 2 and lp.runs == 3
    assert np.array_equal(np.flatnonzero(lp.raw[:, 0]), np.arange(n - 1))
    assert np.array_equal(np.flatnonzero(lp.raw[:, 1]), np.arange(n + 1, 2 * n))
    assert np.array_equal(lp.xyz[:n - 1, 0], X[:n - 1, 0])       # raw as given
    assert np.array_equal(lp.xyz[n + 1:2 * n, 1], X[n + 1:2 * n, 1])
    assert not np.allclose(lp.xyz[n:, 0], X[n:, 0])              # the long run filtered
    assert not np.allclose(lp.xyz[:n, 1], X[:n, 1])              # a run of exactly n too
    # a run filtered is filtered as on its own (nothing from the other side of the gap)
    sos = signal.butter(2, 6.0 / 30.0, output="sos")
    assert np.allclose(lp.xyz[n:, 0], signal.sosfiltfilt(sos, X[n:, 0], axis=0))
    assert np.allclose(lp.xyz[:n, 1], signal.sosfiltfilt(sos, X[:n, 1], axis=0))
    assert np.all(np.isnan(lp.xyz[n - 1, 0])) and np.all(np.isnan(lp.xyz[[n, 2 * n], 1]))


def test_order_and_cutoff_shape_the_filter():
    fps, truth, noisy = _noisy_sines(seed=7)
    noise = noisy - truth
    lo = lowpass_trajectories(noise, fps, cutoff_hz=3.0)
    hi = lowpass_trajectories(noise, fps, cutoff_hz=12.0)
    assert np.std(lo.xyz) < np.std(hi.xyz) < np.std(noise)
    # a 20-Hz tone, above the 12-Hz cut-off: the higher order attenuates it more
    tone = np.zeros((240, 1, 3))
    tone[:, 0, 0] = np.sin(2 * np.pi * 20.0 * np.arange(240) / fps)
    gain = {o: np.ptp(lowpass_trajectories(tone, fps, cutoff_hz=12.0, order=o).xyz[60:180])
            / np.ptp(tone[60:180]) for o in (2, 4, 8)}
    assert 1 > gain[2] > gain[4] > gain[8]
    assert lo.cutoff_hz == 3.0 and lo.order == 4 and lo.fps == 60.0
    assert not lo.xyz.flags.writeable
    empty = lowpass_trajectories(np.full((20, 1, 3), np.nan), fps)
    assert empty.runs == empty.short_runs == 0 and np.isnan(empty.xyz).all()
    assert lowpass_trajectories(np.zeros((20, 0, 3)), fps).xyz.shape == (20, 0, 3)


def test_bad_input():
    X = np.zeros((30, 2, 3))
    with pytest.raises(ValueError, match=r"cutoff_hz: .*Nyquist .* 30 Hz"):
        lowpass_trajectories(X, 60.0, cutoff_hz=30.0)
    with pytest.raises(ValueError, match="cutoff_hz"):
        lowpass_trajectories(X, 60.0, cutoff_hz=0.0)
    with pytest.raises(ValueError, match="order: expected an even"):
        lowpass_trajectories(X, 60.0, cutoff_hz=6.0, order=3)
    with pytest.raises(ValueError, match="order"):
        lowpass_trajectories(X, 60.0, cutoff_hz=6.0, order=0)
    with pytest.raises(ValueError, match="fps"):
        lowpass_trajectories(X, -60.0)
    with pytest.raises(ValueError, match=r"xyz: expected an array of shape \(N, N, 3\)"):
        lowpass_trajectories(np.zeros((30, 2)), 60.0)
    bad = X.copy()
    bad[3, 0, 0] = np.inf
    with pytest.raises(ValueError, match="xyz: contains infinite"):
        lowpass_trajectories(bad, 60.0)
    with pytest.raises(TypeError):
        lowpass_trajectories(X, 60.0, 6.0)               # the cut-off is keyword-only
