"""Multi-camera calibration: reference-bar self-calibrating bundle adjustment (LSMTA §2.1)
and the virtual calibration object (Davis §3.2)."""

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
from .targets import Blobs, TargetTracks, detect_blobs, track_targets

__all__ = [
    "DEFAULT_INTRINSICS", "INTRINSIC_NAMES", "PARAMETER_NAMES", "Bar", "Blobs",
    "BundleResult", "TargetTracks", "bundle_adjust", "camera_to_params", "detect_blobs",
    "params_to_camera", "project_params", "relative_orientation_start", "scaled",
    "track_targets",
]
