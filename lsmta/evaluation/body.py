"""Arm-fitting trials: ground truth of the generated arm, tracked joints, scores.

The generator's arm is the textured ellipsoid body of :mod:`lsmta.synth.body` (one
ellipsoid per part): the fitted three-ball model never has the exact true shape, as with a
real arm. Its truth in the fit's convention: the torso frame, the shoulder in it, bone
lengths (upper arm 300 mm, forearm 265 mm), and the angles ``(b, a, c, elbow)`` of
:mod:`lsmta.body.arm` (the generator's forearm twist is a rotation about the upper arm's
axis, so it joins the shoulder's ``c``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_rng
from ..body import ModelState, angles_from_joints, arm_model, iso_surface, shoulder_angles
from ..body.arm import base_poses
from ..body.fitting import BodyFit, FitParams, FitStatus, fit_sequence
from ..synth.body import Body, Motion, inside_parts, surface_samples

ARM_PARTS = ("upper_arm_r", "forearm_r", "hand_r")


@dataclass(frozen=True, eq=False)
class ArmTruth:
    """Ground truth of the right arm over T frames.

    Attributes
    ----------
    frames : (T,) int array
    torso_poses : (T, 4, 4) array
    shoulder_local : (3,) array
        Shoulder in the torso frame, mm.
    lengths : (2,) array
        Upper-arm and forearm lengths, mm.
    angles : (T, 5) array
        ``(b, a, c, elbow, wrist)`` radians, the convention of :func:`lsmta.body.arm_model`.
    joints : (T, 3, 3) array
        World shoulder, elbow, wrist per frame, mm.
    """

    frames: np.ndarray
    torso_poses: np.ndarray
    shoulder_local: np.ndarray
    lengths: np.ndarray
    angles: np.ndarray
    joints: np.ndarray


def arm_truth(body: Body, motion: Motion, frames) -> ArmTruth:
    """The right arm's truth in the frames ``frames``."""
    frames = np.atleast_1d(np.asarray(frames, int))
    poses = body.part_poses(motion, frames=frames)
    it, iu, iff, ih = (body.index(n) for n in ("torso",) + ARM_PARTS)
    torso = poses[:, it]
    fore_a = motion.angle("forearm_r")[frames]                  # (T, 3)
    Rf = poses[:, iff, :3, :3]
    c, s = np.cos(fore_a[:, 0]), np.sin(fore_a[:, 0])
    Rx_inv = np.zeros((len(frames), 3, 3))
    Rx_inv[:, 0, 0] = 1
    Rx_inv[:, 1, 1] = c
    Rx_inv[:, 1, 2] = s
    Rx_inv[:, 2, 1] = -s
    Rx_inv[:, 2, 2] = c
    U = np.einsum("tji,tjk->tik", torso[:, :3, :3], Rf @ Rx_inv)
    angles = np.concatenate([shoulder_angles(U), fore_a[:, :1], np.zeros((len(frames), 1))],
                            axis=1)
    joints = np.stack([poses[:, iu, :3, 3], poses[:, iff, :3, 3], poses[:, ih, :3, 3]], axis=1)
    return ArmTruth(frames=frames, torso_poses=torso,
                    shoulder_local=np.asarray(body.parts[iu].joint, float),
                    lengths=np.array([-body.parts[iff].joint[2], -body.parts[ih].joint[2]], float),
                    angles=angles, joints=joints)


def initial_state(truth: ArmTruth, *, rng: np.random.Generator | int | None = None,
                  joint_noise_mm: float = 15.0, width_mm: float = 70.0,
                  model=None) -> tuple[ModelState, np.ndarray]:
    """A starting state as from tracked joints: the true joints plus Gaussian noise, inverse
    kinematics, template lengths scaled to the tracked mean lengths, round template balls.

    Returns the state and the tracked joints ``(T, 3, 3)``.
    """
    rng = as_rng(rng)
    model = arm_model() if model is None else model
    tracked = truth.joints + rng.normal(0, joint_noise_mm, truth.joints.shape)
    angles, shoulder, lengths = angles_from_joints(truth.torso_poses, tracked[:, 0],
                                                   tracked[:, 1], tracked[:, 2])
    scales = np.array([lengths[:, 0].mean() / model.segments[0].length,
                       lengths[:, 1].mean() / model.segments[1].length, 1.0])
    size = np.array([[width_mm, width_mm], [width_mm, width_mm],
                     [width_mm * 0.6, width_mm * 0.6]])
    state = ModelState(angles=angles, shoulder=shoulder, scales=scales,
                       radii=model.simplified_radii(size, scales))
    return state, tracked


