"""The LSMTA system of D'Apuzzo, Plänkers & Fua (2000), from pixels to a fitted arm model.

What goes in is what the papers' user had: synchronised videos of the person, videos of a
reference bar, the bar's length and the cameras as built (:func:`capture_body`). Nothing of
the generator's truth enters: no true camera, seed, start point, noise level or pose. It is
the calibration from the bar (:func:`~lsmta.systems.rig.calibrate_rig`) followed by
:func:`~lsmta.systems.capture_recording` with the arm model as its last stage; a user with a
camera file or a board calibration calls :func:`~lsmta.systems.capture_recording` directly.

:func:`capture_walk` is the same system on a person moving through the whole volume (the
walk), from the triplet or from an all-round studio: no arm model; the surfaces of the whole
visible body, from every view group (each pair or triple of cameras that sees one side),
tracked into trajectories and filtered; :meth:`~lsmta.systems.BodyCapture.points_at` gives
each frame's points.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

from .._validate import as_scalar
from ..calibration import DEFAULT_INTRINSICS
from ..tracking import TrackerParams
from .arm import ArmFitParams
from .capture import BodyCapture, CaptureParams, FilterParams, _frame_indices, capture_recording
from .checks import check_cameras, check_videos
from .rig import calibrate_rig
from .surfaces import SurfaceParams


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
    arm : ArmFitParams or None
        The arm model stage; None leaves it out (:func:`capture_walk` does).
    max_angle_deg : float
        Largest angle between the optical axes of a view group's cameras
        (:func:`~lsmta.systems.views.view_groups`).
    """

    intrinsics: tuple = DEFAULT_INTRINSICS
    bar_sigma: float = 0.01
    reject_k: float | None = None
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    density_every: int = 4
    tracker: TrackerParams = field(default_factory=TrackerParams)
    filters: FilterParams = field(default_factory=FilterParams)
    arm: ArmFitParams | None = field(default_factory=ArmFitParams)
    max_angle_deg: float = 75.0

    def __post_init__(self):
        angle = as_scalar(self.max_angle_deg, "max_angle_deg", positive=True)
        if angle > 180.0:
            raise ValueError(f"max_angle_deg: expected an angle in (0, 180] degrees, got "
                             f"{angle}")
        if self.arm is not None and not isinstance(self.arm, ArmFitParams):
            raise TypeError(f"arm: expected an ArmFitParams or None, got "
                            f"{type(self.arm).__name__}")

    @classmethod
    def walking(cls) -> BodySystemParams:
        """:func:`capture_walk`'s default, for the whole body of a walking person: the
        filters of :meth:`FilterParams.walking` (the swinging limbs kept) and seeds 50 mm
        apart on the subject, up to 200 per frame and view group
        (:class:`SurfaceParams` ``seed_spacing_mm``: half a hand's or a foot's width, so
        that the growth reaches them; chosen on the generated studio walk, seed 36); no arm
        model. Held out on seed 37, the same body and walk with other camera jitter, texture
        and noise (``experiments/results/walk_cover.json``): the seen skin without a point
        within 15 mm 0.62 -> 0.44, the points 0.97 -> 1.02 mm from the skin; the full-body
        fit on seed 36 (``walk_full_fit_studio_rom_walking.json``) skin 4.8 -> 3.0 mm, but
        the forearm -1.3 -> -9.7 % long. Change fields with :func:`dataclasses.replace`."""
        return cls(filters=FilterParams.walking(), arm=None,
                   surface=SurfaceParams(n_seeds=200, seed_spacing_mm=50.0))

    def capture(self) -> CaptureParams:
        """The settings of the stages after the calibration."""
        return CaptureParams(max_angle_deg=self.max_angle_deg, surface=self.surface,
                             density_every=self.density_every, tracker=self.tracker,
                             filters=self.filters, arm=self.arm)


