"""Multi-camera calibration: reference-bar self-calibrating bundle adjustment (LSMTA §2.1),
the virtual calibration object (Davis §3.2), the one-call wand calibration, and a given
rig refined from tie points found in its own frames."""

from .approximations import relative_orientation_start, resect_pnp, scaled
from .bundle import (
    DEFAULT_INTRINSICS,
    INTRINSIC_NAMES,
    PARAMETER_NAMES,
    Bar,
    BundleParams,
    BundleResult,
    bundle_adjust,
    camera_to_params,
    params_to_camera,
    project_params,
)
from .chain import ChainStart, chain_cameras, datum_from_distance, shared_points
from .refine import CameraRefinement, RefineParams, refine_cameras
from .result import CalibrationResult
from .targets import Blobs, TargetParams, TargetStatus, TargetTracks, detect_blobs, track_targets
from .tie_lsm import TieLSM, TieLSMParams, refine_tie_points
from .tie_points import TieParams, TiePoints, find_tie_points, recording_inliers
from .virtual_object import (
    IMPROVED_ALTERNATION,
    AlternationParams,
    ConvergenceHistory,
    alternate,
    joint_adjustment,
    projection_error,
    resect,
    resect_all,
    triangulate_optimal,
)
from .wand import WandCalibration, WandStatus, calibrate_wand

__all__ = [
    "DEFAULT_INTRINSICS", "IMPROVED_ALTERNATION", "INTRINSIC_NAMES", "PARAMETER_NAMES",
    "AlternationParams", "Bar", "Blobs", "BundleParams", "BundleResult", "CalibrationResult",
    "CameraRefinement", "ChainStart", "ConvergenceHistory", "RefineParams", "TargetParams",
    "TargetStatus", "TargetTracks", "TieLSM", "TieLSMParams", "TieParams", "TiePoints",
    "WandCalibration", "WandStatus",
    "alternate", "bundle_adjust", "calibrate_wand", "camera_to_params", "chain_cameras",
    "datum_from_distance", "detect_blobs", "find_tie_points", "joint_adjustment",
    "params_to_camera", "project_params", "projection_error", "refine_cameras",
    "recording_inliers", "refine_tie_points",
    "relative_orientation_start", "resect", "resect_all", "resect_pnp", "scaled",
    "shared_points", "track_targets", "triangulate_optimal",
]
