"""The pan-tilt heads' calibration targets found in rendered images (Davis 2002, §4.2, the
procedure of notebook 11), for the mixed-scale system's calibration
(:func:`lsmta.evaluation.mixed_scale.calibrate_scene` and
:func:`lsmta.evaluation.mixed_scale.calibrate_heads` with ``from_images=True``).

A calibration target of LEDs lit one at a time (one frame per LED, so each spot is known
to be that LED) is filmed by the head at each setting of its sweeps
(:func:`lsmta.synth.pantilt.render_target_frames`); the LED's image point is then found as
the ceiling's are and as the system finds the body's LEDs (:func:`lsmta.widearea.detect`,
thresholds learnt from frames of the empty view, :func:`lsmta.widearea.noise_threshold`).
The generator only renders: the image points come from the detector, not from projecting
the truth.

* :func:`head_target_centroids` — the LED's image point in each observation's frame;
* :func:`calibrate_head` — a head calibrated from those image points (or, for controlled
  studies, from projected truth plus noise), :class:`HeadCalibration`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_int, as_rng, as_scalar
from ..pantilt import PanTiltCamera, calibrate, calibrate_intrinsics
from ..synth.pantilt import (
    PanTiltData,
    calibration_sweeps,
    intrinsic_target,
    render_target_frames,
)
from ..widearea import detect, noise_threshold

#: the 3-D intrinsics target's survey error, mm per coordinate (a precise target)
TARGET_SIGMA_MM = 0.1


def head_target_centroids(head: PanTiltCamera, pan, tilt, X, *,
                          rng: np.random.Generator | int | None = None,
                          threshold_sigmas: float = 5.0, n_background: int = 8,
                          chunk: int = 40) -> np.ndarray:
    """The calibration LED found in the frames ``head`` films of it.

    The head first films ``n_background`` frames of the empty view (the target's backdrop,
    which fills its view at every setting; thresholds learnt once), then, at each setting
    (pan, tilt) among the observations, its LEDs, one lit per frame and facing the head
    (:func:`lsmta.synth.pantilt.render_target_frames` through ``head.camera_at(pan,
    tilt)``: image noise, a textured backdrop, Gaussian spots). The library's detector then
    finds the spot: thresholds ``threshold_sigmas`` times the image noise measured in the
    empty view above its maximum, every pixel tested. A frame with exactly one feature
    gives its intensity centroid; none or several give NaN.

    Parameters
    ----------
    head : PanTiltCamera
        The head that films (in a simulation the true head: it only renders).
    pan, tilt : (N,) arrays
        Setting of each observation, degrees.
    X : (N, 3) array
        Where the LED is at each observation, mm.
    rng : numpy.random.Generator, int or None
        The frames' image noise.
    threshold_sigmas : float
        The detection threshold's offset in units of the measured image noise (> 0).
    n_background : int
        Frames of the empty view (>= 2: the noise is measured from
        differences of consecutive frames).
    chunk : int
        Frames rendered at once (memory: ``chunk`` float32 frames of the head's size).

    Returns
    -------
    (N, 2) array
        Centroids, px (NaN: not found or ambiguous).
    """
    if not isinstance(head, PanTiltCamera):
        raise TypeError(f"head: expected an lsmta.pantilt.PanTiltCamera, got "
                        f"{type(head).__name__}")
    X = as_array(X, "X", shape=(None, 3))
    pan = as_array(pan, "pan", shape=(len(X),))
    tilt = as_array(tilt, "tilt", shape=(len(X),))
    sigmas = as_scalar(threshold_sigmas, "threshold_sigmas", positive=True)
    n_background = as_int(n_background, "n_background", minimum=2)
    chunk = as_int(chunk, "chunk", minimum=1)
    rng = as_rng(rng)
    out = np.full((len(X), 2), np.nan)
    threshold = None
    for p, t in np.unique(np.c_[pan, tilt], axis=0):
        idx = np.flatnonzero((pan == p) & (tilt == t))
        cam = head.camera_at(p, t)
        for lo in range(0, len(idx), chunk):
            sel = idx[lo:lo + chunk]
            v = render_target_frames(cam, X[sel], rng=rng,
                                     n_background=n_background if threshold is None else 0)
            if threshold is None:                  # the empty view, once
                threshold = noise_threshold(v.background, sigmas=sigmas)
            found = detect(v.frames, threshold)
            one = np.flatnonzero(np.diff(found.start) == 1)
            out[sel[one]] = found.xy[found.start[one]]
    return out


@dataclass(frozen=True, eq=False)
class HeadCalibration:
    """One head calibrated by :func:`calibrate_head`.

    Attributes
    ----------
    model : PanTiltCamera
        The calibrated general model.
    check_rms_px : float
        Image RMS on held-out sweep settings against the true head (true points, true
        images), px: a score that uses the truth.
    fit_rms_px : float
        Reprojection RMS of the sweeps' fit on its own image points, px (no truth).
    n_points : int
        Observations offered (target and sweeps).
    n_used : int
        Of them, image points found (all of them on the projected route).
    from_images : bool
        True: the image points were found by the detector in rendered frames
        (:func:`head_target_centroids`); False: projected truth plus noise.
    """

    model: PanTiltCamera
    check_rms_px: float
    fit_rms_px: float
    n_points: int
    n_used: int
    from_images: bool


def calibrate_head(head: PanTiltCamera, *, rng: np.random.Generator | int | None = None,
                   from_images: bool = True, image_sigma: float = 0.3,
                   world_sigma: float = 0.3, distortion=("k1",), n_target: int | None = None,
                   points_per_setting: int | None = None,
                   threshold_sigmas: float = 5.0) -> HeadCalibration:
    """``head`` calibrated by notebook 11's procedure with a precise target: intrinsics
    (``distortion`` terms) from one view at home of a 3-D target of ``n_target`` LEDs
    measured to :data:`TARGET_SIGMA_MM` mm (:func:`lsmta.pantilt.calibrate_intrinsics`),
    then home pose and axes of the general model from the thesis's sweeps,
    ``points_per_setting`` LED positions surveyed to ``world_sigma`` mm at each setting
    (:func:`lsmta.pantilt.calibrate`). A zoomed lens sees only the middle of its
    distortion: one radial term keeps the model monotonic where the aiming search looks
    outside the image.

    The image points: with ``from_images``, found by the detector in rendered frames
    (:func:`head_target_centroids`, ``threshold_sigmas``; ``image_sigma`` unused; the
    observations whose LED is not found, or ambiguous, are left out); otherwise the true
    projections plus ``image_sigma`` px of Gaussian noise, the route for controlled
    studies. Both routes draw the same target, survey noise and check points from ``rng``
    (the renderer draws from a child of it). Defaults: 200 target LEDs and 20 per setting
    on both routes, so the image route gets the same survey as the projected one (about
    580 rendered frames per head; a survey of 60 and 6 left heads up to 0.8 px off over
    their grid).

    Returns
    -------
    HeadCalibration
    """
    if not isinstance(head, PanTiltCamera):
        raise TypeError(f"head: expected an lsmta.pantilt.PanTiltCamera, got "
                        f"{type(head).__name__}")
    if not isinstance(from_images, (bool, np.bool_)):
        raise TypeError(f"from_images: expected True or False, got {from_images!r}")
    n_target = as_int(200 if n_target is None else n_target,
                      "n_target", minimum=10)
    per = as_int(20 if points_per_setting is None
                 else points_per_setting, "points_per_setting", minimum=1)
    rng = as_rng(rng)
    render = rng.spawn(1)[0]
    target = intrinsic_target(head, rng=rng, n=n_target, image_sigma=image_sigma,
                              world_sigma=TARGET_SIGMA_MM)
    sweeps = calibration_sweeps(head, rng=rng, points_per_setting=per,
                                image_sigma=image_sigma, world_sigma=world_sigma,
                                depth=(2000.0, 4000.0))
    offered = len(target.X) + len(sweeps.X)
    if from_images:
        target, sweeps = (_found(head, d, rng=render, threshold_sigmas=threshold_sigmas)
                          for d in (target, sweeps))
    intr = calibrate_intrinsics(target.X, target.xy, head.camera.image_size,
                                distortion=tuple(distortion))
    fit = calibrate(intr.model, sweeps.pan, sweeps.tilt, sweeps.X, sweeps.xy, kind="general")
    held = calibration_sweeps(head, rng=rng, points_per_setting=5, image_sigma=0.0,
                              world_sigma=0.0, depth=(2000.0, 4000.0))
    e = fit.model.project(held.X_true, held.pan, held.tilt) - held.xy_true
    return HeadCalibration(model=fit.model,
                           check_rms_px=float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
                           fit_rms_px=float(np.sqrt(np.mean(np.sum(fit.residuals**2, axis=1)))),
                           n_points=offered, n_used=len(target.X) + len(sweeps.X),
                           from_images=bool(from_images))


def _found(head: PanTiltCamera, data: PanTiltData, *, rng, threshold_sigmas: float):
    """``data`` with its image points found in rendered frames of its true world points
    (:func:`head_target_centroids`), the observations not found left out."""
    xy = head_target_centroids(head, data.pan, data.tilt, data.X_true, rng=rng,
                               threshold_sigmas=threshold_sigmas)
    ok = np.isfinite(xy).all(axis=1)
    return PanTiltData(pan=data.pan[ok], tilt=data.tilt[ok], X=data.X[ok], xy=xy[ok],
                       X_true=data.X_true[ok], xy_true=data.xy_true[ok])
