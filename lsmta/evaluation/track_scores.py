"""Scores of a wide-area tracking run against the LEDs' ground truth: our matching of tracks
to LEDs (identity changes, birth and death delays, RMS error, coverage) and Stone Soup's
metrics (OSPA, SIAP) of the same run."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from stonesoup.dataassociator.tracktotrack import TrackToTruth
from stonesoup.measures import Euclidean
from stonesoup.metricgenerator.manager import MultiManager
from stonesoup.metricgenerator.ospametric import OSPAMetric
from stonesoup.metricgenerator.tracktotruthmetrics import SIAPMetrics
from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
from stonesoup.types.state import State
from stonesoup.types.track import Track

from ..synth.widearea import LedScene
from ..widearea import TrackingResult
from ..widearea.peers import seconds_to_datetime

MATCH_MM = 60.0   # a track within this distance of an LED may be that LED's track


@dataclass(frozen=True)
class LedTrackScore:
    """A tracking run scored against the LEDs' ground truth.

    Attributes
    ----------
    times : (T,) array
        Evaluation times, s.
    assigned : (T, N) int array
        Track id assigned to each LED at each time (-1: none within ``MATCH_MM``; -2: LED off).
    error : (T, N) array
        Distance of the assigned track from the LED, mm (NaN when none).
    rms_mm : float
        Root mean square of ``error`` over assigned (LED, time) pairs only; read it with
        ``coverage`` (an LED without a track within ``MATCH_MM`` adds nothing to it).
    identity_changes : int
        Times an LED's assigned track id changed to another id (gaps not counted).
    birth_delay, death_delay : (N,) arrays
        Birth of the first track an LED got minus the LED's switch-on time; death of its
        last track minus the switch-off time (NaN when never born / still alive), s.
    coverage : float
        Fraction of (LED on, time) pairs with an assigned track.
    spurious_tracks : int
        Tracks never assigned to any LED.
    never_born : int
        LEDs on at some scoring time that were never assigned a track (a failed birth;
        their ``birth_delay`` is NaN).
    never_deleted : int
        LEDs switched off before the last scoring time whose last track was still alive
        at the end of the run (a failed death; their ``death_delay`` is NaN). An LED that
        was never born is not counted here.
    """

    times: np.ndarray
    assigned: np.ndarray
    error: np.ndarray
    rms_mm: float
    identity_changes: int
    birth_delay: np.ndarray
    death_delay: np.ndarray
    coverage: float
    spurious_tracks: int
    never_born: int = 0
    never_deleted: int = 0


def score_led_tracks(scene: LedScene, result: TrackingResult, times) -> LedTrackScore:
    """Match tracks to LEDs at ``times`` (Hungarian on distances, gated at ``MATCH_MM``)."""
    times = np.asarray(times, dtype=float)
    truth = scene.positions_at(times)                                  # (T, N, 3)
    est = result.positions_at(times)                                   # (T, M, 3)
    T, N = truth.shape[:2]
    ids = np.array([tr.id for tr in result.tracks], dtype=int)
    assigned = np.full((T, N), -1)
    error = np.full((T, N), np.nan)
    on = np.isfinite(truth).all(axis=2)
    assigned[~on] = -2
    for k in range(T):
        if est.shape[1] == 0:
            break
        d = np.linalg.norm(truth[k][:, None] - est[k][None], axis=2)
        d = np.where(np.isfinite(d), d, 1e9)
        r, c = linear_sum_assignment(d)
        ok = d[r, c] <= MATCH_MM
        assigned[k, r[ok]] = ids[c[ok]]
        error[k, r[ok]] = d[r[ok], c[ok]]
    changes = 0
    birth = np.full(N, np.nan)
    death = np.full(N, np.nan)
    by_id = {tr.id: tr for tr in result.tracks}
    never_born = never_deleted = 0
    for n in range(N):
        seq = assigned[:, n][assigned[:, n] >= 0]
        if len(seq):
            changes += int(np.count_nonzero(np.diff(seq)))
            birth[n] = by_id[seq[0]].birth_time - scene.on[n, 0]
            if np.isfinite(scene.on[n, 1]) and scene.on[n, 1] < times[-1]:
                death[n] = by_id[seq[-1]].death_time - scene.on[n, 1]
                never_deleted += int(np.isnan(death[n]))
        elif on[:, n].any():
            never_born += 1
    used = set(assigned[assigned >= 0].tolist())
    e = error[np.isfinite(error)]
    return LedTrackScore(times=times, assigned=assigned, error=error,
                      rms_mm=float(np.sqrt(np.mean(e**2))) if len(e) else np.nan,
                      identity_changes=changes, birth_delay=birth, death_delay=death,
                      coverage=float((assigned >= 0).sum() / max(on.sum(), 1)),
                      spurious_tracks=len(ids) - len(used & set(ids.tolist())),
                      never_born=never_born, never_deleted=never_deleted)


def stonesoup_metrics(scene: LedScene, result: TrackingResult, times, *, c_mm: float = 100.0,
                      threshold_mm: float = MATCH_MM) -> dict:
    """Stone Soup's OSPA (p = 1, cut-off ``c_mm``) and SIAP metrics of a run.

    Truth and tracks are sampled at ``times`` (tracks: their real-time estimate, the last
    state carried forward at constant velocity) and handed to Stone Soup as
    ``GroundTruthPath`` and ``Track`` objects; tracks are associated with truths by
    ``TrackToTruth`` (Euclidean position distance below ``threshold_mm``).

    Returns
    -------
    dict
        ``ospa_mm`` (mean over time), ``siap_completeness``, ``siap_spuriousness``,
        ``siap_ambiguity``, ``siap_position_accuracy_mm``, ``siap_track_number_change_rate``
        (per second). (Stone Soup's CLEAR MOT generator refuses runs in which two tracks
        sit on one truth at the same time, which a newborn ghost near an LED causes, so it
        is not used.)
    """
    times = np.asarray(times, dtype=float)
    stamps = [seconds_to_datetime(t) for t in times]

    def paths(P, make_path, make_state):
        out = set()
        for n in range(P.shape[1]):
            v = np.nan_to_num(np.gradient(P[:, n], times, axis=0))
            path = make_path()
            for k, when in enumerate(stamps):
                if np.isfinite(P[k, n]).all():
                    path.append(make_state(np.r_[P[k, n], v[k]].reshape(-1, 1),
                                           timestamp=when))
            if len(path):
                out.add(path)
        return out

    truths = paths(scene.positions_at(times), GroundTruthPath, GroundTruthState)
    tracks = paths(result.positions_at(times), Track, State)
    pos, vel = Euclidean(mapping=(0, 1, 2)), Euclidean(mapping=(3, 4, 5))
    manager = MultiManager(
        [OSPAMetric(c=c_mm, p=1, measure=pos),
         SIAPMetrics(position_measure=pos, velocity_measure=vel)],
        associator=TrackToTruth(association_threshold=threshold_mm, measure=pos))
    manager.add_data({"groundtruth_paths": truths, "tracks": tracks})
    m = manager.generate_metrics()
    ospa = m["ospa_generator"]["OSPA distances"].value
    siap = m["siap_generator"]
    return {
        "ospa_mm": float(np.mean([s.value for s in ospa])),
        "siap_completeness": float(siap["SIAP Completeness"].value),
        "siap_spuriousness": float(siap["SIAP Spuriousness"].value),
        "siap_ambiguity": float(siap["SIAP Ambiguity"].value),
        "siap_position_accuracy_mm": float(siap["SIAP Position Accuracy"].value),
        "siap_track_number_change_rate": float(siap["SIAP Rate of Track Number Change"].value),
    }



def longest_track_estimate(result: TrackingResult, times) -> np.ndarray:
    """Positions ``(T, 3)`` at ``times`` of the track alive longest over them (NaN where it
    is not alive; all NaN without tracks)."""
    est = result.positions_at(times)                  # (T, M, 3)
    if est.shape[1] == 0:
        return np.full((len(times), 3), np.nan)
    # the track alive longest over the window
    best = np.argmax(np.isfinite(est[..., 0]).sum(axis=0))
    return est[:, best]
