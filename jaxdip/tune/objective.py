"""Monte Carlo objectives over closed loops, evaluated by ``jd.monte_carlo`` (its seed convention: seed i of a
base key ``key`` runs with ``fold_in(key, i)``), with memory bounded on long horizons.

``mc_objective`` is J(theta, key) = mean over given seeds of a loss of ``monte_carlo``'s outputs; the seeds may
be any increasing indices (``monte_carlo_at``: one ``monte_carlo`` call per contiguous run), so the tuning seeds
and a disjoint held-out set are two calls of one code path.

``checkpointed`` runs a ``jd.Rollout`` as an outer ``lax.scan`` over chunks whose body is
``jax.checkpoint``-ed: reverse mode stores one loop state per chunk and recomputes a chunk's periods while it
differentiates through it, so memory grows like n_steps / chunk + chunk instead of n_steps (chunk ~ sqrt(n_steps)
is the usual choice). Randomness is per period (keyed by the absolute period index), so the chunking changes no number.

Quantised sensors: with the exact quantiser the pathwise derivative treats every reading as locally constant
(round' = 0), which is the derivative of one sample path but misses the feedback through the encoders. A sensor
built with ``straight_through=True`` (``jd.LinearSensor``, the DIP and TWIP encoders) passes gradients straight
through its quantiser (forward: the same rounded readings; backward: d round(y)/dy := 1); with white noise of a
fraction of a count before rounding, E[round(y + noise)] is close to y, so that derivative approximates the
derivative of the *expected* loss.
"""

from __future__ import annotations

from typing import Any, Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine.driver import monte_carlo


from jaxdip._public import public_dir

__all__ = ["Objective", "seed_runs", "monte_carlo_at", "Checkpointed", "checkpointed", "mc_objective"]
__dir__ = public_dir(globals())


class Objective:
    """J(theta, key) = mean over seeds of ``per_seed(theta, key)``; ``diverged(theta, key)`` (optional) flags
    the seeds whose trajectories failed. A plain object rather than attributes stuck on a function, so what an
    objective offers is visible in its type. ``seeds`` and ``on_seeds(seeds) -> Objective`` (both or neither):
    the seed indices it averages over and the same objective over a subset of them, which lets ``tune`` split
    the seed batch over the processes of ``jax.distributed`` (``share``)."""

    def __init__(self, per_seed: Callable, diverged: Callable | None = None, *, seeds=None,
                 on_seeds: Callable | None = None):
        self.per_seed = per_seed
        self.diverged = diverged
        self.seeds = None if seeds is None else [int(s) for s in seeds]
        self.on_seeds = on_seeds

    def __call__(self, theta, key):
        return jnp.mean(self.per_seed(theta, key))

    def share(self, index: int, count: int) -> tuple[Optional["Objective"], float]:
        """Block ``index`` of ``count`` near-equal consecutive blocks of the seeds, as (objective over it, its
        fraction of the seeds): J is the sum over the blocks of fraction x block objective. ``None`` for an
        empty block (fewer seeds than blocks)."""
        if self.seeds is None or self.on_seeds is None:
            raise ValueError("this objective does not know its seeds (build it with mc_objective)")
        block = [int(s) for s in np.array_split(np.asarray(self.seeds), count)[index]]
        return (self.on_seeds(block) if block else None), len(block) / len(self.seeds)


def seed_runs(seeds) -> list[tuple[int, int]]:
    """The contiguous runs (offset, length) of a list of seed indices, in order (one ``monte_carlo`` each)."""
    out: list[list[int]] = []
    for s in (int(v) for v in seeds):
        if out and s == out[-1][0] + out[-1][1]:
            out[-1][1] += 1
        else:
            out.append([s, 1])
    if not out:
        raise ValueError("no seeds")
    return [(off, n) for off, n in out]


def monte_carlo_at(fn: Callable, key, seeds, *, then: Optional[Callable] = None, **monte_carlo_kw) -> Any:
    """``monte_carlo(fn, key, ...)`` at the given seed indices: one call per contiguous run, each call's output
    passed through ``then`` (if given), the results concatenated over the seeds in the order given."""
    parts = []
    for offset, n in seed_runs(seeds):
        out = monte_carlo(fn, key, n, offset=offset, **monte_carlo_kw)
        parts.append(out if then is None else then(out))
    return jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)


class Checkpointed(eqx.Module):
    """A ``jd.Rollout`` run as ``checkpointed(rollout, key, chunk)``: a trial ``monte_carlo`` can batch."""

    rollout: Any
    chunk: int = eqx.field(static=True)

    def __call__(self, key):
        return checkpointed(self.rollout, key, self.chunk)


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


def mc_objective(make_fn: Callable, seeds, loss: Optional[Callable] = None, *, diverged: Optional[Callable] = None,
                 chunk: int = 0, **monte_carlo_kw) -> Objective:
    """``J(theta, key)`` = mean over ``seeds`` (increasing indices) of the per-seed losses
    ``loss(monte_carlo(make_fn(theta), key, ...))`` (``loss`` maps a batch of outputs to one loss per seed;
    ``None``: the outputs are the losses), seed i running with ``fold_in(key, i)``. ``diverged`` maps a batch of
    outputs to per-seed failure flags (the objective's ``diverged``). ``chunk > 0``: ``make_fn(theta)`` is a
    ``jd.Rollout`` rematerialised per ``chunk`` periods for reverse mode (``checkpointed``). Further keywords go
    to ``monte_carlo`` (``shard``, ``index``)."""

    def fn(theta):
        f = make_fn(theta)
        return Checkpointed(f, chunk) if chunk > 0 else f

    def per_seed(theta, key):
        return monte_carlo_at(fn(theta), key, seeds, then=loss, **monte_carlo_kw)

    def flags(theta, key):
        return monte_carlo_at(fn(theta), key, seeds, then=diverged, **monte_carlo_kw)

    def on_seeds(subset):
        return mc_objective(make_fn, subset, loss, diverged=diverged, chunk=chunk, **monte_carlo_kw)

    return Objective(per_seed, flags if diverged is not None else None, seeds=seeds, on_seeds=on_seeds)
