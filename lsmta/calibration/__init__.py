"""Multi-camera calibration: reference-bar self-calibrating bundle adjustment (LSMTA §2.1),
the virtual calibration object (Davis §3.2) and the one-call wand calibration."""

from .approximations import relative_orientation_start, scaled
from .bundle import (
    DEFAULT_INTRINSICS,
    INTRINSIC_NAMES,
    PARAMETER_NAMES,
    Bar,
    BundleResult,
    bundle_adjust,
    camera_to_params,
    params_to_camera,
    project_params,
)
from .targets import Blobs, TargetStatus, TargetTracks, detect_blobs, track_targets
from .virtual_object import (
    ConvergenceHistory,
    alternate,
    joint_adjustment,
    projection_error,
    resect,
    triangulate_optimal,
)
from .wand import WandCalibration, WandStatus, calibrate_wand

__all__ = [
    "DEFAULT_INTRINSICS", "INTRINSIC_NAMES", "PARAMETER_NAMES", "Bar", "Blobs",
    "BundleResult", "ConvergenceHistory", "TargetStatus", "TargetTracks", "alternate",
    "bundle_adjust",
    "camera_to_params", "detect_blobs", "joint_adjustment", "params_to_camera",
    "project_params", "projection_error", "relative_orientation_start", "resect", "scaled",
    "track_targets", "triangulate_optimal", "WandCalibration", "WandStatus", "calibrate_wand",
]
