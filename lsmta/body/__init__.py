"""Body modelling (Plänkers, Fua & D'Apuzzo 1999): skeleton, metaballs, fitting to 3-D data.

``skeleton``   single-DoF joints about local z; forward kinematics and analytic Jacobians
``metaballs``  ellipsoidal metaballs (eqs. 4-7), the three-ball limb, skin distance, iso-surface
``arm``        the arm model (3-DoF shoulder, elbow, wrist) and its initialisation from joints
``full_body``  the full-body template (30 single-DoF joints, 15 segments; lengths from
               anthropometric ratios of one stature) with anatomical joint limits
``full_fit``   the full body fitted to frames of points and lines of sight (shape shared)
``skin``       B-spline skin: ray-cast cross-sections of the implicit surface, one bicubic
               patch per part, closed triangle meshes (pyvista merge)
``silhouette`` the silhouette term: closest approach of a line of sight to the skin and its
               analytic derivative by the joint angles (envelope theorem); fit_pose
``fitting``    weighted robust least squares over radii, limb scales and joint angles (eq. 14)
``posterior``  emcee posterior of one frame's radii and lengths
``functional_joints`` joint centres (SCoRE) and hinge axes (SARA) from two segments' points,
               with what the motion determined

Angles are in radians, lengths in mm.
"""

from .arm import JOINTS, LIMBS, angles_from_joints, arm_model, base_poses, shoulder_angles
from .fitting import BodyFit, FitParams, FitStatus, ModelState, fit_frame, fit_sequence
from .full_body import full_body_model, limit_violations, limits, template_size
from .full_fit import BodyShape, FullBodyFit, FullBodyFitParams, fit_full_body
from .functional_joints import (
    JointCentre,
    JointStatus,
    SegmentMotion,
    fit_joint,
    fit_joint_from_points,
    segment_motion,
)
from .mesh import BodyMesh, body_mesh, body_volume, metaball_mesh, metaball_volume, write_mesh
from .metaballs import (
    THRESHOLD,
    MetaballModel,
    Segment,
    SkinDistance,
    ellipsoid_distance,
    field,
    iso_surface,
    potential,
    surface_distance,
    surface_distance_terms,
)
from .posterior import LimbPosterior, sample_limb_posterior
from .silhouette import PoseFit, PoseFitParams, SilhouetteTerms, fit_pose, silhouette_terms
from .skeleton import Joint, Skeleton, rot_x, rot_y, rot_z
from .skin import SkinParams, SkinPatch, merge_patches, model_skin, skin_patch

__all__ = [
    "JOINTS", "LIMBS", "THRESHOLD", "BodyFit", "FitStatus", "Joint", "LimbPosterior",
    "MetaballModel",
    "ModelState", "Segment", "Skeleton", "angles_from_joints", "arm_model", "base_poses",
    "ellipsoid_distance", "field", "fit_frame", "fit_sequence", "iso_surface", "potential",
    "rot_x", "rot_y", "rot_z", "sample_limb_posterior", "shoulder_angles", "surface_distance",
    "surface_distance_terms", "SkinDistance", "FitParams", "SkinParams", "SkinPatch",
    "merge_patches", "model_skin", "skin_patch", "SilhouetteTerms", "silhouette_terms",
    "PoseFit", "PoseFitParams", "fit_pose", "BodyShape", "FullBodyFit", "FullBodyFitParams",
    "fit_full_body",
    "full_body_model", "limit_violations", "limits",
    "template_size", "BodyMesh", "body_mesh", "body_volume", "metaball_mesh", "metaball_volume",
    "write_mesh", "JointCentre", "JointStatus", "SegmentMotion", "fit_joint",
    "fit_joint_from_points", "segment_motion",
]
