"""The papers' whole systems, pixels in, models out, calling the rooms of the library.

A system receives what a user has (videos, a bar and its length, the cameras as built) and
never the generator's truth: nothing here imports :mod:`lsmta.synth` or
:mod:`lsmta.evaluation` (a test checks it).

``capture``   the LSMTA system on any recording with calibrated cameras: view groups, image
              noise, surfaces, surface tracking, trajectories and filters, optionally the
              arm model; BodyCapture
``views``     which cameras see the same side (the view groups)
``markers``   markers found per view, tracked in 2-D, joined across views by their paths
``arm``       the arm model stage (Plänkers' arm fitted to the trajectories)
``body``      the papers' system (D'Apuzzo, Plänkers & Fua 2000): bar calibration, then
              capture_recording with the arm model
``rig``       the rig calibrated from a bar video, in the user's world
``refinement`` or: a camera file's rig refined from the recording itself (tie points,
              the file's cameras as priors, held-out places to check it)
``surfaces``  surfaces of chosen frames from automatic seeds
``rectified`` or: a pair's surface from its rectified images (SurfaceParams(method="rectified"))
``subject``   the moving subject's pixels from the recording (SurfaceParams(subject_mask))
``more_views`` a pair's points matched in every other camera that sees them (add_views)
``mixed_scale`` Davis's mixed-scale system, closed: ceiling LED frames, the streaming
              wide-area tracker, the pan-tilt heads steered (:mod:`lsmta.pantilt.steering`),
              close-up marker video, triangulation at the read-back angles, the face filled
              per frame
``ceiling``   its ceiling input (CeilingFeed), checked, in arrival order
``close_up``  pieces of its close-up stages: the first settled frame, the best pair of heads
              per marker (any number of heads), re-acquisition seeds
``face_identification`` the face markers identified without an operator: dots, stereo, the
              face model's layout fitted (rigid ICP with an optimal assignment, then its
              expressions) and each dot labelled
``checks``    argument checks shared by the systems (cameras, videos, heads as devices)
"""

from .arm import ArmFit, ArmFitParams, fit_arm, fit_self_consistent, observed_frames
from .body import BodySystemParams, capture_body, capture_walk
from .capture import (
    BodyCapture,
    CaptureParams,
    FilterParams,
    ViewCapture,
    capture_recording,
    track_surface,
)
from .ceiling import CeilingFeed
from .close_up import PairChoice, best_pairs, first_settled, reacquisition_seeds
from .face_identification import FaceIdentification, IdentifyParams, identify_face_markers
from .markers import (
    MarkerCapture,
    MarkerParams,
    Tracker2D,
    capture_markers,
    nyquist_checked,
)
from .mixed_scale import (
    MixedScaleCapture,
    MixedScaleParams,
    capture_mixed_scale,
    fill_face,
    triangulate_frames,
)
from .readback import ReadbackRefinement, refine_readback
from .refinement import RigRefinement, RigRefinementParams, refine_rig
from .rig import Levelling, RigCalibration, calibrate_rig, level_rig
from .surfaces import SurfaceParams, measure_surfaces, working_distance
from .views import ViewGroup, axis_angles, view_groups

__all__ = [
    "ArmFit", "ArmFitParams", "BodyCapture", "BodySystemParams", "CaptureParams",
    "CeilingFeed", "ViewCapture", "ViewGroup", "axis_angles", "capture_recording",
    "view_groups", "MarkerCapture", "MarkerParams", "Tracker2D", "capture_markers",
    "nyquist_checked",
    "FilterParams", "MixedScaleCapture", "MixedScaleParams", "capture_mixed_scale",
    "triangulate_frames", "fill_face", "ReadbackRefinement", "refine_readback",
    "PairChoice", "best_pairs", "first_settled", "reacquisition_seeds",
    "FaceIdentification", "IdentifyParams", "identify_face_markers",
    "RigCalibration", "RigRefinement", "RigRefinementParams", "SurfaceParams", "calibrate_rig",
    "capture_body", "capture_walk", "fit_arm", "refine_rig", "Levelling", "level_rig",
    "fit_self_consistent", "measure_surfaces", "observed_frames", "track_surface",
    "working_distance",
]
