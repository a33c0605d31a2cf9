"""Wand calibration trials: :func:`lsmta.calibration.calibrate_wand` on a generated wand
recording (:mod:`lsmta.synth.wand`), scored against the generator's truth (notebook 19,
tests, experiments).

Scores: the wand length scatter of the calibration frames next to its floor - the scatter
the *true* cameras give on the same noisy observations, which no calibration can beat -,
held-out wand lengths (frames not used for the calibration), camera centre errors after
the best rigid motion onto the truth (the scale is the wand's, so no scale is fitted),
focal length errors, and whether the wand's ends carry consistent labels in every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibration.bundle import Bar, BundleParams, bundle_adjust
from ..calibration.wand import WandCalibration, calibrate_wand
from ..rigid import apply_rigid, fit_rigid
from ..synth.wand import WandRecording, wand_recording, wand_rig
from ..triangulation import triangulate


@dataclass(frozen=True, eq=False)
class WandTrial:
    """One wand calibration against the truth.

    Attributes
    ----------
    recording, heldout : WandRecording
        Calibration frames and held-out frames (same rig, same visibility).
    result : WandCalibration
    floor_std_percent : float
        Wand length scatter of the calibration frames intersected with the true cameras, %.
    heldout_error_percent : (T_h,) array
        Held-out wand lengths (intersected with the calibrated cameras) minus the true
        length, in per cent of it.
    centre_error : (K,) array
        Camera centre errors after the best rigid motion onto the true centres, mm.
    focal_error_percent : (K,) array
        Calibrated minus true focal length, per cent.
    labels_consistent : float
        Fraction of used frames whose two ends carry the same labels in every camera
        (up to exchanging both, which the wand cannot tell).
    """

    recording: WandRecording
    heldout: WandRecording
    result: WandCalibration
    floor_std_percent: float
    heldout_error_percent: np.ndarray
    centre_error: np.ndarray
    focal_error_percent: np.ndarray
    labels_consistent: float


def distortion_error_px(camera, truth, r_max_px: float, *, n: int = 200) -> float:
    """Largest difference of the radial lens displacement of ``camera`` and ``truth``, px,
    at image radii up to ``r_max_px`` (the farthest observation from the centre).

    The displacement of a point at pixel radius ``r`` (ideal image, from the principal
    point) is ``r (k1 rn^2 + k2 rn^4 + k3 rn^6)`` with ``rn = r / f``. A part of it linear
    in ``r`` is a change of the focal length, which the adjustment takes into ``f``; it is
    fitted (least squares over the radii) and left out, so this is the error of the lens
    *shape*. Decentring and the principal point are not part of it.
    """
    r = np.linspace(0.0, float(r_max_px), n)

    def shift(c):
        rn = r / c.f
        return r * rn**2 * (c.k1 + rn**2 * (c.k2 + rn**2 * c.k3))

    d = shift(camera) - shift(truth)
    a = float(r @ d / (r @ r))
    return float(np.abs(d - a * r).max())


def observed_radius_px(camera, xy) -> float:
    """The largest distance of the observations ``xy`` ``(..., 2)`` from the image centre
    of ``camera``, px."""
    p = np.asarray(xy, float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    return float(np.hypot(p[:, 0] - camera.cx, p[:, 1] - camera.cy).max())


def length_scatter_percent(cameras, xy, length: float) -> float:
    """Standard deviation of the wand lengths intersected from ``xy`` ``(K, T, 2, 2)`` with
    ``cameras``, in per cent of ``length``."""
    K, T = xy.shape[:2]
    X = triangulate(cameras, xy.reshape(K, 2 * T, 2), min_angle_deg=0.0).points
    d = np.linalg.norm(X[0::2] - X[1::2], axis=1)
    return float(100 * np.nanstd(d, ddof=1) / length)


def wand_trial(*, seed: int = 0, n_frames: int = 25, n_heldout: int = 40,
               sigma_px: float = 0.3, seen_by=(2, 3), swap_fraction: float = 0.1,
               n_tie: int = 0, length: float = 600.0, focal_px=None,
               distortion: str = "auto", robust: bool = True,
               rig: dict | None = None) -> WandTrial:
    """Generate a wand recording (and held-out frames) and calibrate from it.

    The library receives only what a user has: the measured (possibly mislabelled) ends,
    the wand's length, the image sizes and, if given, ``focal_px``. ``rig``: keywords of
    :func:`~lsmta.synth.wand.wand_rig` (e.g. :data:`~lsmta.synth.wand.WIDE_RIG`), and
    optionally ``half_size``, the volume the wand is waved through (mm; of
    :func:`~lsmta.synth.wand.wand_recording`).
    """
    rng = np.random.default_rng(seed)
    rig = dict(rig or {})
    half_size = rig.pop("half_size", (900.0, 900.0, 600.0))
    cameras = wand_rig(rng=rng, **rig)
    rec = wand_recording(cameras=cameras, rng=rng, n_frames=n_frames, length=length,
                         sigma_px=sigma_px, seen_by=seen_by, swap_fraction=swap_fraction,
                         n_tie=n_tie, half_size=half_size)
    held = wand_recording(cameras=cameras, rng=rng, n_frames=n_heldout, length=length,
                          sigma_px=sigma_px, seen_by=seen_by, half_size=half_size)
    result = calibrate_wand(rec.xy, length, [c.image_size for c in cameras],
                            focal_px=focal_px, tie_xy=rec.tie_xy if n_tie else None,
                            distortion=distortion, robust=robust)
    K = len(cameras)
    # the floor: the true cameras on the same observations with the true labels
    true_labels = np.where(rec.swapped[..., None, None], rec.xy[:, :, ::-1], rec.xy)
    floor = length_scatter_percent(cameras, true_labels, length)
    Xh = triangulate(result.cameras, held.xy.reshape(K, -1, 2), min_angle_deg=0.0).points
    held_err = 100 * (np.linalg.norm(Xh[0::2] - Xh[1::2], axis=1) - length) / length
    A = np.array([c.C for c in result.cameras])
    B = np.array([c.C for c in cameras])
    R, t = fit_rigid(A, B)
    centre = np.linalg.norm(apply_rigid(R, t, A) - B, axis=1)
    focal = 100 * np.array([(c.f - g.f) / g.f for c, g in zip(result.cameras, cameras)])
    # labels relative to the truth must agree across the cameras that see a frame
    rel = result.swapped ^ rec.swapped
    seen = np.isfinite(rec.xy).all(axis=(2, 3))
    ok = [len(set(rel[seen[:, t], t].tolist())) == 1 for t in np.flatnonzero(result.used)]
    return WandTrial(recording=rec, heldout=held, result=result, floor_std_percent=floor,
                     heldout_error_percent=held_err, centre_error=centre,
                     focal_error_percent=focal, labels_consistent=float(np.mean(ok)))


def dlt_peer_rms(result: WandCalibration, length: float, *, tie_xy=None) -> np.ndarray:
    """``(K,)`` the image RMS per coordinate (easyWand's convention), px, of the 11-parameter
    DLT camera fitted to the same observations: the stand-in for easyWand's DLT.

    A DLT is the projective camera without distortion: exterior orientation, focal length,
    principal point, affinity and shear (``f, cx, cy, b1, b2``: 11 parameters). Here every
    camera's 11 parameters and all points are adjusted together (a bundle adjustment with
    that camera model, the wand length observed, from ``result``'s cameras without their
    lens), which is the least any DLT fit of these observations can reach; easyWand fits
    its DLT to the points of its own adjustment, which can only be higher.
    """
    cams = [c.replace(k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0) for c in result.cameras]
    K, T = result.wand_xy.shape[:2]
    obs = result.wand_xy.reshape(K, 2 * T, 2)
    if tie_xy is not None:
        obs = np.concatenate([obs, np.asarray(tie_xy, float).reshape(K, -1, 2)], axis=1)
    X = triangulate(cams, obs, min_angle_deg=0.0).points
    seen = np.isfinite(obs).all(axis=2).sum(axis=0) >= 2
    obs = np.where(seen[None, :, None], obs, np.nan)
    X = np.where(seen[:, None], X, 0.0)
    pairs = np.arange(2 * T).reshape(T, 2)[result.used]
    bar = Bar(pairs=pairs, length=float(length), sigma=1e-4 * float(length))
    fit = bundle_adjust(cams, obs, X, intrinsics=("f", "cx", "cy", "b1", "b2"),
                        fixed_exterior=(0,), bar=bar,
                        params=BundleParams(loss="soft_l1", f_scale=3.0, reject_k=4.0))
    res = np.where(fit.rejected[..., None], np.nan, fit.residuals)
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.nanmean(res.reshape(K, -1) ** 2, axis=1))
