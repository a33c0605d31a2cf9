"""The emcee driver (lsmta.mcmc): a known Gaussian recovered, reproducible from the seed,
arguments checked."""

import numpy as np
import pytest

from lsmta.mcmc import sample_ensemble

MEAN, STD = np.array([1.0, -2.0]), np.array([0.5, 2.0])


def _log_prob(theta):
    return -0.5 * float(np.sum(((theta - MEAN) / STD) ** 2))


def test_a_gaussian_is_recovered_and_the_seed_reproduces_the_chain():
    kw = dict(n_walkers=16, n_steps=1500, burn=300, thin=5)
    a = sample_ensemble(_log_prob, [0.0, 0.0], [1.0, 1.0], rng=3, **kw)
    b = sample_ensemble(_log_prob, [0.0, 0.0], [1.0, 1.0], rng=np.random.default_rng(3), **kw)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.samples.shape == (16 * (1500 - 300) // 5, 2)
    np.testing.assert_allclose(a.samples.mean(axis=0), MEAN, atol=0.25)
    np.testing.assert_allclose(a.samples.std(axis=0), STD, rtol=0.15)
    assert 0.2 < a.acceptance < 0.9


@pytest.mark.parametrize("kw, message", [
    (dict(n_walkers=3, n_steps=10, burn=2), "n_walkers"),
    (dict(n_walkers=8, n_steps=10, burn=10), "burn"),
    (dict(n_walkers=8, n_steps=10, burn=2, rng="1"), "rng"),
])
def test_arguments_are_checked(kw, message):
    with pytest.raises((ValueError, TypeError), match=message):
        sample_ensemble(_log_prob, [0.0, 0.0], [1.0, 1.0], **kw)
