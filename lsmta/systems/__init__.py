"""The papers' whole systems, pixels in, models out, calling the rooms of the library.

A system receives what a user has (videos, a bar and its length, the cameras as built) and
never the generator's truth: nothing here imports :mod:`lsmta.synth` or
:mod:`lsmta.evaluation` (a test checks it).

``body``      the LSMTA system (D'Apuzzo, Plänkers & Fua 2000): bar calibration, image
              noise, surfaces, surface tracking, trajectories and filters, arm model
``rig``       its first stage: the rig calibrated from a bar video, in the user's world
``surfaces``  surfaces of chosen frames from automatic seeds
``mixed_scale`` Davis's mixed-scale system, closed: ceiling LED frames, the streaming
              wide-area tracker, predicted aim of pan-tilt heads, close-up marker video,
              triangulation at the read-back angles, the face filled per frame
"""

from .body import (
    ArmFit,
    ArmFitParams,
    BodyCapture,
    BodySystemParams,
    FilterParams,
    capture_body,
    fit_arm,
    fit_self_consistent,
    observed_frames,
    track_surface,
)
from .mixed_scale import (
    CeilingFeed,
    MixedScaleCapture,
    MixedScaleParams,
    body_offsets,
    capture_mixed_scale,
    coast_head,
    first_settled,
    head_target,
    lead_displacement,
    reacquisition_seeds,
)
from .rig import RigCalibration, calibrate_rig
from .surfaces import SurfaceParams, measure_surfaces, working_distance

__all__ = [
    "ArmFit", "ArmFitParams", "BodyCapture", "BodySystemParams", "CeilingFeed",
    "FilterParams", "MixedScaleCapture", "MixedScaleParams", "capture_mixed_scale",
    "body_offsets", "coast_head", "first_settled", "head_target", "lead_displacement",
    "reacquisition_seeds",
    "RigCalibration", "SurfaceParams", "calibrate_rig", "capture_body", "fit_arm",
    "fit_self_consistent", "measure_surfaces", "observed_frames", "track_surface",
    "working_distance",
]
