"""The full-body fit on the generated walk, scored against the truth after the fact.

Data (truth as an input, said here and in notebook 20): the 3-D points are the generator's
surface samples of every part facing the silhouette camera (no occlusion test; or from all
round the body, :func:`walk_observations`), with
Gaussian noise and planted outliers (:func:`lsmta.synth.body.surface_samples`): the LSMTA
system measures only the arm. The silhouettes are the snakes' contours of
:mod:`lsmta.evaluation.silhouettes` (background model, trajectory prediction), turned into
lines of sight of that camera.

Scores
    joint angles: for each joint, the direction of the child's bone in its parent's frame,
    fitted against true (degrees; the model's segment frames are turned so that at rest
    they coincide with the generator's part frames, both body-aligned); the pelvis: the
    angle of the rotation between the fitted and the true pelvis frame. Twist about a bone
    is not scored (the walk has none, and a straight limb does not show it).
    segment lengths: joint-to-joint distances of the fitted skeleton against the
    generator's (upper arm, forearm, thigh, shank, trunk: hip-level joint to the neck,
    shoulder width, hip width).
    skin: vertices of the fitted B-spline skin (those not inside another segment's skin)
    to the true body surface, and samples of the true outer surface to the skin mesh
    (exact distances, :mod:`lsmta.synth.surface`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body.full_fit import FullBodyFit
from ..body.skin import SkinParams, merge_patches, model_skin
from ..synth.body import Body, Motion, inside_parts, surface_samples
from ..synth.surface import distance_to_body

# fitted segment -> generator part, and each part's bone direction in its own frame
PART = {"trunk": "torso"}
BONE = {"torso": (0.0, 0.0, 1.0), "head": (0.0, 0.0, 1.0), "foot_r": (0.0, 1.0, 0.0),
        "foot_l": (0.0, 1.0, 0.0)}
MAJOR = {"trunk": ("pelvis", "trunk")} | {
    f"{j}_{s}": (p.format(s), c.format(s)) for s in ("r", "l") for j, p, c in (
        ("shoulder", "trunk", "upper_arm_{}"), ("elbow", "upper_arm_{}", "forearm_{}"),
        ("hip", "pelvis", "thigh_{}"), ("knee", "thigh_{}", "shank_{}"))}
MINOR = {"neck": ("trunk", "head")} | {
    f"{j}_{s}": (p.format(s), c.format(s)) for s in ("r", "l") for j, p, c in (
        ("wrist", "forearm_{}", "hand_{}"), ("ankle", "shank_{}", "foot_{}"))}
LENGTHS = {"upper_arm": ("shoulder_r_c", "elbow_r", "upper_arm_r", "forearm_r"),
           "forearm": ("elbow_r", "wrist_r", "forearm_r", "hand_r"),
           "thigh": ("hip_r_c", "knee_r", "thigh_r", "shank_r"),
           "shank": ("knee_r", "ankle_r", "shank_r", "foot_r"),
           "trunk": ("trunk_c", "neck_c", "torso", "head"),
           "shoulder width": ("shoulder_r_c", "shoulder_l_c", "upper_arm_r", "upper_arm_l"),
           "hip width": ("hip_r_c", "hip_l_c", "thigh_r", "thigh_l")}


def _part(name):
    return PART.get(name, name)


def _model_frames(fit: FullBodyFit) -> np.ndarray:
    """Segment rotations ``(T, S, 3, 3)`` turned to coincide with the generator's at rest."""
    m = fit.model
    F = m.frames(fit.angles, fit.scales, base=fit.base)[..., :3, :3]
    F0 = m.frames(np.zeros((1, m.skeleton.n_joints)), fit.scales)[0, :, :3, :3]
    return F @ np.swapaxes(F0, -1, -2)[None]


