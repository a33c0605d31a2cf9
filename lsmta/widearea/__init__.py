"""Wide-area LED tracking (Davis 2002, ch. 3): LED detection in images, a constant-velocity
Kalman filter per target updated by single-camera 2-D observations from unsynchronised
cameras, association, the late-observation and queue policies, track birth and death."""

from .association import Association, associate
from .detection import (
    DetectionParams,
    Detections,
    Threshold,
    background_threshold,
    detect,
    needs_new_threshold,
    relearn_threshold,
    search_mask,
)
from .kalman import ekf_update, predict, projection_jacobian, transition
from .management import Birth, find_birth, ray_distance, starved
from .observations import Frames
from .scheduler import POLICIES, Schedule, schedule
from .tracker import TrackerParams, TrackingResult, WideAreaTrack, track

__all__ = [
    "POLICIES", "Association", "Birth", "DetectionParams", "Detections", "Frames",
    "Schedule", "Threshold", "background_threshold", "detect", "needs_new_threshold",
    "relearn_threshold", "search_mask",
    "TrackerParams", "TrackingResult", "WideAreaTrack", "associate",
    "ekf_update", "find_birth", "predict",
    "projection_jacobian", "ray_distance", "schedule", "starved", "track",
    "transition",
]
