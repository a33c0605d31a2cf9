"""The heads' angles recovered from their 0.1° read-back and their commands (issue 39):
a simulated head (the generator's motor: dead time, ramp, rate limit) driven by jittery
commands; the truth only here, to score."""

import numpy as np
import pytest

from lsmta.synth.mixed_scale import SimulatedHead
from lsmta.synth.pantilt import pantilt_head
from lsmta.systems import MixedScaleParams, fill_face, refine_readback


def _drive(n_ticks=200, n_frames=150, rate=30.0, seed=0, step=0.1, jumps=0):
    """Commands at every tick (a sweep plus jitter, some ticks without a command, and
    ``jumps`` steps of 5° in pan that drive the motor into its rate limit), the angles
    reached and read back at the last ``n_frames`` ticks."""
    rng = np.random.default_rng(seed)
    dev = SimulatedHead(pantilt_head(rng=seed), None, period=1 / rate, rng=seed,
                        readback_step=step)
    t = np.arange(n_ticks) / rate
    cmd = np.stack([20 * np.sin(0.9 * t) + rng.normal(0, 0.08, n_ticks),
                    4 * np.sin(1.3 * t + 1) + rng.normal(0, 0.08, n_ticks)], axis=1)
    for i in rng.choice(np.arange(n_ticks - n_frames, n_ticks), jumps, replace=False):
        cmd[i:, 0] += 5.0                                  # 80 deg/s: 2.7 deg a tick at most
    cmd[rng.random(n_ticks) < 0.05] = np.nan              # ticks without a command
    start = dev.read_back(dev.reached(0.0))
    true, back = [], []
    for i, ti in enumerate(t):
        if np.isfinite(cmd[i]).all():
            dev.command(ti, cmd[i])
        if i >= n_ticks - n_frames:
            s = dev.reached(ti)
            true.append(s)
            back.append(dev.read_back(s))
    return cmd[None], np.array(back)[None], start[None], np.array(true)[None]


def test_recovers_angles_disturbed_within_an_encoder_step():
    cmd, back, start, true = _drive()
    before = (cmd.copy(), back.copy(), start.copy())
    r = refine_readback(cmd, back, start, step=0.1, taps=12)
    err_back = np.sqrt(np.mean((back - true) ** 2))
    err = np.sqrt(np.mean((r.angles - true) ** 2))
    assert 0.02 < err_back < 0.04                        # the rounding: 0.1 / sqrt(12)
    assert err < err_back / 2.5                          # the fitted response: far closer
    assert np.abs(r.angles - back).max() <= 0.05 + 1e-12   # never outside the encoder step
    assert r.fitted.all() and r.weights.shape == (1, 2, 13)
    # the motor's 0.25 s dead time at 30 Hz: the weight sits 7-9 ticks back
    assert set(np.argsort(r.weights[0, 0])[-2:]) <= {7, 8, 9}
    assert np.all(np.abs(r.residual_median - 0.1 / 4) < 0.01)      # the rounding's median
    for a, b in zip((cmd, back, start), before):           # inputs unchanged
        assert np.array_equal(a, b, equal_nan=True)


def test_frames_a_rate_limit_bends_do_not_spoil_the_others():
    cmd, back, start, true = _drive(seed=5, jumps=2)
    assert np.abs(np.diff(true[0, :, 0])).max() > 2.6          # the motor hit its rate limit
    r = refine_readback(cmd, back, start, step=0.1, taps=12)
    assert r.fitted.all() and np.abs(r.angles - back).max() <= 0.05 + 1e-12
    err = np.abs(r.angles - true)
    assert np.median(err) < np.median(np.abs(back - true)) / 2.5


def test_the_window_in_seconds_fits_at_another_frame_rate():
    # the window is in seconds: 12 ticks at the notebook's 30 Hz, 24 at 60 Hz, both 0.4 s,
    # enough for the motor's 0.25 s dead time and one command period
    assert MixedScaleParams().motor_taps == 12
    taps = MixedScaleParams(video_rate=60.0).motor_taps
    assert taps == 24
    cmd, back, start, true = _drive(n_ticks=400, n_frames=300, rate=60.0, seed=3)
    # 12 ticks at 60 Hz (0.2 s) miss the dead time: the fit is refused, the read-back kept
    assert not refine_readback(cmd, back, start, step=0.1, taps=12).fitted.any()
    r = refine_readback(cmd, back, start, step=0.1, taps=taps)
    assert r.fitted.all() and np.abs(r.angles - back).max() <= 0.05 + 1e-12
    err_back = np.sqrt(np.mean((back - true) ** 2))
    assert np.sqrt(np.mean((r.angles - true) ** 2)) < err_back / 2.5


def test_a_response_the_commands_do_not_explain_keeps_the_read_back():
    cmd, back, start, _ = _drive(seed=1)
    rng = np.random.default_rng(2)
    shuffled = cmd[:, rng.permutation(cmd.shape[1])]        # commands unrelated to the angles
    r = refine_readback(shuffled, back, start, step=0.1, taps=12)
    assert not r.fitted.any() and np.array_equal(r.angles, back)
    assert (r.residual_median > 1.5 * 0.1 / 4).all()
    # too short a history to fit the weights: the read-back, nothing fitted
    r = refine_readback(cmd[:, -20:], back[:, -20:], start, step=0.1, taps=12)
    assert not r.fitted.any() and np.array_equal(r.angles, back[:, -20:])


def test_bad_input_names_the_argument():
    cmd, back, start, _ = _drive(n_ticks=60, n_frames=40)
    for kwargs, name in ((dict(step=0.0), "step"), (dict(taps=-1), "taps"),
                         (dict(max_median=-1.0), "max_median")):
        with pytest.raises(ValueError, match=name):
            refine_readback(cmd, back, start, **kwargs)
    with pytest.raises(ValueError, match="commands"):
        refine_readback(cmd[:, :30], back, start)              # fewer ticks than frames
    with pytest.raises(ValueError, match="commands"):
        refine_readback(cmd[:, :, :1], back, start)
    with pytest.raises(ValueError, match="start"):
        refine_readback(cmd, back, start[0])
    with pytest.raises(ValueError, match="readback"):
        refine_readback(cmd, np.where(back > 0, np.nan, back), start)
    for bad, name, error in ((dict(motor_fit="yes"), "motor_fit", TypeError),
                             (dict(motor_window=-0.1), "motor_window", ValueError),
                             (dict(encoder_step=0.0), "encoder_step", ValueError)):
        with pytest.raises(error, match=name):
            MixedScaleParams(**bad)
    with pytest.raises(TypeError, match="face_model"):
        fill_face(np.zeros((2, 3, 3)), object())