def joint_angle_errors(fit: FullBodyFit, body: Body, motion: Motion, frames, *,
                       joints=None) -> dict:
    """Angle errors ``(T,)`` in degrees per joint (module docstring) and for the pelvis."""
    joints = MAJOR if joints is None else joints
    m = fit.model
    A = _model_frames(fit)
    G = body.part_poses(motion, frames=frames)[..., :3, :3]
    out = {}
    for name, (parent, child) in joints.items():
        sp, sc = m.names.index(parent), m.names.index(child)
        gp, gc = body.index(_part(parent)), body.index(_part(child))
        u = np.asarray(BONE.get(_part(child), (0.0, 0.0, -1.0)))
        true = np.einsum("tji,tjk,k->ti", G[:, gp], G[:, gc], u)
        ours = np.einsum("tji,tjk,k->ti", A[:, sp], A[:, sc], u)
        out[name] = np.degrees(np.arccos(np.clip(np.sum(true * ours, axis=1), -1, 1)))
    sp, gp = m.names.index("pelvis"), body.index("pelvis")
    R = np.swapaxes(A[:, sp], -1, -2) @ G[:, gp]
    out["pelvis (orientation)"] = np.degrees(np.arccos(np.clip(
        (np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    return out


def length_errors(fit: FullBodyFit, body: Body) -> dict:
    """(fitted, true) joint-to-joint lengths in mm (module docstring)."""
    m = fit.model
    X = m.skeleton.transforms(np.zeros((1, m.skeleton.n_joints)), fit.scales)[0, :, :3, 3]
    rest = Motion(name="rest", fps=25.0, root_position=np.zeros((1, 3)),
                  joint_angles=np.zeros((1, len(body.parts), 3)), part_names=tuple(body.names))
    Y = body.part_poses(rest)[0, :, :3, 3]
    names = m.skeleton.names
    return {k: (float(np.linalg.norm(X[names.index(a)] - X[names.index(b)])),
                float(np.linalg.norm(Y[body.index(p)] - Y[body.index(q)])))
            for k, (a, b, p, q) in LENGTHS.items()}


@dataclass(frozen=True, eq=False)
class SkinScore:
    """Distances (mm) of one frame's fitted skin to the true body, both ways.

    Attributes
    ----------
    to_truth : (V,) array
        |distance| of the skin's outer vertices to the true surface.
    segment : (V,) int array
        The fitted segment of each of those vertices.
    from_truth : (N,) array
        Distance of true outer-surface samples to the skin mesh.
    open_edges : int
        Of the merged mesh (0: every patch closed).
    """

    to_truth: np.ndarray
    segment: np.ndarray
    from_truth: np.ndarray
    open_edges: int


def skin_score(fit: FullBodyFit, body: Body, motion: Motion, frame_index: int, frame: int, *,
               n_samples: int = 300, rng=None, skin_params: SkinParams | None = None) -> SkinScore:
    """Score the skin of the fit's frame ``frame_index`` (the walk's frame ``frame``)."""
    m, t = fit.model, frame_index
    patches = model_skin(m, fit.angles[[t]], fit.scales, fit.radii, base=fit.base[[t]],
                         params=skin_params or SkinParams(n_u=36, n_v=28))
    mesh = merge_patches(patches)
    v = np.vstack([p.vertices for p in patches])
    seg = np.concatenate([np.full(len(p.vertices), k) for k, p in enumerate(patches)])
    d = m.all_distances(v, fit.angles[[t]], fit.scales, fit.radii, base=fit.base[[t]])
    d[np.arange(len(v)), seg] = np.inf
    outer = d.min(axis=1) >= 0
    poses = body.part_poses(motion, frames=frame)[0]
    to_truth = np.abs(distance_to_body(body, poses, v[outer]))
    part, local = body.sample_surface(n_per_part=n_samples, rng=rng)
    world = np.einsum("nij,nj->ni", poses[part, :3, :3], local) + poses[part, :3, 3]
    world = world[~inside_parts(body, poses, world, exclude=part)]
    _, closest = mesh.find_closest_cell(world, return_closest_point=True)
    return SkinScore(to_truth=to_truth, segment=seg[outer],
                     from_truth=np.linalg.norm(world - closest, axis=1),
                     open_edges=int(mesh.n_open_edges))


@dataclass(frozen=True, eq=False)
class WalkObservations:
    """A few frames of the walk as the fit sees them.

    Attributes
    ----------
    frames : (T,) int array
        Frames of the walk.
    points : tuple of (N, 3) arrays
        Noisy surface points with outliers (truth input; module docstring).
    rays : tuple of (origins, directions)
        Lines of sight through the snake's contour points in each frame.
    camera_centre : (3,) array
    is_outlier : tuple of (N,) bool arrays
        Which points were planted as outliers (for scoring only).
    """

    frames: np.ndarray
    points: tuple
    rays: tuple
    camera_centre: np.ndarray
    is_outlier: tuple


def walk_observations(data, contours, frames, *, n_points: int = 1500, noise_mm: float = 1.0,
                      outlier_share: float = 0.05, around: bool = False,
                      rng=None) -> WalkObservations:
    """Points and lines of sight for ``frames`` of a
    :class:`~lsmta.evaluation.silhouettes.SilhouetteWalk` whose snake contours are
    ``contours (T_all, n, 2)`` (pixels); the points face the camera (the papers' rig in
    front of the person) or, with ``around``, come from all round the body (a studio with
    cameras on every side)."""
    rng = np.random.default_rng(rng)
    body, motion, cam = data.scene.body, data.scene.motion, data.camera
    pts, out, rays = [], [], []
    for t in frames:
        p, _, part = surface_samples(body, motion, int(t), rng=rng, parts=body.names, n=n_points,
                                     noise_mm=noise_mm, outlier_share=outlier_share,
                                     view_from=None if around else cam.C)
        pts.append(p)
        out.append(part < 0)
        rays.append(cam.rays(np.asarray(contours[int(t)], float)))
    return WalkObservations(frames=np.asarray(frames, int), points=tuple(pts), rays=tuple(rays),
                            camera_centre=np.asarray(cam.C, float), is_outlier=tuple(out))
