"""Wide-area LED tracking (Davis 2002, ch. 3): LED detection in images, a constant-velocity
Kalman filter per target updated by single-camera 2-D observations from unsynchronised
cameras, association, the late-observation and queue policies, track birth and death."""

from .association import Association, associate, innovation_gate
from .detection import (
    GRIDS,
    DetectionParams,
    Detections,
    Threshold,
    background_threshold,
    detect,
    needs_new_threshold,
    noise_threshold,
    relearn_threshold,
    search_mask,
)
from .joining import CameraJoin, JoinParams, JoinStatus, calibrate_from_targets
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
from .observations import FrameIntake, Frames, Screened, screen_frame, screen_values
from .scheduler import POLICIES, Schedule, schedule
from .search import FrameFeatures, SearchSetup, search_frame, search_setup
from .stages import CameraStatus
from .tracker import (
    EstimatorParams,
    FrameStatus,
    ImagePrediction,
    TargetEstimate,
    TrackingResult,
    WideAreaTrack,
    WideAreaTracker,
    track,
)

__all__ = [
    "GRIDS", "POLICIES", "Association", "Birth", "CameraJoin", "CameraStatus", "DetectionParams",
    "Detections", "EstimatorParams", "FrameFeatures", "FrameIntake", "FrameStatus", "Frames",
    "ImagePrediction", "JoinParams", "JoinStatus", "RayPool", "Schedule", "Screened",
    "SearchSetup", "TargetEstimate", "Threshold", "TrackingResult", "WideAreaTrack",
    "WideAreaTracker", "associate", "background_threshold", "calibrate_from_targets", "detect",
    "ekf_update", "find_birth", "innovation_gate", "kalman_update", "measurement",
    "needs_new_threshold", "noise_threshold", "predict", "process_noise",
    "projection_jacobian", "ray_distance", "relearn_threshold", "schedule", "screen_frame",
    "screen_values", "search_frame", "search_mask", "search_setup", "starved", "track",
    "transition",
]