def true_skin(body: Body, motion: Motion, frame: int, *, n: int = 30000,
              rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Dense samples ``(M, 3)`` of the arm's outer skin in one frame (world mm)."""
    rng = as_rng(rng)
    poses = body.part_poses(motion, frames=frame)[0]
    part, local = body.sample_surface(n_per_part=n // 3, rng=rng, parts=ARM_PARTS)
    world = np.einsum("nij,nj->ni", poses[part, :3, :3], local) + poses[part, :3, 3]
    return world[~inside_parts(body, poses, world, exclude=part)]


def arm_distance(body: Body, motion: Motion, frame: int, points) -> np.ndarray:
    """Distance (mm) of world points ``(N, 3)`` to the true arm skin: the smallest
    first-order distance ``|k - 1| / |grad k|`` (``k`` the ellipsoid's implicit function
    ``sum (x / r)^2``, halved gradient) over the three arm ellipsoids."""
    poses = body.part_poses(motion, frames=frame)[0]
    pts = np.asarray(points, float)
    best = np.full(len(pts), np.inf)
    for name in ARM_PARTS:
        i = body.index(name)
        spec = body.parts[i]
        r = np.asarray(spec.radii, float)
        loc = (pts - poses[i, :3, 3]) @ poses[i, :3, :3] - np.asarray(spec.centre)
        k = np.sum((loc / r) ** 2, axis=1)
        g = 2 * np.linalg.norm(loc / r**2, axis=1)
        # distance along the gradient to the level k = 1 (exact for a sphere)
        d = np.abs(np.sqrt(k) - 1) * np.sqrt(k) * 2 / np.maximum(g, 1e-12)
        best = np.minimum(best, d)
    return best


def skin_error(fit_state: ModelState, t: int, model, truth: ArmTruth, body: Body,
               motion: Motion, *, spacing: float = 8.0, near=None,
               near_mm: float = 15.0) -> np.ndarray:
    """Distances (mm) from the fitted skin of frame ``t`` of the fit to the true arm skin.

    Vertices of the fitted iso-surface hidden inside non-arm body parts (the torso) are
    left out. With ``near`` (points ``(N, 3)``), only vertices within ``near_mm`` of one of
    them are scored: the skin where there was data.
    """
    base = base_poses(truth.torso_poses[t:t + 1], fit_state.shoulder[t])
    verts, _ = iso_surface(model, fit_state.angles[t:t + 1], fit_state.scales, fit_state.radii,
                           base=base, spacing=spacing)
    frame = int(truth.frames[t])
    poses = body.part_poses(motion, frames=frame)[0]
    others = np.array([i for i, p in enumerate(body.parts) if p.name not in ARM_PARTS])
    keep = np.ones(len(verts), bool)
    for i in others:
        spec = body.parts[i]
        loc = (verts - poses[i, :3, 3]) @ poses[i, :3, :3] - np.asarray(spec.centre)
        keep &= np.sum((loc / np.asarray(spec.radii)) ** 2, axis=1) >= 1.0
    if near is not None:
        pts = np.asarray(near, float)
        pts = pts[np.isfinite(pts).all(axis=1)]
        d, _ = cKDTree(pts).query(verts)
        keep &= d < near_mm
    return arm_distance(body, motion, frame, verts[keep])


def score_fit(fit: BodyFit, truth: ArmTruth) -> dict:
    """Errors of a fit against the truth: angles (degrees, per frame and joint), bone lengths
    (mm and %), shoulder position (mm)."""
    st = fit.state
    da = np.degrees(np.angle(np.exp(1j * (st.angles[:, :4] - truth.angles[:, :4]))))
    dl = fit.lengths[:2] - truth.lengths
    return {"angle_err_deg": da, "max_angle_err_deg": float(np.abs(da).max()),
            "length_err_mm": dl, "length_err_pct": 100 * dl / truth.lengths,
            "shoulder_err_mm": float(np.linalg.norm(st.shoulder.mean(axis=0)
                                                    - truth.shoulder_local))}


RIG_CENTRE = (0.0, -2500.0, 1100.0)   # the triplet rig's centre camera in the notebook (mm)


def controlled_points(body: Body, motion: Motion, truth: ArmTruth, *,
                      rng: np.random.Generator | int | None = None, n: int = 400,
                      noise_mm: float = 2.0, outlier_share: float = 0.1,
                      view_from=RIG_CENTRE) -> list:
    """Noisy samples of the arm's skin seen from the rig, one ``(n, 3)`` array per frame."""
    rng = as_rng(rng)


    return [surface_samples(body, motion, int(f), rng=rng, n=n, noise_mm=noise_mm,
                            outlier_share=outlier_share, view_from=view_from)[0]
            for f in truth.frames]


def fit_arm_trial(points, torso_poses, init: ModelState, *, params: FitParams | None = None,
                  tracked=None, model=None, full: bool = True, full_rounds: int = 3):
    """Simplified fit of a sequence (or one frame) with ``params`` (and ``tracked`` joints),
    then the full model from it (the same settings, at most ``full_rounds`` segmentation
    rounds).

    ``torso_poses`` ``(T, 4, 4)`` are given to the fit as known (in the notebook: the
    generator's exact torso poses, ``ArmTruth.torso_poses``); nothing else of the truth is
    used.

    Returns ``(simplified, full)`` :class:`~lsmta.body.BodyFit` (``full`` is None without
    ``full``).
    """
    model = arm_model() if model is None else model
    params = FitParams() if params is None else params
    simple = fit_sequence(model, points, torso_poses, init, params=params, tracked=tracked)
    if not full or simple.status == FitStatus.INIT_FAR:
        return simple, None
    return simple, fit_sequence(model, points, torso_poses, simple.state, tracked=tracked,
                                params=replace(params, shape="full", max_rounds=full_rounds))


def skin_errors(fit: BodyFit, truth: ArmTruth, body: Body, motion: Motion, *, model=None,
                frames=None, spacing: float = 8.0, points=None, near_mm: float = 15.0):
    """Distances (mm) of the fitted skin to the true skin, pooled over ``frames``
    (indices into the fit; default all); with ``points`` (one array per frame), only where
    there was data (:func:`skin_error`)."""
    model = arm_model() if model is None else model
    frames = range(len(truth.frames)) if frames is None else frames
    return np.concatenate([skin_error(fit.state, t, model, truth, body, motion,
                                      spacing=spacing, near_mm=near_mm,
                                      near=None if points is None else points[t])
                           for t in frames])


def true_skin_to_fit(fit: BodyFit, truth: ArmTruth, body: Body, motion: Motion, points, *,
                     model=None, frames=None, spacing: float = 8.0, near_mm: float = 15.0,
                     n: int = 30000, seed: int = 0) -> np.ndarray:
    """Distances (mm) from samples of the TRUE arm skin to the fitted skin, pooled over
    ``frames`` (indices into the fit; default all): the reverse of :func:`skin_errors`.

    Only true-skin samples within ``near_mm`` of a data point of their frame are scored
    (where there was data); the fitted skin is the marching-cubes mesh of
    :func:`lsmta.body.iso_surface` and the distance is to its triangles (VTK's implicit
    poly-data distance via pyvista), not to its vertices.
    """
    import pyvista as pv  # deferred: heavy (about 1 s to import), only this score needs it

    model = arm_model() if model is None else model
    frames = range(len(truth.frames)) if frames is None else frames
    rng = np.random.default_rng(seed)
    out = []
    for t in frames:
        st = fit.state
        base = base_poses(truth.torso_poses[t:t + 1], st.shoulder[t])
        verts, faces = iso_surface(model, st.angles[t:t + 1], st.scales, st.radii, base=base,
                                   spacing=spacing)
        mesh = pv.PolyData(verts, np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
        skin = true_skin(body, motion, int(truth.frames[t]), rng=rng, n=n)
        pts = np.asarray(points[t], float)
        pts = pts[np.isfinite(pts).all(axis=1)]
        d, _ = cKDTree(pts).query(skin)
        skin = skin[d < near_mm]
        probe = pv.PolyData(skin).compute_implicit_distance(mesh)
        out.append(np.abs(np.asarray(probe["implicit_distance"])))
    return np.concatenate(out)


def arm_point_errors(points, body: Body, motion: Motion, frame: int) -> np.ndarray:
    """Distance (mm) of measured points ``(N, 3)`` to the true arm skin."""
    return arm_distance(body, motion, frame, points)
