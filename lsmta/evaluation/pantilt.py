"""Pan-tilt calibration trials: generator and library side by side (notebook 11, tests,
experiments).

:func:`three_conditions` runs the thesis's experiment of Section 4.5 on synthetic data —
intrinsics from a target at home, then the home-only, simple and general calibrations,
each scored on an independent evaluation grid against the floor that the true model
reaches on the same noisy data. :func:`misalignment_sweep` repeats it for heads whose axes
are further from the ideal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_rng
from ..pantilt import Fit, PanTiltCamera, calibrate, calibrate_intrinsics, projection_errors
from ..synth.pantilt import (
    PanTiltData,
    calibration_sweeps,
    evaluation_grid,
    intrinsic_target,
    pantilt_head,
)

CONDITIONS = ("home", "simple", "general")


@dataclass(frozen=True, eq=False)
class PanTiltTrial:
    """One run of the three calibration conditions.

    Attributes
    ----------
    head : PanTiltCamera
        The true camera.
    intrinsics : Fit
        The intrinsic calibration (``model`` is the camera the others start from).
    calibration, evaluation : PanTiltData
        The calibration sweeps and the evaluation grid.
    fits : dict
        ``{"home", "simple", "general"}`` -> :class:`~lsmta.pantilt.Fit`.
    errors : dict
        Same keys plus ``"truth"`` -> ``(N, 2)`` projection errors on the evaluation grid,
        pixels (the truth's are the floor: noise alone).
    """

    head: PanTiltCamera
    intrinsics: Fit
    calibration: PanTiltData
    evaluation: PanTiltData
    fits: dict
    errors: dict

    def median(self, key: str) -> float:
        """Median projection error (pixels) of a condition or ``"truth"``."""
        return float(np.nanmedian(np.hypot(*self.errors[key].T)))


def three_conditions(head: PanTiltCamera, *, rng: np.random.Generator | int | None = None,
                     loss: str = "linear", f_scale: float = 10.0, points_per_setting: int = 20,
                     image_sigma: float = 8.0, world_sigma: float = 25.0) -> PanTiltTrial:
    """The thesis's three calibration conditions on data generated from ``head``.

    ``image_sigma`` (px) and ``world_sigma`` (mm) are the noise of the calibration and
    evaluation observations (:func:`lsmta.synth.pantilt.observe`'s defaults);
    ``loss`` and ``f_scale`` apply to the three pose/axis calibrations.
    """
    rng = as_rng(rng)
    target = intrinsic_target(head, rng=rng)
    intr = calibrate_intrinsics(target.X, target.xy, head.camera.image_size)
    noise = dict(image_sigma=image_sigma, world_sigma=world_sigma)
    cal = calibration_sweeps(head, rng=rng, points_per_setting=points_per_setting, **noise)
    ev = evaluation_grid(head, rng=rng, **noise)
    h = cal.home
    cam = intr.model
    kw = dict(loss=loss, f_scale=f_scale)
    fits = {"home": calibrate(cam, cal.pan[h], cal.tilt[h], cal.X[h], cal.xy[h], kind="simple",
                              **kw),
            "simple": calibrate(cam, cal.pan, cal.tilt, cal.X, cal.xy, kind="simple", **kw),
            "general": calibrate(cam, cal.pan, cal.tilt, cal.X, cal.xy, kind="general", **kw)}
    errors = {k: projection_errors(f.model, ev.pan, ev.tilt, ev.X, ev.xy) for k, f in fits.items()}
    errors["truth"] = projection_errors(head, ev.pan, ev.tilt, ev.X, ev.xy)
    return PanTiltTrial(head=head, intrinsics=intr, calibration=cal, evaluation=ev, fits=fits,
                        errors=errors)


def misalignment_sweep(scales, *, rng: np.random.Generator | int | None = None, repeats: int = 1,
                       loss: str = "linear", f_scale: float = 10.0, points_per_setting: int = 20,
                       image_sigma: float = 8.0, world_sigma: float = 25.0) -> dict:
    """Median errors of the three conditions for heads with ``misalignment`` in ``scales``.

    ``loss``, ``f_scale``, ``points_per_setting``, ``image_sigma`` and ``world_sigma`` are
    :func:`three_conditions`'s. Each scale is run ``repeats`` times with fresh data; medians
    are averaged over the repeats.

    Returns
    -------
    dict
        ``"scale"`` (S,), and ``"home"``, ``"simple"``, ``"general"``, ``"truth"`` (S,) arrays of
        median projection errors, pixels.
    """
    rng = as_rng(rng)
    out = {k: np.zeros(len(scales)) for k in (*CONDITIONS, "truth")}
    for i, s in enumerate(scales):
        for _ in range(repeats):
            trial = three_conditions(pantilt_head(misalignment=s), rng=rng, loss=loss,
                                     f_scale=f_scale, points_per_setting=points_per_setting,
                                     image_sigma=image_sigma, world_sigma=world_sigma)
            for k in out:
                out[k][i] += trial.median(k) / repeats
    out["scale"] = np.asarray(scales, dtype=float)
    return out
