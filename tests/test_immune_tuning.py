"""E[I] differentiable in the threshold: gradients against central differences, optax against bisection."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.immune import quadrature as Q
from jaxdip.immune import tuning as Tn
from jaxdip.immune.costs import Distance, Uniform
from jaxdip.immune.model import Infection

MODEL = Infection()
LOG_R = -7.2765


@pytest.mark.parametrize("cost", [Uniform(), Distance(10.0)], ids=["uniform", "distance"])
def test_quadrature_gradient_matches_central_differences(cost):
    e, de = Tn.progeny_and_slope(MODEL, cost, LOG_R, n=1024)
    h = 1e-5
    fd = (float(Tn.progeny_and_slope(MODEL, cost, LOG_R + h, n=1024)[0])
          - float(Tn.progeny_and_slope(MODEL, cost, LOG_R - h, n=1024)[0])) / (2 * h)
    assert float(de) == pytest.approx(fd, rel=1e-6)
    assert float(e) == pytest.approx(float(MODEL.R0) - float(Q.F(MODEL, cost, jnp.asarray(LOG_R), 1024).g))


def test_monte_carlo_gradient_matches_central_differences_and_is_unbiased():
    key = jax.random.PRNGKey(11)
    e, de = Tn.progeny_and_slope(MODEL, Uniform(), LOG_R, method="mc", key=key, n=4096)
    h = 1e-5
    fd = (float(Tn.progeny_and_slope(MODEL, Uniform(), LOG_R + h, method="mc", key=key, n=4096)[0])
          - float(Tn.progeny_and_slope(MODEL, Uniform(), LOG_R - h, method="mc", key=key, n=4096)[0])) / (2 * h)
    assert float(de) == pytest.approx(fd, rel=1e-6)
    # over independent batches, value and slope average to the quadrature's
    vals = [Tn.progeny_and_slope(MODEL, Uniform(), LOG_R, method="mc", key=jax.random.fold_in(key, i), n=4096)
            for i in range(24)]
    v, s = np.array([float(a) for a, _ in vals]), np.array([float(b) for _, b in vals])
    eq, sq = Tn.progeny_and_slope(MODEL, Uniform(), LOG_R, n=2048)
    assert abs(v.mean() - float(eq)) < 4.5 * v.std(ddof=1) / math.sqrt(v.size)
    assert abs(s.mean() - float(sq)) < 4.5 * s.std(ddof=1) / math.sqrt(s.size)


def test_optax_reaches_the_bisection_threshold():
    th = Q.threshold(MODEL, Uniform(), float(MODEL.R0) - 1.0, n=1024)
    tq = Tn.tune_threshold(MODEL, Uniform(), 1.0, th.log_r - 1.0, steps=150, lr=0.1, n_quad=1024)
    assert math.exp(tq.log_r - th.log_r) == pytest.approx(1.0, abs=1e-4)


@pytest.mark.slow
def test_optax_monte_carlo_within_one_percent():
    th = Q.threshold(MODEL, Uniform(), float(MODEL.R0) - 1.0, n=2048)
    tm = Tn.tune_threshold(MODEL, Uniform(), 1.0, th.log_r - 1.0, steps=300, lr=0.1, method="mc",
                           key=jax.random.PRNGKey(3), batch=8192)
    assert abs(math.exp(tm.log_r - th.log_r) - 1.0) < 0.01


def test_optax_monte_carlo_small():
    """Fast twin of the slow test: fewer, smaller batches, a looser tolerance (its noise is larger)."""
    th = Q.threshold(MODEL, Uniform(), float(MODEL.R0) - 1.0, n=1024)
    tm = Tn.tune_threshold(MODEL, Uniform(), 1.0, th.log_r - 1.0, steps=100, lr=0.1, method="mc",
                           key=jax.random.PRNGKey(3), batch=4096)
    assert abs(math.exp(tm.log_r - th.log_r) - 1.0) < 0.04
