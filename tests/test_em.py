"""EM for Q, R (and Phi, C): the likelihood never decreases, and the fixed point is the maximum-likelihood fit
found by an independent optimiser (scipy L-BFGS on the Cholesky factors, jax gradients)."""

import numpy as np
import pytest
import scipy.optimize

import jax
import jax.numpy as jnp

from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators.em import em_step, fit_em
from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.recorded import log_likelihood

PHI = np.array([[0.9, 0.2], [-0.2, 0.85]])
C = np.array([[1.0, 0.0], [0.5, 1.0]])
Q_TRUE = np.array([[0.3, 0.1], [0.1, 0.2]])
R_TRUE = np.array([[0.5, -0.1], [-0.1, 0.4]])


def _simulate(seed, B, T):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(B, 2))
    ys = np.empty((B, T, 2))
    Lq, Lr = np.linalg.cholesky(Q_TRUE), np.linalg.cholesky(R_TRUE)
    for k in range(T):
        ys[:, k] = x @ C.T + rng.normal(size=(B, 2)) @ Lr.T
        x = x @ PHI.T + rng.normal(size=(B, 2)) @ Lq.T
    return ys


def _kf(Q, R, Phi=PHI, C_=C):
    return KalmanFilter(Phi, None, C_, Q, R, np.eye(2), np.zeros(2))


def _chol(v):
    L = jnp.array([[jnp.exp(v[0]), 0.0], [v[1], jnp.exp(v[2])]])
    return L @ L.T


def _ml_fit(ys, mask):
    """Maximum likelihood over (Q, R) by scipy L-BFGS-B, from the true values."""
    ys_j, mask_j = jnp.asarray(ys), jnp.asarray(mask)

    def nll(v):
        kf = _kf(_chol(v[:3]), _chol(v[3:]))
        return -jnp.sum(jax.vmap(lambda y, m: log_likelihood(kf, y, mask=m))(ys_j, mask_j))

    vg = jax.jit(jax.value_and_grad(nll))

    def start(M):
        L = np.linalg.cholesky(M)
        return [np.log(L[0, 0]), L[1, 0], np.log(L[1, 1])]

    res = scipy.optimize.minimize(lambda v: tuple(np.asarray(a) for a in vg(v)), start(Q_TRUE) + start(R_TRUE),
                                  jac=True, method="L-BFGS-B", options={"gtol": 1e-10, "ftol": 1e-15,
                                                                        "maxiter": 500})
    return np.asarray(_chol(res.x[:3])), np.asarray(_chol(res.x[3:])), -res.fun


def test_em_increases_the_likelihood_and_reaches_the_ml_fit_with_missing_data():
    ys = _simulate(0, 4, 150)
    mask = np.random.default_rng(1).random(ys.shape) < 0.8
    mask[:, 10] = False  # fully missing steps
    res = fit_em(_kf(np.eye(2), np.eye(2)), ys, mask=mask, tol=1e-13, max_iter=2000)
    ll = res.log_likelihood
    print(f"EM: {res.iterations} iterations, {res.status}, log-likelihood {ll[0]:.3f} -> {ll[-1]:.6f}")
    assert res.status == "converged"
    assert np.all(np.diff(ll) >= -1e-10 * np.abs(ll[1:]))  # monotone up to rounding
    Q_ml, R_ml, ll_ml = _ml_fit(ys, mask)
    print("EM Q, R", np.asarray(res.model.Q).tolist(), np.asarray(res.model.R).tolist())
    print("ML Q, R", Q_ml.tolist(), R_ml.tolist())
    np.testing.assert_allclose(res.model.Q, Q_ml, rtol=1e-4, atol=1e-4 * np.abs(Q_ml).max())
    np.testing.assert_allclose(res.model.R, R_ml, rtol=1e-4, atol=1e-4 * np.abs(R_ml).max())
    assert ll[-1] <= ll_ml + 1e-8 * abs(ll_ml) and ll[-1] >= ll_ml - 1e-6 * abs(ll_ml)


def test_em_with_phi_and_c_never_decreases_the_likelihood():
    ys = _simulate(2, 2, 80)
    res = fit_em(_kf(np.eye(2), np.eye(2), Phi=0.5 * np.eye(2), C_=np.eye(2)), ys, update=("Phi", "Q", "C", "R"),
                 max_iter=40)
    assert np.all(np.diff(res.log_likelihood) >= -1e-10 * np.abs(res.log_likelihood[1:]))
    assert res.log_likelihood[-1] > res.log_likelihood[0] + 10.0


def test_em_step_one_sequence_is_a_batch_of_one_and_bad_arguments_are_refused():
    ys = _simulate(3, 1, 30)
    kf = _kf(np.eye(2), np.eye(2))
    a, ll_a = em_step(kf, ys[0])
    b, ll_b = em_step(kf, ys)
    np.testing.assert_allclose(a.Q, b.Q, rtol=1e-14)
    assert float(ll_a) == pytest.approx(float(log_likelihood(kf, ys[0])), rel=1e-12)
    # feedthrough: fitting y with D u is fitting y - D u without it
    us = np.random.default_rng(4).normal(size=(30, 1))
    Dm = np.array([[0.5], [-1.0]])
    c, ll_c = em_step(kf, ys[0] + us @ Dm.T, us, D=Dm)
    np.testing.assert_allclose(c.R, a.R, rtol=1e-12)
    np.testing.assert_allclose(c.Q, a.Q, rtol=1e-12)
    assert float(ll_c) == pytest.approx(float(ll_a), rel=1e-12)
    with pytest.raises(ArgumentError, match="update"):
        em_step(kf, ys, update=("P0",))
    with pytest.raises(ArgumentError, match="C only"):
        em_step(kf, ys, mask=np.zeros(ys.shape, bool), update=("C",))
    with pytest.raises(ArgumentTypeError, match="KalmanFilter"):
        em_step(object(), ys)


@pytest.mark.slow
def test_em_reaches_the_likelihood_fitters_optimum():
    import optax

    from jaxdip.tune.likelihood import LGSSMModel, fit_marginal_likelihood

    ys = _simulate(0, 4, 150)
    mask = np.random.default_rng(1).random(ys.shape) < 0.8
    mask[:, 10] = False
    res = fit_em(_kf(np.eye(2), np.eye(2)), ys, mask=mask, tol=1e-13, max_iter=2000)

    def build(theta):
        return LGSSMModel(Phi=PHI, C=C, Q=_chol(theta["q"]), R=_chol(theta["r"]), m0=jnp.zeros(2), P0=jnp.eye(2))

    fit = fit_marginal_likelihood(build, {"q": jnp.zeros(3), "r": jnp.zeros(3)}, ys, mask=mask,
                                  optimizer=optax.lbfgs(), tol=1e-9, max_iter=500)
    print(f"EM {res.iterations} iterations; L-BFGS fitter {fit.iterations} iterations, {fit.status}")
    assert fit.status == "converged"
    for got, ref in ((res.model.Q, _chol(fit.theta["q"])), (res.model.R, _chol(fit.theta["r"]))):
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4 * float(np.abs(ref).max()))
