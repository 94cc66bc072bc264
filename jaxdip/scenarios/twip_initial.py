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

    The studies start seed 0 at x0 itself: run seed 0 with ``spread = 0`` and the others with the spread
    (``jaxdip.scenarios.twip_extra.run_seeds``), which draws from the same keys as one call would."""

    x0: jax.Array = param()
    spread: jax.Array = param(0.0)

    def __call__(self, key):
        return self.x0 * (1.0 + self.spread * jax.random.uniform(key, self.x0.shape, minval=-1.0, maxval=1.0))


def run_seeds(first, rest, key, n: int, *, sweep=None, **mc):
    """Seeds 0 .. n-1 of a study whose seed 0 starts at x0 exactly: seed 0 by ``first`` (the trial with a zero
    spread, and possibly a richer ``save`` for the figures), seeds 1 .. n-1 by ``rest``, each through
    ``jd.monte_carlo`` with the same base key (so with the keys one call would give). Returns ``(head, tail)``:
    the two outputs, seed axis of length 1 and n - 1 (``tail`` is None for n = 1). ``mc``: further
    ``monte_carlo`` arguments for ``rest`` (chunk, progress, desc)."""
    from jaxdip.engine.driver import monte_carlo

    head = monte_carlo(first, key, 1, sweep=sweep)
    tail = monte_carlo(rest, key, n - 1, offset=1, sweep=sweep, **mc) if n > 1 else None
    return head, tail


def seed_runs(seeds) -> list[list[int]]:
    """The contiguous runs [offset, length] of an increasing list of seed indices (one ``monte_carlo`` each)."""
    out: list[list[int]] = []
    for s in (int(v) for v in seeds):
        if out and s == out[-1][0] + out[-1][1]:
            out[-1][1] += 1
        else:
            out.append([s, 1])
    return out
