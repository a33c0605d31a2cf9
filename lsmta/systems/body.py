"""The LSMTA system of D'Apuzzo, Plänkers & Fua (2000), from pixels to a fitted arm model.

What goes in is what a user has: synchronised videos of the person, videos of a reference
bar, the bar's length and the cameras as built (:func:`capture_body`). Nothing of the
generator's truth enters: no true camera, seed, start point, noise level or pose. The
stages, each also callable on its own:

1. *calibration* from the bar video (:func:`~lsmta.systems.rig.calibrate_rig`);
2. *image noise* measured in the person's video (:func:`~lsmta.noise.temporal_noise`), the
   sigma of every LSM threshold that needs one;
3. *surfaces* of the first frame and of every ``density_every``-th frame, from automatic
   seeds (:func:`~lsmta.systems.surfaces.measure_surfaces`);
4. *surface tracking* (:func:`track_surface`): every matched point of the first frame is
   tracked (:func:`~lsmta.tracking.track_points`), and the density check takes its new
   points from the library's own surface of that frame;
5. *trajectories* by forward intersection and the trajectory filters (the paper's two and
   our drift filter, :func:`~lsmta.tracking.apply_filters`);
6. *the arm model* (:func:`fit_arm`): started where the data put it
   (:func:`~lsmta.body.start.arm_start`: rigid groups of the trajectories, functional
   joints), fitted in sequence mode to the arm groups' points, first the simplified model,
   then the full one.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from tqdm.auto import tqdm

from .._validate import as_scalar
from ..body import BodyFit, FitParams, ModelState, arm_model, fit_sequence
from ..body.start import ArmStart, arm_start
from ..calibration import DEFAULT_INTRINSICS
from ..noise import NoiseEstimate, temporal_noise
from ..tracking import (
    TrackerParams,
    Tracks,
    Trajectories,
    apply_filters,
    track_points,
    trajectories_from_tracks,
)
from .checks import check_cameras, check_videos
from .rig import RigCalibration, calibrate_rig
from .surfaces import SurfaceParams, measure_surfaces


@dataclass(frozen=True)
class FilterParams:
    """Trajectory filters (:func:`~lsmta.tracking.apply_filters`; notebook 05's values)."""

    max_speed: float = 2000.0
    max_acceleration: float = 40000.0
    voxel: float = 150.0
    max_deviation: float = 400.0
    window: int = 10
    max_drift: float = 8.0


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


@dataclass(frozen=True)
class BodySystemParams:
    """Settings of :func:`capture_body`, one bundle per stage.

    Attributes
    ----------
    intrinsics, bar_sigma, reject_k
        The calibration (:func:`~lsmta.systems.rig.calibrate_rig`): free interior
        parameters, the bar length's standard deviation (mm), outlier rejection.
    surface : SurfaceParams
    density_every : int
        Frames between density checks (and so between measured surfaces).
    tracker : TrackerParams
    filters : FilterParams
    arm : ArmFitParams
    """

    intrinsics: tuple = DEFAULT_INTRINSICS
    bar_sigma: float = 0.01
    reject_k: float | None = None
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    density_every: int = 4
    tracker: TrackerParams = field(default_factory=TrackerParams)
    filters: FilterParams = field(default_factory=FilterParams)
    arm: ArmFitParams = field(default_factory=ArmFitParams)


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


@dataclass(frozen=True, eq=False)
class BodyCapture:
    """Everything :func:`capture_body` measured, stage by stage.

    Attributes
    ----------
    cameras : list of Camera
        The calibrated cameras, user's world, mm.
    calibration : RigCalibration
    noise : NoiseEstimate
    frames : (T,) int array
        The frames of the input videos that were processed (index 0 here is ``frames[0]``).
    surfaces : dict of int -> SurfaceResult
        Measured surfaces, by processed frame.
    tracks : Tracks
    trajectories : Trajectories
        Before the filters.
    filters : tuple of FilterReport
        The three filters in order; the last one's trajectories are the result.
    arm : ArmFit
    seconds : dict of str -> float
        Wall time per stage.
    params : BodySystemParams
        The settings it ran with.
    """

    cameras: list
    calibration: RigCalibration
    noise: NoiseEstimate
    frames: np.ndarray
    surfaces: dict
    tracks: Tracks
    trajectories: Trajectories
    filters: tuple
    arm: ArmFit
    seconds: dict
    params: BodySystemParams

    @property
    def filtered(self) -> Trajectories:
        """The trajectories after all filters."""
        return self.filters[-1].trajectories

    def summary(self) -> list:
        """One row per stage: ``{"stage", "seconds", "result"}``, for a table."""
        cal, full = self.calibration, self.arm.full
        s0 = self.surfaces[min(self.surfaces)]
        kept = self.filtered.present.any(axis=0).sum()
        rows = [
            ("calibration", f"{cal.n_positions} bar positions, image RMS {cal.bundle.rms:.4f} px "
                            f"({cal.rms_over_limit:.3f} x the noise limit), "
                            f"{cal.labels.n_swapped} swapped target labels fixed"),
            ("image noise", f"sigma {self.noise.sigma:.2f} grey levels"),
            ("surfaces", f"{len(self.surfaces)} frames; first frame "
                         f"{int(s0.neighbourhood_ok.sum())} points"),
            ("tracking", f"{len(self.tracks)} tracks ({int(self.tracks.added.sum())} added by "
                         f"the density check), {int(self.tracks.alive[-1].sum())} alive at "
                         "the end"),
            ("trajectories", f"{int(kept)} of {len(self.trajectories)} kept by the filters"),
            ("arm model", f"{full.status.name} after {full.rounds} round(s) in "
                          f"{len(self.arm.frames)} of {len(self.frames)} frames (both arm "
                          f"segments tracked); bone lengths {full.lengths[0]:.1f} / "
                          f"{full.lengths[1]:.1f} mm; sigma {self.arm.sigma_mm:.2f} mm"),
        ]
        return [{"stage": s, "seconds": self.seconds.get(s, float("nan")), "result": r}
                for s, r in rows]


def track_surface(videos, surfaces: dict, *, params: TrackerParams | None = None,
                  progress: bool = False) -> Tracks:
    """Surface tracking (Fig. 9): every point of the first surface, new points from later ones.

    Parameters
    ----------
    videos : (K, T, H, W) array
    surfaces : dict of int -> SurfaceResult
        Must hold frame 0; its points that passed the filters start the tracks, and the
        later frames' feed the density check (every ``params.density_every`` frames).
    params : TrackerParams, optional
    progress : bool

    Returns
    -------
    Tracks
    """
    if 0 not in surfaces:
        raise ValueError("surfaces: expected the surface of frame 0 (the start points)")
    first = surfaces[0]
    start = first.xy[:, first.neighbourhood_ok]
    if start.shape[1] == 0:
        raise ValueError("surfaces: frame 0's surface has no point to track")
    new = {t: s.xy[:, s.neighbourhood_ok] for t, s in surfaces.items() if t > 0}
    return track_points(videos, start, params=params, new_points=new, progress=progress)


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


@dataclass
class _State:
    """What the stages of :func:`capture_body` hand on."""

    videos: np.ndarray
    bar_videos: object
    bar_length: float
    nominal: list
    fps: float
    params: BodySystemParams
    progress: bool
    seed: int
    calibration: RigCalibration | None = None
    noise: NoiseEstimate | None = None
    surfaces: dict | None = None
    tracks: Tracks | None = None
    trajectories: Trajectories | None = None
    filters: tuple | None = None
    arm: ArmFit | None = None


def _calibration(st: _State) -> None:
    p = st.params
    st.calibration = calibrate_rig(st.bar_videos, st.bar_length, st.nominal,
                                   intrinsics=p.intrinsics, bar_sigma=p.bar_sigma,
                                   reject_k=p.reject_k, progress=st.progress)


def _image_noise(st: _State) -> None:
    st.noise = temporal_noise(st.videos)


def _surfaces(st: _State) -> None:
    T = st.videos.shape[1]
    every = st.params.density_every
    st.surfaces = measure_surfaces(st.videos, st.calibration.cameras, range(0, T, every),
                                   sigma=st.noise.sigma, params=st.params.surface,
                                   progress=st.progress)


def _tracking(st: _State) -> None:
    p = st.params
    tracker = replace(p.tracker, density_every=p.density_every, template=p.surface.template)
    st.tracks = track_surface(st.videos, st.surfaces, params=tracker, progress=st.progress)


def _trajectories(st: _State) -> None:
    st.trajectories = trajectories_from_tracks(st.calibration.cameras, st.tracks, st.fps)
    st.filters = apply_filters(st.trajectories, **asdict(st.params.filters))


def _arm_model(st: _State) -> None:
    st.arm = fit_arm(st.filters[-1].trajectories, st.calibration.cameras,
                     settings=st.params.arm, rng=st.seed)


STAGES = (("calibration", _calibration), ("image noise", _image_noise),
          ("surfaces", _surfaces), ("tracking", _tracking), ("trajectories", _trajectories),
          ("arm model", _arm_model))


def _frame_indices(frames, T: int) -> np.ndarray:
    if frames is None:
        return np.arange(T)
    if isinstance(frames, slice):
        idx = np.arange(T)[frames]
    else:
        idx = np.asarray(frames)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"frames: expected a slice or a sequence of frame indices, got "
                             f"{frames!r}")
    if len(idx) < 3:
        raise ValueError(f"frames: expected at least 3 frames, got {len(idx)}")
    if idx.min() < 0 or idx.max() >= T:
        raise ValueError(f"frames: expected indices in [0, {T - 1}], got {idx.min()}..{idx.max()}")
    if np.any(np.diff(idx) != 1):
        raise ValueError("frames: expected consecutive frames (the tracker follows them one "
                         "by one)")
    return idx


