"""What every calibration of K cameras returns first: the cameras and the adjustment.

:class:`CalibrationResult` is the shared head of the results of
:func:`~lsmta.calibration.calibrate_board`, :func:`~lsmta.calibration.calibrate_wand` and
:func:`~lsmta.systems.calibrate_rig`; each adds its own fields after these.
"""

from __future__ import annotations

from dataclasses import dataclass

from .bundle import BundleResult


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """The calibrated cameras and the bundle adjustment they came from.

    Attributes
    ----------
    cameras : list of K Camera
        The calibrated cameras, in the calibration's world frame, mm.
    bundle : BundleResult
        The final adjustment (in its own frame, which may differ from the cameras' by the
        datum; its residuals and statistics do not depend on it).
    """

    cameras: list
    bundle: BundleResult

    @property
    def rms_over_limit(self) -> float:
        """Image RMS residual over the noise limit ``sigma_px sqrt(1 - p/n)`` (1: the
        residuals are what the stated image precision predicts)."""
        return float(self.bundle.rms / self.bundle.noise_limit)
