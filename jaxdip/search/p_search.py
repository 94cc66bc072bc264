"""Procedure 1 (thesis §2.6.4): performance maps for the ensemble Kalman search over P.

* discrete systems: the projection control (2.9) with P = P_v (2.19) is simulated for K steps from x_0 and
  scored by (2.23): y_1 = ||x_K||^2 and y_2 = <f(x_K) - x_K, x_K>_P / (||f(x_K) - x_K||_P ||x_K||_P);
* continuous systems: the relaxed projection control (2.14) with P = P_{V,s} (2.20) is simulated over [0, T]
  and scored by (2.24): y = 1/(T - t*) int_{t*}^T x^T Q x dt, with the thesis's failure rule (a state norm
  above ``fail_norm`` ends the simulation with performance ``penalty``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.control.projection import projection, relaxed_continuous, drift_and_input
from jaxdip.control.spd import P_v, P_Vs, orthonormalize
from jaxdip.sim.integrate import rk4_zoh


def discrete_performance(plant, plant_params, s: float, K: int, x0_std: float = 1.0,
                         fail_norm: float = 10.0, penalty: float = 1000.0, n_x0: int = 1):
    """G(v, key) of (2.23) for a discrete plant under the projection control with P_v(v, s).

    The thesis's failure rule applies here too: a state norm above ``fail_norm`` scores y = (penalty, 1)
    (the worst angle). Without it, members just across the stability boundary score 1e17 and their
    covariances swamp the ensemble update, which then stalls on the unstable side. With ``n_x0 > 1`` the
    measures are averaged over that many initial states (the thesis used one).
    """
    step = plant.step
    m = plant.m

    def one(P, key):
        x0 = x0_std * jax.random.normal(key, (plant.n,))

        def body(c, _):
            x, failed = c
            fx, gx = drift_and_input(step, plant_params, x, m)
            u = projection(P, fx, gx)
            xn = fx + gx @ u
            failed = failed | ~jnp.all(jnp.isfinite(xn)) | (jnp.linalg.norm(xn) > fail_norm)
            return (jnp.where(failed, x, xn), failed), None

        (xK, failed), _ = jax.lax.scan(body, (x0, False), None, length=K)
        fK = step(plant_params, xK, jnp.zeros(m))
        d = fK - xK
        pn = lambda z: jnp.sqrt(z @ P @ z)
        y1 = xK @ xK
        y2 = (d @ P @ xK) / (pn(d) * pn(xK))
        return jnp.where(failed, jnp.array([penalty, 1.0]), jnp.stack([y1, y2]))

    def G(v, key):
        P = P_v(v, s)
        if n_x0 == 1:
            return one(P, key)
        return jax.vmap(lambda k: one(P, k))(jax.random.split(key, n_x0)).mean(axis=0)

    return G


class BasisMember(NamedTuple):
    V: jnp.ndarray  # (N, d): the N free basis vectors as rows (contiguous in the flat member)
    log_s: jnp.ndarray  # (N,) log singular values (keeps them positive under the additive EKI update)


def project_member(m: BasisMember) -> BasisMember:
    """Procedure 1 step 8: re-orthonormalise the basis after each update."""
    return BasisMember(orthonormalize(m.V.T).T, m.log_s)


def member_P(m: BasisMember):
    return P_Vs(m.V.T, jnp.exp(m.log_s))


def member_blocks(N: int, d: int):
    """(start, stop) of each basis vector in the flat member, for ``align_signs``."""
    return [(i * d, (i + 1) * d) for i in range(N)]


class ContinuousSearch(NamedTuple):
    dt: float
    n_steps: int
    t_star_steps: int
    gamma: float
    Qpos: jnp.ndarray  # (n, n) weight of (2.24)
    noise_std: float  # state noise added every period
    x0_std: jnp.ndarray  # (n,) std of the random initial state
    fail_norm: float = 10.0
    penalty: float = 1000.0
    substeps: int = 2


def continuous_performance(plant, plant_params, cfg: ContinuousSearch, n_x0: int = 1, penalize: bool = True):
    """G(member, key) of (2.24) for a continuous plant under (2.14) with P = P_{V,s}, averaged over n_x0
    initial states (the thesis used one). ``penalize=False`` returns the integral up to the failure instead of
    the penalty (a smooth objective for gradients)."""
    m = plant.m

    def one(P, key):
        k0, kn = jax.random.split(key)
        x0 = cfg.x0_std * jax.random.normal(k0, (plant.n,))

        def body(c, k):
            x, acc, failed = c
            fx, gx = drift_and_input(plant.f, plant_params, x, m)
            u = relaxed_continuous(P, fx, gx, x, cfg.gamma)
            xn = rk4_zoh(plant.f, plant_params, x, u, cfg.dt, cfg.substeps)
            xn = xn + cfg.noise_std * jax.random.normal(jax.random.fold_in(kn, k), xn.shape)
            bad = ~jnp.all(jnp.isfinite(xn)) | (jnp.linalg.norm(xn) > cfg.fail_norm)
            failed = failed | bad
            xn = jnp.where(failed, x, xn)
            w = (k >= cfg.t_star_steps) & ~failed
            acc = acc + jnp.where(w, xn @ cfg.Qpos @ xn, 0.0)
            return (xn, acc, failed), None

        (xT, acc, failed), _ = jax.lax.scan(body, (x0, 0.0, False), jnp.arange(cfg.n_steps))
        y = acc / (cfg.n_steps - cfg.t_star_steps)
        return jnp.where(failed & penalize, cfg.penalty, y)

    def G(member: BasisMember, key):
        P = member_P(member)
        ys = jax.vmap(lambda k: one(P, k))(jax.random.split(key, n_x0))
        return jnp.atleast_1d(ys.mean())

    return G
