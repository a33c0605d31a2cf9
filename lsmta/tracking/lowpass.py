"""Zero-lag Butterworth low-pass of 3-D trajectories with gaps.

The filter that biomechanics tools apply to marker trajectories before writing them
(Pose2Sim's default: ``butterworth``, ``order = 4``, ``cut_off_frequency = 6`` Hz). As in
Pose2Sim, ``order`` is the order of the two passes together: a Butterworth filter of order
``order / 2`` run forwards and backwards (:func:`scipy.signal.sosfiltfilt`: no phase lag),
its cut-off the single pass's -3 dB frequency. So 6 Hz is Pose2Sim's nominal 6 Hz (as
Pose2Sim does it: no correction for the second pass, unlike Winter's; the two passes
attenuate 6 Hz by 6 dB, and their -3 dB point is at about 4.9 Hz at 60 fps, 5.0 Hz at
30 fps).

A trajectory is filtered per *run*: each stretch of consecutive frames in which all three of
its coordinates are finite. A gap is never bridged (nothing is interpolated; missing
samples stay NaN). A run too short for the filter's edge padding (``sosfiltfilt``'s default
``padlen``; 10 frames or more are filtered at order 4) is left raw and counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from .._validate import as_array, as_int, as_scalar, freeze


@dataclass(frozen=True)
class Lowpass:
    """Trajectories low-pass filtered by :func:`lowpass_trajectories`.

    Attributes
    ----------
    xyz : (T, M, 3) array
        The filtered positions, in the input's unit (NaN where the input is missing in any
        coordinate).
    raw : (T, M) bool array
        Samples left raw: present, but in a run too short to filter.
    runs : int
        Runs filtered.
    short_runs : int
        Runs left raw (too short).
    cutoff_hz, fps : float
    order : int
    """

    xyz: np.ndarray
    raw: np.ndarray
    runs: int
    short_runs: int
    cutoff_hz: float
    fps: float
    order: int

    def __post_init__(self):
        freeze(self, ("xyz", "raw"))


def min_run(order: int) -> int:
    """Shortest run (frames) that :func:`lowpass_trajectories` filters at ``order``
    (``sosfiltfilt``'s default padding plus one)."""
    order = as_int(order, "order", minimum=2)
    # the padding counts the sections and their zero trailing coefficients, set by the
    # order alone: any cut-off (here half the Nyquist frequency) gives the same length
    sos = signal.butter(order // 2, 0.5, btype="low", output="sos")
    origin = min((sos[:, 2] == 0).sum(), (sos[:, 5] == 0).sum())
    return 3 * (2 * len(sos) + 1 - int(origin)) + 1


def lowpass_trajectories(xyz, fps: float, *, cutoff_hz: float = 6.0,
                         order: int = 4) -> Lowpass:
    """Low-pass filter trajectories with gaps, without lag (see the module docstring).

    Parameters
    ----------
    xyz : (T, M, 3) array
        Positions of M points in T frames, any unit (mm in lsmta; NaN: missing). Not
        modified.
    fps : float
        Frame rate, Hz (> 0).
    cutoff_hz : float
        Cut-off frequency, Hz, in (0, fps / 2).
    order : int
        Order of the two passes together, even, >= 2 (Pose2Sim's ``order``).

    Returns
    -------
    Lowpass

    Raises
    ------
    ValueError
        ``xyz`` not ``(T, M, 3)`` or holding infinities; ``fps`` not positive;
        ``cutoff_hz`` not below the Nyquist frequency ``fps / 2``; ``order`` odd or < 2.
    """
    X = as_array(xyz, "xyz", shape=(None, None, 3), allow_nan=True)
    fps = as_scalar(fps, "fps", positive=True)
    cutoff_hz = as_scalar(cutoff_hz, "cutoff_hz", positive=True)
    if cutoff_hz >= fps / 2:
        raise ValueError(f"cutoff_hz: expected a frequency below the Nyquist frequency "
                         f"fps / 2 = {fps / 2:g} Hz, got {cutoff_hz:g} Hz")
    order = as_int(order, "order", minimum=2)
    if order % 2:
        raise ValueError(f"order: expected an even order (the two passes together), got "
                         f"{order}")
    sos = signal.butter(order // 2, cutoff_hz / (fps / 2), btype="low", output="sos")
    shortest = min_run(order)
    out = np.full(X.shape, np.nan)
    raw = np.zeros(X.shape[:2], bool)
    runs = short = 0
    present = np.isfinite(X).all(axis=2)
    for m in range(X.shape[1]):
        for start, stop in _runs(present[:, m]):
            seg = X[start:stop, m]
            if stop - start < shortest:
                out[start:stop, m] = seg
                raw[start:stop, m] = True
                short += 1
            else:
                out[start:stop, m] = signal.sosfiltfilt(sos, seg, axis=0,
                                                        padlen=shortest - 1)
                runs += 1
    return Lowpass(xyz=out, raw=raw, runs=runs, short_runs=short, cutoff_hz=cutoff_hz,
                   fps=fps, order=order)


def _runs(present: np.ndarray) -> list:
    """``(start, stop)`` of every stretch of True in a 1-D bool array."""
    edges = np.diff(np.concatenate(([0], present.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))
