"""The arm model stage of the LSMTA system: Plänkers' arm fitted to filtered trajectories.

Started where the data put it (:func:`~lsmta.body.start.arm_start`: rigid groups of the
trajectories, functional joints), fitted in sequence mode to the arm groups' points, first
the simplified model, then the full one. The optional last stage of
:func:`~lsmta.systems.capture_recording`, always run by :func:`~lsmta.systems.capture_body`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_scalar
from ..body import BodyFit, FitParams, ModelState, arm_model, fit_sequence
from ..body.start import ArmStart, arm_start
from ..tracking import Trajectories
from .checks import check_cameras


@dataclass(frozen=True)
class ArmFitParams:
    """The arm model stage (:func:`fit_arm`).

    Attributes
    ----------
    sigma_prior_mm : float
        A-priori standard deviation of a 3-D point; replaced by the fit's own robust
        residual scale when they differ by more than 10 % (notebook 07's rule).
    sigma_joint_mm : float
        Standard deviation of the functional joints (shoulder, elbow) as observations.
    full_rounds : int
        Segmentation rounds of the full model after the simplified one.
    rigidity_mm : float
        Tolerance of the rigid groups (:func:`~lsmta.tracking.segmentation.rigid_groups`).
    min_segment_points : int
        The model is fitted in the frames where the upper arm and the forearm each have at
        least this many points: without points of its own a segment's angle is free (a
        forearm that stops being tracked has no elbow angle to recover).
    """

    sigma_prior_mm: float = 2.0
    sigma_joint_mm: float = 15.0
    full_rounds: int = 3
    rigidity_mm: float = 4.0
    min_segment_points: int = 10


@dataclass(frozen=True, eq=False)
class ArmFit:
    """The arm model fitted to trajectories (:func:`fit_arm`).

    Attributes
    ----------
    start : ArmStart
        Where the data put the arm: rigid groups, joints, torso poses, the arm's points
        (all frames).
    frames : (F,) int array
        The frames fitted (both arm segments tracked); the fits' frame i is ``frames[i]``.
    simplified, full : BodyFit
        The simplified model, then the full model started from it.
    sigma_mm : float
        The points' standard deviation the fits used, mm.
    """

    start: ArmStart
    frames: np.ndarray
    simplified: BodyFit
    full: BodyFit
    sigma_mm: float


def fit_arm(trajectories: Trajectories, cameras, *, settings: ArmFitParams | None = None,
            rng: np.random.Generator | int | None = None) -> ArmFit:
    """Fit the arm model to filtered trajectories, started from the data.

    The person is taken to face the rig (against the cameras' mean viewing direction), in a
    world whose +Z is up (the tape-measured rig's world): that fixes the torso frame's axes
    (:func:`~lsmta.body.start.torso_frame`); everything else comes from the trajectories.

    Parameters
    ----------
    trajectories : Trajectories
    cameras : sequence of Camera
        Calibrated cameras in the world of the trajectories.
    settings : ArmFitParams, optional
    rng : numpy.random.Generator, int or None
        For the rigid groups' sample.

    Returns
    -------
    ArmFit
    """
    cams = check_cameras(cameras, "cameras")
    s = settings or ArmFitParams()
    X = np.asarray(trajectories.xyz)
    if not np.isfinite(X).all(axis=2).any():
        raise ValueError("trajectories: no trajectory has a position")
    facing = -np.mean([c.R[2] for c in cams], axis=0)      # against the viewing direction
    if np.hypot(facing[0], facing[1]) < 0.3:
        raise ValueError("cameras: they do not look at the person from one side (their mean "
                         "horizontal viewing direction nearly cancels), so the person's facing "
                         "direction is unknown; fit the arm with the cameras in front of it")
    start = arm_start(trajectories, forward=facing, up=(0.0, 0.0, 1.0),
                      tolerance=s.rigidity_mm, rng=rng)
    present = np.isfinite(X).all(axis=2)
    counts = np.stack([(present & (start.groups.label == g)).sum(axis=1)
                       for g in (start.upper_arm, start.forearm)], axis=1)
    frames = observed_frames(counts, min_points=s.min_segment_points)
    simple, full, sigma = fit_self_consistent(start.points, start.torso_poses, start.state,
                                              tracked=start.joints, frames=frames, settings=s)
    return ArmFit(start=start, frames=frames, simplified=simple, full=full, sigma_mm=sigma)


def observed_frames(counts, *, min_points: int = 10) -> np.ndarray:
    """Frames in which every segment has at least ``min_points`` points.

    Parameters
    ----------
    counts : (T, S) int array
        Points per frame and segment.

    Raises
    ------
    ValueError
        Fewer than 3 such frames.
    """
    counts = np.asarray(counts)
    frames = np.flatnonzero((counts >= min_points).all(axis=1))
    if len(frames) < 3:
        raise ValueError(f"trajectories: every arm segment has >= {min_points} points in only "
                         f"{len(frames)} of {len(counts)} frames; the arm model needs >= 3")
    return frames


def fit_self_consistent(points, torso_poses, init, *, tracked=None, frames=None,
                        settings: ArmFitParams | None = None):
    """The simplified model, then the full one, with a point sigma the fit agrees with.

    The simplified fit runs with ``settings.sigma_prior_mm``; if its own robust residual
    scale differs by more than 10 %, it runs again with that scale (notebook 07's rule), and
    the full model starts from it with the same sigma.

    Parameters
    ----------
    points : sequence of T (N_t, 3) arrays
    torso_poses : (T, 4, 4) array
    init : ModelState
    tracked : (T, 3, 3) array, optional
        Shoulder, elbow and wrist as observations (the wrist is left out: NaN).
    frames : sequence of int, optional
        Fit only these frames (default: all).
    settings : ArmFitParams, optional

    Returns
    -------
    (simplified BodyFit, full BodyFit, sigma_mm float)
    """
    s = settings or ArmFitParams()
    model = arm_model()
    if frames is not None:
        frames = np.asarray(frames, int)
        points = [points[t] for t in frames]
        torso_poses = np.asarray(torso_poses)[frames]
        init = ModelState(angles=init.angles[frames], shoulder=init.shoulder[frames],
                          scales=init.scales, radii=init.radii)
    if tracked is not None:
        tracked = np.array(tracked, float)
        tracked = tracked if frames is None else tracked[frames]
        tracked[:, 2] = np.nan              # the wrist is a guess, not a measurement
    sigma = as_scalar(s.sigma_prior_mm, "settings.sigma_prior_mm", positive=True)

    def fit(state, **params):
        return fit_sequence(model, points, torso_poses, state, tracked=tracked,
                            params=FitParams(sigma_joint_mm=s.sigma_joint_mm, **params))

    simple = fit(init, sigma_mm=sigma)
    if abs(simple.sigma_mm - sigma) > 0.1 * sigma:
        sigma = simple.sigma_mm
        simple = fit(init, sigma_mm=sigma)
    full = fit(simple.state, sigma_mm=sigma, shape="full", max_rounds=s.full_rounds)
    return simple, full, float(sigma)
