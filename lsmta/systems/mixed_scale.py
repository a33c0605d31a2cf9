"""Davis's mixed-scale system (2002, chapters 2-5, Figs. 4, 5, 50), closed: ceiling cameras
track LEDs on the body, their estimate steers pan-tilt heads, the heads film the face.

What goes in is what a user has: the ceiling cameras' frames with their time stamps and
frames of the empty room, the ceiling cameras and the pan-tilt heads as the library
calibrated them, the heads themselves as devices (they take commands and return a frame and
the angles they report), and a face model learnt from an earlier capture. The face markers
are identified by the system itself (:mod:`~lsmta.systems.face_identification`), or, for a
controlled study, by callables that stand for an operator labelling one frame per head by
hand, as the thesis does. The system sees nothing else; how realistic those inputs are is
the caller's affair (notebook 15 says what its simulation gives).
:func:`capture_mixed_scale` runs the stages:

1. *closed loop*, one tick per pan-tilt frame (``params.video_rate``): every ceiling frame
   that has arrived is searched for LEDs (:func:`~lsmta.widearea.detect`, thresholds
   learnt from the empty room: its maximum plus a multiple of its measured noise) and fed
   to the streaming tracker (:class:`~lsmta.widearea.WideAreaTracker`); the heads are
   steered from its newest estimate (:class:`~lsmta.pantilt.Steering`: the highest live
   target predicted ``params.lead`` s ahead, braking with it, coasted on the body's other
   targets while its track is dead, moved by ``params.aim_offset`` to the face, damped,
   every head aimed at it from its previous command; the first search starts from the
   angles the heads report before any command); each head then grabs its frame at the
   angles its motors reached and reports them;
2. *marker tracking* in each head's close-up video (:func:`~lsmta.tracking.markers.
   track_markers`), started from the identification of the first frame at which the heads
   have followed the same target for ``params.settle`` s: automatic
   (:func:`~lsmta.systems.face_identification.identify_face_markers`: dots, the face model's
   layout fitted and assigned, ``params.identify``; when it refuses, tried again on later
   frames, ``params.retry``) or the ``identify`` callables;
3. *triangulation* of every marker of every frame from one pair of heads, the best pair
   that sees it (:func:`~lsmta.systems.close_up.best_pairs`: of the pairs whose
   intersection passes the angle and reprojection checks, the one with the smallest
   predicted error, σ √(d_a² + d_b²) / sin θ; any number K >= 2 of heads; never the rays
   of three or more heads mixed in one marker, §5.2), each head the calibrated model at its
   read-back angles (:meth:`~lsmta.pantilt.PanTiltCamera.camera_at`), or with
   ``params.motor_fit`` at the angles recovered from the read-back and the commands
   (:func:`~lsmta.systems.readback.refine_readback`; identification and re-acquisition
   use them too);
4. *fill*: occluded and lost markers from the face model
   (:meth:`lsmta.face.FaceModel.fill`), the face per frame; measured markers far from the
   fitted face are dropped as wrong and the face is filled again;
5. *re-acquisition* (``params.reacquire`` passes): lost markers start again where the
   filled face, projected into a head at its read-back angles, falls on a dot
   (:func:`reacquisition_seeds`); tracking, triangulation and fill run again;
6. *body*: every LED track sampled at the frame times.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, fields

import numpy as np
from tqdm.auto import tqdm

from .._validate import as_array, as_int, as_scalar
from ..face import FaceModel
from ..face.basis import FaceFit
from ..pantilt import PanTiltCamera, Steering, SteeringParams
from ..tracking.markers import MarkerStatus, track_markers
from ..widearea import (
    EstimatorParams,
    TrackingResult,
    WideAreaTracker,
    detect,
    noise_threshold,
)
from .ceiling import CeilingFeed, arrival_order, check_ceiling_feed
from .checks import check_heads
from .close_up import best_pairs, first_settled, reacquisition_seeds
from .face_identification import FaceIdentification, IdentifyParams, identify_face_markers
from .readback import ReadbackRefinement, refine_readback


@dataclass(frozen=True)
class MixedScaleParams:
    """Settings of :func:`capture_mixed_scale`.

    The steering's fields, ``lead``, ``accel_window``, ``speed_up``, ``lead_height``,
    ``damping``, ``aim_offset``, ``head_margin``, ``coast``, ``body_radius`` and ``tol_px``,
    are explained at :class:`lsmta.pantilt.SteeringParams`, whose defaults they take
    (:attr:`steering` gathers them):
    the head predicted ``lead`` s beyond the tick (thesis: 0.3; 0: the newest estimate),
    braking with it (its acceleration over ``accel_window`` s), its height held; damped by
    α = ``damping``; moved by ``aim_offset`` (mm) to the face; the highest target, kept
    unless another is ``head_margin`` mm higher; coasted on the body within
    ``body_radius`` mm for up to ``coast`` s when its target dies; aimed to ``tol_px``.

    Attributes
    ----------
    video_rate : float
        Pan-tilt frames and commands per second, Hz.
    start, stop : float
        Clock times of the first pan-tilt frame and of the end of the recording, s.
    threshold_sigmas : float
        The LED thresholds: each pixel's maximum over the empty-room frames plus this many
        times the image noise measured in them (:func:`~lsmta.widearea.noise_threshold`),
        no fixed floor (a floor of 60 grey levels over a background of 30 missed the head
        LED seen dim by a far ceiling camera; 4 to 5 keep noise from passing).
    estimator : EstimatorParams
        The wide-area tracker's settings; default: a walking head's acceleration density
        (1e6 mm²/s³, notebook 12's), a target that dies and is born again within 0.3 s and
        100 mm of where it would be keeps its identity (``rejoin``), the rest
        :class:`~lsmta.widearea.EstimatorParams`'s.
    min_angle_deg : float
        Smallest ray angle of a triangulated marker, degrees.
    max_reprojection_px : float
        A triangulated marker whose intersection reprojects farther than this from its
        image in either head is dropped (a marker tracked onto its neighbour in one head), px.
        It must leave room for the heads' read-back: an angle reported to 0.1° (thesis §5.2)
        is off by up to 0.05°, 2.6 px at a principal distance of 3000 px; 1 px dropped half
        of notebook 15's markers, 4 px keeps them.
    max_fill_mm : float
        After a first fill, measured markers farther than this from the fitted face are
        dropped as wrong, and the face is filled again, mm.
    merge_px : float
        A marker image tracked to within this distance of another marker's image in the
        same head and frame is dropped, both of them (two markers tracked onto one dot: at
        most one is right; re-acquisition may restart them), px. 0: none dropped so.
    min_view_cos : float
        After the first fill, a measured marker is also dropped (and filled) where a head
        of its pair sees the fitted face's surface there at a grazing angle: the cosine
        between the surface's normal (the plane through the marker and its
        ``VIEW_NEIGHBOURS`` nearest neighbours in the fitted face, turned away from the
        face's centroid) and the line of sight to the head's centre below this. A dot seen
        edge-on crowds its neighbours in the image and is tracked onto them. -1 (the
        default): none dropped so.
    settle : float
        The markers are identified in the first frame at which the same head target has
        been aimed at for this long (its motors have caught up), s.
    reacquire : int
        Passes of re-acquisition: lost markers restarted where the filled face, projected
        into a head at its read-back angles, falls on a dot, then tracking, triangulation
        and fill again (0: markers lost stay lost, notebook 13's rule).
    dot_contrast : float
        A projected marker starts again only where the image is brighter than its 9 x 9
        neighbourhood's median by this much, grey levels (a dot is there, not skin).
    identify : IdentifyParams
        The automatic identification of the face markers in the first settled frame
        (:func:`~lsmta.systems.face_identification.identify_face_markers`), used when no
        ``identify`` callables are given.
    retry, retry_step : float
        When the automatic identification refuses (labels nothing), it is tried again on
        the frames ``retry_step`` s apart after the first settled one, for up to ``retry``
        s, and tracking starts from the first frame it labels; the frames before it have no
        face. A refusal is a view the identification does not trust (a face turned far
        from the heads, merged dots); a walking face turns a few degrees in 0.1 s, so a
        later frame is another view, at the price of one more identification (about a
        second) per try. 0: no retry, the capture goes on without a face.
    motor_fit : bool
        Triangulate, identify and re-acquire at the heads' angles recovered from their
        read-back and their commands (:func:`~lsmta.systems.readback.refine_readback`: each
        head's response to its commands fitted to its read-back over the recording, clipped
        into the encoder's interval) instead of at the read-back itself; only when every
        read-back lies on the ``encoder_step`` grid (an encoder of that step: the interval
        holds), else the read-back as it is (an exact or finer encoder). It assumes a motor
        linear in its commands (see :mod:`lsmta.systems.readback`). Its design (the window,
        the robust loss, the refusal rule) and the choice to have it on by default were made
        on two walks of notebook 15's setting, seeds 18 (the notebook's scored walk) and 20;
        the face error with and without it, on those and on fresh walks: notebook 15 and
        ``experiments/results/mixed_scale_motor_fit.json``. False: the read-back, as before.
    motor_window : float
        Seconds of commands before a frame that its angle depends on (``motor_fit``),
        enough for the motor's dead time and ramp (the thesis's dead time is 0.25-0.3 s);
        ``round(motor_window * video_rate)`` ticks (12 at 30 Hz).
    encoder_step : float
        The heads' encoder step, degrees (thesis §5.2: 0.1): the head is within half a step
        of its read-back (``motor_fit``).
    """

    video_rate: float = 30.0
    lead: float = SteeringParams.lead
    accel_window: float = SteeringParams.accel_window
    speed_up: bool = SteeringParams.speed_up
    lead_height: bool = SteeringParams.lead_height
    damping: float = SteeringParams.damping
    start: float = 0.9
    stop: float | None = None
    aim_offset: tuple = SteeringParams.aim_offset
    head_margin: float = SteeringParams.head_margin
    threshold_sigmas: float = 5.0
    estimator: EstimatorParams = field(
        default_factory=lambda: EstimatorParams(accel_density=1e6, rejoin=0.3))
    tol_px: float = SteeringParams.tol_px
    min_angle_deg: float = 2.0
    max_reprojection_px: float = 4.0
    max_fill_mm: float = 3.0
    merge_px: float = 0.0
    min_view_cos: float = -1.0
    coast: float = SteeringParams.coast
    body_radius: float = SteeringParams.body_radius
    settle: float = 0.5
    reacquire: int = 2
    dot_contrast: float = 30.0
    identify: IdentifyParams = field(default_factory=IdentifyParams)
    retry: float = 0.5
    retry_step: float = 0.1
    motor_fit: bool = True
    motor_window: float = 0.4
    encoder_step: float = 0.1

    def __post_init__(self):
        for key in ("video_rate", "threshold_sigmas", "min_angle_deg", "max_reprojection_px",
                    "max_fill_mm", "dot_contrast", "retry_step"):
            as_scalar(getattr(self, key), key, positive=True)
        for key in ("start", "settle", "retry", "merge_px"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_int(self.reacquire, "reacquire", minimum=0)
        if not -1.0 <= as_scalar(self.min_view_cos, "min_view_cos") <= 1.0:
            raise ValueError(f"min_view_cos: expected a cosine in [-1, 1], got {self.min_view_cos}")
        as_scalar(self.motor_window, "motor_window", nonnegative=True)
        as_scalar(self.encoder_step, "encoder_step", positive=True)
        if not isinstance(self.motor_fit, bool):
            raise TypeError(f"motor_fit: expected a bool, got {self.motor_fit!r}")
        _ = self.steering                   # building it checks the steering's fields
        if self.stop is not None and not as_scalar(self.stop, "stop") > self.start:
            raise ValueError(f"stop: expected a time after start={self.start}, got {self.stop}")
        if not isinstance(self.estimator, EstimatorParams):
            raise TypeError("estimator: expected an lsmta.widearea.EstimatorParams")
        if not isinstance(self.identify, IdentifyParams):
            raise TypeError("identify: expected an lsmta.systems.IdentifyParams")

    @property
    def motor_taps(self) -> int:
        """``motor_window`` in ticks of ``video_rate``: the commands before a frame that
        :func:`~lsmta.systems.readback.refine_readback` fits its angle to."""
        return int(round(self.motor_window * self.video_rate))

    @property
    def steering(self) -> SteeringParams:
        """The steering's fields as a :class:`lsmta.pantilt.SteeringParams`."""
        return SteeringParams(**{f.name: getattr(self, f.name) for f in fields(SteeringParams)})


@dataclass(frozen=True, eq=False)
class MixedScaleCapture:
    """Everything :func:`capture_mixed_scale` measured, stage by stage.

    Attributes
    ----------
    times : (F,) array
        Pan-tilt frame (and command) times, s.
    tracking : TrackingResult
        The wide-area tracker at the end.
    head_id : (F,) int array
        The target taken for the head at each tick (-1: none alive, no command).
    coasted : (F,) bool array
        The head's target had died and the aim came from the body's other targets
        (``params.coast``).
    aim_points : (F, 3) array
        Where the heads were aimed (predicted head + offset), mm; NaN without a command.
    commands, settings : (K, F, 2) arrays
        Commanded and read-back pan and tilt per head and frame, degrees.
    angles : (K, F, 2) array
        The pan and tilt the system triangulated at, degrees: ``settings``, or with
        ``params.motor_fit`` the angles recovered from the read-back and the commands.
    readback_fit : ReadbackRefinement or None
        The recovery of the angles (``params.motor_fit``): which head and axis were fitted
        (``fitted``; a refused fit keeps the read-back) and the fit's residual median. None:
        not tried (``motor_fit`` off, or a read-back off the ``encoder_step`` grid).
    images : (K, F, H, W) uint8 array or None
        The close-up videos (``keep_images``).
    markers : list of K MarkerTracks
        The last pass of the marker tracker.
    xy : (K, F, M, 2) array
        Marker positions found (tracked or second search), px; NaN elsewhere.
    points : (F, M, 3) array
        Triangulated markers, mm (NaN: no pair of heads saw the marker with a usable
        intersection, or dropped by the fill check).
    pairs : (F, M, 2) int array
        The pair of heads that measured each marker in each frame (``(-1, -1)``: none).
    face : FaceFit
        The face per frame, gaps filled from the face model.
    body : (F, N, 3) array
        Every LED track's position at the frame times, mm (NaN when not alive).
    first : int
        The frame in which the face markers were identified (the first settled one, or a
        later one when the automatic identification refused and was tried again; the last
        one tried when it always refused).
    identification : FaceIdentification or None
        The automatic identification in that frame (None: ``identify`` callables given).
    tries : int
        Frames on which the automatic identification was tried (0: ``identify`` callables).
    seconds : dict of str -> float
        Seconds per stage (``"identification"``: the automatic identification, a part of
        ``"marker tracking"``).
    params : MixedScaleParams
    """

    times: np.ndarray
    tracking: TrackingResult
    head_id: np.ndarray
    coasted: np.ndarray
    aim_points: np.ndarray
    commands: np.ndarray
    settings: np.ndarray
    images: np.ndarray | None
    markers: list
    xy: np.ndarray
    points: np.ndarray
    pairs: np.ndarray
    face: FaceFit
    body: np.ndarray
    first: int
    identification: FaceIdentification | None
    seconds: dict
    params: MixedScaleParams
    tries: int = 1
    angles: np.ndarray | None = None
    readback_fit: ReadbackRefinement | None = None

    def summary(self) -> list:
        """One row per stage: ``{"stage", "seconds", "result"}``."""
        tr = self.tracking
        found = np.isfinite(self.xy).all(axis=3)
        rows = [
            ("closed loop", f"{len(self.times)} ticks, {len(tr.tracks)} LED tracks, "
                            f"{int(tr.frames_used.sum())} ceiling frames used; commands in "
                            f"{int((self.head_id >= 0).sum())} ticks "
                            f"({int(self.coasted.sum())} coasted on the body)"),
            ("marker tracking", f"{found.mean():.1%} of marker images found per head; "
                                + ("identified by the callables" if self.identification
                                   is None else "identified automatically: "
                                   f"{int(self.identification.labelled.sum())} marker images")
                                + f" at t = {self.times[self.first]:.2f} s"),
            ("triangulation", f"{np.isfinite(self.points).all(axis=2).mean():.1%} of markers "
                              f"triangulated, {_angles_text(self.readback_fit)}"),
            ("fill", f"{int(self.face.fitted.sum())} of {len(self.times)} frames fitted"),
            ("re-acquisition", f"{self.params.reacquire} pass(es): lost markers restarted "
                               "from the filled face"),
            ("body", f"{self.body.shape[1]} LED tracks at the frame times"),
        ]
        return [{"stage": s, "seconds": self.seconds.get(s, float("nan")), "result": r}
                for s, r in rows]


def _angles_text(fit: ReadbackRefinement | None) -> str:
    """Which angles the heads were triangulated at, per head and axis (for summary())."""
    if fit is None:
        return "at the read-back angles (motor_fit not tried)"
    used = fit.fitted.any(axis=1)                                        # (K, 2)
    names = [f"head {k} {('pan', 'tilt')[a]}" for k, a in np.argwhere(~used)]
    res = ", ".join(f"{v:.4f}" for v in fit.residual_median.ravel())
    return ("at the angles recovered from the read-back and the commands"
            + (f", the read-back kept (fit refused) on {', '.join(names)}" if names else "")
            + f" (residual medians {res} deg)")


@dataclass
class _State:
    """What the stages of :func:`capture_mixed_scale` hand on."""

    feed: CeilingFeed
    heads: list
    devices: list
    identify: list | None
    face_model: FaceModel
    params: MixedScaleParams
    progress: bool
    times: np.ndarray
    tracker: WideAreaTracker | None = None
    head_id: np.ndarray | None = None
    coasted: np.ndarray | None = None
    head_since: np.ndarray | None = None
    aim_points: np.ndarray | None = None
    commands: np.ndarray | None = None
    settings: np.ndarray | None = None
    angles: np.ndarray | None = None
    readback_fit: ReadbackRefinement | None = None
    tick_commands: np.ndarray | None = None
    start_settings: np.ndarray | None = None
    images: np.ndarray | None = None
    markers: list | None = None
    starts: list | None = None
    first: int = 0
    identification: FaceIdentification | None = None
    identify_seconds: float = float("nan")
    tries: int = 0
    xy: np.ndarray | None = None
    points: np.ndarray | None = None
    pairs: np.ndarray | None = None
    face: FaceFit | None = None
    body: np.ndarray | None = None


def _closed_loop(st: _State) -> None:
    """One tick per pan-tilt frame: the ceiling frames arrived so far detected and fed to
    the tracker, the heads steered (:class:`~lsmta.pantilt.Steering`), their frames grabbed
    from ``params.start`` on."""
    p, feed = st.params, st.feed
    thresholds = [noise_threshold(b, sigmas=p.threshold_sigmas) for b in feed.backgrounds]
    # every pixel of a frame is tested on its own (detect's "full" mode): each camera's
    # frames are detected in one call (the same features as frame by frame, without
    # preparing the threshold again for every frame) and fed to the tracker as they arrive
    detections = [detect(np.asarray(frames), thr,
                         invalid=None if feed.invalid is None else feed.invalid[k])
                  for k, (frames, thr) in enumerate(zip(feed.frames, thresholds))]
    st.tracker = WideAreaTracker(feed.cameras, params=p.estimator)
    queue, q = arrival_order(feed), 0
    K, F = len(st.heads), len(st.times)
    st.head_id = np.full(F, -1)
    st.coasted = np.zeros(F, bool)
    st.head_since = np.full(F, np.nan)
    st.aim_points = np.full((F, 3), np.nan)
    st.commands = np.full((K, F, 2), np.nan)
    st.settings = np.full((K, F, 2), np.nan)
    images = None
    # the loop runs from the first ceiling frame; frames are kept from params.start on
    # (counted back from the first frame, 1 / video_rate apart, the earliest at or after the
    # first ceiling frame)
    early = int(np.floor((st.times[0] - queue[0, 0]) * p.video_rate + 1e-9))
    ticks = np.r_[st.times[0] - np.arange(early, 0, -1) / p.video_rate, st.times]
    # the aim's search starts from the angles each head reports before its first command
    start = [_grab(device, ticks[0], k)[1] for k, device in enumerate(st.devices)]
    st.start_settings = np.array(start)
    st.tick_commands = np.full((K, len(ticks), 2), np.nan)
    steering = Steering(st.heads, start, params=p.steering)
    first = len(ticks) - F
    for i, t in enumerate(tqdm(ticks, desc="closed loop", disable=not st.progress,
                               leave=False)):
        while q < len(queue) and queue[q, 0] <= t:
            k, j = int(queue[q, 1]), int(queue[q, 2])
            st.tracker.feed(k, float(feed.stamps[k][j]), detections[k].centroids(j))
            q += 1
        step = steering.step(st.tracker.estimate(), t)
        if step.settings is not None:
            st.tick_commands[:, i] = step.settings
            for device, setting in zip(st.devices, step.settings):
                device.command(t, setting)
        if i < first:
            continue
        f = i - first
        st.head_id[f], st.head_since[f], st.coasted[f] = step.head_id, step.since, step.coasted
        if step.settings is not None:
            st.aim_points[f] = step.aim_point
            st.commands[:, f] = step.settings
        grabbed = [_grab(device, t, k) for k, device in enumerate(st.devices)]
        st.settings[:, f] = [s for _, s in grabbed]
        if images is None:      # (K, F, H, W), filled in place: no list of frames to stack
            images = np.empty((K, F, *grabbed[0][0].shape), grabbed[0][0].dtype)
        for k, (img, _) in enumerate(grabbed):
            if img.shape != images.shape[2:] or img.dtype != images.dtype:
                raise ValueError(f"devices: head {k}'s grab({t:.3f}) returned a {img.dtype} "
                                 f"image of shape {img.shape}; expected {images.dtype} "
                                 f"{images.shape[2:]} as the first frame")
            images[k, f] = img
    st.images = images
    st.angles = st.settings
    steps = st.settings / p.encoder_step
    if p.motor_fit and np.allclose(steps, np.round(steps), rtol=0, atol=1e-6):
        st.readback_fit = refine_readback(st.tick_commands, st.settings, st.start_settings,
                                          step=p.encoder_step, taps=p.motor_taps)
        st.angles = st.readback_fit.angles


def _grab(device, t: float, k: int):
    img, s = device.grab(t)
    img = np.asarray(img)
    s = np.asarray(s, float)
    if img.ndim != 2 or s.shape != (2,) or not np.isfinite(s).all():
        raise ValueError(f"devices: head {k}'s grab({t:.3f}) returned an image of shape "
                         f"{img.shape} and a setting {s}; expected (H, W) and finite "
                         "(pan, tilt) degrees")
    return img, s


def _marker_tracking(st: _State) -> None:
    p = st.params
    st.first = first_settled(st.times, st.head_since, p.settle)
    if st.identify is None:
        t0 = time.perf_counter()
        for f in _tries(st.times, st.first, p.retry, p.retry_step):
            st.first, st.tries = f, st.tries + 1
            st.identification = identify_face_markers(
                st.images[:, f], st.heads, st.angles[:, f], st.face_model,
                params=p.identify)
            if st.identification.labelled.any():
                break
        st.identify_seconds = time.perf_counter() - t0
        st.starts = list(st.identification.xy)
        if not st.identification.labelled.any():
            _warn_refused(st.identification, p.identify, st.times[st.first], st.tries)
    else:
        st.starts = [as_array(f(st.times[st.first], st.settings[k, st.first]),
                              f"identify[{k}](...)", shape=(None, 2), allow_nan=True)
                     for k, f in enumerate(st.identify)]
    _track(st, None)


def _tries(times, first: int, retry: float, step: float) -> list:
    """The frames the identification is tried on: ``first``, then the first frame at or
    after each further ``step`` s, up to ``retry`` s after it (each frame once)."""
    out = [first]
    for dt in np.arange(step, retry + 1e-9, step):
        f = int(np.searchsorted(times, times[first] + dt - 1e-9))
        if f < len(times) and f > out[-1]:
            out.append(f)
    return out


def _warn_refused(ident: FaceIdentification, params: IdentifyParams, t: float,
                  tries: int) -> None:
    """Warn that the automatic identification labelled nothing: the capture goes on
    without a face."""
    why = (f"its fit's residual {ident.residual_mm:.2f} mm exceeds params.identify."
           f"max_residual_mm = {params.max_residual_mm:g} mm"
           if np.isfinite(ident.residual_mm) else
           f"no fit (residual found: none; params.identify.max_residual_mm = "
           f"{params.max_residual_mm:g} mm; {ident.n_points} stereo points)")
    warnings.warn(f"identify_face_markers labelled no face marker at t = {t:.3f} s "
                  f"({tries} frame(s) tried): {why}; "
                  "the capture continues without a face", RuntimeWarning, stacklevel=4)


def _track(st: _State, seeds) -> None:
    # a later pass tracks the same videos: the frames' dominant shifts and sharpness are the
    # first pass's
    before = st.markers
    st.markers, xy = [], []
    K, F = st.images.shape[:2]
    for k, start in enumerate(st.starts):
        s = np.full((F, len(start), 2), np.nan) if seeds is None else seeds[k].copy()
        s[st.first] = start                     # frame 0's start is its initial position
        initial = start if st.first == 0 else np.full((len(start), 2), np.nan)
        tr = track_markers(st.images[k], initial, seeds=s,
                           shifts=None if before is None else before[k].shift,
                           sharpness=None if before is None else before[k].sharpness)
        ok = np.isin(tr.status, (MarkerStatus.TRACKED, MarkerStatus.SECOND_SEARCH))
        if st.params.merge_px > 0:
            ok &= ~coinciding_markers(np.where(ok[..., None], tr.xy, np.nan),
                                      tol_px=st.params.merge_px)
        st.markers.append(tr)
        xy.append(np.where(ok[..., None], tr.xy, np.nan))
    st.xy = np.stack(xy)


def coinciding_markers(xy, *, tol_px: float = 1.0) -> np.ndarray:
    """``(F, M)`` bool: the marker images ``xy`` (F, M, 2) px (NaN: not found) within
    ``tol_px`` px of another marker's image in the same frame (markers tracked onto one
    dot); not modified."""
    xy = as_array(xy, "xy", shape=(None, None, 2), allow_nan=True)
    tol_px = as_scalar(tol_px, "tol_px", positive=True)
    gap = np.linalg.norm(xy[:, :, None] - xy[:, None], axis=3)           # (F, M, M)
    gap[:, np.arange(xy.shape[1]), np.arange(xy.shape[1])] = np.inf
    return (np.nan_to_num(gap, nan=np.inf) <= tol_px).any(axis=2)


def _reacquisition(st: _State) -> None:
    for _ in range(st.params.reacquire):
        seeds = reacquisition_seeds(st.images, st.heads, st.angles, st.face.frames,
                                    np.isfinite(st.xy).all(axis=3),
                                    dot_contrast=st.params.dot_contrast)
        if not np.isfinite(seeds).any():
            break
        _track(st, seeds)
        _triangulation(st)
        _fill(st)


def triangulate_frames(xy, heads, settings, *, min_angle_deg: float = 2.0,
                       max_reprojection_px: float = 1.0):
    """Stage 3 of :func:`capture_mixed_scale`: every marker of every frame triangulated from
    the best pair of heads that sees it (:func:`~lsmta.systems.close_up.best_pairs`: the
    usable pair with the smallest predicted error), each head
    ``heads[k].camera_at(*settings[k, f])``. With two heads every marker has the one pair.

    Parameters
    ----------
    xy : (K, F, M, 2) array
        Marker images, px (NaN: not found).
    heads : sequence of K >= 2 PanTiltCamera
    settings : (K, F, 2) array
        Pan and tilt of each head and frame, degrees.
    min_angle_deg, max_reprojection_px
        As :class:`MixedScaleParams`.

    Returns
    -------
    points : (F, M, 3) array
        mm; NaN where no pair gives a usable intersection (seen by both, the rays' angle,
        the reprojection check).
    pairs : (F, M, 2) int array
        The heads that measured each marker, ``(-1, -1)`` where none.
    """
    heads = list(heads)
    if len(heads) < 2 or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError("heads: expected at least 2 calibrated lsmta.pantilt.PanTiltCamera")
    xy = as_array(xy, "xy", shape=(len(heads), None, None, 2), allow_nan=True)
    settings = as_array(settings, "settings", shape=(len(heads), xy.shape[1], 2))
    K, F, M = xy.shape[:3]
    points = np.full((F, M, 3), np.nan)
    pairs = np.full((F, M, 2), -1)
    for f in range(F):
        cams = [h.camera_at(*settings[k, f]) for k, h in enumerate(heads)]
        r = best_pairs(cams, xy[:, f], min_angle_deg=min_angle_deg,
                       max_reprojection_px=max_reprojection_px)
        points[f], pairs[f] = r.points, r.pair
    return points, pairs


def _triangulation(st: _State) -> None:
    st.points, st.pairs = triangulate_frames(
        st.xy, st.heads, st.angles, min_angle_deg=st.params.min_angle_deg,
        max_reprojection_px=st.params.max_reprojection_px)


#: Neighbours of a marker in the fitted face whose plane gives its surface normal
#: (``MixedScaleParams.min_view_cos``)
VIEW_NEIGHBOURS = 6


def _view_cosines(model, centres, pairs):
    """(F, M) smallest cosine, over the heads of each marker's pair, between the fitted
    face's surface normal at the marker (``model`` (F, M, 3) mm; the plane through it and
    its nearest neighbours, turned away from the face's centroid) and its line of sight to
    the head (``centres`` (K, F, 3) mm); NaN where no pair or no fitted face."""
    ref = np.nanmean(model, axis=0)
    gap = np.linalg.norm(ref[:, None] - ref[None], axis=2)
    near = np.argsort(np.nan_to_num(gap, nan=np.inf), axis=1)[:, :VIEW_NEIGHBOURS + 1]
    patch = model[:, near]                                                   # (F, M, k, 3)
    patch = patch - patch.mean(axis=2, keepdims=True)
    cov = np.einsum("fmki,fmkj->fmij", patch, patch)
    ok = np.isfinite(cov).all(axis=(2, 3))
    normal = np.full(model.shape, np.nan)
    normal[ok] = np.linalg.eigh(cov[ok])[1][..., 0]
    out = model - np.nanmean(model, axis=1, keepdims=True)
    normal *= np.where(np.einsum("fmi,fmi->fm", normal, out) < 0, -1.0, 1.0)[..., None]
    cosine = np.full(pairs.shape, np.nan)
    for j in range(2):
        k = np.clip(pairs[..., j], 0, None)
        ray = centres[k, np.arange(len(k))[:, None]] - model                 # (F, M, 3)
        cosine[..., j] = np.einsum("fmi,fmi->fm", normal, ray) / np.linalg.norm(ray, axis=2)
    return np.where((pairs >= 0).all(axis=2), cosine.min(axis=2), np.nan)


def fill_face(points, face_model: FaceModel, *, max_fill_mm: float = 3.0, views=None,
              min_view_cos: float = -1.0):
    """Stage 4 of :func:`capture_mixed_scale`: the face per frame filled from the face
    model; measured markers farther than ``max_fill_mm`` (mm) from that first fitted face,
    or seen by a head of their pair at a grazing angle to it (``views``,
    ``min_view_cos``: :class:`MixedScaleParams`), are dropped as wrong and the face is
    filled again.

    Parameters
    ----------
    points : (F, M, 3) array
        Triangulated markers, mm (NaN: not measured).
    face_model : lsmta.face.FaceModel
    max_fill_mm : float
    views : tuple ``(centres (K, F, 3) mm, pairs (F, M, 2) int)``, optional
        The heads' projection centres per frame and the pair that measured each marker
        (:func:`triangulate_frames`); needed when ``min_view_cos > -1``.
    min_view_cos : float

    Returns
    -------
    points : (F, M, 3) array
        ``points`` with the dropped markers NaN (a new array).
    face : FaceFit
    """
    if not isinstance(face_model, FaceModel):
        raise TypeError(f"face_model: expected an lsmta.face.FaceModel, got "
                        f"{type(face_model).__name__}")
    points = as_array(points, "points", shape=(None, None, 3), allow_nan=True)
    max_fill_mm = as_scalar(max_fill_mm, "max_fill_mm", positive=True)
    min_view_cos = as_scalar(min_view_cos, "min_view_cos")
    if min_view_cos > -1 and views is None:
        raise ValueError("views: expected (centres, pairs) with min_view_cos > -1")
    first = face_model.fill(points)
    with np.errstate(invalid="ignore"):
        wrong = np.linalg.norm(points - first.model, axis=2) > max_fill_mm
        if min_view_cos > -1:
            centres = as_array(views[0], "views[0]", shape=(None, len(points), 3))
            pairs = np.asarray(views[1])
            if pairs.shape != points.shape[:2] + (2,):
                raise ValueError(f"views[1]: expected pairs of shape {points.shape[:2] + (2,)}, "
                                 f"got {pairs.shape}")
            wrong |= _view_cosines(first.model, centres, pairs) < min_view_cos
    points = np.where(wrong[..., None], np.nan, points)
    return points, (face_model.fill(points) if wrong.any() else first)


def _fill(st: _State) -> None:
    views = None
    if st.params.min_view_cos > -1:
        views = (np.array([[h.camera_at(*a).C for a in angles]
                           for h, angles in zip(st.heads, st.angles)]), st.pairs)
    st.points, st.face = fill_face(st.points, st.face_model, max_fill_mm=st.params.max_fill_mm,
                                   views=views, min_view_cos=st.params.min_view_cos)
    st.pairs = np.where(np.isnan(st.points).any(axis=2)[..., None], -1, st.pairs)


def _body(st: _State) -> None:
    st.body = st.tracker.result().positions_at(st.times)


STAGES = (("closed loop", _closed_loop), ("marker tracking", _marker_tracking),
          ("triangulation", _triangulation), ("fill", _fill),
          ("re-acquisition", _reacquisition), ("body", _body))


def capture_mixed_scale(ceiling: CeilingFeed, heads, devices, identify, face_model: FaceModel,
                        *, params: MixedScaleParams | None = None, keep_images: bool = True,
                        progress: bool = True) -> MixedScaleCapture:
    """Run the mixed-scale system: LEDs tracked from the ceiling steer the pan-tilt heads,
    whose close-up videos give the face per frame (see the module).

    Parameters
    ----------
    ceiling : CeilingFeed
        The ceiling cameras (calibrated), their frames, stamps and empty-room frames.
    heads : sequence of K >= 2 PanTiltCamera
        The pan-tilt heads as calibrated (notebook 11's procedure).
    devices : sequence of K objects
        The heads themselves: ``command(t, setting)`` sends a (pan, tilt) in degrees at time
        ``t`` (s); ``grab(t)`` returns the frame ``(H, W)`` at ``t`` and the setting the head
        reports (its motors' angles, degrees).
    identify : sequence of K callables or None
        None: the face markers are identified automatically in the first frame at which the
        heads have followed the same target for ``params.settle`` s
        (:func:`~lsmta.systems.face_identification.identify_face_markers`: dots, stereo,
        the face model's layout fitted and assigned; when it labels nothing, a
        ``RuntimeWarning`` names the fit's residual and ``params.identify.max_residual_mm``
        and the capture goes on without a face). Or ``identify[k](t, setting)``: the M
        face markers identified by hand in head k's frame at time ``t`` (that frame),
        ``(M, 2)`` px, NaN for markers not seen.
    face_model : lsmta.face.FaceModel
        Learnt from an earlier capture of the same markers (:func:`lsmta.face.learn`).
    params : MixedScaleParams, optional
    keep_images : bool
        Keep the close-up videos in the result.
    progress : bool

    Returns
    -------
    MixedScaleCapture
        Nothing passed in is modified.
    """
    feed = check_ceiling_feed(ceiling)
    heads, devices, identify = check_heads(heads, devices, identify)
    if not isinstance(face_model, FaceModel):
        raise TypeError(f"face_model: expected an lsmta.face.FaceModel, got "
                        f"{type(face_model).__name__}")
    p = MixedScaleParams() if params is None else params
    if not isinstance(p, MixedScaleParams):
        raise TypeError(f"params: expected a MixedScaleParams, got {type(p).__name__}")
    last = max(float(np.max(s)) for s in feed.stamps)
    stop = last if p.stop is None else min(p.stop, last)
    times = np.arange(p.start, stop, 1.0 / p.video_rate)
    if len(times) < 3:
        raise ValueError(f"params.start: the recording from {p.start} s to {stop:.3f} s (the "
                         "last ceiling stamp or params.stop) has fewer than 3 frames")
    st = _State(feed=feed, heads=heads, devices=devices, identify=identify,
                face_model=face_model, params=p, progress=progress,
                times=times)
    seconds = {}
    for name, stage in tqdm(STAGES, desc="mixed-scale system", disable=not progress):
        t0 = time.perf_counter()
        stage(st)
        seconds[name] = time.perf_counter() - t0
    if st.identification is not None:        # part of "marker tracking"
        seconds["identification"] = st.identify_seconds
    return MixedScaleCapture(times=times, tracking=st.tracker.result(), head_id=st.head_id,
                             coasted=st.coasted, aim_points=st.aim_points, commands=st.commands,
                             settings=st.settings,
                             images=st.images if keep_images else None, markers=st.markers,
                             xy=st.xy, points=st.points, pairs=st.pairs, face=st.face,
                             body=st.body, first=st.first, tries=st.tries,
                             identification=st.identification, seconds=seconds, params=p,
                             angles=st.angles, readback_fit=st.readback_fit)

