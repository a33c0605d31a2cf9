"""The synthetic world and its ground truth: rigs, a textured articulated body, its motions,
and a ray-cast renderer. Library code outside ``lsmta.synth`` never imports it; notebooks and
tests use it to make data and to score results."""

from .body import (
    RANGE_OF_MOTION_PHASES,
    Body,
    Motion,
    Part,
    SolidTexture,
    arm_wave,
    make_body,
    range_of_motion,
    walk,
)
from .pantilt import (
    PanTiltData,
    calibration_sweeps,
    evaluation_grid,
    intrinsic_target,
    pantilt_head,
    side_to_side,
)
from .render import (
    BACKGROUND,
    NOTHING,
    Background,
    RenderedFrame,
    Renderer,
    Scene,
    SurfaceProjection,
    cast_body,
    make_background,
    project_surface_points,
)
from .rigs import ring_rig, studio_rig, triplet_rig

__all__ = [
    "BACKGROUND", "NOTHING", "RANGE_OF_MOTION_PHASES", "Background", "Body", "Motion",
    "PanTiltData", "Part", "RenderedFrame", "Renderer", "Scene", "SolidTexture",
    "SurfaceProjection", "arm_wave", "range_of_motion",
    "calibration_sweeps", "cast_body", "evaluation_grid", "intrinsic_target", "make_background",
    "make_body", "pantilt_head", "project_surface_points", "ring_rig", "side_to_side",
    "studio_rig",
    "triplet_rig", "walk",
]
