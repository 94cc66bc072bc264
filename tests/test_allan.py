"""jaxdip.sim.allan: the overlapping Allan variance against a plain loop and the noise laws it is used to check."""

import numpy as np
import pytest

from jaxdip.sim.allan import (allan_variance, avar_differenced_quantised, avar_gauss_markov,
                              avar_sampled_white_gauss_markov, avar_white)


def allan_loop(y, m):
    """Plain-Python overlapping Allan variance (the defining sum)."""
    n = len(y)
    means = [sum(y[k:k + m]) / m for k in range(n - m + 1)]
    d = [(means[k + m] - means[k]) ** 2 for k in range(n - 2 * m + 1)]
    return 0.5 * sum(d) / len(d)


def test_matches_the_defining_sum():
    y = np.random.default_rng(0).normal(size=301).cumsum() * 0.1 + 3.0
    ms = [1, 2, 7, 50, 150]
    np.testing.assert_allclose(allan_variance(y, ms), [allan_loop(list(y), m) for m in ms], rtol=1e-10)


def test_white_noise_law_sigma2_over_tau():
    rng = np.random.default_rng(1)
    s = 0.3
    y = s * rng.normal(size=400_000)
    ms = np.array([1, 4, 32, 256])
    # relative standard error of the overlapping estimate is about sqrt(1 / (N / m)) at these sizes
    np.testing.assert_allclose(allan_variance(y, ms), avar_white(s**2, ms), rtol=0.06)
    np.testing.assert_allclose(avar_sampled_white_gauss_markov(s**2, 0.0, 1.0, 0.1, ms), avar_white(s**2, ms),
                               rtol=1e-12)


def test_gauss_markov_law():
    rng = np.random.default_rng(2)
    dt, T, q, n = 0.1, 5.0, 0.02, 2_000_000
    a = np.exp(-dt / T)
    w = np.sqrt(q * T / 2 * (1 - a * a)) * rng.normal(size=n)  # exact discretisation of b' = -b/T + w
    b = np.empty(n)
    b[0] = np.sqrt(q * T / 2) * rng.normal()
    for k in range(1, n):  # the reference is a plain loop on purpose
        b[k] = a * b[k - 1] + w[k]
    ms = np.array([10, 50, 200, 1000])
    # the closed form is for continuous averages; point samples differ by O(dt / tau) (at m = 1 by a factor
    # 3/2: (1/2) E[(b_{k+1} - b_k)^2] = q dt / 2 against q tau / 3), so m starts at 10
    np.testing.assert_allclose(allan_variance(b, ms), avar_gauss_markov(q, T, ms * dt), rtol=0.1)
    # the exact law of the samples, m = 1 included
    ms = np.array([1, 3, 10, 50, 200, 1000])
    np.testing.assert_allclose(allan_variance(b, ms), avar_sampled_white_gauss_markov(0.0, q, T, dt, ms), rtol=0.06)
    np.testing.assert_allclose(avar_sampled_white_gauss_markov(0.0, q, T, dt, 1), q * T / 2 * (1 - np.exp(-dt / T)),
                               rtol=1e-12)  # (1/2) E[(b1 - b0)^2] = Var b (1 - a)
    # far above dt the sampled and the continuous forms meet
    np.testing.assert_allclose(avar_sampled_white_gauss_markov(0.0, q, T, 1e-3, 20_000),
                               avar_gauss_markov(q, T, 20.0), rtol=1e-3)
    # limits: tau << T gives the random walk q tau / 3, tau >> T gives white noise q T^2 / tau
    np.testing.assert_allclose(avar_gauss_markov(q, T, 1e-3), q * 1e-3 / 3, rtol=1e-3)
    np.testing.assert_allclose(avar_gauss_markov(q, T, 1e5), q * T**2 / 1e5, rtol=1e-3)


def test_differenced_quantised_rate():
    # a position that moves several quanta per sample at random, so that the quantisation errors are close to
    # independent U(-Q/2, Q/2) (a constant speed makes them a deterministic Weyl sequence instead)
    Q, dt = 0.01, 0.01
    pos = np.cumsum(np.random.default_rng(3).normal(0.0, 5 * Q, size=400_000))
    p = Q * np.round(pos / Q)
    rate = np.diff(p) / dt - np.diff(pos) / dt  # the quantisation part of the differenced rate
    ms = np.array([1, 3, 10, 100])
    np.testing.assert_allclose(allan_variance(rate, ms), avar_differenced_quantised(Q, ms * dt), rtol=0.05)


def test_bad_cluster_size():
    with pytest.raises(ValueError):
        allan_variance(np.zeros(10), [5])
