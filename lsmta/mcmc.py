"""Posterior samples by emcee's affine-invariant ensemble sampler, reproducible from one
generator: the walkers start in a Gaussian ball drawn from ``rng``, and emcee's own legacy
generator is seeded from the same ``rng``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validate import as_array, as_rng


class SampleMoments:
    """Mean and sample standard deviation (ddof 1) over the rows of ``self.samples``
    ``(S, P)``; a base of the posterior results."""

    @property
    def mean(self) -> np.ndarray:
        return self.samples.mean(axis=0)

    @property
    def std(self) -> np.ndarray:
        return self.samples.std(axis=0, ddof=1)


@dataclass(frozen=True, eq=False)
class Chain:
    """Samples of an ensemble run.

    Attributes
    ----------
    samples : (S, P) array
        After burn-in and thinning, all walkers.
    acceptance : float
        Mean acceptance fraction of the walkers.
    """

    samples: np.ndarray
    acceptance: float


def sample_ensemble(log_prob, centre, spread, *, n_walkers: int, n_steps: int, burn: int,
                    thin: int = 1, rng: np.random.Generator | int | None = None) -> Chain:
    """Run ``n_walkers`` walkers for ``n_steps`` steps from ``centre + spread * N(0, 1)``.

    Parameters
    ----------
    log_prob : callable
        ``log_prob(theta (P,)) -> float``, -inf outside the support.
    centre, spread : (P,) arrays
        Centre and per-parameter standard deviation of the walkers' start.
    n_walkers, n_steps, burn, thin : int
        Walkers (at least twice the number of parameters), steps per walker, steps
        discarded, thinning.
    rng : numpy.random.Generator, int or None

    Returns
    -------
    Chain
    """
    centre = as_array(centre, "centre", shape=(None,))
    ndim = len(centre)
    spread = as_array(spread, "spread", shape=(ndim,))
    if n_walkers < 2 * ndim:
        raise ValueError(f"n_walkers: expected at least {2 * ndim} (twice the {ndim} "
                         f"parameters), got {n_walkers}")
    if not 0 <= burn < n_steps:
        raise ValueError(f"burn: expected 0 <= burn < n_steps = {n_steps}, got {burn}")
    rng = as_rng(rng)
    start = centre + spread * rng.standard_normal((n_walkers, ndim))
    import emcee  # deferred: emcee imports scipy.stats (~0.4 s CPU) for every lsmta import

    sampler = emcee.EnsembleSampler(n_walkers, ndim, log_prob)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**32))).get_state()
    with np.errstate(invalid="ignore"):       # -inf - -inf for proposals outside the support
        sampler.run_mcmc(start, n_steps, progress=False)
    return Chain(samples=sampler.get_chain(discard=burn, thin=thin, flat=True),
                 acceptance=float(np.mean(sampler.acceptance_fraction)))
