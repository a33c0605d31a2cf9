"""The synthetic world and its ground truth: rigs, a textured articulated body, its motions,
and a ray-cast renderer. Library code outside ``lsmta.synth`` never imports it; notebooks and
tests use it to make data and to score results."""

from .body import Body, Motion, Part, SolidTexture, arm_wave, make_body, walk
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
from .rigs import ring_rig, triplet_rig

__all__ = [
    "BACKGROUND", "NOTHING", "Background", "Body", "Motion", "Part", "RenderedFrame", "Renderer",
    "Scene", "SolidTexture", "SurfaceProjection", "arm_wave", "cast_body", "make_background",
    "make_body", "project_surface_points", "ring_rig", "triplet_rig", "walk",
]
