"""Wide-area LED tracking (Davis 2002, ch. 3): LED detection in images, a constant-velocity
Kalman filter per target updated by single-camera 2-D observations from unsynchronised
cameras, association, the late-observation and queue policies, track birth and death."""

from .association import Association, associate, innovation_gate
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
from .kalman import (
    ekf_update,
    kalman_update,
    measurement,
    predict,
    process_noise,
    projection_jacobian,
    transition,
)
from .management import Birth, RayPool, find_birth, ray_distance, starved
from .observations import FrameIntake, Frames, Screened, screen_frame
from .scheduler import POLICIES, Schedule, schedule
from .tracker import EstimatorParams, TrackingResult, WideAreaTrack, track

__all__ = [
    "POLICIES", "Association", "Birth", "DetectionParams", "Detections", "EstimatorParams",
    "FrameIntake", "Frames", "RayPool", "Schedule", "Screened", "Threshold", "TrackingResult",
    "WideAreaTrack", "associate", "background_threshold", "detect", "ekf_update", "find_birth",
    "innovation_gate", "kalman_update", "measurement", "needs_new_threshold", "predict",
    "process_noise", "projection_jacobian", "ray_distance", "relearn_threshold", "schedule",
    "screen_frame", "search_mask", "starved", "track", "transition",
]
