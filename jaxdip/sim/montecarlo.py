"""Monte Carlo over noise seeds: ``vmap`` over seeds, chunked over time, optionally sharded over devices.

Seed i's key is ``fold_in(base_key, i)``: the same trajectory whether it runs alone, in a batch of 4096, or
on any number of devices. Its initial state is drawn from ``fold_in(seed_key, 0)`` and the loop's noise from
other folds of the same key (see ``jaxdip.sim.loop``).
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.progress import Progress
from jaxdip.sim.loop import Carry, Loop, LoopParams, advance, init_carry


class MCResult(NamedTuple):
    seeds: np.ndarray
    carry: Carry  # final carry, batched over seeds (stats, diverged flags, final states)
    records: Optional[object]  # recorded pytree with leading axes (seed, time), or None
    x0: jnp.ndarray


def seed_key(base_key, i):
    return jax.random.fold_in(base_key, i)


def _init(loop, x0_fn, params, base_key, i):
    sk = seed_key(base_key, i)
    x0 = x0_fn(jax.random.fold_in(sk, 0))
    return init_carry(loop, params, x0, sk), x0


def _advance(loop, n_steps, n, record_every, record_fn, params, base_key, i, carry):
    return advance(loop, n_steps, params, seed_key(base_key, i), carry, n, record_every, record_fn)


def _chunks(n_steps: int, chunk: int, record_every: int):
    if record_every > 0 and n_steps % record_every:
        raise ValueError(f"n_steps={n_steps} is not a multiple of record_every={record_every}")
    if record_every > 0:
        chunk = max(record_every, (chunk // record_every) * record_every)
    sizes = [chunk] * (n_steps // chunk)
    if n_steps % chunk:
        sizes.append(n_steps % chunk)
    return sizes


def device_mesh():
    from jax.sharding import Mesh

    return Mesh(np.array(jax.devices()), ("seeds",))


def run(
    loop: Loop,
    params: LoopParams,
    x0_fn: Callable,
    base_key,
    n_seeds: int,
    n_steps: int,
    *,
    record_every: int = 0,
    record_fn: Optional[Callable] = None,
    chunk_steps: Optional[int] = None,
    seed_offset: int = 0,
    shard: bool = False,
    progress: bool = True,
    desc: str = "simulate",
) -> MCResult:
    """Simulate seeds ``seed_offset .. seed_offset + n_seeds - 1`` of a closed loop for ``n_steps`` periods."""
    if n_seeds < 1:
        raise ValueError(f"n_seeds must be >= 1, got {n_seeds}")
    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    seeds = np.arange(seed_offset, seed_offset + n_seeds, dtype=np.int64)
    n_dev = jax.device_count() if shard else 1
    pad = (-n_seeds) % n_dev
    seeds_padded = np.concatenate([seeds, np.repeat(seeds[-1:], pad)]) if pad else seeds
    seeds_arr = jnp.asarray(seeds_padded, dtype=jnp.uint32)
    if shard and n_dev > 1:
        from jax.sharding import NamedSharding, PartitionSpec

        seeds_arr = jax.device_put(seeds_arr, NamedSharding(device_mesh(), PartitionSpec("seeds")))

    init_b = jax.jit(jax.vmap(partial(_init, loop, x0_fn), in_axes=(None, None, 0)))
    carry, x0 = init_b(params, base_key, seeds_arr)

    chunk = chunk_steps or max(1, n_steps // 20)
    sizes = _chunks(n_steps, chunk, record_every)
    compiled = {}
    recs = []
    bar = Progress(n_steps, desc=desc, enabled=progress)
    for n in sizes:
        if n not in compiled:
            fn = partial(_advance, loop, n_steps, n, record_every, record_fn)
            compiled[n] = jax.jit(jax.vmap(fn, in_axes=(None, None, 0, 0)))
        carry, rec = compiled[n](params, base_key, seeds_arr, carry)
        if rec is not None:
            recs.append(rec)
        jax.block_until_ready(carry)  # dispatch is asynchronous: wait so the bar tells the truth
        bar.update(n)
    bar.close()

    records = None
    if recs:
        records = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a, axis=1), *recs)
    if pad:
        carry, x0 = jax.tree_util.tree_map(lambda a: a[:n_seeds], (carry, x0))
        if records is not None:
            records = jax.tree_util.tree_map(lambda a: a[:n_seeds], records)
    return MCResult(seeds=seeds, carry=carry, records=records, x0=x0)
