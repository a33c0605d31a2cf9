"""Tracking in image space and 3-D trajectories.

``track_points`` is the LSMTA tracker (temporal and spatial LSM, density check for surface
tracking, 2-D mode with one camera; ``track_step``: one step of it); ``track_klt`` the
OpenCV KLT peer;
``trajectories_from_tracks`` intersects tracks into :class:`Trajectories` (velocities,
accelerations); ``threshold_filter`` and ``uniformity_filter`` (the paper's) and
``drift_filter`` (ours) cut false trajectories, ``apply_filters`` chains the three;
``lowpass_trajectories`` smooths trajectories with gaps (zero-lag Butterworth, per run).
``markers`` is the small-scale marker tracker of Davis §5.1.
``guided`` is guided tracking (Davis Fig. 56: tracking state, enlarged view, a lost marker
placed by hand and tracked on); ``guided_ui`` its ipywidgets interface.
"""

from .filters import (
    FilterReport,
    Reason,
    apply_filters,
    drift_deviation,
    drift_filter,
    threshold_filter,
    uniformity_filter,
)
from .klt import track_klt
from .lowpass import Lowpass, lowpass_trajectories
from .points import StepResult, TrackerParams, Tracks, TrackStatus, track_points, track_step
from .trajectories import Trajectories, trajectories_from_tracks

__all__ = [
    "FilterReport", "Lowpass", "Reason", "StepResult", "TrackStatus", "TrackerParams", "Tracks",
    "Trajectories",
    "apply_filters", "drift_deviation", "drift_filter", "lowpass_trajectories", "threshold_filter",
    "track_klt",
    "track_points", "track_step", "trajectories_from_tracks", "uniformity_filter",
]
