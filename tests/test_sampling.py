"""Forward-filter backward-sample: the draws' moments against the RTS smoother's within Monte Carlo error."""

import numpy as np
import pytest

import jax

from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.recorded import rts_smoother
from jaxdip.estimators.sampling import sample_posterior

N = 10_000


def _setup(seed=0, T=6, d=3, p=2, m=1):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(d, d))
    Q = 0.2 * (A @ A.T / d + 0.3 * np.eye(d))
    kf = KalmanFilter(0.9 * np.eye(d) + 0.2 * rng.normal(size=(d, d)), rng.normal(size=(d, m)),
                      rng.normal(size=(p, d)), Q, np.array([0.3, 0.5]), np.eye(d), rng.normal(size=d))
    obs = rng.random((T, p)) < 0.7
    obs[3] = False
    return kf, rng.normal(size=(T, p)), rng.normal(size=(T, m)), obs


def test_ffbs_moments_match_the_rts_smoother():
    kf, ys, us, obs = _setup()
    sm = rts_smoother(kf, ys, us, mask=obs)
    xs = np.asarray(sample_posterior(jax.random.PRNGKey(1), kf, ys, us, N, mask=obs))
    T, d = sm.mean.shape
    assert xs.shape == (N, T, d)
    for k in range(T):
        P = np.asarray(sm.cov[k])
        se = np.sqrt(np.diag(P) / N)
        assert np.all(np.abs(xs[:, k].mean(0) - sm.mean[k]) < 4.5 * se), k
        # the standard error of a sample covariance entry of a Gaussian: sqrt((P_ii P_jj + P_ij^2) / N)
        se_cov = np.sqrt((np.outer(np.diag(P), np.diag(P)) + P**2) / N)
        assert np.all(np.abs(np.cov(xs[:, k].T) - P) < 4.5 * se_cov), k
    for k in range(T - 1):  # the lag-one covariance of the draws is the smoother's
        a, b = xs[:, k + 1] - xs[:, k + 1].mean(0), xs[:, k] - xs[:, k].mean(0)
        var_a, var_b = np.diag(sm.cov[k + 1]), np.diag(sm.cov[k])
        se_cross = np.sqrt((np.outer(var_a, var_b) + np.asarray(sm.cross_cov[k]) ** 2) / N)
        assert np.all(np.abs(a.T @ b / (N - 1) - sm.cross_cov[k]) < 4.5 * se_cross), k


def test_ffbs_is_reproducible_and_checks_its_count():
    kf, ys, us, _ = _setup(1)
    a = sample_posterior(jax.random.PRNGKey(3), kf, ys, us, 4)
    b = sample_posterior(jax.random.PRNGKey(3), kf, ys, us, 4)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ArgumentError, match="n_samples"):
        sample_posterior(jax.random.PRNGKey(3), kf, ys, us, 0)
    with pytest.raises(ArgumentTypeError, match="transition_jacobian"):
        sample_posterior(jax.random.PRNGKey(3), object(), ys, us, 2)
