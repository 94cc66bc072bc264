"""Monte Carlo objectives over closed loops, with memory bounded on long horizons.

``checkpointed_rollout`` runs the loop of ``jaxdip.sim.loop`` as an outer ``lax.scan`` over chunks whose body
is ``jax.checkpoint``-ed: reverse mode stores one carry per chunk and recomputes a chunk's periods while it
differentiates through it, so memory grows like n_steps / chunk + chunk instead of n_steps (chunk ~ sqrt(n_steps)
is the usual choice). Randomness is per period (``fold_in(seed_key, k)``), so the chunking changes no number.

``straight_through_sensor`` is the sensor of ``jaxdip.sim.sensors.linear_sensor`` whose quantiser passes
gradients straight through (forward: the same rounded readings; backward: d round(y)/dy := 1). With the exact
quantiser the pathwise derivative treats every reading as locally constant (round' = 0), which is the
derivative of one sample path but misses the feedback through the encoders; with white noise of a fraction of a
count before rounding, E[round(y + noise)] is close to y, so the straight-through derivative approximates the
derivative of the *expected* loss.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from jaxdip.sim import montecarlo
from jaxdip.sim.component import Component
from jaxdip.sim.loop import Loop, advance, init_carry
from jaxdip.sim.sensors import linear_sensor, quantize


class Objective:
    """J(theta, key) = mean over seeds of ``per_seed(theta, key)``; ``diverged(theta, key)`` (optional) flags
    the seeds whose trajectories failed. A plain object rather than attributes stuck on a function, so what an
    objective offers is visible in its type."""

    def __init__(self, per_seed: Callable, diverged: Callable | None = None):
        self.per_seed = per_seed
        self.diverged = diverged

    def __call__(self, theta, key):
        return jnp.mean(self.per_seed(theta, key))


def straight_through_sensor(dt: float, stationary_start: bool = True) -> Component:
    base = linear_sensor(dt, stationary_start)

    def step(params, bias, x, key, k):
        bias, y_raw = base.step(params._replace(quantum=jnp.zeros_like(params.quantum)), bias, x, key, k)
        y_q = quantize(jax.lax.stop_gradient(y_raw), params.quantum)
        return bias, y_raw + jax.lax.stop_gradient(y_q - y_raw)

    return Component(base.init, step)


def checkpointed_rollout(loop: Loop, params, x0, seed_key, n_steps: int, chunk: int = 0):
    """Final carry of one trajectory of ``n_steps`` periods (no records), rematerialised per chunk."""
    carry = init_carry(loop, params, x0, seed_key)
    if chunk <= 0 or chunk >= n_steps:
        return advance(loop, n_steps, params, seed_key, carry, n_steps)[0]
    n_chunks, rest = divmod(n_steps, chunk)

    @jax.checkpoint
    def body(c, _):
        return advance(loop, n_steps, params, seed_key, c, chunk)[0], None

    carry, _ = jax.lax.scan(body, carry, None, length=n_chunks)
    if rest:
        carry = advance(loop, n_steps, params, seed_key, carry, rest)[0]
    return carry


def mc_objective(loop: Loop, make_params: Callable, x0_fn: Callable, n_steps: int, loss_fn: Callable,
                 seeds, chunk: int = 0) -> Objective:
    """``J(theta, key)`` = mean over ``seeds`` of ``loss_fn(final_carry, params)``.

    ``make_params(theta) -> LoopParams`` puts the hyperparameters into the loop's params; seed i uses
    ``montecarlo.seed_key(key, i)`` (as ``jaxdip.sim.montecarlo.run`` does), its x0 from ``fold_in(., 0)``.
    The ``Objective``'s ``per_seed(theta, key)`` gives the vector of per-seed losses.
    """
    seeds = jnp.asarray(seeds, dtype=jnp.uint32)

    def one(params, key, i):
        sk = montecarlo.seed_key(key, i)
        x0 = x0_fn(jax.random.fold_in(sk, 0))
        carry = checkpointed_rollout(loop, params, x0, sk, n_steps, chunk)
        return loss_fn(carry, params)

    def per_seed(theta, key):
        params = make_params(theta)
        return jax.vmap(one, in_axes=(None, None, 0))(params, key, seeds)

    return Objective(per_seed)
