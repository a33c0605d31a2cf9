"""The mixed-scale system (Davis 2002, Figs. 4, 5, 50) run on a generated walk and scored
after the fact against the truth.

* :func:`calibrate_scene` — the ceiling rig and the pan-tilt heads calibrated by the
  library's own procedures from generated observations (the ceiling: resection of a
  tape-measured guess from surveyed LED positions, :func:`lsmta.calibration.resect_all`,
  the LED's image points either projected truth plus noise or found by the detector in
  rendered frames, :func:`ceiling_survey_centroids`;
  each head: intrinsics from one view of a 3-D target of LEDs, then home pose and axes from
  sweeps, :func:`lsmta.pantilt.calibrate` — notebook 11's procedure with a precise target,
  the LEDs' image points either found by the detector in rendered frames or projected
  truth plus noise, :mod:`lsmta.evaluation.head_survey`);
* :func:`walk_inputs` — what the system receives for a walk: the ceiling feed, the heads
  as devices, hand labels of a frame of each, a face model learnt from another capture;
* :func:`score_capture` — the error budget per stage against the truth;
* :func:`face_split` — the face's median error over measured and over filled markers;
* :func:`hidden_shares` — the share of the face's marker-frames each occlusion rule hides;
* :func:`label_score` — the face markers' first-frame labels (automatic or by hand)
  against the generator's: correct, wrong and missed (:func:`label_outcome`, the rule);
* :func:`exact_readback` — a controlled study: the same marker images triangulated (and
  filled) at the read-back, at the angles the heads were at, as if they reported them
  exactly, and at the angles the system used;
* :func:`face_at_angles` — the same marker images triangulated and filled at any angles;
* :func:`angle_error_parts` — the face's error when only the common or the differential
  part of two heads' pan or tilt error is left;
* :data:`MOTOR_FIT_RESULT`, :func:`read_motor_fit_result` — the committed face errors
  over ten walks with the angles recovered (``motor_fit``) and at the read-back
  (:data:`OCCLUSION_RESULT`: the same walks with the ray-cast self-occlusion on and the
  view gate; :data:`OCCLUSION_NO_GATE_RESULT`: on, without the gate);
* :data:`VIEW_GATE_DESIGN_RESULT`, :func:`read_view_gate_design` — the runs the view
  gate's ``min_view_cos`` was chosen on;
* :data:`HEADS_RESULT`, :func:`read_heads_result` — the committed result of
  ``experiments/mixed_scale_system.py --heads 2 4`` (two heads against four over seeds),
  which notebook 15 quotes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import as_array, as_int, as_rng, as_scalar
from ..calibration import resect_all
from ..face import distance_deviation, learn
from ..synth.calibration import led_path, poor_guess, project_observations
from ..synth.face import face_sequence, visible
from ..synth.mixed_scale import (
    MixedScaleScene,
    SimulatedHead,
    ceiling_videos,
    hand_labels,
)
from ..synth.widearea import LedScene, LedVideoParams, render_led_video
from ..systems import CeilingFeed, MixedScaleCapture, fill_face, triangulate_frames
from ..widearea import detect, noise_threshold
from .head_survey import calibrate_head
from .track_scores import score_led_tracks

# the committed result of `experiments/mixed_scale_system.py --heads ...`, in the repository
# (written by the experiment, read by notebook 15 and its test; one place for the path)
HEADS_RESULT = Path(__file__).resolve().parents[2] / "experiments" / "results" \
    / "mixed_scale_heads.json"
# the committed result of `experiments/mixed_scale_system.py --seed 18 --seeds 10
# --no-baseline`: the face error with motor_fit (and at the read-back) per walk, quoted by
# notebook 15 (seeds 18 and 20 are the walks motor_fit was designed on)
MOTOR_FIT_RESULT = HEADS_RESULT.with_name("mixed_scale_motor_fit.json")
# the committed result of `experiments/mixed_scale_system.py --seed 18 --seeds 10 --no-baseline
# --occlusion surface --min-view-cos 0.4`: the same walks with the ray-cast self-occlusion on
# and the system's view gate (designed on seeds 18 and 20), quoted by notebook 15
OCCLUSION_RESULT = HEADS_RESULT.with_name("mixed_scale_occlusion.json")
# the same command without --min-view-cos: self-occlusion on, no view gate
OCCLUSION_NO_GATE_RESULT = HEADS_RESULT.with_name("mixed_scale_occlusion_no_gate.json")
# the view gate's design runs: notebook 15's walk at each min_view_cos tried, seeds 18 and 20
VIEW_GATE_DESIGN_RESULT = HEADS_RESULT.with_name("mixed_scale_view_gate_design.json")
HEADS_FIELDS = ("measured", "covered", "face_median_mm", "rigid_median_mm", "labels_correct",
                "labels_coverage", "tries")   # per number of heads, one value per seed


def _result_file(path: Path, keys) -> dict | None:
    """A committed result file's fields (None when it is absent); refuses one that lacks any
    of ``keys``."""
    if not path.is_file():
        return None
    data = json.loads(path.read_text(encoding="utf-8"))
    for key in keys:
        if key not in data:
            raise ValueError(f"path: {path.name} has no {key!r}")
    return data


def read_heads_result(*, path=None) -> dict | None:
    """The committed two-against-four-heads result (:data:`HEADS_RESULT` unless ``path``),
    or None when there is no such file.

    Returns
    -------
    dict or None
        ``command``, ``date``, ``seeds`` (list of int), ``settings`` (dict) and ``heads``:
        for each number of heads (a str key, "2", "4"), :data:`HEADS_FIELDS` each as a
        (S,) float array over the seeds (NaN: none, e.g. no face when the identification
        refused); ``seeds_met``: each target's share of seeds met.

    Raises
    ------
    ValueError
        When the file lacks a field or a list's length is not the number of seeds.
    """
    path = HEADS_RESULT if path is None else Path(path)
    data = _result_file(path, ("command", "date", "seeds", "settings", "heads", "seeds_met"))
    if data is None:
        return None
    n = len(data["seeds"])
    for K, per in data["heads"].items():
        for key in HEADS_FIELDS:
            v = np.array([np.nan if x is None else x for x in per.get(key, [])], float)
            if v.shape != (n,):
                raise ValueError(f"path: {path.name}'s heads[{K!r}][{key!r}] has "
                                 f"{v.size} values; expected one per seed ({n})")
            per[key] = v
    return data


def read_motor_fit_result(*, path=None) -> dict | None:
    """The committed face errors over walks (:data:`MOTOR_FIT_RESULT` unless ``path``), or
    None when there is no such file.

    Returns
    -------
    dict or None
        ``command``, ``date``, ``motor_fit`` (bool: the system's angles were recovered),
        ``seeds`` (S,) int array, and (S,) float arrays in mm (NaN: the seed failed or had
        no face): ``face_median_mm`` (the system's), ``readback_face_mm`` (the same images
        at the read-back angles) and ``true_angles_face_mm`` (at the heads' true angles);
        ``face_measured_mm``, ``face_filled_mm`` and ``face_fitted`` (the share of frames
        with a face); ``labels_correct`` and ``labels_coverage``, the first frame's labels
        correct of those given and of the marker images drawn (shares; NaN: not recorded);
        ``occlusion`` and ``min_view_cos``, the run's rule and gate ("normals" and -1 for
        runs that recorded none).

    Raises
    ------
    ValueError
        When the file lacks a field.
    """
    path = MOTOR_FIT_RESULT if path is None else Path(path)
    data = _result_file(path, ("command", "date", "seeds", "motor_fit"))
    if data is None:
        return None
    seeds = sorted(data["seeds"], key=int)

    def value(seed, get):
        r = data["seeds"][seed]
        try:
            v = get(r)
        except (KeyError, IndexError, TypeError):
            return np.nan
        return np.nan if v is None else float(v)

    return {"command": data["command"], "date": data["date"],
            "motor_fit": bool(data["motor_fit"]),
            "occlusion": data.get("occlusion", "normals"),
            "min_view_cos": float(data.get("min_view_cos", -1.0)),
            **{key: np.array([value(s, lambda r, key=key: r[key]) for s in seeds])
               for key in ("face_measured_mm", "face_filled_mm", "face_fitted",
                           "labels_coverage")},
            "labels_correct": np.array([value(s, lambda r: r["labels_correct_share"])
                                        for s in seeds]),
            "seeds": np.array([int(s) for s in seeds]),
            "face_median_mm": np.array([value(s, lambda r: r["face_median_mm"])
                                        for s in seeds]),
            "readback_face_mm": np.array([value(s, lambda r: r["detail"]
                                                ["readback_face_median_mm"][0][0])
                                          for s in seeds]),
            "true_angles_face_mm": np.array([value(s, lambda r: r["detail"]
                                                   ["readback_face_median_mm"][1][0])
                                             for s in seeds])}


def read_view_gate_design(*, path=None) -> dict | None:
    """The committed design runs of the view gate (:data:`VIEW_GATE_DESIGN_RESULT` unless
    ``path``), or None when there is no such file.

    Returns
    -------
    dict or None
        The file's fields; ``min_view_cos`` (C,) array (the gates tried), ``seeds`` (S,) int
        array and, per field of ``runs``, an (S, C) float array (``face_median_mm``,
        ``face_measured_mm``, ``face_filled_mm`` in mm; ``measured``, ``fitted`` shares;
        ``rigid_median_mm``).

    Raises
    ------
    ValueError
        When the file lacks a field or a run's length is not the number of gates.
    """
    path = VIEW_GATE_DESIGN_RESULT if path is None else Path(path)
    data = _result_file(path, ("commands", "date", "occlusion", "min_view_cos", "chosen", "runs"))
    if data is None:
        return None
    gates = np.array(data["min_view_cos"], float)
    seeds = sorted(data["runs"], key=int)
    fields = sorted({k for s in seeds for k in data["runs"][s]})
    out = {**data, "min_view_cos": gates, "seeds": np.array([int(s) for s in seeds])}
    for key in fields:
        v = np.array([data["runs"][s].get(key, [np.nan] * len(gates)) for s in seeds], float)
        if v.shape != (len(seeds), len(gates)):
            raise ValueError(f"path: {path.name}'s runs[...][{key!r}] has shape {v.shape}; "
                             f"expected one value per gate ({len(gates)})")
        out[key] = v
    return out


@dataclass(frozen=True, eq=False)
class SceneCalibration:
    """The cameras as the library calibrated them.

    Attributes
    ----------
    ceiling : list of Camera
    heads : list of PanTiltCamera
    ceiling_rms_px : (K,) array
        Image RMS of each ceiling camera on an independent LED path against the true
        cameras, px (a score that uses the truth).
    head_rms_px : (K,) array
        Image RMS of each head on held-out sweep points (true points, true images), px.
    ceiling_fit_rms_px : (K,) array
        Reprojection RMS of each ceiling camera on its own calibration image points, px
        (the calibration's own residual: no truth beyond the surveyed LED positions).
    ceiling_from_images : bool
        True: the ceiling's image points were found in rendered frames
        (:func:`ceiling_survey_centroids`); False: projected truth plus noise.
    head_fit_rms_px : (K,) array
        Reprojection RMS of each head's sweeps fit on its own image points, px (no truth).
    head_points : (K, 2) int array
        Per head: calibration image points found, and offered (target and sweeps).
    heads_from_images : bool
        True: the heads' image points were found in rendered frames
        (:func:`lsmta.evaluation.head_survey.head_target_centroids`); False: projected
        truth plus noise (the route for controlled studies).
    """

    ceiling: list
    heads: list
    ceiling_rms_px: np.ndarray
    head_rms_px: np.ndarray
    ceiling_fit_rms_px: np.ndarray
    ceiling_from_images: bool
    head_fit_rms_px: np.ndarray
    head_points: np.ndarray
    heads_from_images: bool


@dataclass(frozen=True, eq=False)
class CeilingCalibration:
    """The ceiling cameras resected by :func:`calibrate_ceiling`.

    Attributes
    ----------
    cameras : list of K Camera
    check_rms_px : (K,) array
        Image RMS on an independent LED path against the true cameras, px.
    fit_rms_px : (K,) array
        Reprojection RMS on the calibration's own image points (surveyed positions), px.
    n_points : (K,) int array
        Image points each camera was resected from.
    from_images : bool
        Whether the image points were found in rendered frames.
    """

    cameras: list
    check_rms_px: np.ndarray
    fit_rms_px: np.ndarray
    n_points: np.ndarray
    from_images: bool


def _monitor_mask(video) -> np.ndarray:
    """The operator's mask of a ceiling video: its monitor's box and 2 px around it."""
    m = np.zeros(video.frames.shape[1:], bool)
    x0, y0, x1, y1 = video.monitor.astype(int)
    m[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = True
    return m


def ceiling_survey_centroids(scene: MixedScaleScene, X, *,
                             rng: np.random.Generator | int | None = None,
                             threshold_sigmas: float = 5.0) -> np.ndarray:
    """The calibration LED found in rendered ceiling frames, one frame per position.

    Each ceiling camera of ``scene`` films the LED (facing up, as the body's LEDs) at each
    of ``X`` (:func:`lsmta.synth.widearea.render_led_video`, the room, monitor and image
    noise of the walk's ceiling frames, no flicker or reflections, as
    :func:`lsmta.synth.mixed_scale.ceiling_videos`). The library's detector then finds it
    as the system does: thresholds ``threshold_sigmas`` times the image noise over the
    empty room's frames (:func:`lsmta.widearea.noise_threshold`), every pixel tested
    (:func:`lsmta.widearea.detect`), the monitor masked (the operator's mask of
    :func:`walk_inputs`). A frame with exactly one feature gives its centroid; none or
    several (a reflection, a split spot) give NaN.

    Parameters
    ----------
    scene : MixedScaleScene
    X : (N, 3) array
        The LED's positions, mm.
    rng : numpy.random.Generator, int or None
        The rendered frames' image noise.
    threshold_sigmas : float
        The detection threshold's offset in units of the measured image noise (> 0).

    Returns
    -------
    (K, N, 2) array
        Intensity centroids, px (NaN: not found or ambiguous).
    """
    X = as_array(X, "X", shape=(None, 3))
    if len(X) < 2:
        raise ValueError(f"X: expected at least 2 LED positions, got {len(X)}")
    sigmas = as_scalar(threshold_sigmas, "threshold_sigmas", positive=True)
    rng = as_rng(rng)
    times = np.arange(len(X), dtype=float)          # one sample per frame: no interpolation
    normals = np.zeros((len(X), 1, 3))
    normals[..., 2] = 1.0
    leds = LedScene(name="calibration LED", times=times, positions=X[:, None].copy(),
                    normals=normals, on=np.array([[0.0, np.inf]]))
    params = LedVideoParams(monitor_flicker=0.0, reflections=0.0)
    out = np.full((len(scene.ceiling), len(X), 2), np.nan)
    for k, cam in enumerate(scene.ceiling):
        v = render_led_video(leds, cam, times, rng=rng, params=params)
        found = detect(v.frames, noise_threshold(v.background, sigmas=sigmas),
                       invalid=_monitor_mask(v))
        one = np.flatnonzero(np.diff(found.start) == 1)
        out[k, one] = found.xy[found.start[one]]
    return out


def calibrate_ceiling(scene: MixedScaleScene, *, rng: np.random.Generator | int | None = None,
                      image_sigma: float = 0.3, world_sigma: float = 0.3, n_survey: int = 300,
                      from_images: bool = False,
                      threshold_sigmas: float = 5.0) -> CeilingCalibration:
    """The ceiling cameras resected from a tape-measured guess
    (:func:`lsmta.synth.calibration.poor_guess`) with ``n_survey`` LED positions surveyed to
    ``world_sigma`` mm (:func:`lsmta.calibration.resect_all`).

    The LED's image points: with ``from_images``, found by the library's detector in
    rendered frames (:func:`ceiling_survey_centroids` with ``threshold_sigmas``;
    ``image_sigma`` is then unused); otherwise its true projections plus ``image_sigma`` px
    of Gaussian noise.

    Returns
    -------
    CeilingCalibration
    """
    if not isinstance(from_images, (bool, np.bool_)):
        raise TypeError(f"from_images: expected True or False, got {from_images!r}")
    n_survey = as_int(n_survey, "n_survey", minimum=10)
    image_sigma = as_scalar(image_sigma, "image_sigma", nonnegative=True)
    world_sigma = as_scalar(world_sigma, "world_sigma", nonnegative=True)
    rng = as_rng(rng)
    box = dict(center=(0.0, 0.0, 1300.0), half_size=(1900.0, 2500.0, 500.0))
    X = led_path(n=n_survey, rng=rng, **box)
    # both routes draw the same numbers from rng (the renderer draws from a child of it):
    # survey noise, start and check path are then the same, and only the route differs
    xy = project_observations(scene.ceiling, X, rng=rng, sigma_px=image_sigma)
    if from_images:
        xy = ceiling_survey_centroids(scene, X, rng=rng.spawn(1)[0],
                                      threshold_sigmas=threshold_sigmas)
    Xs = X + rng.normal(0, world_sigma, X.shape)
    guess = poor_guess(scene.ceiling, rng=rng, pose_mm=100.0, pose_deg=2.0, f_rel=0.03)
    ceiling = resect_all(guess, Xs, xy, n_iter=60)
    fit = project_observations(ceiling, Xs) - xy
    check = led_path(n=100, rng=rng, **box)
    d = project_observations(scene.ceiling, check) - project_observations(ceiling, check)
    return CeilingCalibration(
        cameras=ceiling, check_rms_px=np.sqrt(np.nanmean(np.sum(d**2, axis=2), axis=1)),
        fit_rms_px=np.sqrt(np.nanmean(np.sum(fit**2, axis=2), axis=1)),
        n_points=np.isfinite(xy).all(axis=2).sum(axis=1), from_images=bool(from_images))


def calibrate_heads(heads, *, rng: np.random.Generator | int | None = None,
                    image_sigma: float = 0.3, world_sigma: float = 0.3,
                    distortion=("k1",), from_images: bool = False):
    """Each head calibrated by notebook 11's procedure with a precise target
    (:func:`lsmta.evaluation.head_survey.calibrate_head`): intrinsics (``distortion``
    terms) from one view of a 3-D target, then home pose and axes of the general model from
    the thesis's sweeps. The image points: with ``from_images``, the target's LEDs found by
    the detector in rendered frames; otherwise projected truth plus ``image_sigma`` px.

    Returns
    -------
    (list of PanTiltCamera, (K,) image RMS on held-out sweep settings, true points, px)
    """
    fits = _head_fits(heads, rng=as_rng(rng), image_sigma=image_sigma,
                      world_sigma=world_sigma, distortion=distortion, from_images=from_images)
    return [f.model for f in fits], np.array([f.check_rms_px for f in fits])


def _head_fits(heads, *, rng, image_sigma, world_sigma, distortion, from_images):
    """Each of ``heads`` calibrated (:func:`lsmta.evaluation.head_survey.calibrate_head`),
    a list of HeadCalibration."""
    return [calibrate_head(h, rng=rng, from_images=from_images, image_sigma=image_sigma,
                           world_sigma=world_sigma, distortion=distortion) for h in heads]


def calibrate_scene(scene: MixedScaleScene, *, rng: np.random.Generator | int | None = None,
                    image_sigma: float = 0.3, world_sigma: float = 0.3,
                    from_images: bool = False,
                    heads_from_images: bool | None = None) -> SceneCalibration:
    """The ceiling rig and the heads of ``scene`` calibrated (:func:`calibrate_ceiling`,
    :func:`lsmta.evaluation.head_survey.calibrate_head`, both with ``image_sigma`` px and
    ``world_sigma`` mm).

    ``from_images``: the calibration targets found in rendered frames, the ceiling's LED
    (about 1 s per camera for 300 positions) and the heads' LEDs (a few seconds per head
    for about 580 frames), instead of projected truth plus noise. ``heads_from_images`` (default:
    ``from_images``) sets the heads' route alone, e.g. the projected route for a controlled
    study."""
    rng = as_rng(rng)
    heads_from_images = from_images if heads_from_images is None else heads_from_images
    c = calibrate_ceiling(scene, rng=rng, image_sigma=image_sigma, world_sigma=world_sigma,
                          from_images=from_images)
    fits = _head_fits(scene.heads, rng=rng, image_sigma=image_sigma, world_sigma=world_sigma,
                      distortion=("k1",), from_images=heads_from_images)
    return SceneCalibration(ceiling=c.cameras, heads=[f.model for f in fits],
                            ceiling_rms_px=c.check_rms_px,
                            head_rms_px=np.array([f.check_rms_px for f in fits]),
                            ceiling_fit_rms_px=c.fit_rms_px,
                            ceiling_from_images=c.from_images,
                            head_fit_rms_px=np.array([f.fit_rms_px for f in fits]),
                            head_points=np.array([[f.n_used, f.n_points] for f in fits]),
                            heads_from_images=bool(heads_from_images))


def head_devices(scene: MixedScaleScene, *, heads=None,
                 rng: np.random.Generator | int | None = None, video_rate: float = 30.0,
                 fixed: bool = False, start=(0.0, 0.0), readback_step: float = 0.1,
                 readback_noise: float = 0.0):
    """The true heads (default ``scene.heads``) as devices
    (:class:`lsmta.synth.mixed_scale.SimulatedHead`, reporting their angles in
    ``readback_step`` degrees with ``readback_noise``) and an operator's hand labels of each
    (0.5 px). ``fixed``: cameras on fixed mounts at ``start``."""
    rng = as_rng(rng)
    heads = scene.heads if heads is None else heads
    devices = [SimulatedHead(h, scene, period=1.0 / video_rate, rng=rng, fixed=fixed,
                             start=start, readback_step=readback_step,
                             readback_noise=readback_noise) for h in heads]
    return devices, [hand_labels(d, rng=rng) for d in devices]


@dataclass(frozen=True, eq=False)
class WalkInputs:
    """What :func:`lsmta.systems.capture_mixed_scale` gets for a walk (and the devices, to
    read their truth afterwards)."""

    ceiling: CeilingFeed
    devices: list
    identify: list
    face_model: object
    videos: object


def walk_inputs(scene: MixedScaleScene, calibration: SceneCalibration, *,
                rng: np.random.Generator | int | None = None, n_train: int = 300,
                train_noise: float = 0.2, video_rate: float = 30.0,
                readback_step: float = 0.1, readback_noise: float = 0.0) -> WalkInputs:
    """Render the ceiling frames, make the heads' devices (the true heads, the motor model
    of :class:`lsmta.pantilt.Motor`), the hand labels (0.5 px) and a face model learnt from
    a separate still capture of ``n_train`` frames (:func:`lsmta.face.learn`), measured with
    ``train_noise`` mm of Gaussian noise per coordinate (the generator's shapes with the
    error of a capture like this one's, not the exact shapes).

    The devices report their angles in ``readback_step`` degrees (the thesis's 0.1°) with
    ``readback_noise`` degrees of encoder noise (:class:`~lsmta.synth.mixed_scale.
    SimulatedHead`).

    Truth in these inputs, stated: the ceiling cameras' masks cover the renderer's monitor
    box (an operator's mask); the hand labels are the true image positions with 0.5 px
    noise and no mislabel."""
    rng = as_rng(rng)
    as_scalar(train_noise, "train_noise", nonnegative=True)
    cv = ceiling_videos(scene, rng=rng)
    invalid = [_monitor_mask(v) for v in cv.videos]
    feed = CeilingFeed(cameras=calibration.ceiling, frames=[v.frames for v in cv.videos],
                       stamps=cv.stamps, backgrounds=[v.background for v in cv.videos],
                       arrival=cv.arrival, invalid=invalid)
    devices, identify = head_devices(scene, rng=rng, video_rate=video_rate,
                                     readback_step=readback_step,
                                     readback_noise=readback_noise)
    training = face_sequence(scene.face, n_train, rng=rng, moving=False).head
    training = training + rng.normal(0.0, train_noise, training.shape)
    return WalkInputs(ceiling=feed, devices=devices, identify=identify,
                      face_model=learn(training), videos=cv)


def rigid_pairs(scene: MixedScaleScene) -> np.ndarray:
    """All pairs of the markers no expression moves (thesis Fig. 64's measure)."""
    r = np.flatnonzero(scene.face.rigid)
    i, j = np.triu_indices(len(r), 1)
    return np.stack([r[i], r[j]], axis=1)


@dataclass(frozen=True, eq=False)
class MixedScaleScores:
    """A capture scored against the truth.

    Attributes
    ----------
    face_error : (F, M) array
        3-D error of every marker of the filled face, mm (NaN: frame not fitted).
    measured : (F, M) bool array
        Markers triangulated (the rest filled from the model).
    rigid_deviation : (F, P) array
        Distance deviation of the rigid pairs in the measured markers, mm.
    in_frame : (K, F) bool array
        The whole face (every marker) inside head k's frame.
    centre_px : (K, F) array
        Distance of the face centre's image (the markers' mean) from the principal point, px.
    aim_error : (F,) array
        Distance of the aim point from the true face centre ``horizon`` s later (when the
        heads get there), mm.
    led : LedTrackScore
        The LED tracks against the LEDs (identity changes, RMS).
    led_rms_mm : float
    marker_px : (K,) array
        Median image error of the markers found, px.
    readback_deg : (K, F, 2) array
        The read-back angles the system used minus the angles each head was at, degrees.
    """

    face_error: np.ndarray
    measured: np.ndarray
    rigid_deviation: np.ndarray
    in_frame: np.ndarray
    centre_px: np.ndarray
    aim_error: np.ndarray
    led: object
    led_rms_mm: float
    marker_px: np.ndarray
    readback_deg: np.ndarray

    @property
    def face_median_mm(self) -> float:
        """Median 3-D error of the face's markers, mm, over the frames the face was
        reconstructed in (their share: the capture's ``face.fitted``)."""
        return float(np.nanmedian(self.face_error))

    @property
    def rigid_median_mm(self) -> float:
        """The thesis's measure: median absolute distance deviation of the rigid pairs, mm."""
        return float(np.nanmedian(np.abs(self.rigid_deviation)))

    @property
    def both_in_frame(self) -> float:
        """Share of frames with the face inside every head's frame."""
        return float(self.in_frame.all(axis=0).mean())


def score_capture(capture: MixedScaleCapture, scene: MixedScaleScene, devices, *,
                  horizon: float = 0.3) -> MixedScaleScores:
    """Score a capture of ``scene`` against its truth (the devices give the true heads and
    the angles they were at, not the read-back the system used).
    ``horizon``: when the heads get where they were sent, s after the command (the motors'
    dead time and about one command period); the aim point is scored against the face
    then."""
    t = capture.times
    world, _, _ = scene.face_at(t)
    centre = world.mean(axis=1)
    err = np.linalg.norm(capture.face.frames - world, axis=2)
    measured = np.isfinite(capture.points).all(axis=2)
    K, F = len(devices), len(t)
    in_frame = np.zeros((K, F), bool)
    centre_px = np.full((K, F), np.nan)
    marker_px = np.full(K, np.nan)
    readback = np.full((K, F, 2), np.nan)
    for k, d in enumerate(devices):
        e_all = []
        true_settings = d.true_settings(t)
        readback[k] = capture.settings[k] - true_settings
        for f in range(F):
            cam = d.head.camera_at(*true_settings[f])
            p = cam.project(world[f], behind="nan")
            in_frame[k, f] = bool(cam.in_image(p).all())
            c = cam.project(centre[f][None], behind="nan")[0]
            centre_px[k, f] = np.hypot(c[0] - cam.cx, c[1] - cam.cy)
            tru = d.true_xy(t[f], true_settings[f])
            e_all.append(np.linalg.norm(capture.xy[k, f] - tru, axis=1))
        e = np.concatenate(e_all)
        marker_px[k] = np.nanmedian(e) if np.isfinite(e).any() else np.nan
    ahead, _, _ = scene.face_at(t + horizon)
    aim_error = np.linalg.norm(capture.aim_points - ahead.mean(axis=1), axis=1)
    led = score_led_tracks(scene.leds, capture.tracking, t)
    return MixedScaleScores(face_error=err, measured=measured,
                            rigid_deviation=distance_deviation(
                                np.where(measured[..., None], capture.points, np.nan),
                                rigid_pairs(scene)),
                            in_frame=in_frame, centre_px=centre_px, aim_error=aim_error,
                            led=led, led_rms_mm=float(led.rms_mm), marker_px=marker_px,
                            readback_deg=readback)


def face_split(scores: MixedScaleScores, capture: MixedScaleCapture) -> dict:
    """The face's median 3-D error, mm, over the markers both heads measured
    (``face_measured_mm``) and over those filled from the face model in fitted frames
    (``face_filled_mm``); NaN where there are none."""
    def median(e):
        return float(np.nanmedian(e)) if np.isfinite(e).any() else float("nan")

    filled = ~scores.measured & capture.face.fitted[:, None]
    return {"face_measured_mm": median(scores.face_error[scores.measured]),
            "face_filled_mm": median(scores.face_error[filled])}


def hidden_shares(capture: MixedScaleCapture, scene: MixedScaleScene, devices) -> dict:
    """Of the face's marker-frames the heads grabbed (every head, frame and marker, at the
    angles the heads were at): the share the normals rule hides
    (:func:`lsmta.synth.face.visible`, ``hidden_normals``), the share the head's surface
    hides (ray casting, :meth:`lsmta.synth.mixed_scale.SimulatedHead.clear_of_head`,
    ``hidden_ray_cast``; NaN when the scene casts no rays, ``occlusion="normals"``) and the
    share only the ray cast hides (``hidden_ray_cast_only``). Which rule the images
    followed is the scene's ``occlusion``."""
    t = capture.times
    world, normals, _ = scene.face_at(t)
    faces, clear = [], []
    for d in devices:
        centres = d.head.poses(*d.true_settings(t).T)[1]
        faces.append(visible(world, normals, centres[:, None]))
        clear.append([d.clear_of_head(t[f], centres[f]) for f in range(len(t))])
    faces, clear = np.array(faces), np.array(clear)
    cast = scene.occlusion != "normals"
    nan = float("nan")
    return {"hidden_normals": float((~faces).mean()),
            "hidden_ray_cast": float((~clear).mean()) if cast else nan,
            "hidden_ray_cast_only": float((faces & ~clear).mean()) if cast else nan}


@dataclass(frozen=True)
class LabelScore:
    """First-frame labels against the generator's (:func:`label_score`).

    Attributes
    ----------
    correct, wrong, missed : int
        Marker images (over heads) labelled with the marker's own dot; labelled with any
        other position (another marker's dot, or none drawn there); drawn but not labelled.
    """

    correct: int
    wrong: int
    missed: int

    @property
    def share_correct(self) -> float:
        """Correct labels over all labels given (NaN: none given, e.g. a refused
        identification; read it with :attr:`coverage`)."""
        n = self.correct + self.wrong
        return self.correct / n if n else float("nan")

    @property
    def coverage(self) -> float:
        """Correct labels over the labels given plus the marker images drawn but not
        labelled (every drawn image, and any label where no marker is drawn); 0 when
        nothing was labelled (NaN: no label given and no marker drawn)."""
        n = self.correct + self.wrong + self.missed
        return self.correct / n if n else float("nan")


def label_outcome(xy, truth, *, tol_px: float = 3.0):
    """The scoring rule of labels: which are given, which markers are drawn and which
    labels are correct.

    A label is correct when its own marker's true image is the drawn one nearest to it,
    within ``tol_px`` (the centroid of a dot that touches another's is pulled towards it by
    a pixel or two).

    Parameters
    ----------
    xy : (..., M, 2) array
        The labels: each marker's position in the image, px (NaN: not labelled).
    truth : (..., M, 2) array
        The markers' true images, px (NaN: not drawn), the same shape as ``xy``.
    tol_px : float
        Largest distance of a correct label from its marker's true image, px.

    Returns
    -------
    given, drawn, correct : (..., M) bool arrays
        Labelled; drawn; labelled with its own marker's dot (``correct`` implies both).
    """
    tol_px = as_scalar(tol_px, "tol_px", positive=True)
    xy, truth = np.asarray(xy, float), np.asarray(truth, float)
    if truth.ndim < 2 or truth.shape[-1] != 2:
        raise ValueError(f"truth: expected an array of shape (..., M, 2), got {truth.shape}")
    if xy.shape != truth.shape:
        raise ValueError(f"xy: expected the shape of the true images {truth.shape}, got "
                         f"{xy.shape}")
    given = np.isfinite(xy).all(axis=-1)
    drawn = np.isfinite(truth).all(axis=-1)
    to_all = np.nan_to_num(np.linalg.norm(xy[..., :, None, :] - truth[..., None, :, :],
                                          axis=-1), nan=np.inf)
    own = np.arange(xy.shape[-2])
    correct = (given & drawn & (to_all.argmin(axis=-1) == own)
               & (to_all[..., own, own] <= tol_px))
    return given, drawn, correct


def label_score(xy, devices, t: float, *, tol_px: float = 3.0) -> LabelScore:
    """Score labels of the frames the ``devices`` grabbed at time ``t`` against the true
    images of the markers drawn in them, by :func:`label_outcome`'s rule.

    Parameters
    ----------
    xy : (K, M, 2) array
        The labels of each device's frame, px (NaN: not labelled); M the markers of the
        devices' face.
    devices : sequence of K SimulatedHead
        The heads that grabbed the frames (their truth: the angles they were at and the
        markers' true images).
    t : float
        When the frames were grabbed, s.
    tol_px : float
        Largest distance of a correct label from its marker's true image, px.

    Returns
    -------
    LabelScore
        Correct, wrong and missed marker images, summed over the heads.

    Raises
    ------
    ValueError
        When ``xy`` is not (K, M, 2) with K the devices and M their face's markers.
    """
    tol_px = as_scalar(tol_px, "tol_px", positive=True)
    xy = np.asarray(xy, float)
    if xy.ndim != 3 or xy.shape[0] != len(devices) or xy.shape[2] != 2:
        raise ValueError(f"xy: expected an array of shape ({len(devices)}, M, 2), got "
                         f"{xy.shape}")
    truth = np.stack([d.true_xy(t, d.true_settings(t)[0]) for d in devices])
    if truth.shape != xy.shape:
        raise ValueError(f"xy: expected {truth.shape[1]} markers per head (the devices' "
                         f"face), got an array of shape {xy.shape}")
    given, drawn, ok = label_outcome(xy, truth, tol_px=tol_px)
    return LabelScore(correct=int(ok.sum()), wrong=int((given & ~ok).sum()),
                      missed=int((drawn & ~given).sum()))


@dataclass(frozen=True, eq=False)
class ReadbackStudy:
    """A capture's marker images triangulated by the system's rule at the read-back angles,
    again at the angles the heads were at (an exact encoder), and at the angles the system
    used (``capture.angles``: the read-back, or with ``params.motor_fit`` the angles it
    recovered), and each filled from the face model by the system's rule.

    Attributes
    ----------
    rigid_median_mm : (3,) array
        Median absolute distance deviation of the rigid pairs, mm: read-back, exact, the
        system's angles.
    point_median_mm : (3,) array
        Median 3-D error of the triangulated markers, mm (before the fill's check).
    face_median_mm : (3, 3) array
        Median 3-D error of the filled face, mm, per angle source (rows) over all markers,
        the measured ones and the filled ones (columns), in the frames fitted (NaN: no
        ``face_model`` given).
    frame_median_mm : (3, F) array
        Median 3-D error of the filled face per frame, mm (NaN: not fitted).
    """

    rigid_median_mm: np.ndarray
    point_median_mm: np.ndarray
    face_median_mm: np.ndarray
    frame_median_mm: np.ndarray


def exact_readback(capture: MixedScaleCapture, scene: MixedScaleScene, devices,
                   heads, *, face_model=None) -> ReadbackStudy:
    """Triangulate ``capture.xy`` with the calibrated ``heads`` by the system's own rule
    (:func:`lsmta.systems.triangulate_frames` with ``capture.params``) at the read-back
    angles ``capture.settings``, at the angles the ``devices`` were at
    (:meth:`~lsmta.synth.mixed_scale.SimulatedHead.true_settings`): what an exact encoder
    would have given, everything else equal; and at ``capture.angles``. With
    ``face_model``, each is filled by the system's rule (:func:`lsmta.systems.fill_face`)
    and scored over all markers, measured and filled."""
    t = capture.times
    true = np.stack([d.true_settings(t) for d in devices])
    used = capture.settings if capture.angles is None else capture.angles
    rows = [face_at_angles(capture, scene, heads, settings, face_model=face_model)
            for settings in (capture.settings, true, used)]
    rigid, point = [r[0] for r in rows], [r[1] for r in rows]
    face = np.array([r[2] for r in rows])
    frame = np.array([r[3] for r in rows])
    return ReadbackStudy(rigid_median_mm=np.array(rigid), point_median_mm=np.array(point),
                         face_median_mm=face, frame_median_mm=frame)



def face_at_angles(capture: MixedScaleCapture, scene: MixedScaleScene, heads, angles, *,
                   face_model=None):
    """``capture.xy`` triangulated at ``angles`` (K, F, 2) degrees by the system's rule
    (:func:`lsmta.systems.triangulate_frames` with ``capture.params``) and, with
    ``face_model``, filled by its rule (:func:`lsmta.systems.fill_face`, with
    ``capture.params.min_view_cos`` at these angles), scored against the truth.

    Parameters
    ----------
    capture : MixedScaleCapture
        The system's run: its marker images ``xy`` (K, F, M, 2) px, frame ``times`` (F,) s
        and ``params`` (the triangulation's and the fill's rules).
    scene : MixedScaleScene
        The generated walk: the truth to score against.
    heads : sequence of K calibrated pan-tilt head models
        The heads as the system has them (``calibrate_scene(...).heads``).
    angles : (K, F, 2) array
        Pan and tilt of each head at each frame to triangulate at, degrees.
    face_model : FaceModel, optional
        Fill the markers not triangulated from it (None: no fill, ``face_mm`` NaN).

    Returns
    -------
    rigid_mm, point_mm : float
        Median absolute distance deviation of the rigid pairs and median 3-D error of the
        triangulated markers (before the fill's check), mm.
    face_mm : (3,) array
        Median 3-D error of the filled face over all markers, the measured ones and the
        filled ones, in the frames fitted, mm (NaN without ``face_model``).
    frame_mm : (F,) array
        Median 3-D error of the filled face per frame, mm (NaN: not fitted).
    """
    world, _, _ = scene.face_at(capture.times)
    pts, pairs = triangulate_frames(capture.xy, heads, angles,
                                min_angle_deg=capture.params.min_angle_deg,
                                max_reprojection_px=capture.params.max_reprojection_px)
    rigid = float(np.nanmedian(np.abs(distance_deviation(pts, rigid_pairs(scene)))))
    point = float(np.nanmedian(np.linalg.norm(pts - world, axis=2)))
    face, frame = np.full(3, np.nan), np.full(len(world), np.nan)
    if face_model is not None:
        gate = capture.params.min_view_cos
        views = None if gate <= -1 else (
            np.array([[h.camera_at(*a).C for a in ang] for h, ang in zip(heads, angles)]), pairs)
        pts, fit = fill_face(pts, face_model, max_fill_mm=capture.params.max_fill_mm,
                             views=views, min_view_cos=gate)
        err = np.where(fit.fitted[:, None], np.linalg.norm(fit.frames - world, axis=2), np.nan)
        measured = np.isfinite(pts).all(axis=2)
        face = np.array([np.nanmedian(err), np.nanmedian(err[measured]),
                         np.nanmedian(err[~measured])])
        frame[fit.fitted] = np.nanmedian(err[fit.fitted], axis=1)
    return rigid, point, face, frame


ANGLE_PARTS = ("common pan", "differential pan", "common tilt", "differential tilt")


def angle_error_parts(capture: MixedScaleCapture, scene: MixedScaleScene, devices, heads, *,
                      face_model, angles=None) -> dict:
    """The face's median 3-D error when only one part of two heads' angle error is left.

    The error of ``angles`` (default ``capture.settings``, the read-back) against the angles
    the two ``devices`` were at is split, per frame and axis, into the heads' common part
    ``(e0 + e1) / 2`` and their differential part ``(e0 - e1) / 2``; each of the four parts
    (:data:`ANGLE_PARTS`) alone is added to the true angles, and ``capture.xy`` is
    triangulated and filled by the system's rules (:func:`lsmta.systems.triangulate_frames`,
    :func:`lsmta.systems.fill_face`) and scored over all markers in the frames fitted.

    Returns
    -------
    dict of str -> float
        Median 3-D error of the face per part, mm.
    """
    if len(devices) != 2 or len(heads) != 2:
        raise ValueError(f"devices, heads: expected two heads (a common and a differential "
                         f"part), got {len(devices)} and {len(heads)}")
    true = np.stack([d.true_settings(capture.times) for d in devices])
    used = capture.settings if angles is None else as_array(angles, "angles",
                                                              shape=true.shape)
    err = used - true
    common, diff = (err[0] + err[1]) / 2, (err[0] - err[1]) / 2
    out = {}
    for name in ANGLE_PARTS:
        axis = 0 if name.endswith("pan") else 1
        part = np.zeros_like(err)
        if name.startswith("common"):
            part[:, :, axis] = common[:, axis]
        else:
            part[0, :, axis], part[1, :, axis] = diff[:, axis], -diff[:, axis]
        out[name] = float(face_at_angles(capture, scene, heads, true + part,
                                         face_model=face_model)[2][0])
    return out
