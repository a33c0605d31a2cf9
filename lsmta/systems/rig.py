"""Stage 1 of the LSMTA system: the rig calibrated from a video of the reference bar.

What a user has: K synchronised videos of a bar with two bright targets moved through the
volume, the bar's length, and the cameras as built - the lens's nominal focal length, the
image size and the camera positions and directions measured with a tape (tens of
millimetres and a few degrees off). From that, with no ground truth:

1. *targets*: the two targets measured and tracked in every camera
   (:func:`~lsmta.calibration.track_targets`); each position's precision comes from its
   Gaussian fit, and their RMS is the a-priori ``sigma_px`` of the adjustment;
2. *approximations*: relative orientation of the pair of cameras with the longest nominal
   baseline, resection of the others (:func:`~lsmta.calibration.relative_orientation_start`,
   RANSAC), then the bar's ends made consistent across cameras
   (:func:`~lsmta.calibration.labels.consistent_bar_labels`) and the approximations again;
   the ends are first made consistent through the tape-measured cameras, frame by frame,
   so that cameras facing each other (an all-round studio) start from the same naming;
3. *bundle adjustment* with the bar length as an observation
   (:func:`~lsmta.calibration.bundle_adjust`);
4. *datum*: the adjustment's frame (its first camera at the origin) is turned and moved onto
   the tape-measured cameras (the rotation that best maps the adjusted camera attitudes
   onto the measured ones, then the mean shift of the centres); the scale stays the bar's.
   So the calibrated rig lives in the user's world (its floor, its up direction), as well
   as a tape measure fixes that world;
5. *level* (optional, :func:`level_rig`): a tape-measured attitude is a degree or more off,
   and the camera centres of a rig in a row cannot fix a turn about the row, so the world's
   up is as far off as the attitudes' mean error. With a video of the bar stood upright
   with a spirit level (a studio's ground-plane step), the bar's direction is intersected
   with the calibrated cameras in each frame, frames whose bar length or reprojection error
   is off are dropped, and the world is turned, about the cameras' mean centre and by the
   smallest rotation, so that the remaining directions' robust mean is +Z.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from .._validate import as_scalar
from ..calibration import DEFAULT_INTRINSICS, Bar, BundleParams, bundle_adjust
from ..calibration.approximations import relative_orientation_start
from ..calibration.labels import BarLabels, consistent_bar_labels
from ..calibration.result import CalibrationResult
from ..calibration.targets import track_targets
from ..triangulation import triangulate
from .checks import check_cameras, check_videos

MIN_BAR_FRAMES = 10
MIN_LEVEL_FRAMES = 3
MAX_LEVEL_DEG = 15.0     # a levelled bar further than this from the tape's up: not upright
LEVEL_LENGTH_TOL = 0.03  # a levelling frame's bar length off by more (fraction): dropped
LEVEL_REPROJ_PX = 2.0    # ... or its largest reprojection error above this (and above
LEVEL_REPROJ_K = 5.0     # this many times the frames' median largest error), px: dropped
LEVEL_CUT_K = 3.0        # robust mean: directions beyond this many robust SDs are left out
LEVEL_CUT_MIN_DEG = 0.5  # ... but never a cut below this, degrees (a spirit level's error)


@dataclass(frozen=True, eq=False)
class Levelling:
    """The world levelled with the bar stood upright (:func:`level_rig`).

    Attributes
    ----------
    up : (3,) array
        The bar's mean direction (unit, upwards) in the world before levelling.
    rotation : (3, 3) array
        The turn applied to the world: ``x_levelled = rotation @ (x - centre) + centre``.
    centre : (3,) array
        The point it turns about (the cameras' mean centre), mm.
    correction_deg : float
        Angle between the world's up before levelling and the bar's, degrees.
    spread_deg : float
        RMS angle of the single frames' directions from their mean, degrees.
    n_frames : int
        Frames whose direction makes the mean (intersected, kept by the length and
        reprojection tests and inside the robust mean's cut).
    n_dropped : int
        Intersected frames left out (bar length, reprojection error or direction off).
    """

    up: np.ndarray
    rotation: np.ndarray
    centre: np.ndarray
    correction_deg: float
    spread_deg: float
    n_frames: int
    n_dropped: int = 0


@dataclass(frozen=True, eq=False)
class RigCalibration(CalibrationResult):
    """The rig calibrated from a bar video (see the module docstring).

    Attributes
    ----------
    cameras : list of K Camera
        Calibrated cameras in the user's world (the tape-measured cameras' frame), mm.
    bundle : BundleResult
        The adjustment, in its own frame (its first camera at the origin).
    targets : (K, Tb, 2, 2) array
        The bar's targets per camera and frame, px, with consistent ends (NaN: not seen).
    labels : BarLabels
        Which frames had their ends exchanged in which camera.
    sigma_px : float
        A-priori standard deviation of a target coordinate, px: the RMS of the Gaussian
        fits' own precisions.
    pair : (int, int)
        The cameras of the relative orientation.
    datum_rotation : (3, 3) array
        Rotation Q from the adjustment's frame to the user's world (levelled, if it was):
        a point ``x`` of the adjustment is ``Q @ x + t`` in the world, and each camera is
        ``R = R_bundle @ Q.T``, ``C = Q @ C_bundle + t``.
    datum_translation : (3,) array
        Its translation t, mm.
    datum_residual : (K,) array
        Distance of each calibrated camera centre from its tape-measured place, mm.
    n_positions : int
        Bar positions whose two targets are seen by at least two cameras.
    seconds : float
    level : Levelling or None
        How the world was levelled (None: the tape's up kept).
    """

    targets: np.ndarray
    labels: BarLabels
    sigma_px: float
    pair: tuple
    datum_rotation: np.ndarray
    datum_translation: np.ndarray
    datum_residual: np.ndarray
    n_positions: int
    seconds: float
    level: Levelling | None = None


def _datum(adjusted, nominal):
    """Rotation and translation carrying the adjusted cameras onto the nominal ones."""
    Q = Rotation.from_matrix(np.stack([n.R.T @ a.R for a, n in zip(adjusted, nominal)]))
    Q = Q.mean().as_matrix()
    t = np.mean([n.C - Q @ a.C for a, n in zip(adjusted, nominal)], axis=0)
    return Q, t


def level_rig(cameras, level_videos, bar_length: float, *,
              progress: bool = False) -> tuple[list, Levelling]:
    """Level the world of calibrated cameras with videos of the bar stood upright.

    Parameters
    ----------
    cameras : sequence of K Camera
        Calibrated cameras, in a world whose +Z is roughly up (the tape-measured one).
    level_videos : (K, Tl, H, W) array or sequence of K (Tl, H, W) arrays
        Grey frames of the bar stood vertically (set with a spirit level), at one or more
        places; every frame counts once.
    bar_length : float
        Distance between the bar's two targets, mm (to tell its ends apart across cameras).
    progress : bool
        Show a progress bar over the cameras' target measurement.

    Returns
    -------
    cameras : list of K Camera
        The same rig turned so that the bar's robust mean direction is +Z (Notes).
    level : Levelling

    Notes
    -----
    A frame is dropped when its intersected bar length is more than 3 % off
    ``bar_length``, or when the largest reprojection error of its two targets exceeds
    2 px and 5 times the frames' median of that error (a target mismeasured or mixed up in
    one camera). The up direction is then a robust mean of the kept frames' unit
    directions: starting from their normalised component-wise median, the mean of the
    directions within 3 robust SDs (1.4826 times the median angle from the current mean;
    the cut at least 0.5 degrees, a spirit level's own error) is taken, until the set stops
    changing (at most 10 rounds). One bad frame then moves it by nothing, where a plain
    mean moves it by its angle over the number of frames.

    Raises
    ------
    TypeError
        ``cameras`` is not a sequence of :class:`~lsmta.camera.Camera`.
    ValueError
        Fewer than 3 frames with both targets intersected (and kept), a bar more than 15
        degrees from the world's up (not stood upright, or not this world), videos of the
        wrong number, size or length, or a bar length that is not positive.
    """
    cams = check_cameras(cameras, "cameras")
    K = len(cams)
    videos = check_videos(level_videos, "level_videos", cams, min_frames=MIN_LEVEL_FRAMES)
    length = as_scalar(bar_length, "bar_length", positive=True)
    xy = np.stack([track_targets(videos[k]).xy for k in tqdm(range(K), desc="level targets",
                                                              disable=not progress)])
    xy = consistent_bar_labels(cams, xy, length).xy                  # (K, Tl, 2, 2)
    inter = triangulate(cams, xy.reshape(K, -1, 2))
    X = inter.points.reshape(-1, 2, 3)
    d = X[:, 1] - X[:, 0]
    found = np.isfinite(d).all(axis=1)
    n_found = int(found.sum())
    if n_found < MIN_LEVEL_FRAMES:
        raise ValueError(f"level_videos: both targets are intersected in {n_found} frames; "
                         f"levelling needs >= {MIN_LEVEL_FRAMES}")
    d = _kept_directions(d, found, inter.reprojection_error.reshape(K, -1, 2), length)
    d = d * np.sign(d[:, 2:3] + (d[:, 2:3] == 0))                    # upwards
    up, inside = _robust_direction(d)
    d = d[inside]
    correction = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    if correction > MAX_LEVEL_DEG:
        raise ValueError(f"level_videos: the bar stands {correction:.1f} degrees from the "
                         f"world's up; expected it stood upright (within {MAX_LEVEL_DEG:g})")
    spread = float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(d @ up, -1.0, 1.0))**2))))
    axis = np.cross(up, [0.0, 0.0, 1.0])
    turn = np.linalg.norm(axis)
    Rm = Rotation.from_rotvec(axis / turn * np.arctan2(turn, up[2]) if turn > 0
                              else np.zeros(3)).as_matrix()
    centre = np.mean([c.C for c in cams], axis=0)
    out = [c.replace(R=c.R @ Rm.T, C=Rm @ (c.C - centre) + centre) for c in cams]
    return out, Levelling(up=up, rotation=Rm, centre=centre, correction_deg=correction,
                          spread_deg=spread, n_frames=len(d), n_dropped=n_found - len(d))


def _kept_directions(d, found, reproj, length: float) -> np.ndarray:
    """Unit bar directions (N, 3) of the frames :func:`level_rig` keeps (its Notes), from
    the intersected directions ``d`` (Tl, 3), mm, which of them were ``found`` (Tl,), and the
    targets' reprojection errors ``reproj`` (K, Tl, 2), px."""
    n_found = int(found.sum())
    err = np.fmax.reduce(reproj, axis=(0, 2))                                    # (Tl,)
    err_cut = max(LEVEL_REPROJ_PX, LEVEL_REPROJ_K * float(np.nanmedian(err[found])))
    keep = found & (np.abs(np.linalg.norm(np.where(found[:, None], d, 0.0), axis=1) - length)
                    <= LEVEL_LENGTH_TOL * length) & ~(err > err_cut)
    d = d[keep]
    if len(d) < MIN_LEVEL_FRAMES:
        raise ValueError(f"level_videos: {len(d)} of the {n_found} intersected frames have a "
                         f"bar length within {LEVEL_LENGTH_TOL:.0%} of bar_length and a "
                         f"reprojection error below {err_cut:.2g} px; levelling needs "
                         f">= {MIN_LEVEL_FRAMES}")
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _robust_direction(d):
    """Robust mean of unit directions ``d`` (N, 3) (see :func:`level_rig`'s Notes): the
    unit mean and which rows it is the mean of."""
    up = np.median(d, axis=0)
    up /= np.linalg.norm(up)
    inside = np.ones(len(d), bool)
    for _ in range(10):
        angle = np.degrees(np.arccos(np.clip(d @ up, -1.0, 1.0)))
        cut = max(LEVEL_CUT_K * 1.4826 * float(np.median(angle)), LEVEL_CUT_MIN_DEG)
        now = angle <= cut                       # never empty: the cut is above the median
        up = d[now].mean(axis=0)
        up /= np.linalg.norm(up)
        if np.array_equal(now, inside):
            break
        inside = now
    return up, inside


def _pair(nominal, seen) -> tuple:
    """The two cameras sharing at least 8 targets with the longest nominal baseline."""
    K = len(nominal)
    best, pair = -1.0, None
    for i in range(K):
        for j in range(i + 1, K):
            if (seen[i] & seen[j]).sum() < 8:
                continue
            d = np.linalg.norm(nominal[i].C - nominal[j].C)
            if d > best:
                best, pair = d, (i, j)
    return pair


def _bar_targets(videos, progress: bool):
    """The bar's targets in every camera, (K, Tb, 2, 2) px; the a-priori sigma of a target
    coordinate, px; and the positions seen whole by at least two cameras."""
    tracks = [track_targets(v) for v in tqdm(videos, desc="bar targets",
                                             disable=not progress)]
    xy = np.stack([tr.xy for tr in tracks])                         # (K, Tb, 2, 2)
    both = np.isfinite(xy).all(axis=(2, 3))                          # (K, Tb)
    n_pos = int((both.sum(axis=0) >= 2).sum())
    if n_pos < MIN_BAR_FRAMES:
        raise ValueError(f"bar_videos: both targets are seen by at least two cameras in "
                         f"{n_pos} of {xy.shape[1]} frames; the calibration needs "
                         f">= {MIN_BAR_FRAMES}")
    std = np.concatenate([tr.std.ravel() for tr in tracks])
    return xy, float(np.sqrt(np.nanmean(std**2))), n_pos


def calibrate_rig(bar_videos, bar_length: float, nominal_cameras, *,
                  intrinsics=DEFAULT_INTRINSICS, bar_sigma: float = 0.01,
                  reject_k: float | None = None, level_videos=None,
                  progress: bool = False) -> RigCalibration:
    """Calibrate K cameras from videos of a reference bar (see the module docstring).

    Parameters
    ----------
    bar_videos : (K, Tb, H, W) array or sequence of K (Tb, H, W) arrays
        Grey frames of the bar from each camera (uint8 or float); each camera's frames are
        of its nominal image size.
    bar_length : float
        Distance between the bar's two targets, mm.
    nominal_cameras : sequence of K Camera
        The cameras as built: nominal focal length and image size, tape-measured pose (in a
        world with +Z up); their distortion and principal point are ignored.
    intrinsics : sequence of str
        Interior and additional parameters adjusted (all by default, as in the paper).
    bar_sigma : float
        Standard deviation of the bar length, mm.
    reject_k : float, optional
        Outlier rejection of :func:`~lsmta.calibration.bundle_adjust`.
    level_videos : (K, Tl, H, W) array, optional
        The bar stood upright with a spirit level: the world is levelled with it
        (:func:`level_rig`); without, its up stays the tape's.
    progress : bool
        Show a progress bar over the cameras' target measurement.

    Returns
    -------
    RigCalibration

    Raises
    ------
    TypeError
        ``nominal_cameras`` is not a sequence of :class:`~lsmta.camera.Camera`.
    ValueError
        Too few bar frames, a bar never seen by two cameras, or image sizes that do not
        match the cameras; with ``level_videos``, those of :func:`level_rig`: videos of the
        wrong number, size or length (refused before the adjustment), fewer than 3 upright
        frames intersected and kept, or a bar more than 15 degrees from the tape's up.
    """
    t0 = time.perf_counter()
    nominal = check_cameras(nominal_cameras, "nominal_cameras")
    K = len(nominal)
    videos = check_videos(bar_videos, "bar_videos", nominal, min_frames=MIN_BAR_FRAMES)
    length = as_scalar(bar_length, "bar_length", positive=True)
    if level_videos is not None:            # refused before the adjustment, not after
        level_videos = check_videos(level_videos, "level_videos", nominal,
                                    min_frames=MIN_LEVEL_FRAMES)
    xy, sigma_px, n_pos = _bar_targets(videos, progress)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # frames a camera misses
        # a camera facing another (an all-round studio) names the ends the other way
        # round, and track_targets may rename them partway through a video: the ends are
        # first made consistent frame by frame through the tape-measured cameras
        xy = consistent_bar_labels(nominal, xy, length).xy
    Tb = xy.shape[1]
    seen = np.isfinite(xy).all(axis=3)                               # (K, Tb, 2)
    pair = _pair(nominal, seen.reshape(K, -1))
    if pair is None:
        raise ValueError("bar_videos: no two cameras see 8 or more bar targets in common")
    bar = Bar(pairs=np.arange(2 * Tb).reshape(Tb, 2), length=length, sigma=bar_sigma)
    cams0, _ = relative_orientation_start(nominal, xy.reshape(K, -1, 2), bar=bar, pair=pair)
    labels = consistent_bar_labels(cams0, xy, length)
    flat = labels.xy.reshape(K, -1, 2)
    cams0, X0 = relative_orientation_start(nominal, flat, bar=bar, pair=pair)
    bundle = bundle_adjust(cams0, flat, X0, intrinsics=intrinsics, fixed_exterior=(pair[0],),
                           bar=bar, sigma_px=sigma_px, params=BundleParams(reject_k=reject_k))
    Q, t = _datum(bundle.cameras, nominal)
    cameras = [c.replace(R=c.R @ Q.T, C=Q @ c.C + t) for c in bundle.cameras]
    level = None
    if level_videos is not None:
        cameras, level = level_rig(cameras, level_videos, length, progress=progress)
        Q, t = level.rotation @ Q, level.rotation @ (t - level.centre) + level.centre
    residual = np.array([np.linalg.norm(c.C - n.C) for c, n in zip(cameras, nominal)])
    return RigCalibration(cameras=cameras, bundle=bundle, targets=labels.xy, labels=labels,
                          sigma_px=sigma_px, pair=pair, datum_rotation=Q,
                          datum_translation=t, datum_residual=residual, n_positions=n_pos,
                          seconds=time.perf_counter() - t0, level=level)
