"""The LSMTA system on a generated capture session, scored against the truth after the fact.

:func:`arm_wave_session` makes what a user would bring to :func:`lsmta.systems.capture_body`
- the triplet's videos of a seated person waving the right arm, a bar video, the bar's
length and the cameras as built (a tape-measured pose, the lens's nominal focal length) -
and keeps the truth beside it. The other functions score each stage of a
:class:`~lsmta.systems.BodyCapture` against that truth, and run the same stage fed with
truth instead of its predecessor's output, as notebooks 01-07 do (true cameras, seeds and
start points from the truth, the generator's noise, the exact torso pose), so that the
error each stage adds can be read off.

The system's world is the tape-measured one, a few centimetres and degrees from the true
world; before 3-D errors are taken, the system's results are carried into the true world by
the rigid motion that best maps its check points onto theirs (:func:`world_alignment`; the
scale is left as the bar made it).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import as_int, as_scalar, as_vector
from ..body import arm_model, shoulder_angles
from ..body.arm import base_poses
from ..calibration import track_targets
from ..calibration.labels import consistent_bar_labels
from ..camera import scaled_camera
from ..matching import GrowParams, LSMThresholds, MeasureSurfaceParams, measure_surface
from ..rigid import fit_rigid
from ..synth import Scene, arm_wave, make_body, triplet_rig
from ..synth.body import Motion
from ..synth.calibration import BarTrack, bar_footage
from ..synth.render import Renderer, cast_body
from ..synth.sequence import Sequence, render_sequence
from ..systems import ArmFitParams, BodyCapture, FilterParams
from ..systems.arm import fit_self_consistent, observed_frames
from ..tracking import TrackerParams, Trajectories, apply_filters, track_points
from ..tracking.trajectories import trajectories_from_tracks
from ..triangulation import triangulate
from . import body as eb
from .calibration import check_point_errors, heldout_bar_errors
from .surface import node_truth, score_surface, seeds_from_truth
from .tracking import TrackScore, score_tracks, track_identity

ARM_PARTS = eb.ARM_PARTS
# the committed result of `experiments/lsmta_system.py --seeds 5 --frames 20 --first 14
# --width 576 --height 432` (notebook 14's settings over seeds), quoted by notebook 14
SYSTEM_SEEDS_RESULT = Path(__file__).resolve().parents[2] / "experiments" / "results" \
    / "lsmta_system_seeds.json"


@dataclass(frozen=True, eq=False)
class ArmWaveSession:
    """A generated capture session: what a user has, and the truth.

    Attributes
    ----------
    videos : (K, T, H, W) uint8 array
        The person, from the three cameras.
    bar_videos : (K, Tb, H, W) uint8 array
        The reference bar.
    bar_length : float
        mm.
    nominal : list of Camera
        The cameras as built: tape-measured pose, nominal focal length, principal point at
        the image centre, no distortion.
    fps : float
    cameras : list of Camera
        The true cameras.
    sequence : Sequence
        The rendered sequence with its scene and the visible surface points of the frames
        the density check looks at (the truth-fed tracker's candidates).
    bar, heldout : BarTrack
        The bar's true positions, and held-out positions (check points).
    heldout_videos : (K, Th, H, W) uint8 array
    noise_sigma : float
        The generator's image noise, grey levels (before rounding).
    first : int
        Frame of :func:`lsmta.synth.arm_wave` shown as frame 0.
    seed : int
    level_videos : (K, Tl, H, W) uint8 array or None
        The bar stood upright with a spirit level (:func:`lsmta.synth.calibration.levelled_bar`),
        what the user has to level the world; None without.
    level : BarTrack or None
        Its true positions.
    """

    videos: np.ndarray
    bar_videos: np.ndarray
    bar_length: float
    nominal: list
    fps: float
    cameras: list
    sequence: Sequence
    bar: BarTrack
    heldout: BarTrack
    heldout_videos: np.ndarray
    noise_sigma: float
    first: int
    seed: int
    level_videos: np.ndarray | None = None
    level: BarTrack | None = None

    @property
    def scene(self) -> Scene:
        return self.sequence.scene


def roi_camera(camera, width: int, height: int):
    """The camera's centred ``width x height`` region of interest (a sensor read-out window:
    same lens and pose, smaller image)."""
    return camera.replace(width=width, height=height,
                          cx=camera.cx - (camera.width - width) / 2,
                          cy=camera.cy - (camera.height - height) / 2)


@dataclass(frozen=True)
class ArmWaveSessionParams:
    """The studio, the bar and the tape measure of :func:`arm_wave_session`.

    Attributes
    ----------
    roi : (2,) ints
        Width and height of the centred read-out window of the 768 x 576 sensors, px.
    distance, baseline, height : float
        Rig to person, between neighbouring cameras, and camera height, mm.
    person : (2,) floats
        Where the person sits (x, y), mm.
    noise : float
        Image noise, grey levels.
    backdrop : float
        The dark backdrop's grey level (a camera's black level).
    bar_length : float
        mm.
    n_bar, n_heldout : int
        Bar positions filmed for the calibration and held out for the check points.
    bar_half_size : (3,) floats
        Half size of the volume the bar moves in, mm.
    tape_mm, tape_deg, lens_rel : float
        The nominal cameras' errors: position per axis (mm), attitude per axis (degrees),
        relative focal length.
    level_places : int
        Places the bar is stood upright with a spirit level (three frames each), to level
        the world; 0: no levelling video.
    level_deg : float
        How far from vertical the level leaves the bar each time, per horizontal axis, deg.
    """

    roi: tuple = (576, 432)
    distance: float = 1700.0
    baseline: float = 480.0
    height: float = 1150.0
    person: tuple = (450.0, 0.0)
    noise: float = 2.0
    backdrop: float = 20.0
    bar_length: float = 400.0
    n_bar: int = 150
    n_heldout: int = 40
    bar_half_size: tuple = (380.0, 250.0, 300.0)
    tape_mm: float = 30.0
    tape_deg: float = 2.0
    lens_rel: float = 0.01
    level_places: int = 4
    level_deg: float = 0.2

    def __post_init__(self):
        if len(self.roi) != 2:
            raise ValueError(f"roi: expected (width, height), got {self.roi!r}")
        for k, v in zip(("roi width", "roi height"), self.roi):
            as_int(v, k, unit="px")
        for key in ("distance", "baseline", "height", "bar_length"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("noise", "backdrop", "tape_mm", "tape_deg", "lens_rel", "level_deg"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_vector(self.person, "person", 2)
        as_vector(self.bar_half_size, "bar_half_size", 3)
        as_int(self.n_bar, "n_bar")
        as_int(self.n_heldout, "n_heldout")
        as_int(self.level_places, "level_places", minimum=0)


def arm_wave_session(*, seed: int = 1998, n_frames: int = 24, first: int = 10, every: int = 4,
                     scale: float = 1.0,
                     params: ArmWaveSessionParams | None = None) -> ArmWaveSession:
    """Render the arm wave in the triplet and a bar video, and make the tape-measured rig.

    The triplet of :func:`~lsmta.synth.triplet_rig` (perturbed as a hand-built rig) stands
    ``distance`` mm from the person with ``baseline`` mm between neighbours, its cameras
    reading a centred ``roi`` window of their 768 x 576 sensors (the arm fills the frames
    as in the paper's Fig. 8). The person sits at ``person`` facing the rig, so that the
    right arm sweeps across the view; frames ``first`` to ``first + n_frames - 1`` of
    :func:`~lsmta.synth.arm_wave` (25 Hz) are shown, with the density check's surface
    points every ``every`` frames. The backdrop is dark but ``backdrop`` grey levels above
    black, like a camera's black level. The nominal cameras are the true ones moved by
    ``tape_mm`` per axis and turned by ``tape_deg`` per axis, with the focal length off by
    ``lens_rel`` and no lens model (:func:`~lsmta.synth.calibration.poor_guess`).
    With ``level_places`` > 0 the bar is also filmed stood upright with a spirit level
    (:func:`~lsmta.synth.calibration.levelled_bar`, ``level_deg`` off vertical), the video a
    user levels the world with; it is drawn last, so the rest of the session does not depend
    on it. ``scale`` shrinks the images (fewer, coarser pixels: for quick tests). The settings
    named here are those of ``params`` (default: ``ArmWaveSessionParams()``).
    """
    p = ArmWaveSessionParams() if params is None else params
    roi, distance, baseline, height, person = (p.roi, p.distance, p.baseline, p.height,
                                               p.person)
    noise, backdrop, bar_length, n_bar, n_heldout = (p.noise, p.backdrop, p.bar_length,
                                                     p.n_bar, p.n_heldout)
    bar_half_size, tape_mm, tape_deg, lens_rel = (p.bar_half_size, p.tape_mm, p.tape_deg,
                                                  p.lens_rel)
    rng = np.random.default_rng(seed)
    full = triplet_rig(rng=rng, distance=distance, baseline=baseline, camera_height=height,
                       target_height=height)
    cams = [scaled_camera(roi_camera(c, *roi), scale) for c in full]
    body = make_body(rng=np.random.default_rng(seed), contrast=0.3, wavelength=(12.0, 50.0))
    wave = arm_wave(n_frames=first + n_frames, position=person)
    motion = Motion(name=wave.name, fps=wave.fps, root_position=wave.root_position[first:],
                    joint_angles=wave.joint_angles[first:], part_names=wave.part_names)
    scene = Scene(body=body, motion=motion, backdrop=backdrop)
    seq = render_sequence(scene, cams, rng=rng, noise_sigma=noise,
                          surface_frames=range(0, n_frames, every), step=4)
    f = bar_footage(cams, rng=rng, length=bar_length, center=(0.0, 0.0, height),
                    half_size=bar_half_size, n=(n_bar, n_heldout), noise=noise,
                    tape=(tape_mm, tape_deg, lens_rel), level_places=p.level_places, step=70.0,
                    level_half_size=0.5 * np.asarray(bar_half_size), level_tilt_deg=p.level_deg)
    return ArmWaveSession(videos=seq.images, bar_videos=f.bar_videos, bar_length=bar_length,
                          nominal=f.nominal, fps=motion.fps, cameras=cams, sequence=seq,
                          bar=f.bar, heldout=f.heldout, heldout_videos=f.heldout_videos,
                          noise_sigma=noise, first=first, seed=seed,
                          level_videos=f.level_videos, level=f.level)


# ------------------------------------------------------------------ alignment
@dataclass(frozen=True)
class Alignment:
    """Rigid motion from the system's world to the true world: ``x_true = R x + t``, fitted
    on ``n_points`` check points (0: not from check points)."""

    R: np.ndarray
    t: np.ndarray
    n_points: int = 0

    @property
    def tilt_deg(self) -> float:
        """Angle (degrees) between the system world's up (+Z) and the true world's."""
        return float(np.degrees(np.arccos(np.clip(self.R[2, 2], -1.0, 1.0))))

    def points(self, x) -> np.ndarray:
        return np.asarray(x, float) @ self.R.T + self.t

    def cameras(self, cameras) -> list:
        return [c.replace(R=c.R @ self.R.T, C=self.R @ c.C + self.t) for c in cameras]


def heldout_points(cameras, session: ArmWaveSession) -> np.ndarray:
    """``(K, 2 Th, 2)`` held-out bar targets measured in their video, ends made consistent
    with ``cameras`` (targets A, B interleaved)."""
    xy = np.stack([track_targets(v).xy for v in session.heldout_videos])
    xy = consistent_bar_labels(cameras, xy, session.bar_length).xy
    return xy.reshape(len(cameras), -1, 2)


def world_alignment(cameras, session: ArmWaveSession) -> Alignment:
    """The rigid motion (no scale) that best maps the held-out bar targets, intersected with
    ``cameras``, onto their true positions: the check points of notebook 01. (Aligning by
    the camera attitudes instead would be a milliradian off: an attitude trades off against
    the principal point.)"""
    X = triangulate(cameras, heldout_points(cameras, session)).points
    truth = session.heldout.points.reshape(-1, 3)
    ok = np.isfinite(X).all(axis=1)
    R, t = fit_rigid(X[ok], truth[ok])
    return Alignment(R=R, t=t, n_points=int(ok.sum()))


# ------------------------------------------------------------------ calibration
def calibration_scores(cameras, session: ArmWaveSession) -> dict:
    """Held-out bar lengths and check points measured with ``cameras``: the held-out bar
    video's targets (ends made consistent), intersected; check points after the best rigid
    motion onto the truth (no scale), as in notebook 01. Returns mm values:
    ``bar_error`` (T_h,), ``check_error`` (2 T_h,), ``check_rms``, ``centre_error`` (K,)
    (camera centres after :func:`world_alignment`)."""
    xy = heldout_points(cameras, session)
    bar = heldout_bar_errors(cameras, xy, session.bar_length)
    check = check_point_errors(cameras, xy, session.heldout.points.reshape(-1, 3))
    al = world_alignment(cameras, session)
    centres = np.array([np.linalg.norm(al.points(c.C) - t.C)
                        for c, t in zip(cameras, session.cameras)])
    return {"bar_error": bar, "check_error": check,
            "check_rms": float(np.sqrt(np.nanmean(check**2))), "centre_error": centres}


def target_sigma(capture: BodyCapture, session: ArmWaveSession) -> float:
    """RMS error of the measured bar targets against their true projections, per
    coordinate, px (the truth the a-priori sigma estimates)."""
    xy = capture.calibration.targets                                  # (K, Tb, 2, 2)
    true = np.stack([c.project(session.bar.points.reshape(-1, 3), behind="nan")
                     for c in session.cameras]).reshape(xy.shape)
    d = xy - true
    ok = np.isfinite(d).all(axis=3) & (np.linalg.norm(np.nan_to_num(d, nan=9e9), axis=3) < 1)
    return float(np.sqrt(np.mean(d[ok] ** 2)))


# ------------------------------------------------------------------ surface
def surface_truth(session: ArmWaveSession, frame: int, *, step: int = 4, patch: int = 13):
    """:func:`~lsmta.evaluation.surface.node_truth` of one frame (noise-free render)."""
    shot = Renderer(session.scene, session.cameras, supersample=1).render(frame)
    return node_truth(shot, session.scene, session.cameras, step=step, patch=patch)


def score_system_surface(result, truth: dict, alignment: Alignment) -> dict:
    """:func:`~lsmta.evaluation.surface.score_surface` of a surface measured in the system's
    world, after carrying its points into the true world."""
    inter = dataclasses.replace(result.intersection,
                                points=alignment.points(result.intersection.points))
    return score_surface(dataclasses.replace(result, intersection=inter), truth)


def truth_fed_surface(session: ArmWaveSession, frame: int, *, step: int = 4, patch: int = 7,
                      retry_patch=(9, 5), per_part: int = 1):
    """The surface of notebook 03's setting: true cameras, seeds from the truth, LSM
    thresholds from the generator's noise."""
    rng = np.random.default_rng(session.seed + frame)
    seeds = seeds_from_truth(session.scene, session.cameras, frame, rng=rng,
                             per_part=per_part)
    thresholds = LSMThresholds(max_sigma0=2.0 * session.noise_sigma, max_displacement=step,
                               max_sigma_xy=0.2, scale_range=(0.5, 2.0), max_shear=0.5)
    grow = GrowParams(step=step, patch=patch, retry_patch=retry_patch, thresholds=thresholds)
    return measure_surface(session.videos[:, frame], session.cameras, seeds,
                           params=MeasureSurfaceParams(grow=grow))


# ------------------------------------------------------------------ tracking
def track_identity_from_rays(session: ArmWaveSession, tracks, *, template: int = 1):
    """``(part (N,), local (N, 3))``: the body surface point under each track's first
    template position (the template camera's ray cast at the exact sub-pixel position)."""
    body, motion = session.scene.body, session.scene.motion
    cam = session.cameras[template]
    N = len(tracks)
    part = np.full(N, -1)
    local = np.full((N, 3), np.nan)
    for f in np.unique(tracks.start):
        sel = np.flatnonzero(tracks.start == f)
        xy = tracks.xy[f, template, sel]
        ok = np.isfinite(xy).all(axis=1)
        if not ok.any():
            continue
        _, dirs = cam.rays(xy[ok])
        hit = cast_body(body, body.part_poses(motion, frames=int(f))[0], cam.C, dirs)
        part[sel[ok]] = np.where(np.isfinite(hit.t), hit.part, -1)
        local[sel[ok]] = hit.local
    return part, local


def score_system_tracks(session: ArmWaveSession, tracks, trajectories: Trajectories, *,
                        alignment: Alignment | None = None, template: int = 1,
                        false_mm: float = 10.0) -> tuple[TrackScore, np.ndarray, np.ndarray]:
    """Score tracks and their trajectories against the surface points they started on;
    trajectories in the system's world are first carried into the true world. Tracks that
    did not start on the body get NaN errors. Returns ``(score, part, local)``."""
    part, local = track_identity_from_rays(session, tracks, template=template)
    xyz = trajectories.xyz if alignment is None else alignment.points(trajectories.xyz)
    traj = Trajectories(xyz, trajectories.fps)
    on = part >= 0
    safe_part = np.where(on, part, 0)
    safe_local = np.where(on[:, None], local, 0.0)
    score = score_tracks(session.sequence, tracks, safe_part, safe_local, traj=traj,
                         false_mm=false_mm)
    score = dataclasses.replace(
        score, image_error=np.where(on, score.image_error, np.nan),
        step_error=np.where(on, score.step_error, np.nan),
        error_3d=np.where(on, score.error_3d, np.nan),
        false_from=np.where(on, score.false_from, -1))
    return score, part, local


def last_frame_error(score: TrackScore, present) -> tuple[float, int]:
    """Median 3-D error (mm) of the trajectories present in the last frame, and their count."""
    e = score.error_3d[-1][present[-1] & np.isfinite(score.error_3d[-1])]
    return (float(np.median(e)) if e.size else float("nan")), int(e.size)


@dataclass(frozen=True, eq=False)
class TruthFedTracking:
    """Notebook 04's tracking on the session's video: true cameras, start points and density
    candidates from the truth, the same tracker and filters as the system."""

    tracks: object
    trajectories: Trajectories
    filters: tuple
    score: TrackScore
    part: np.ndarray
    local: np.ndarray
    seconds: float


def truth_fed_tracking(session: ArmWaveSession, *, params: TrackerParams | None = None,
                       filters: FilterParams | None = None,
                       every: int = 4) -> TruthFedTracking:
    """Track all of frame 0's visible grid points with the true cameras (see the class)."""
    seq = session.sequence
    s0 = seq.surface[0]
    p = dataclasses.replace(params or TrackerParams(), density_every=every)
    t0 = time.perf_counter()
    tracks = track_points(session.videos, s0.xy, params=p,
                          new_points={t: s.xy for t, s in seq.surface.items() if t > 0})
    seconds = time.perf_counter() - t0
    part, local = track_identity(seq, tracks, s0.part, s0.local)
    traj = trajectories_from_tracks(session.cameras, tracks, session.fps)
    reports = apply_filters(traj, **dataclasses.asdict(filters or FilterParams()))
    score = score_tracks(seq, tracks, part, local, traj=reports[-1].trajectories)
    return TruthFedTracking(tracks=tracks, trajectories=traj, filters=reports, score=score,
                            part=part, local=local, seconds=seconds)


# ------------------------------------------------------------------ arm model
def session_arm_truth(session: ArmWaveSession) -> eb.ArmTruth:
    """The arm's truth in every frame of the session."""
    return eb.arm_truth(session.scene.body, session.scene.motion,
                        np.arange(session.videos.shape[1]))


def score_arm(fit, torso_poses, truth: eb.ArmTruth, *, frames=None, score_frames=None,
              alignment: Alignment | None = None) -> dict:
    """Angle and length errors of an arm fit, its posture compared in the TRUE torso frame.

    The fitted upper arm's attitude in the world (the fit's torso frame times its shoulder
    angles), carried into the true world, is expressed in the true torso frame and turned
    into the angles ``(b, a, c)``; the elbow angle is intrinsic. So the score does not
    depend on how the system chose its torso frame. ``torso_poses`` and ``truth`` cover all
    frames; ``frames`` are the ones the fit covers (default: all); ``score_frames`` (a
    subset of them) restricts the angle scores, so that two fits can be compared on the
    frames both cover. Returns ``angle_err_deg`` (F, 4), ``max_angle_err_deg``, per-joint
    worst ``joint_max_deg`` (4,), ``length_err_pct`` (2,) and ``lengths`` (2,) mm.
    """
    if frames is not None:
        frames = np.asarray(frames, int)
        torso_poses = np.asarray(torso_poses)[frames]
        truth = dataclasses.replace(truth, frames=truth.frames[frames],
                                    torso_poses=truth.torso_poses[frames],
                                    angles=truth.angles[frames], joints=truth.joints[frames])
    st = fit.state
    model = arm_model()
    W = model.skeleton.transforms(st.angles, st.scales,
                                  base=base_poses(torso_poses, st.shoulder))
    U = W[:, 2, :3, :3]                                   # upper arm after the rotation c
    if alignment is not None:
        U = np.einsum("ij,tjk->tik", alignment.R, U)
    U_true = np.einsum("tji,tjk->tik", truth.torso_poses[:, :3, :3], U)
    ang = np.concatenate([shoulder_angles(U_true), st.angles[:, 3:4]], axis=1)
    d = np.degrees(np.angle(np.exp(1j * (ang - truth.angles[:, :4]))))
    if score_frames is not None:
        fr = np.arange(len(d)) if frames is None else np.asarray(frames, int)
        keep = np.isin(fr, score_frames)
        if not np.isin(score_frames, fr).all():
            raise ValueError("score_frames: expected a subset of the fit's frames")
        d = d[keep]
    lengths = np.asarray(fit.lengths[:2], float)
    return {"angle_err_deg": d, "max_angle_err_deg": float(np.abs(d).max()),
            "joint_max_deg": np.abs(d).max(axis=0), "lengths": lengths,
            "length_err_pct": 100 * (lengths - truth.lengths) / truth.lengths}


def score_arm_own_frame(fit, truth: eb.ArmTruth, *, frames, score_frames=None) -> dict:
    """Angle errors of an arm fit read as a user reads them: the fit's own angles, in the
    torso frame the system estimated, against the true angles in the true torso frame. No
    alignment: the system's world and torso frame as they are.

    Parameters
    ----------
    fit : BodyFit
        The arm fit (:class:`lsmta.body.fitting.BodyFit`); ``fit.state.angles`` is
        ``(F, >= 4)``, radians.
    truth : ArmTruth
        The arm's truth in every video frame (``truth.angles`` ``(T, >= 4)``, radians).
    frames : (F,) int array_like
        The video frames the fit covers: its frame i is ``frames[i]``.
    score_frames : int array_like, optional
        A subset of ``frames`` the scores are restricted to (default: all of them).

    Returns
    -------
    dict
        ``angle_err_deg`` (F', 4) own minus true angle, wrapped to (-180, 180], degrees
        (F' the scored frames); ``max_angle_err_deg`` (float) its largest magnitude;
        ``joint_max_deg`` (4,) each joint's largest magnitude.

    Raises
    ------
    ValueError
        ``frames`` of another length than the fit's frames, outside the truth's, or
        ``score_frames`` not a subset of them.
    """
    frames = np.asarray(frames)
    angles = np.asarray(fit.state.angles)
    if frames.ndim != 1 or len(frames) != len(angles):
        raise ValueError(f"frames: expected the fit's {len(angles)} frame indices, got shape "
                         f"{frames.shape}")
    if not np.issubdtype(frames.dtype, np.integer) and len(frames):
        raise ValueError(f"frames: expected integer frame indices, got dtype {frames.dtype}")
    frames = frames.astype(int)
    if len(frames) and (frames.min() < 0 or frames.max() >= len(truth.angles)):
        raise ValueError(f"frames: expected frame indices in [0, {len(truth.angles) - 1}], "
                         f"got {frames.min()}..{frames.max()}")
    keep = np.ones(len(frames), bool)
    if score_frames is not None:
        if not np.isin(score_frames, frames).all():
            raise ValueError("score_frames: expected a subset of the fit's frames")
        keep = np.isin(frames, score_frames)
    a = angles[keep, :4]
    d = np.degrees(np.angle(np.exp(1j * (a - truth.angles[frames[keep], :4]))))
    return {"angle_err_deg": d, "max_angle_err_deg": float(np.abs(d).max()),
            "joint_max_deg": np.abs(d).max(axis=0)}


@dataclass(frozen=True, eq=False)
class TruthFedArm:
    """Notebook 07's arm fit on the truth-fed tracking's arm points: exact torso poses, the
    true joints (exact by default) as the start and as observations, the arm's points
    picked by their true part, fitted
    in the frames where the upper arm and the forearm (with the hand) each have enough
    points (the system's rule)."""

    frames: np.ndarray
    simplified: object
    full: object
    sigma_mm: float
    points: list


def truth_fed_arm(session: ArmWaveSession, tracking: TruthFedTracking, *,
                  settings: ArmFitParams | None = None,
                  joint_noise_mm: float = 0.0) -> TruthFedArm:
    """The arm fit as notebook 07 feeds it (see :class:`TruthFedArm`), with the system's
    settings (the same sigma rule, the same rounds)."""
    truth = session_arm_truth(session)
    init, tracked = eb.initial_state(truth, rng=session.seed, joint_noise_mm=joint_noise_mm)
    s = settings or ArmFitParams()
    body = session.scene.body
    arm = np.isin(tracking.part, [body.index(n) for n in ARM_PARTS])
    X = tracking.filters[-1].trajectories.xyz
    present = np.isfinite(X).all(axis=2)
    points = [X[t, arm & present[t]] for t in range(len(X))]
    upper = tracking.part == body.index(ARM_PARTS[0])
    fore = np.isin(tracking.part, [body.index(n) for n in ARM_PARTS[1:]])
    counts = np.stack([(present & upper).sum(axis=1), (present & fore).sum(axis=1)], axis=1)
    frames = observed_frames(counts, min_points=s.min_segment_points)
    simple, full, sigma = fit_self_consistent(points, truth.torso_poses, init, tracked=tracked,
                                              frames=frames, settings=s)
    return TruthFedArm(frames=frames, simplified=simple, full=full, sigma_mm=sigma,
                       points=points)


def torso_frame_error(torso_poses, truth: eb.ArmTruth, alignment: Alignment, *,
                      frames=None) -> np.ndarray:
    """``(F,)`` angle (degrees) between a torso frame carried into the true world and the
    true torso frame, per frame."""
    P = np.asarray(torso_poses)
    R_true = truth.torso_poses[:, :3, :3]
    if frames is not None:
        P, R_true = P[np.asarray(frames, int)], R_true[np.asarray(frames, int)]
    R = np.einsum("ij,tjk->tik", alignment.R, P[:, :3, :3])
    cos = (np.einsum("tji,tji->t", R_true, R) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def torso_axis_errors(torso_poses, truth: eb.ArmTruth, alignment: Alignment, *,
                      frames=None) -> tuple[np.ndarray, np.ndarray]:
    """Where a torso frame's error lies: per frame, the angle between its up axis (z) and
    the true one's, and between its forward axes (y) once both are made horizontal in the
    true world (the heading). Both after ``alignment``.

    Parameters
    ----------
    torso_poses : (T, 4, 4) array_like
        The system's torso poses in its world, every video frame (mm).
    truth : ArmTruth
        The arm's truth; ``truth.torso_poses`` (T, 4, 4) in the true world.
    alignment : Alignment
        Carries the system's world into the true one (only its rotation is used).
    frames : int array_like, optional
        The frames to compare (default: all T).

    Returns
    -------
    up_deg : (F,) array
        Angle between the up axes, degrees.
    heading_deg : (F,) array
        Angle between the horizontal forward axes, degrees in [0, 180].
    """
    P = np.asarray(torso_poses)
    R_true = truth.torso_poses[:, :3, :3]
    if frames is not None:
        P, R_true = P[np.asarray(frames, int)], R_true[np.asarray(frames, int)]
    R = np.einsum("ij,tjk->tik", alignment.R, P[:, :3, :3])
    up = np.degrees(np.arccos(np.clip(np.einsum("ti,ti->t", R[:, :, 2], R_true[:, :, 2]),
                                      -1.0, 1.0)))
    a = np.arctan2(R[:, 1, 1], R[:, 0, 1]) - np.arctan2(R_true[:, 1, 1], R_true[:, 0, 1])
    return up, np.abs(np.degrees(np.angle(np.exp(1j * a))))


def centre_errors(cameras, true_cameras) -> np.ndarray:
    """``(K,)`` distances (mm) of camera centres from the true ones after the best rigid
    motion of the centres onto them: the rig's own geometry, whatever its datum (the same
    measure for a tape-measured and a calibrated rig)."""
    C = np.stack([c.C for c in cameras])
    Ct = np.stack([c.C for c in true_cameras])
    R, t = fit_rigid(C, Ct)
    return np.linalg.norm(C @ R.T + t - Ct, axis=1)


def joint_position_errors(start, truth: eb.ArmTruth, alignment: Alignment) -> np.ndarray:
    """``(T, 3)`` distances (mm) of the start's shoulder, elbow and wrist from the truth."""
    return np.linalg.norm(alignment.points(start.joints) - truth.joints, axis=2)


def group_parts(session: ArmWaveSession, groups, part) -> list:
    """For each rigid group, ``{part name: count}`` of its trajectories' true parts."""
    names = session.scene.body.names
    out = []
    for g in range(groups.n_groups):
        p = part[groups.label == g]
        u, c = np.unique(p, return_counts=True)
        out.append({(names[a] if a >= 0 else "off body"): int(n) for a, n in zip(u, c)})
    return out


__all__ = [
    "Alignment", "ArmWaveSession", "ArmWaveSessionParams", "TruthFedArm", "TruthFedTracking",
    "arm_wave_session", "calibration_scores", "centre_errors", "group_parts",
    "heldout_points", "joint_position_errors", "last_frame_error", "roi_camera", "score_arm",
    "score_arm_own_frame", "score_system_surface", "score_system_tracks", "session_arm_truth",
    "surface_truth", "target_sigma", "torso_axis_errors", "torso_frame_error",
    "track_identity_from_rays", "truth_fed_arm", "truth_fed_surface", "truth_fed_tracking",
    "world_alignment",
]


def read_system_seeds(*, path=None) -> dict | None:
    """The committed sweep of notebook 14's system over seeds (:data:`SYSTEM_SEEDS_RESULT`
    unless ``path``), or None when there is no such file.

    Returns
    -------
    dict or None
        ``command``, ``date``, ``settings`` (dict), ``seeds`` (S,) int array, ``values``:
        each headline key (``experiments/lsmta_system.py``'s ``HEADLINES``) as an (S,) float
        array over the seeds (NaN: the seed could not measure it, or failed), ``failed``:
        ``{seed: the error recorded for it}`` for the seeds that failed (all their values
        NaN), and ``detail``: each other seed's detail dictionary (per-stage times,
        per-frame arm errors and points), keyed by the int seed.

    Raises
    ------
    ValueError
        When the file is not the ``lsmta_system`` experiment's, lacks a field, has no seeds,
        a seed has no values or (not failed) no detail, the seeds' headline keys differ, or
        a value is neither a number nor null (naming the file, the seed and the key).
    """
    path = SYSTEM_SEEDS_RESULT if path is None else Path(path)
    if not path.is_file():
        return None
    data = json.loads(path.read_text(encoding="utf-8"))
    for key in ("experiment", "command", "date", "seeds", "settings", "per_seed", "results"):
        if key not in data:
            raise ValueError(f"path: {path.name} has no {key!r}")
    if data["experiment"] != "lsmta_system":
        raise ValueError(f"path: {path.name} is the {data['experiment']!r} experiment's, "
                         "expected 'lsmta_system'")
    seeds = [int(s) for s in data["seeds"]]
    if not seeds:
        raise ValueError(f"path: {path.name} has no seeds")
    failed = {int(s): str(e) for s, e in data.get("failed", {}).items()}
    for s in seeds:
        if str(s) not in data["per_seed"] or (
                s not in failed and "detail" not in data["results"].get(str(s), {})):
            raise ValueError(f"path: {path.name} has no values or no detail for seed {s}")
    values = _seed_values(data["per_seed"], seeds, failed, path.name)
    return {"command": data["command"], "date": data["date"], "settings": data["settings"],
            "seeds": np.array(seeds, int), "values": values,
            "failed": {s: failed[s] for s in seeds if s in failed},
            "detail": {s: data["results"][str(s)]["detail"] for s in seeds if s not in failed}}


def _seed_values(per_seed: dict, seeds: list, failed: dict, name: str) -> dict:
    # each headline key as an (S,) float array over the seeds; a failed seed's are NaN
    keys = set(per_seed[str(seeds[0])])
    for s in seeds[1:]:
        if set(per_seed[str(s)]) != keys:
            raise ValueError(f"path: {name}: seed {s}'s headline keys differ from seed "
                             f"{seeds[0]}'s: {sorted(keys ^ set(per_seed[str(s)]))}")
    for s in seeds:
        for k, v in per_seed[str(s)].items():
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ValueError(f"path: {name}: seed {s}'s {k!r} is {v!r}, expected a number "
                                 "or null")
    return {k: np.array([np.nan if s in failed or per_seed[str(s)][k] is None
                         else per_seed[str(s)][k] for s in seeds], float)
            for k in per_seed[str(seeds[0])]}
