"""The Bayesian view of one frame's fit: emcee samples of limb lengths and ball sizes.

With the posture (angles, shoulder) and the segmentation of a :class:`BodyFit` held, and
independent Gaussian point residuals of standard deviation ``sigma_mm`` under flat priors,
the posterior of the bone lengths and the simplified model's widths and depths is
``exp(-|r(θ)|² / (2 sigma_mm²))``. The least-squares answer is the Gaussian
``N(θ̂, sigma² (JᵀJ)⁻¹)`` of the same residuals; the samples show whether that holds.
Only the points within ``3 sigma`` of the fitted skin enter (the robust fit's inliers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_rng, as_scalar
from ..mcmc import SampleMoments, sample_ensemble
from .fitting import BodyFit, ModelState, _Layout, _residuals
from .metaballs import MetaballModel


@dataclass(frozen=True, eq=False)
class LimbPosterior(SampleMoments):
    """Posterior samples and the least-squares Gaussian of the same parameters.

    Attributes
    ----------
    names : tuple of str
        ``length_<limb>`` (mm) then ``<segment>_width`` / ``_depth`` (mm, middle ball).
    samples : (S, P) array
    acceptance : float
        Mean acceptance fraction of the walkers.
    ls_mean, ls_std : (P,) arrays
        The least-squares estimate and its standard deviations ``sigma² (JᵀJ)⁻¹``.
    n_points : int
        Points used.
    """

    names: tuple
    samples: np.ndarray
    acceptance: float
    ls_mean: np.ndarray
    ls_std: np.ndarray
    n_points: int


def sample_limb_posterior(model: MetaballModel, fit: BodyFit, points, torso_pose, *,
                          rng: np.random.Generator | int | None = None,
                          sigma_mm: float | None = None, n_walkers: int = 24, n_steps: int = 300,
                          burn: int = 100, thin: int = 5) -> LimbPosterior:
    """Sample lengths and sizes of a one-frame simplified fit with emcee.

    Parameters
    ----------
    model : MetaballModel
    fit : BodyFit
        A one-frame fit of the simplified model (:func:`~lsmta.body.fit_frame`).
    points : (N, 3) array
        The points that were fitted (world mm; NaN rows allowed, as in the fit).
    torso_pose : (4, 4) array
    rng : numpy.random.Generator, int or None
        Seeds the walkers' start and emcee's own generator.
    sigma_mm : float, optional
        Point noise (default: the fit's robust residual scale).
    n_walkers, n_steps, burn, thin : int
        emcee settings.
    """
    rng = as_rng(rng)
    if not isinstance(fit, BodyFit) or len(fit.segment) != 1:
        raise TypeError("fit: expected a one-frame BodyFit from fit_frame")
    P = as_array(torso_pose, "torso_pose", shape=(4, 4))[None]
    pts = as_array(points, "points", shape=(None, 3), allow_nan=True)
    if len(pts) != len(fit.segment[0]):
        raise ValueError(f"points: expected the {len(fit.segment[0])} fitted points, "
                         f"got {len(pts)}")
    sigma = fit.sigma_mm if sigma_mm is None else as_scalar(sigma_mm, "sigma_mm",
                                                            positive=True)
    seg = fit.segment[0]
    use = (seg >= 0) & (np.abs(np.nan_to_num(fit.residuals[0], nan=np.inf)) < 3 * sigma)
    X, S = pts[use], seg[use]
    F = np.zeros(len(X), int)
    lay = _Layout(model, 1, "simplified", True, ())
    st = fit.state
    x0 = lay.pack(st)
    free = np.zeros(len(x0), bool)
    free[lay.i_scale] = True
    free[lay.i_shape.ravel()] = True
    L0 = np.array([model.segments[[s.limb for s in model.segments].index(li)].length
                   for li in range(len(model.skeleton.limbs))])
    to_phys = np.ones(free.sum())
    to_phys[:len(L0)] = L0                                  # scale -> length (mm)
    template = ModelState(angles=st.angles, shoulder=st.shoulder, scales=st.scales, radii=st.radii)

    def resid(theta, jac=False):
        xx = x0.copy()
        xx[free] = theta
        if np.any(xx[free] <= 0):
            return None, None
        s = lay.unpack(xx, template, model)
        return _residuals(model, lay, s, P, X, F, S, jac=jac)

    def log_prob(theta):
        r, _ = resid(theta)
        if r is None:
            return -np.inf
        chi2 = float(np.sum(r * r))
        return -0.5 * chi2 / sigma**2 if np.isfinite(chi2) else -np.inf

    r, J = resid(x0[free], jac=True)
    J = J[:, free]
    cov = np.linalg.pinv(J.T @ J) * sigma**2
    ls_std = np.sqrt(np.diag(cov))
    chain = sample_ensemble(log_prob, x0[free], 0.5 * ls_std, n_walkers=n_walkers,
                            n_steps=n_steps, burn=burn, thin=thin, rng=rng)
    names = tuple(f"length_{n}" for n in model.skeleton.limbs) + tuple(
        np.array(lay.names)[lay.i_shape.ravel()])
    return LimbPosterior(names=names, samples=chain.samples * to_phys,
                         acceptance=chain.acceptance, ls_mean=x0[free] * to_phys,
                         ls_std=ls_std * to_phys, n_points=int(len(X)))
