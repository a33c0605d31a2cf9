"""The Bayesian view of a pan-tilt calibration: emcee samples of the model parameters.

With independent Gaussian image errors of standard deviation ``sigma_px`` per coordinate
and flat priors, the posterior of the parameters of :func:`lsmta.pantilt.calibrate` is
``exp(-|r(θ)|² / (2 sigma_px²))``. Near a well-determined solution it is close to the
Gaussian ``N(θ̂, s² (JᵀJ)⁻¹)`` that :class:`~lsmta.pantilt.Fit` reports; the samples show
whether that holds, and the pairwise correlations (axis offset against home position,
for example).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_rng, as_scalar, freeze
from ..camera import Camera
from ..mcmc import SampleMoments, sample_ensemble
from .fitting import Fit, _observations, project_pantilt_params


@dataclass(frozen=True, eq=False)
class Posterior(SampleMoments):
    """Posterior samples.

    Attributes
    ----------
    names : tuple of str
        Parameter names (those of the :class:`Fit`).
    samples : (S, P) array
        Samples after burn-in and thinning, in the units of :attr:`Fit.params`.
    acceptance : float
        Mean acceptance fraction of the walkers.
    """

    names: tuple
    samples: np.ndarray
    acceptance: float

    def __post_init__(self):
        freeze(self, ("samples",))


def sample_posterior(fit: Fit, camera: Camera, pan, tilt, X, xy, *,
                     rng: np.random.Generator | int | None = None, sigma_px: float | None = None,
                     n_walkers: int = 32, n_steps: int = 400, burn: int = 150,
                     thin: int = 5) -> Posterior:
    """Sample the posterior of a :func:`~lsmta.pantilt.calibrate` fit with emcee.

    Parameters
    ----------
    fit : Fit
        The least-squares solution; walkers start in a small ball around it.
    camera : Camera
        The ``camera`` that was passed to :func:`calibrate` (intrinsics, starting pose).
    pan, tilt, X, xy : arrays
        The observations that were passed to :func:`calibrate`.
    rng : numpy.random.Generator, int or None
        Seeds the walkers' start and emcee's own generator.
    sigma_px : float, optional
        Image noise per coordinate, pixels (default: the fit's residual ``sigma_px``).
    n_walkers, n_steps, burn, thin : int
        emcee settings: walkers (at least twice the number of parameters), steps per
        walker, steps discarded, thinning.

    Returns
    -------
    Posterior
    """
    rng = as_rng(rng)
    if not isinstance(fit, Fit):
        raise TypeError(f"fit: expected a Fit from calibrate, got {type(fit).__name__}")
    kind = fit.model.kind
    limits = dict(pan_limits=fit.model.pan_limits, tilt_limits=fit.model.tilt_limits)
    pan, tilt, X, xy = _observations(pan, tilt, X, xy, (limits["pan_limits"],
                                                        limits["tilt_limits"]))
    sigma = fit.sigma_px if sigma_px is None else as_scalar(sigma_px, "sigma_px", positive=True)

    def log_prob(p):
        r = project_pantilt_params(camera, p, kind, X, pan, tilt) - xy
        chi2 = float(np.sum(r * r))
        return -0.5 * chi2 / sigma**2 if np.isfinite(chi2) else -np.inf

    chain = sample_ensemble(log_prob, fit.params, 0.1 * fit.std, n_walkers=n_walkers,
                            n_steps=n_steps, burn=burn, thin=thin, rng=rng)
    return Posterior(names=fit.names, samples=chain.samples, acceptance=chain.acceptance)
