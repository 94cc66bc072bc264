"""E[I] as a differentiable function of the protection threshold, and its tuning with optax.

Two differentiable routes to E[I](r) = R0 - F(r) for the level set L_r of a cost:
- quadrature: F(r) by Simpson's rule in s; the shells' boundaries carry implicit tangents
  (``levelset``), so ``jax.grad`` gives dF/dr exactly for the discretised F;
- Monte Carlo, Rao–Blackwellised: given that a virion enters a cell at time T ~ Exp(gamma + delta) (the
  process (A4)–(A5) conditioned on entering first), its probability of infecting is 1 - m(T; r), m the heat
  kernel's mass in A(T) (the position (A6) integrated out in closed form); E[I] = R0 E[1 - m(T; r)], an unbiased
  estimator that, unlike the indicator of the plain Monte Carlo, is smooth in r, so its pathwise gradient is an
  unbiased estimator of dE[I]/dr.
``tune_threshold`` drives log r with optax Adam to E[I] = target; with Monte Carlo it uses two independent
batches per step (value and gradient), so the gradient of (E[I] - target)^2 is unbiased, and reports the mean
of the last half of the iterates.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxdip.engine.driver import monte_carlo
from jaxdip import program_cache
from jaxdip.immune import quadrature as Q
from jaxdip.immune.controls import LevelSet
from jaxdip.immune.model import Infection


def expected_progeny_quadrature(model: Infection, cost, log_r, n: int = 4096):
    """E[I] = R0 - F(r) under L_r, by quadrature (differentiable in log_r)."""
    return model.R0 - Q.F(model, cost, log_r, n).g


class EnteringVirion(eqx.Module):
    """One Rao–Blackwellised sample: 1 - m(T), T ~ Exp(gamma + delta) the entry time of an entering virion and
    m(T) the heat kernel's mass in A(T) (P(infects | T), the position integrated out). A pure function of a key,
    so ``jd.monte_carlo`` runs it with the library's seed convention; smooth in every leaf of ``control``."""

    model: Infection
    control: LevelSet

    def __call__(self, key):
        t = jax.random.exponential(key) / self.model.k
        return 1.0 - self.control.profile(self.model, jnp.maximum(t, Q.T_MIN), self.control.cost)[0]


def _progeny_mc(model, cost, log_r, key, n):
    draws = monte_carlo(EnteringVirion(model, LevelSet(cost=cost, log_r=log_r)), key, n)
    return model.R0 * jnp.mean(draws)


def expected_progeny_mc(model: Infection, cost, log_r, key, n: int):
    """Rao–Blackwellised Monte Carlo estimate of E[I] under L_r from n entering virions (differentiable; virion
    i from ``fold_in(key, i)``)."""
    return _progeny_mc(model, cost, log_r, key, n)


# value and derivative in log r, compiled once each and shared by the gradient checks and the optimiser
@program_cache.jit
def _quad_vg(model, cost, log_r, n):
    return jax.value_and_grad(expected_progeny_quadrature, argnums=2)(model, cost, log_r, n)


@program_cache.jit
def _mc_vg(model, cost, log_r, key, n):
    return jax.value_and_grad(_progeny_mc, argnums=2)(model, cost, log_r, key, n)


def progeny_and_slope(model: Infection, cost, log_r, *, method: str = "quadrature", key=None, n: int = 4096):
    """(E[I], dE[I]/dlog r) at r = exp(log_r): by quadrature with n panels, or by the Rao–Blackwellised Monte
    Carlo with n entering virions drawn from ``key``."""
    x = jnp.asarray(log_r, jnp.float64)
    if method == "quadrature":
        return _quad_vg(model, cost, x, n)
    if method == "mc":
        return _mc_vg(model, cost, x, key, n)
    raise ValueError(f"method must be 'quadrature' or 'mc', got {method!r}")


class TuneResult(NamedTuple):
    log_r: float  # the answer (last iterate for quadrature; mean of the last half for Monte Carlo)
    trace_log_r: np.ndarray
    trace_value: np.ndarray


def tune_threshold(model: Infection, cost, target: float, log_r0: float, *, steps: int = 200, lr: float = 0.05,
                   method: str = "quadrature", key=None, batch: int = 8192, n_quad: int = 2048) -> TuneResult:
    """Adam on log r for (E[I](r) - target)^2 (learning rate decaying x0.01 over the run, b1 = 0.5)."""
    if method not in ("quadrature", "mc"):
        raise ValueError(f"method must be 'quadrature' or 'mc', got {method!r}")
    key = jax.random.PRNGKey(0) if key is None else key
    # b1 = 0.5: less momentum than the default 0.9, which overshoots this one-dimensional valley
    opt = optax.adam(optax.exponential_decay(lr, transition_steps=steps, decay_rate=1e-2), b1=0.5)

    @jax.jit
    def update(x, state, grad):
        upd, state = opt.update(grad, state, x)
        return optax.apply_updates(x, upd), state

    x = jnp.asarray(log_r0, dtype=jnp.float64)
    state = opt.init(x)
    xs, es = [], []
    for i in range(steps):
        if method == "quadrature":
            e, de = progeny_and_slope(model, cost, x, n=n_quad)
        else:
            k1, k2 = jax.random.split(jax.random.fold_in(key, i))
            e, _ = progeny_and_slope(model, cost, x, method="mc", key=k1, n=batch)
            _, de = progeny_and_slope(model, cost, x, method="mc", key=k2, n=batch)
        x, state = update(x, state, 2.0 * (e - target) * de)
        xs.append(float(x))
        es.append(float(e))
    xs = np.asarray(xs)
    answer = float(xs[-1]) if method == "quadrature" else float(np.mean(xs[steps // 2:]))
    return TuneResult(answer, xs, np.asarray(es))
