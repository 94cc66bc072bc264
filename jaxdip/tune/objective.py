"""Monte Carlo objectives over closed loops, with memory bounded on long horizons.

``checkpointed`` runs a ``jd.Rollout`` as an outer ``lax.scan`` over chunks whose body is
``jax.checkpoint``-ed: reverse mode stores one loop state per chunk and recomputes a chunk's periods while it
differentiates through it, so memory grows like n_steps / chunk + chunk instead of n_steps (chunk ~ sqrt(n_steps)
is the usual choice). Randomness is per period (keyed by the absolute period index), so the chunking changes no number.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp


class Objective:
    """J(theta, key) = mean over seeds of ``per_seed(theta, key)``; ``diverged(theta, key)`` (optional) flags
    the seeds whose trajectories failed. A plain object rather than attributes stuck on a function, so what an
    objective offers is visible in its type."""

    def __init__(self, per_seed: Callable, diverged: Callable | None = None):
        self.per_seed = per_seed
        self.diverged = diverged

    def __call__(self, theta, key):
        return jnp.mean(self.per_seed(theta, key))


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
