"""Maximum marginal likelihood recovers the noise scale factors and the damping used to simulate the data."""

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.tune import Log
from jaxdip.tune.likelihood import LGSSMModel, fit_marginal_likelihood, total_log_likelihood

H_STEP = 0.1
Q0 = np.diag([0.01, 0.04])
R0 = np.array([[0.1]])
C = np.array([[1.0, 0.0]])
TRUE = {"q": 1.5, "r": 0.7, "c": 0.3}


def _A(c):
    return jnp.array([[0.0, 1.0], [-1.0, -c]])


def build(theta) -> LGSSMModel:
    Phi = jsl.expm(_A(theta["c"]) * H_STEP)  # the damping enters through the exact discretisation
    return LGSSMModel(Phi=Phi, C=C, Q=theta["q"] * Q0, R=theta["r"] * R0, m0=jnp.zeros(2), P0=jnp.eye(2))


def simulate(seed, B, T):
    rng = np.random.default_rng(seed)
    Phi = scipy.linalg.expm(np.array([[0.0, 1.0], [-1.0, -TRUE["c"]]]) * H_STEP)
    Lq = np.linalg.cholesky(TRUE["q"] * Q0)
    x = rng.normal(size=(B, 2))
    ys = np.empty((B, T, 1))
    for k in range(T):
        ys[:, k] = x @ C.T + np.sqrt(TRUE["r"] * R0[0, 0]) * rng.normal(size=(B, 1))
        x = x @ Phi.T + rng.normal(size=(B, 2)) @ Lq.T
    return ys


SPEC = {"q": Log(), "r": Log(), "c": Log()}
START = {"q": 0.5, "r": 2.0, "c": 0.8}


def _fit(ys, max_iter, **kw):
    return fit_marginal_likelihood(build, START, ys, spec=SPEC, max_iter=max_iter, lr=0.05, **kw)


def _check_recovered(fit):
    for k, v in TRUE.items():
        est, se = float(fit.theta[k]), float(fit.stderr[k])
        assert se < 0.35 * v, (k, se)  # the data pin the parameter down: the check below has power
        assert abs(est - v) < 4.0 * se, (k, est, v, se)


def test_fit_recovers_scales_and_damping_small():
    ys = simulate(0, 32, 100)
    fit = _fit(ys, 400, tol=1e-6)
    assert fit.status == "converged" and fit.iterations < 400
    assert fit.grad_norm_history[-1] <= 1e-6 < fit.grad_norm_history[-2]  # the stated rule, at the first iterate
    _check_recovered(fit)
    # an independent optimiser (scipy L-BFGS on the same log-likelihood, its own start) finds the same maximum
    ys_j = jnp.asarray(ys)

    @jax.jit
    def nll(v):
        theta = {"q": jnp.exp(v[0]), "r": jnp.exp(v[1]), "c": jnp.exp(v[2])}
        return -total_log_likelihood(build(theta), ys_j)

    vg = jax.jit(jax.value_and_grad(nll))
    res = scipy.optimize.minimize(lambda v: tuple(np.asarray(a) for a in vg(v)), np.log([1.0, 1.0, 0.5]),
                                  jac=True, method="L-BFGS-B", options={"gtol": 1e-8})
    for i, k in enumerate(("q", "r", "c")):
        assert abs(float(fit.theta[k]) - np.exp(res.x[i])) < 0.02 * float(fit.stderr[k]), k
    assert abs(float(fit.log_likelihood) + res.fun) < 1e-6 * abs(res.fun)


@pytest.mark.slow
def test_fit_recovers_scales_and_damping_256_sequences():
    # the scale: 256 sequences; the curvature error is checked against the spread over seed sets
    fits = [_fit(simulate(seed, 256, 200), 600, tol=1e-6) for seed in (1, 2, 3, 4)]
    for fit in fits:
        print({k: f"{float(fit.theta[k]):.4f} +- {float(fit.stderr[k]):.4f}" for k in TRUE})
        _check_recovered(fit)
    for k in TRUE:
        spread = np.std([float(f.theta[k]) for f in fits], ddof=1)
        se = np.mean([float(f.stderr[k]) for f in fits])
        print(f"{k}: true {TRUE[k]}, spread over seed sets {spread:.4f}, curvature error {se:.4f}")
        # with 4 sets the sample std is within a factor ~3 of the true one with high probability
        assert se / 3.5 < spread < 3.5 * se, (k, spread, se)


def test_fit_stops_on_max_iterations_and_on_a_non_finite_loss():
    ys = simulate(5, 4, 30)
    ys[0, 3, 0] = np.nan  # declared missing (nan_missing), it is removed and the fit runs
    fit = _fit(ys, 3, tol=1e-12, nan_missing=True)
    assert fit.status == "max_iterations" and fit.iterations == 3 and len(fit.loss_history) == 4
    ll = total_log_likelihood(build(fit.theta), jnp.asarray(ys), nan_missing=True)
    assert float(ll) == pytest.approx(-fit.loss_history.min() * ys.shape[0] * ys.shape[1], rel=1e-12)
    # undeclared, the NaN poisons the likelihood: the fit stops at once
    bad = _fit(ys, 5)
    assert bad.status == "not_finite" and bad.iterations == 0


def test_fit_refuses_bad_arguments():
    from jaxdip.engine.checks import ArgumentError

    ys = simulate(5, 2, 10)
    with pytest.raises(ArgumentError, match="max_iter"):
        _fit(ys, 0)
    with pytest.raises(ArgumentError, match="ys must be"):
        _fit(ys[0], 5)


@pytest.mark.slow
def test_lbfgs_reaches_adams_optimum_in_fewer_steps():
    import optax

    ys = simulate(0, 32, 100)
    adam = _fit(ys, 1000, tol=1e-6)
    lbfgs = _fit(ys, 1000, tol=1e-6, optimizer=optax.lbfgs())
    print(f"iterations to ||grad|| <= 1e-6: L-BFGS {lbfgs.iterations}, Adam {adam.iterations}")
    assert adam.status == lbfgs.status == "converged"
    assert lbfgs.iterations < adam.iterations
    for k in TRUE:
        assert abs(float(lbfgs.theta[k]) - float(adam.theta[k])) < 0.01 * float(adam.stderr[k]), k
    assert abs(float(lbfgs.log_likelihood - adam.log_likelihood)) < 1e-9 * abs(float(adam.log_likelihood))
