"""Optional: jaxdip's batch KF/RTS smoother/log-likelihood against dynamax's (skipped unless dynamax is
installed, e.g. ``pip install -e ".[peers]"``). dynamax adds a fixed 1e-9 to the diagonal of every matrix it
solves with; it is set to 0 here, as in jaxdip.bench.peers, so the two must agree to rounding."""

import functools

import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.recorded import kalman_filter, rts_smoother

dinf = pytest.importorskip("dynamax.linear_gaussian_ssm.inference")


def test_filter_smoother_likelihood_equal_dynamax(monkeypatch):
    from dynamax.linear_gaussian_ssm import lgssm_filter, lgssm_smoother
    from dynamax.utils.utils import psd_solve

    monkeypatch.setattr(dinf, "psd_solve", functools.partial(psd_solve, diagonal_boost=0.0))
    rng = np.random.default_rng(0)
    d, p, m, T = 4, 2, 1, 60
    Phi = np.eye(d) + 0.05 * rng.standard_normal((d, d))
    W = rng.standard_normal((d, m))
    C = rng.standard_normal((p, d))
    A = rng.standard_normal((d, d))
    Q = 0.01 * (A @ A.T + np.eye(d))
    R = np.diag([0.1, 0.3])
    P0 = np.eye(d)
    us = rng.standard_normal((T, m))
    ys = rng.standard_normal((T, p))
    kf = KalmanFilter(Phi, W, C, Q, R, P0, jnp.zeros(d))
    ours_f = kalman_filter(kf, ys, us)
    ours_s = rts_smoother(kf, ys, us)
    params = dinf.make_lgssm_params(jnp.zeros(d), jnp.asarray(P0), jnp.asarray(Phi), jnp.asarray(Q), jnp.asarray(C),
                                    jnp.asarray(R), dynamics_input_weights=jnp.asarray(W))
    # jaxdip's us[k] drives x_k -> x_{k+1}; dynamax's input at index k drives x_{k-1} -> x_k
    dyn_us = jnp.asarray(np.concatenate([np.zeros((1, m)), us[:-1]]))
    df = lgssm_filter(params, jnp.asarray(ys), dyn_us)
    ds = lgssm_smoother(params, jnp.asarray(ys), dyn_us)
    for a, b in ((df.filtered_means, ours_f.mean), (df.filtered_covariances, ours_f.cov),
                 (ds.smoothed_means, ours_s.mean), (ds.smoothed_covariances, ours_s.cov)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(float(df.marginal_loglik), float(ours_f.log_likelihood), rtol=1e-10)
