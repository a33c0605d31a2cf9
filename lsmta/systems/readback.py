"""The pan-tilt heads' angles recovered from their coarse read-back and their commands.

A head reports its angles in encoder steps (the thesis's 0.1°, §5.2), off by up to half a
step from where it is. Marker rays through the two heads cannot repair that: the error that
matters, a difference of the two heads' pans, moves the intersection along the rays (the
face's depth), and a common turn of both heads moves the whole face; the rays still meet.
What the system also knows is what it asked of each head: its commands. The model assumes
a motor answers its commands the same way every time (a dead time, then a ramp: linear in
the commands), so that the angle it is at is a fixed linear combination of the commands of
the last ``taps`` ticks. :func:`refine_readback` fits those weights per head and axis to the
read-back over the whole recording (the rounding error is nearly white while the head moves
and averages out of a fit of a few weights over a hundred frames or more) and takes the
fitted response at each frame, clipped into the encoder's interval about the read-back
(for an encoder that only rounds, the head is there for certain; with encoder noise before
the rounding, e.g. the simulator's ``readback_noise`` > 0, it may lie outside it).
The fit is robust (:func:`scipy.optimize.least_squares`, ``loss="soft_l1"`` with a scale of
half a step, the largest residual rounding alone leaves): a command jump that drives a
motor into its rate limit is not linear, and those frames must not bend the weights of the
others. Where the history of commands is too short, or the fit too poor (the residuals'
median above 1.5 times a quarter step, the rounding's own median), the read-back is kept.

The simulator's motor (:class:`lsmta.synth.mixed_scale.SimulatedHead`) is exactly of this
model's class: a dead time, then a ramp to each command over one command period, with no
backlash, friction or encoder noise; only its rate limit leaves the class. A real motor is
not, and how far the recovery carries over to one is not measured.

The design (a 0.4 s window, 12 taps at 30 Hz; the soft-L1 loss with a half-step scale;
the refusal rule) and the choice to have it on by default in
:class:`~lsmta.systems.MixedScaleParams` were made on two walks of notebook 15's setting,
seeds 18 (the notebook's scored walk) and 20: designed on seeds 18 and 20; fresh: 19 and
21-27: 7 of 8 within 1 mm (``experiments/results/mixed_scale_motor_fit.json``, quoted by
notebook 15).

What this cannot fix: frames where the motor does not answer linearly (rate limits,
backlash) keep the fitted response's error there; the clip keeps it within the step, never
more than a step from the truth (for an encoder that only rounds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_array, as_int, as_scalar


@dataclass(frozen=True, eq=False)
class ReadbackRefinement:
    """What :func:`refine_readback` found.

    Attributes
    ----------
    angles : (K, F, 2) array
        The heads' pan and tilt at each frame, degrees: the fitted response clipped into
        the encoder's interval about the read-back (the read-back where not fitted).
    fitted : (K, F, 2) bool array
        Frames whose angle comes from the fitted response (else the read-back).
    weights : (K, 2, taps + 1) array
        The fitted weights of the commands 0 ... ``taps`` ticks before each frame, per head
        and axis (NaN: not fitted).
    residual_median : (K, 2) array
        Median absolute read-back minus fitted response, degrees (a linear response with
        white rounding: about a quarter step).
    """

    angles: np.ndarray
    fitted: np.ndarray
    weights: np.ndarray
    residual_median: np.ndarray


def _held(commands, start):
    """Commands per tick with gaps (no command sent) holding the previous one; before the
    first, ``start``."""
    out = commands.copy()
    last = start
    for i in range(len(out)):
        if np.isfinite(out[i]):
            last = out[i]
        out[i] = last
    return out


def refine_readback(commands, readback, start, *, step: float = 0.1, taps: int = 12,
                    max_median: float | None = None) -> ReadbackRefinement:
    """The heads' angles at each frame from their read-back and the commands sent to them
    (see the module).

    Parameters
    ----------
    commands : (K, T, 2) array
        Pan and tilt commanded at every tick of the loop, degrees (NaN: no command sent
        then). The frames are the last F ticks.
    readback : (K, F, 2) array
        The angles each head reported at each frame, degrees (multiples of ``step``).
    start : (K, 2) array
        The angles each head reported before its first command, degrees.
    step : float
        The encoder's step, degrees: an encoder that only rounds puts the head within
        ``step / 2`` of its read-back.
    taps : int
        Commands before each frame that its angle depends on (with the frame's own tick:
        ``taps + 1`` weights), enough to span the motor's dead time and ramp (12 ticks at
        30 Hz: 0.4 s; the thesis's dead time is 0.25-0.3 s).
    max_median : float, optional
        A fit whose median absolute residual exceeds this keeps the read-back, degrees
        (default: the rounding's own median, a quarter step, times 1.5).

    Returns
    -------
    ReadbackRefinement
    """
    readback = as_array(readback, "readback", shape=(None, None, 2))
    K, F = readback.shape[:2]
    commands = as_array(commands, "commands", shape=(K, None, 2), allow_nan=True)
    start = as_array(start, "start", shape=(K, 2))
    step = as_scalar(step, "step", positive=True)
    taps = as_int(taps, "taps", minimum=0)
    T = commands.shape[1]
    if T < F:
        raise ValueError(f"commands: expected at least as many ticks as frames ({F}), got {T}")
    limit = 1.5 * step / 4 if max_median is None else as_scalar(max_median, "max_median",
                                                                positive=True)
    angles = readback.copy()
    fitted = np.zeros((K, F, 2), bool)
    weights = np.full((K, 2, taps + 1), np.nan)
    med = np.full((K, 2), np.nan)
    frames = np.arange(T - F, T)
    usable = frames - taps >= 0
    if usable.sum() <= 2 * (taps + 1):
        return ReadbackRefinement(angles=angles, fitted=fitted, weights=weights,
                                  residual_median=med)
    for k in range(K):
        for a in range(2):
            held = _held(commands[k, :, a], start[k, a])
            A = np.stack([held[frames[usable] - j] for j in range(taps + 1)], axis=1)
            r = readback[k, usable, a]
            w = np.linalg.lstsq(A, r, rcond=None)[0]
            w = least_squares(lambda v, A=A, r=r: A @ v - r, w, loss="soft_l1",
                              f_scale=step / 2).x
            med[k, a] = float(np.median(np.abs(r - A @ w)))
            if med[k, a] > limit:
                continue
            weights[k, a] = w
            angles[k, usable, a] = np.clip(A @ w, r - step / 2, r + step / 2)
            fitted[k, usable, a] = True
    return ReadbackRefinement(angles=angles, fitted=fitted, weights=weights,
                              residual_median=med)
