"""Pan-tilt cameras (Davis 2002, ch. 4): models, calibration, aiming, latency.

``model``      the simple (eq. 1) and general (eq. 2) models behind one interface
``fitting``    intrinsics, then home pose and axes, by nonlinear least squares (eq. 4)
``posterior``  emcee samples of the calibration parameters
``aiming``     the setting that centres a world point: local search and direct solve
``latency``    the control loop with motor latency, Kalman estimate, prediction, damping
``steering``   the steering policy: lead prediction (braking, height held), head choice
               with coasting on the body, damped aim of several heads

Angles are in degrees throughout.
"""

from .aiming import Aim, aim, aim_least_squares
from .fitting import (
    AXIS_NAMES,
    POSE_NAMES,
    Fit,
    calibrate,
    calibrate_intrinsics,
    dlt_camera,
    model_from_params,
    params_from_model,
    project_pantilt_params,
    projection_errors,
)
from .latency import (
    Control,
    KalmanCV,
    Motor,
    TrackingRun,
    constant_velocity_filter,
    simulate_tracking,
)
from .model import (
    EVI_D30_PAN_LIMITS,
    EVI_D30_TILT_LIMITS,
    PanTiltCamera,
    axis_rotations,
    pose_arrays,
)
from .posterior import Posterior, sample_posterior
from .steering import (
    HeadChooser,
    LeadPredictor,
    Pointer,
    Steering,
    SteeringParams,
    SteeringStep,
    body_offsets,
    coast_head,
    head_target,
    lead_displacement,
)

__all__ = [
    "AXIS_NAMES", "Aim", "Control", "EVI_D30_PAN_LIMITS", "EVI_D30_TILT_LIMITS", "Fit",
    "HeadChooser", "KalmanCV", "LeadPredictor", "Motor", "POSE_NAMES", "PanTiltCamera",
    "Pointer", "Posterior", "Steering", "SteeringParams", "SteeringStep", "TrackingRun", "aim",
    "aim_least_squares", "axis_rotations", "body_offsets", "calibrate", "calibrate_intrinsics",
    "coast_head", "constant_velocity_filter", "dlt_camera", "head_target", "lead_displacement",
    "model_from_params", "params_from_model", "pose_arrays", "project_pantilt_params",
    "projection_errors", "sample_posterior", "simulate_tracking",
]
