"""Calibration trials: generator and library side by side (notebook 01, tests,
experiments).

:func:`bar_trial` is the LSMTA reference-bar calibration of the triplet: a bar moved
through the volume, its targets rendered into the three cameras (or projected with
Gaussian noise of a known sigma), measured and tracked in the images, approximations from
a relative orientation, then the self-calibrating bundle adjustment with the bar length as
an observation equation (ours) next to the same adjustment without the bar, scaled to the
bar afterwards (the peer: what easyWand and Argus do). Both are scored on held-out bar
positions. :func:`ring_trial` is Davis's virtual calibration object on the ceiling ring,
:func:`partial_overlap_trial` the same on a long room whose cameras see only parts of the
LED path (chained through shared segments, datum and scale from a known distance).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from ..calibration import (
    DEFAULT_INTRINSICS,
    Bar,
    BundleParams,
    BundleResult,
    bundle_adjust,
    relative_orientation_start,
    scaled,
    track_targets,
)
from ..calibration import virtual_object as vo
from ..calibration.bundle import INTRINSIC_NAMES
from ..calibration.chain import ChainStart, chain_cameras, datum_from_distance
from ..camera import Camera
from ..rigid import apply_rigid, fit_rigid
from ..synth.calibration import (
    bar_track,
    led_path,
    long_room_rig,
    poor_guess,
    project_observations,
    render_bar_images,
    sweep_path,
)
from ..synth.rigs import ring_rig, triplet_rig
from ..triangulation import triangulate


def bar_observations(xy_targets):
    """``(K, T, 2, 2)`` per-camera target tracks -> ``(K, 2T, 2)`` observations and the
    :class:`~lsmta.calibration.Bar` pairs ``(T, 2)`` (A of position t is point 2t)."""
    K, T = xy_targets.shape[:2]
    return xy_targets.reshape(K, 2 * T, 2), np.arange(2 * T).reshape(T, 2)


def heldout_bar_errors(cameras, xy, length: float) -> np.ndarray:
    """Triangulated bar length minus the true length, mm, for ``(K, 2T, 2)`` observations of
    T held-out bar positions (NaN where a target is not intersected)."""
    X = triangulate(cameras, xy).points
    return np.linalg.norm(X[0::2] - X[1::2], axis=1) - length


def check_point_errors(cameras, xy, truth) -> np.ndarray:
    """3-D errors (mm) of check points triangulated from ``xy`` ``(K, N, 2)`` after the
    best rigid motion (no scale) onto their true positions ``truth`` ``(N, 3)``."""
    X = triangulate(cameras, xy).points
    ok = np.isfinite(X).all(axis=1)
    R, t = fit_rigid(X[ok], truth[ok])
    err = np.full(len(X), np.nan)
    err[ok] = np.linalg.norm(apply_rigid(R, t, X[ok]) - truth[ok], axis=1)
    return err


@dataclass(frozen=True, eq=False)
class BarTrial:
    """One reference-bar calibration of the synthetic triplet.

    Attributes
    ----------
    truth : list of Camera
    track, heldout : BarTrack
        Calibration and held-out bar positions (true).
    xy, xy_heldout : (3, 2T, 2) arrays
        Measured image coordinates (targets A, B interleaved), px.
    xy_true : (3, 2T, 2) array
        True projections of the calibration targets, px.
    sigma_px : float
        Image noise: the simulated sigma (projected) or the measured targets' RMS error
        against the truth (images).
    ours, peer : BundleResult
        Joint bar adjustment; adjustment without the bar (its cameras and points already
        rescaled; no standard deviations). ``peer`` and its errors are None without it.
    peer_scale : float
        Factor applied to the peer afterwards (known length / median adjusted length).
    bar_error, peer_bar_error : (T_h,) arrays
        Held-out bar length errors, mm.
    check_error, peer_check_error : (2 T_h,) arrays
        3-D errors of the held-out targets after a rigid alignment, mm.
    times : dict
        Wall times (s) of the steps.
    """

    truth: list
    track: object
    heldout: object
    xy: np.ndarray
    xy_heldout: np.ndarray
    xy_true: np.ndarray
    sigma_px: float
    ours: BundleResult
    peer: BundleResult
    peer_scale: float
    bar_error: np.ndarray
    peer_bar_error: np.ndarray
    check_error: np.ndarray
    peer_check_error: np.ndarray
    times: dict


def _measure(cameras, track, rng, mode, sigma_px):
    K = len(cameras)
    pts = track.points.reshape(-1, 3)
    if mode == "projected":
        return project_observations(cameras, pts, rng=rng, sigma_px=sigma_px)
    out = np.empty((K, len(pts), 2))
    for k, cam in enumerate(cameras):
        out[k] = track_targets(render_bar_images(cam, track, rng=rng)).xy.reshape(-1, 2)
    return out


def bar_trial(*, seed: int = 0, n_positions: int = 150, n_heldout: int = 40, mode: str = "images",
              sigma_px: float = 0.05, length: float = 800.0, intrinsics=DEFAULT_INTRINSICS,
              bar_sigma: float = 0.01, reject_k: float | None = None,
              with_peer: bool = True) -> BarTrial:
    """Calibrate the (perturbed) triplet from a reference bar; see the module docstring.

    Parameters
    ----------
    seed : int
        Seeds the rig, the bar tracks and the noise.
    mode : {"images", "projected"}
        Measure rendered target images (sigma then estimated against the truth), or
        project the targets and add Gaussian noise of ``sigma_px``.
    intrinsics : sequence of str
        Free interior/additional parameters (both adjustments).
    with_peer : bool
        Also run the peer (otherwise its fields are None).
    """
    if mode not in ("images", "projected"):
        raise ValueError(f"mode: expected 'images' or 'projected', got {mode!r}")
    rng = np.random.default_rng(seed)
    truth = triplet_rig(rng=rng)
    track = bar_track(n=n_positions, rng=rng, length=length)
    # held-out positions inside the calibrated volume (check points are not extrapolated)
    heldout = bar_track(n=n_heldout, rng=rng, length=length, half_size=(800.0, 560.0, 400.0))
    times = {}
    t0 = time.perf_counter()
    xy = _measure(truth, track, rng, mode, sigma_px)
    xy_h = _measure(truth, heldout, rng, mode, sigma_px)
    times["measure"] = time.perf_counter() - t0
    xy_true = project_observations(truth, track.points.reshape(-1, 3))
    if mode == "images":
        sigma_px = float(np.sqrt(np.nanmean((xy - xy_true) ** 2)))
    pairs = np.arange(2 * n_positions).reshape(-1, 2)
    bar = Bar(pairs=pairs, length=length, sigma=bar_sigma)
    nominal = triplet_rig()
    t0 = time.perf_counter()
    cams0, X0 = relative_orientation_start(nominal, xy, bar=bar, pair=(0, 2))
    times["approximations"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ours = bundle_adjust(cams0, xy, X0, intrinsics=intrinsics, bar=bar, sigma_px=sigma_px,
                         params=BundleParams(reject_k=reject_k))
    times["ours"] = time.perf_counter() - t0
    X_h = heldout.points.reshape(-1, 3)
    peer = scale = peer_bar = peer_check = None
    if with_peer:
        t0 = time.perf_counter()
        peer = bundle_adjust(cams0, xy, X0, intrinsics=intrinsics, scale_camera=2,
                             sigma_px=sigma_px,
                             params=BundleParams(reject_k=reject_k, covariance=False))
        d = np.linalg.norm(peer.points[pairs[:, 0]] - peer.points[pairs[:, 1]], axis=1)
        scale = float(length / np.nanmedian(d))
        pc, pX = scaled(peer.cameras, peer.points, scale)
        peer = dataclasses.replace(peer, cameras=pc, points=pX)
        times["peer"] = time.perf_counter() - t0
        peer_bar = heldout_bar_errors(pc, xy_h, length)
        peer_check = check_point_errors(pc, xy_h, X_h)
    return BarTrial(
        truth=truth, track=track, heldout=heldout, xy=xy, xy_heldout=xy_h, xy_true=xy_true,
        sigma_px=sigma_px, ours=ours, peer=peer, peer_scale=scale,
        bar_error=heldout_bar_errors(ours.cameras, xy_h, length),
        peer_bar_error=peer_bar,
        check_error=check_point_errors(ours.cameras, xy_h, X_h),
        peer_check_error=peer_check, times=times)


def parameter_table(trial: BarTrial, *,
                    names=("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2",
                                             "b1", "b2")):
    """Rows ``(camera, parameter, true, adjusted, std, error / std)`` of the interior and
    additional parameters (frame-independent) of the joint adjustment."""
    rows = []
    for k, (t, e) in enumerate(zip(trial.truth, trial.ours.cameras)):
        for n in names:
            s = trial.ours.std(k, n)
            tv, ev = getattr(t, n), getattr(e, n)
            rows.append((t.name, n, tv, ev, s, (ev - tv) / s if s > 0 else np.nan))
    return rows


@dataclass(frozen=True, eq=False)
class RingTrial:
    """Davis's virtual calibration object on the ceiling ring, several initial guesses.

    Attributes
    ----------
    truth : list of Camera
    path, check_path : (N, 3) arrays
        LED path used for calibration and an independent path for scoring, mm.
    xy, xy_check : (K, N, 2) arrays
        Their noisy observations, px.
    alternation, joint : list of ConvergenceHistory
        One per initial-guess seed (the alternation with reprojection-optimal points).
    linear : list of ConvergenceHistory
        Davis's variant (linear intersection of the rays as the point step), one per seed;
        empty unless asked for.
    improved : list of ConvergenceHistory
        The improved alternation (:data:`~lsmta.calibration.virtual_object.IMPROVED_ALTERNATION`),
        one per seed; empty unless asked for.
    truth_error : float
        Projection error of the true cameras on the independent path, px (the floor).
    sigma_px : float
    """

    truth: list
    path: np.ndarray
    check_path: np.ndarray
    xy: np.ndarray
    xy_check: np.ndarray
    alternation: list
    joint: list
    truth_error: float
    sigma_px: float
    linear: list = dataclasses.field(default_factory=list)
    improved: list = dataclasses.field(default_factory=list)


def ring_trial(*, seeds=(0, 1, 2), n_cameras: int = 10, n_path: int = 300, n_check: int = 150,
               sigma_px: float = 0.3, n_alternation: int = 30, n_joint: int = 30,
               intrinsics=("f", "cx", "cy", "k1", "k2"), data_seed: int = 100, n_linear: int = 0,
               improved: vo.AlternationParams | None = None,
               true_fixed: bool = False) -> RingTrial:
    """The alternation and the joint adjustment from the same poor guesses (one per
    seed), scored per iteration on an independent LED path; with ``n_linear`` > 0 also
    Davis's linear-intersection variant of the alternation for that many iterations, with
    ``improved`` also the alternation with those settings. ``true_fixed``: the interior
    parameters that are not free are set to the truth in the guess (a diagnostic: fewer
    free parameters without unmodelled lens error)."""
    rng = np.random.default_rng(data_seed)
    truth = ring_rig(n=n_cameras, rng=rng)
    path = led_path(n=n_path, rng=rng)
    check = led_path(n=n_check, rng=rng)
    xy = project_observations(truth, path, rng=rng, sigma_px=sigma_px)
    xy_c = project_observations(truth, check, rng=rng, sigma_px=sigma_px)
    intrinsics = tuple(intrinsics)
    alt, jnt, lin, imp = [], [], [], []
    for s in seeds:
        guess = poor_guess(truth, rng=np.random.default_rng(s))
        if true_fixed:
            fixed = [n for n in INTRINSIC_NAMES if n not in intrinsics]
            guess = [g.replace(**{n: getattr(t, n) for n in fixed})
                     for g, t in zip(guess, truth)]
        alt.append(vo.alternate(guess, xy, xy_check=xy_c, params=vo.AlternationParams(
            n_iter=n_alternation, intrinsics=intrinsics)))
        if n_linear:
            lin.append(vo.alternate(guess, xy, xy_check=xy_c, params=vo.AlternationParams(
                n_iter=n_linear, intrinsics=intrinsics, triangulation="linear")))
        if improved is not None:
            imp.append(vo.alternate(guess, xy, xy_check=xy_c,
                                    params=dataclasses.replace(improved, intrinsics=intrinsics)))
        jnt.append(vo.joint_adjustment(guess, xy, n_iter=n_joint, intrinsics=intrinsics,
                                       xy_check=xy_c))
    return RingTrial(truth=truth, path=path, check_path=check, xy=xy, xy_check=xy_c,
                     alternation=alt, joint=jnt, truth_error=vo.projection_error(truth, xy_c),
                     sigma_px=sigma_px, linear=lin, improved=imp)


# ----------------------------------------------------------------------- partial overlap
@dataclass(frozen=True, eq=False)
class OverlapRun:
    """One calibration of the long room (:func:`partial_overlap_trial`), one seed.

    Attributes
    ----------
    seed : int
    truth : list of Camera
    path, check_path : (N, 3), (M, 3) arrays
        Calibration and independent LED paths, mm.
    xy, xy_check : (K, N, 2), (K, M, 2) arrays
        Their noisy observations, px.
    marks, marks_xy : (2, 3), (K, 2, 2) arrays
        The two marks at the known distance and their observations.
    check_marks, check_marks_xy : (2, 3), (K, 2, 2) arrays
        Two more marks whose distance is only used to score the scale.
    guess : list of Camera
        Tape-measured rig: nominal interior orientation (and camera 0's pose, the datum).
    chain : ChainStart
    start : list of Camera
        The chain with the datum: the start of every method.
    plain, improved, joint : ConvergenceHistory
        The paper's alternation, the improved alternation, the joint adjustment.
    calibrated : dict
        Method name -> final cameras with the datum (camera 0's tape pose, the marks'
        distance).
    floor : float
        Projection error of the true cameras on the independent path, px.
    error_3d : dict
        Method name (and ``"truth"``) -> RMS 3-D error of the independent path intersected
        with those cameras, after a rigid (not scaled) alignment to the truth, mm.
    scale_error : dict
        Method name -> intersected distance of the check marks minus the true one, mm.
    """

    seed: int
    truth: list
    path: np.ndarray
    check_path: np.ndarray
    xy: np.ndarray
    xy_check: np.ndarray
    marks: np.ndarray
    marks_xy: np.ndarray
    check_marks: np.ndarray
    check_marks_xy: np.ndarray
    guess: list
    chain: ChainStart
    start: list
    plain: vo.ConvergenceHistory
    improved: vo.ConvergenceHistory
    joint: vo.ConvergenceHistory
    calibrated: dict
    floor: float
    error_3d: dict
    scale_error: dict


MARKS = np.array([[-2000.0, 0.0, 1000.0], [2000.0, 0.0, 1000.0]])         # 4 m apart
CHECK_MARKS = np.array([[-3000.0, -800.0, 600.0], [3000.0, 900.0, 1500.0]])


def partial_overlap_trial(*, seeds=(0, 1, 2), n_path: int = 800, n_check: int = 200,
                          sigma_px: float = 0.3, n_plain: int = 50,
                          improved: vo.AlternationParams = vo.IMPROVED_ALTERNATION,
                          n_joint: int = 40) -> list:
    """The virtual calibration object where no camera sees the whole path: per seed, the
    long room (:func:`lsmta.synth.calibration.long_room_rig`, perturbed), an LED path
    sweeping it (:func:`~lsmta.synth.calibration.sweep_path`, ``n_path`` positions, 4
    passes) and an independent one, observed with Gaussian noise of ``sigma_px``; a
    tape-measured guess (:func:`~lsmta.synth.calibration.poor_guess`) gives the nominal
    interior orientation and camera 0's pose. The cameras are chained through shared path
    segments (:func:`lsmta.calibration.chain.chain_cameras`), given the datum (camera 0's
    tape pose, the LED on two marks 4 m apart:
    :func:`~lsmta.calibration.chain.datum_from_distance`), and calibrated by the paper's
    alternation (``n_plain`` iterations), the improved alternation and the joint
    adjustment, all from that start; each result gets the datum again.

    Returns
    -------
    list of OverlapRun
    """
    runs = []
    distance = float(np.linalg.norm(MARKS[1] - MARKS[0]))
    for seed in seeds:
        rng = np.random.default_rng(seed)
        truth = long_room_rig(rng=rng)
        path = sweep_path(n=n_path, rng=rng, passes=4)
        check = sweep_path(n=n_check, rng=rng)
        xy, xy_c, m_xy, c_xy = (project_observations(truth, p, rng=rng, sigma_px=sigma_px)
                                for p in (path, check, MARKS, CHECK_MARKS))
        guess = poor_guess(truth, rng=rng)
        chain = chain_cameras(guess, xy)
        start = datum_from_distance(chain.cameras, m_xy, distance, pose=guess[0])
        hist = {"plain": vo.alternate(start, xy, xy_check=xy_c,
                                      params=vo.AlternationParams(n_iter=n_plain)),
                "improved": vo.alternate(start, xy, xy_check=xy_c, params=improved),
                "joint": vo.joint_adjustment(start, xy, n_iter=n_joint, xy_check=xy_c)}
        calibrated = {k: datum_from_distance(h.cameras[-1], m_xy, distance, pose=guess[0])
                      for k, h in hist.items()}
        true_check = np.linalg.norm(CHECK_MARKS[1] - CHECK_MARKS[0])
        err3 = {k: float(np.sqrt(np.nanmean(check_point_errors(c, xy_c, check) ** 2)))
                for k, c in {**calibrated, "truth": truth}.items()}
        scale = {k: float(np.linalg.norm(np.subtract(*triangulate(c, c_xy).points))
                          - true_check) for k, c in calibrated.items()}
        runs.append(OverlapRun(
            seed=seed, truth=truth, path=path, check_path=check, xy=xy, xy_check=xy_c,
            marks=MARKS, marks_xy=m_xy, check_marks=CHECK_MARKS, check_marks_xy=c_xy,
            guess=guess, chain=chain, start=start, calibrated=calibrated,
            floor=vo.projection_error(truth, xy_c), error_3d=err3, scale_error=scale, **hist))
    return runs


__all__ = ["BarTrial", "OverlapRun", "RingTrial", "aniposelib_peer",
           "bar_observations", "bar_trial", "check_point_errors", "heldout_bar_errors",
           "parameter_table", "partial_overlap_trial", "ring_trial"]


def aniposelib_peer(trial: BarTrial, cameras0):
    """aniposelib's ``CameraGroup.bundle_adjust_iter`` on the trial's observations, from the
    same approximations as ours, scaled to the median bar length afterwards.

    aniposelib's camera has one focal length, a fixed principal point and one radial term
    (``k1``), and no bar constraint; it is optional (``pip install --no-deps aniposelib
    toml pandas``: its bundle adjustment needs neither opencv-contrib nor jax).

    Returns
    -------
    cameras : list of Camera
    bar_error : (T_h,) array
        Held-out bar length errors, mm.
    check_error : (2 T_h,) array
        Held-out check-point errors after a rigid alignment, mm.
    seconds : float
        Wall time of the adjustment.
    """
    from aniposelib.cameras import Camera as ACamera  # deferred: optional peer, not installed
    from aniposelib.cameras import CameraGroup  # deferred: optional peer, not installed

    acams = []
    for c in cameras0:
        K, dist, rvec, tvec = c.to_opencv()
        acams.append(ACamera(matrix=K, dist=dist, size=c.image_size, rvec=rvec, tvec=tvec,
                             name=c.name))
    group = CameraGroup(acams)
    t0 = time.perf_counter()
    group.bundle_adjust_iter(np.array(trial.xy, dtype=np.float64), n_samp_full=10**6,
                             n_samp_iter=10**6, verbose=False)
    seconds = time.perf_counter() - t0
    cams = [Camera.from_opencv(a.get_camera_matrix(), a.get_distortions(), a.get_rotation(),
                               a.get_translation(), c.image_size, name=c.name)
            for a, c in zip(group.cameras, cameras0)]
    X = triangulate(cams, trial.xy).points
    d = np.linalg.norm(X[0::2] - X[1::2], axis=1)
    cams, _ = scaled(cams, X, trial.track.length / np.nanmedian(d))
    X_h = trial.heldout.points.reshape(-1, 3)
    return (cams, heldout_bar_errors(cams, trial.xy_heldout, trial.track.length),
            check_point_errors(cams, trial.xy_heldout, X_h), seconds)
