"""Monte Carlo objectives over closed loops, with memory bounded on long horizons.

``checkpointed`` runs a ``jd.Rollout`` as an outer ``lax.scan`` over chunks whose body is
``jax.checkpoint``-ed: reverse mode stores one loop state per chunk and recomputes a chunk's periods while it
differentiates through it, so memory grows like n_steps / chunk + chunk instead of n_steps (chunk ~ sqrt(n_steps)
is the usual choice). Randomness is per period (keyed by the absolute period index), so the chunking changes no number.

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

from jaxdip.sim.component import Component
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


def checkpointed(rollout, key, chunk: int = 0):
    """``rollout(key)`` (a ``jd.Rollout`` without ``save``) with its periods rematerialised per ``chunk``:
    reverse mode stores one loop state per chunk and recomputes a chunk's periods while it differentiates
    through it. ``chunk <= 0`` or ``>= steps`` is one plain scan. Same numbers either way."""
    steps = rollout.steps
    if chunk <= 0 or chunk >= steps:
        return rollout(key)
    if rollout.save is not None:
        raise ValueError("checkpointed() records nothing: build the rollout without save")
    n_chunks, rest = divmod(steps, chunk)

    @jax.checkpoint
    def body(state, _):
        return rollout.advance(key, state, chunk)[0], None

    state, _ = jax.lax.scan(body, rollout.init(key), None, length=n_chunks)
    if rest:
        state = rollout.advance(key, state, rest)[0]
    return rollout.finish(state, None)


def mc_objective(make_rollout: Callable, loss_fn: Callable, seeds, chunk: int = 0) -> Objective:
    """``J(theta, key)`` = mean over ``seeds`` of ``loss_fn(solution)``, the rollout ``make_rollout(theta)``
    run for seed i with the Monte Carlo driver's key ``fold_in(key, i)`` (the seeds of ``jd.monte_carlo``),
    rematerialised per ``chunk`` periods for reverse mode (see ``checkpointed``)."""
    seeds = jnp.asarray(seeds, dtype=jnp.uint32)

    def per_seed(theta, key):
        r = make_rollout(theta)
        return jax.vmap(lambda i: loss_fn(checkpointed(r, jax.random.fold_in(key, i), chunk)))(seeds)

    return Objective(per_seed)
