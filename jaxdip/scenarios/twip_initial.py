"""Initial states of the TWIP studies (Stumfoll (179), (184)) and their spread over Monte Carlo seeds."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import param
from jaxdip.sim.twip_sensors import DEG


def thesis_x0(x0=(1.0, 0.3, 10.0, 1.0)) -> jax.Array:
    """(179) = (184): [x, x_dot, phi, phi_dot] given in [m, m/s, deg, deg/s], returned in SI units."""
    return jnp.asarray(x0, dtype=jnp.float64) * jnp.asarray([1.0, 1.0, DEG, DEG])


class Spread(eqx.Module):
    """Initial-state sampler: x0 * (1 + U(-spread, spread)) per component (spread 0: x0 exactly).

    The studies start seed 0 at x0 itself (``exact_first``)."""

    x0: jax.Array = param()
    spread: jax.Array = param(0.0)

    def __call__(self, key):
        return self.x0 * (1.0 + self.spread * jax.random.uniform(key, self.x0.shape, minval=-1.0, maxval=1.0))


def exact_first(rollout, key, i):
    """``rollout`` with its initial state fixed for seed i: the sampler's x0 itself for seed 0, its draw from
    ``fold_in(key, 0)`` for the others (the studies start seed 0 at the nominal state). For trials called as
    ``fn(key, i)`` by ``jd.monte_carlo(..., index=True)``, so seed 0 and the rest share one program."""
    x = jnp.where(i == 0, rollout.x0.x0, rollout.initial_state(key))
    return eqx.tree_at(lambda r: r.x0, rollout, x)