def capture_body(videos, bar_videos, bar_length: float, nominal_cameras, *, fps: float = 25.0,
                 frames=None, progress: bool = True, params: BodySystemParams | None = None,
                 seed: int = 0) -> BodyCapture:
    """Run the LSMTA system on synchronised videos: calibration to fitted arm model.

    Parameters
    ----------
    videos : (K, T, H, W) array
        Grey frames (uint8 or float) of the person from K synchronised cameras; the
        template camera (``params.surface.template``, the centre one) is the one the person
        faces.
    bar_videos : (K, Tb, H, W) array
        The same cameras' frames of the reference bar.
    bar_length : float
        Distance between the bar's targets, mm.
    nominal_cameras : sequence of K Camera
        The cameras as built: nominal lens (focal length in px), image size, positions and
        directions measured with a tape, in a world with +Z up.
    fps : float
        Frame rate, Hz (the trajectory filters' speeds are per second).
    frames : slice or sequence of int, optional
        Consecutive frames of ``videos`` to process (default: all).
    progress : bool
        Progress bars per stage.
    params : BodySystemParams, optional
    seed : int
        Seeds the only random step (the rigid groups' sample of trajectories).

    Returns
    -------
    BodyCapture
        Nothing passed in is modified.
    """
    nominal = check_cameras(nominal_cameras, "nominal_cameras")
    v = check_videos(videos, "videos", nominal, min_frames=3)
    idx = _frame_indices(frames, v.shape[1])
    fps = as_scalar(fps, "fps", positive=True)
    p = params or BodySystemParams()
    if not isinstance(p, BodySystemParams):
        raise TypeError(f"params: expected a BodySystemParams, got {type(p).__name__}")
    st = _State(videos=v[:, idx], bar_videos=bar_videos, bar_length=bar_length,
                nominal=nominal, fps=fps, params=p, progress=progress, seed=int(seed))
    seconds = {}
    for name, stage in tqdm(STAGES, desc="LSMTA system", disable=not progress):
        t0 = time.perf_counter()
        stage(st)
        seconds[name] = time.perf_counter() - t0
    return BodyCapture(cameras=st.calibration.cameras, calibration=st.calibration,
                       noise=st.noise, frames=idx, surfaces=st.surfaces, tracks=st.tracks,
                       trajectories=st.trajectories, filters=st.filters, arm=st.arm,
                       seconds=seconds, params=p)