def capture_body(videos, bar_videos, bar_length: float, nominal_cameras, *, fps: float = 25.0,
                 frames=None, level_videos=None, progress: bool = True,
                 params: BodySystemParams | None = None, seed: int = 0) -> BodyCapture:
    """Run the LSMTA system on synchronised videos: bar calibration to fitted arm model
    (or, with ``params.arm`` None, to filtered trajectories only, as :func:`capture_walk`).

    Parameters
    ----------
    videos : (K, T, H, W) array
        Grey frames (uint8 or float) of the person from K synchronised cameras that look at
        the person from one side (the papers' triplet).
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
    level_videos : (K, Tl, H, W) array, optional
        The same cameras' frames of the bar stood upright with a spirit level: the world's
        up is then the bar's, not the tape's (:func:`~lsmta.systems.rig.level_rig`; the arm's
        torso frame takes its up from the world).
    progress : bool
        Progress bars per stage.
    params : BodySystemParams, optional
    seed : int
        Seeds the only random step (the rigid groups' sample of trajectories).

    Returns
    -------
    BodyCapture
        With ``calibration`` the bar calibration; nothing passed in is modified.
    """
    nominal = check_cameras(nominal_cameras, "nominal_cameras")
    v = check_videos(videos, "videos", nominal, min_frames=3)
    _frame_indices(frames, v.shape[1])          # refuse bad frames before the calibration
    fps = as_scalar(fps, "fps", positive=True)
    p = params or BodySystemParams()
    if not isinstance(p, BodySystemParams):
        raise TypeError(f"params: expected a BodySystemParams, got {type(p).__name__}")
    t0 = time.perf_counter()
    calibration = calibrate_rig(bar_videos, bar_length, nominal, intrinsics=p.intrinsics,
                                bar_sigma=p.bar_sigma, reject_k=p.reject_k,
                                level_videos=level_videos, progress=progress)
    seconds = time.perf_counter() - t0
    capture = capture_recording(v, calibration.cameras, fps=fps, frames=frames,
                                calibration=calibration, params=p.capture(),
                                progress=progress, seed=seed)
    return replace(capture, seconds={"calibration": seconds, **capture.seconds})




def capture_walk(videos, bar_videos, bar_length: float, nominal_cameras, *, fps: float = 25.0,
                 frames=None, level_videos=None, progress: bool = True,
                 params: BodySystemParams | None = None, seed: int = 0) -> BodyCapture:
    """Run the LSMTA system on a person moving through the volume: bar calibration, then
    the surfaces of the whole visible body tracked into filtered trajectories.

    :func:`capture_body` without the arm model (``params.arm`` is set to None), for the
    papers' triplet in front (one view group) or an all-round studio (one view group per
    side, e.g. per pole of two cameras): the bar's ends are made consistent frame by frame
    through the tape-measured cameras, so cameras facing each other calibrate together
    (tested on studio seeds 0-2 and 36 with 8 cameras on 4 poles; a studio of only two
    facing poles, 4 cameras, gave a 20 mm check-point error on seed 36 at half size). Every view
    group measures its surfaces from automatic seeds in the first frame and every
    ``params.density_every`` frames, tracks them, and its trajectories are intersected with
    its own cameras; all groups' trajectories go through the papers' filters together,
    by default with a walking person's limits and seeds spaced for the hands and feet
    (:meth:`BodySystemParams.walking`).

    Parameters
    ----------
    videos, bar_videos, bar_length, nominal_cameras, fps, frames, level_videos, progress, seed
        As :func:`capture_body`; ``videos`` from K >= 2 cameras that share bar positions.
    params : BodySystemParams, optional
        Its ``arm`` is ignored. Default: :meth:`BodySystemParams.walking` (your own params
        keep what they hold: notebook 05's filters and seeds 25 px apart unless you start
        from ``BodySystemParams.walking()``).

    Returns
    -------
    BodyCapture
        ``arm`` None; the filtered points of frame ``t`` are ``points_at(t)``.
    """
    p = params or BodySystemParams.walking()
    if not isinstance(p, BodySystemParams):
        raise TypeError(f"params: expected a BodySystemParams, got {type(p).__name__}")
    return capture_body(videos, bar_videos, bar_length, nominal_cameras, fps=fps,
                        frames=frames, level_videos=level_videos, progress=progress,
                        params=replace(p, arm=None), seed=seed)
