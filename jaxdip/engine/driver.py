"""``monte_carlo``: the one host-side driver. Seeds, chunks, padding, sharding, sweeps and progress live here.

Seed convention: seed i of a run with base key ``key`` gets ``fold_in(key, i)``, so a seed gives the same
numbers alone, in any batch, in any chunking over seeds or time, and on any number of devices. A ``Rollout``
(a loop, an initial-state law, a horizon, what to save, which metrics) draws its initial state from
``fold_in(seed_key, 0)`` when ``x0`` is a sampler, and hands ``seed_key`` to ``simulate``.

Compilation: every batch runs through one module-level ``eqx.filter_jit`` function. Array leaves of ``fn``
(every hyperparameter) are traced arguments and everything else (the static fields, the functions) is the
cache key, so a second call with new numbers but the same structure reuses the compiled program, and a sweep
over a hyperparameter is one program with the swept leaf batched. With the program cache on (the CLI's,
``jaxdip.program_cache``) a batch, on one device or sharded over this process's devices, is served from the
traced program stored for its key, so a warm process skips the trace too.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import program_cache
from jaxdip.engine import checks
from jaxdip.engine import metrics as _metrics
from jaxdip.engine.roles import param
from jaxdip.engine.simulate import Loop, Solution, State, _check_x0, init_state, simulate
from jaxdip.progress import Progress

from jaxdip._public import public_dir

__all__ = ["AUTO_SHARD_MIN_SEEDS", "Ball", "Gaussian", "Rollout", "device_mesh", "monte_carlo"]
__dir__ = public_dir(globals())

# Sharding a batch over the host devices pays once it amortises the partitioned program's extra compile
# (measured on dip-lqr: 2.5x faster at 4096 seeds on 2 cores); below this many seeds ``shard=None`` does not.
AUTO_SHARD_MIN_SEEDS = 512


class Ball(eqx.Module):
    """Initial states uniform in the Euclidean ball of ``radius`` around ``center`` (radius 0: the center)."""

    center: jax.Array = param()
    radius: jax.Array = param(0.0)

    def __check_init__(self):
        checks.check_ndim(self, "center", self.center, (1,), "a vector (one entry per state)")
        checks.check_finite(self, "center", self.center)
        checks.check_ndim(self, "radius", self.radius, (0,), "a scalar")
        checks.check_nonnegative(self, "radius", self.radius)

    def __call__(self, key):
        n = self.center.shape[0]
        k1, k2 = jax.random.split(key)
        d = jax.random.normal(k1, (n,))
        d = d / jnp.linalg.norm(d)
        r = self.radius * jax.random.uniform(k2) ** (1.0 / n)
        return self.center + r * d


class Gaussian(eqx.Module):
    """Initial states ``mean + std * N(0, I)`` (``std`` scalar or per state)."""

    mean: jax.Array = param()
    std: jax.Array = param(0.0)

    def __check_init__(self):
        checks.check_ndim(self, "mean", self.mean, (1,), "a vector (one entry per state)")
        checks.check_finite(self, "mean", self.mean)
        if checks.shape_of(self.std) not in ((), checks.shape_of(self.mean)):
            checks.fail(self, f"std must be a scalar or {checks.fmt_shape(checks.shape_of(self.mean))} like mean, "
                        f"got {checks.fmt_shape(checks.shape_of(self.std))}")
        checks.check_nonnegative(self, "std", self.std)

    def __call__(self, key):
        return self.mean + self.std * jax.random.normal(key, self.mean.shape)


class Rollout(eqx.Module):
    """One Monte Carlo trial of a closed loop, as a pure function of the trial's key: ``rollout(key)``.

    ``x0`` is an initial state (array) or a sampler ``x0(key)`` (``Ball``, or any function/Module), which
    gets ``fold_in(key, 0)``. ``monte_carlo`` recognises a Rollout and can then also chunk it over time.
    """

    loop: Loop
    x0: Any
    steps: int = eqx.field(static=True)
    save: Optional[Callable] = eqx.field(default=None, static=True)
    save_every: int = eqx.field(default=1, static=True)
    metrics: Any = None

    def __check_init__(self):
        if not isinstance(self.loop, Loop):
            raise checks.ArgumentTypeError(f"Rollout: loop must be a jaxdip Loop, got {type(self.loop).__name__}")
        checks.check_int(self, "steps", self.steps, 1)
        checks.check_int(self, "save_every", self.save_every, 1)
        if self.save is not None and self.steps % self.save_every:
            checks.fail(self, f"steps must be a multiple of save_every={self.save_every}, got {self.steps}")
        if self.save is not None and not callable(self.save):
            raise checks.ArgumentTypeError(f"Rollout: save must be a function of a Sample, got {self.save!r}")
        if not callable(self.x0):
            _check_x0("Rollout", self.loop, self.x0)
        elif isinstance(self.x0, (Ball, Gaussian)):
            size = self.x0.center.shape[0] if isinstance(self.x0, Ball) else self.x0.mean.shape[0]
            n = self.loop.plant.n
            if size != n:
                checks.fail(self, f"x0 must draw ({n},) states for the plant {type(self.loop.plant).__name__}, "
                            f"got a {type(self.x0).__name__} of ({size},)")

    def initial_state(self, key) -> jax.Array:
        if callable(self.x0):
            return self.x0(jax.random.fold_in(key, 0))
        return jnp.asarray(self.x0, dtype=jnp.result_type(float))

    def __call__(self, key) -> Solution:
        return simulate(self.loop, self.initial_state(key), key, self.steps, save=self.save,
                        save_every=self.save_every, metrics=self.metrics)

    # the resumable form, for runs chunked over time
    def init(self, key) -> State:
        return init_state(self.loop, self.initial_state(key), key, self.metrics)

    def advance(self, key, state: State, n: int):
        sol = simulate(self.loop, None, key, n, save=self.save, save_every=self.save_every,
                       metrics=self.metrics, start=state)
        return sol.final, sol.saved

    def finish(self, state: State, saved) -> Solution:
        return Solution(state, saved, _metrics.finalize(self.metrics, state.metrics), state.result)


# ---- the compiled batch ----------------------------------------------------------------------------------------


def _m_call(f, key, _, n):
    return f(key)


def _m_call_indexed(f, key, i, n):
    return f(key, i)


def _m_init(f, key, _, n):
    return f.init(key)


def _m_advance(f, key, state, n):
    return f.advance(key, state, n)


def _m_finalize(f, key, state, n):
    return _metrics.finalize(f.metrics, state.metrics)


def _call_batch(method, fn, where, values, base, idx, args, n, detail=None, out_sharding=None):
    """``_batch``, or with the program cache on (the CLI's), the program stored for the call's key, on one
    device or sharded over this process's devices: a warm process then skips tracing and lowering too. The
    compiled code and the results are the same."""
    out = program_cache.call(_batch_body, (method, fn, where, values, base, idx, args, n, detail, out_sharding),
                             "_batch")
    if out is not program_cache.MISS:
        return out
    return _batch(method, fn, where, values, base, idx, args, n, detail, out_sharding)


@eqx.filter_jit
def _batch(method, fn, where, values, base, idx, args, n, detail=None, out_sharding=None):
    return _batch_body(method, fn, where, values, base, idx, args, n, detail, out_sharding)


def _batch_body(method, fn, where, values, base, idx, args, n, detail=None, out_sharding=None):
    """vmap of ``method(fn, fold_in(base, i), arg_i, n)`` over the seed indices ``idx`` (and over the sweep).
    ``detail``: split each seed's output into (per seed, detail) and keep the detail of the batch's first seed.
    ``out_sharding``: lay every output out so (a sharding, static)."""

    def seeds(f, a):
        if method is _m_call_indexed:
            a = idx
        out = jax.vmap(lambda i, ai: method(f, jax.random.fold_in(base, i), ai, n))(idx, a)
        if detail is None:
            return out
        per, det = jax.vmap(detail)(out)
        return per, jax.tree_util.tree_map(lambda v: v[0], det)

    if where is None:
        out = seeds(fn, args)
    else:
        out = jax.vmap(lambda v, a: seeds(eqx.tree_at(where, fn, v), a))(values, args)
    return out if out_sharding is None else jax.lax.with_sharding_constraint(out, out_sharding)


# ---- the driver ------------------------------------------------------------------------------------------------


def _float_leaves_to_arrays(tree):
    # a Python float in a user's Module is a hyperparameter: trace it rather than bake it into the program
    return jax.tree_util.tree_map(
        lambda a: jnp.asarray(a) if isinstance(a, float) else a, tree)


def _concat(parts, axis):
    if parts[0] is None:
        return None
    if len(parts) == 1:
        return parts[0]
    return jax.tree_util.tree_map(lambda *a: jnp.concatenate(a, axis=axis), *parts)


@functools.lru_cache(maxsize=None)
def _replicate(sharding):
    # one identity program per mesh, its outputs whole on every device: XLA gathers the shards
    return jax.jit(lambda leaves: leaves, out_shardings=sharding)


def _gather(tree, devices):
    """Every leaf that spans several processes, as a whole array on this process, in one gathering program
    (a collective: all processes call it in the same order); other leaves as they are. The copy is exact."""
    from jax.sharding import NamedSharding, PartitionSpec

    leaves, treedef = jax.tree_util.tree_flatten(tree)
    spread = [i for i, a in enumerate(leaves) if isinstance(a, jax.Array) and not a.is_fully_addressable]
    if spread:
        whole = _replicate(NamedSharding(device_mesh(devices), PartitionSpec()))([leaves[i] for i in spread])
        for i, a in zip(spread, whole):
            leaves[i] = jnp.asarray(np.asarray(a.addressable_data(0)))
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _global_indices(seeds: np.ndarray, devices):
    """The seed indices as one array over ``devices`` of all processes, sharded on its axis; each process
    supplies the shards of its own devices (every process knows every index)."""
    from jax.sharding import NamedSharding, PartitionSpec

    seeds = seeds.astype(np.uint32)
    sharding = NamedSharding(device_mesh(devices), PartitionSpec("seeds"))
    return jax.make_array_from_callback(seeds.shape, sharding, lambda i: seeds[i])


def _progress_chunk(steps: int, every: int) -> int:
    """About a twentieth of the horizon, a multiple of ``every`` that divides it where one is near: a shorter
    last chunk would be another program to compile."""
    units = max(1, steps // every)
    target = max(1, units // 20)
    near = [d for d in range(max(1, target // 2), min(units, 2 * target) + 1) if units % d == 0]
    return (min(near, key=lambda d: abs(d - target)) if near else target) * every


def device_mesh(devices=None):
    from jax.sharding import Mesh

    return Mesh(np.array(devices if devices is not None else jax.devices()), ("seeds",))


def monte_carlo(fn: Callable, key, n: int, *, offset: int = 0, chunk: Optional[int] = None,
                time_chunk: Optional[int] = None, shard: Optional[bool] = None, progress: bool = False,
                desc: str = "monte carlo", sweep: Optional[tuple[Callable, Any]] = None, index: bool = False,
                detail: Optional[Callable] = None):
    """Evaluate ``fn(fold_in(key, i))`` for seeds i = offset .. offset + n - 1; outputs stacked on axis 0.

    fn: any pure function of a PRNG key (a function, an ``equinox.Module``, a ``Rollout``). Its array leaves
        are traced (new values reuse the compiled program) and may be swept.
    key: base PRNG key, or an int seed for ``jax.random.PRNGKey``.
    chunk: seeds per compiled call (the last call is padded with repeats of its last seed, dropped after);
        ``None``: all seeds in one call.
    time_chunk: for a ``Rollout``, periods per call (rounded to a multiple of ``save_every``); the progress bar
        advances between calls. ``None``: the whole horizon at once, or about 20 calls with ``progress``.
    shard: split each call's seeds over all devices (``None``: when there is more than one device and at
        least ``AUTO_SHARD_MIN_SEEDS`` seeds, and always with ``jax.distributed``, whose devices are those
        of every process; the result is then gathered to every process). Results do not depend on it.
    sweep: ``(where, values)``: run every seed for each entry of ``values`` (leading axis) put into
        ``fn`` at ``where(fn)`` (``eqx.tree_at``), in one program. Outputs get a leading sweep axis before
        the seed axis.
    index: call ``fn(key, i)`` with the seed index i as well (a study that starts seed 0 at a nominal state
        and the others at random ones runs them in one program).
    detail: ``detail(out) -> (per_seed, extra)`` on one seed's output; the result is then
        ``(per_seed stacked over the seeds, extra of the run's first seed only)``, both from the same compiled
        program: a whole trajectory for a figure without keeping every seed's. (With a ``Rollout`` the
        horizon then runs in one call.)

    Returns JAX arrays (no host conversion), so ``jax.grad`` of a function of the result works when the
    hyperparameters are traced; progress is then off.
    """
    checks.check_int("monte_carlo", "n", n, 1)
    checks.check_int("monte_carlo", "offset", offset, 0)
    if chunk is not None:
        checks.check_int("monte_carlo", "chunk", chunk, 1)
    if time_chunk is not None:
        checks.check_int("monte_carlo", "time_chunk", time_chunk, 1)
    if not callable(fn):
        raise checks.ArgumentTypeError(f"monte_carlo: fn must be a function of a PRNG key, got {type(fn).__name__}")
    if sweep is not None and (not isinstance(sweep, tuple) or len(sweep) != 2 or not callable(sweep[0])):
        raise checks.ArgumentTypeError("monte_carlo: sweep must be a pair (where, values) with where a function, "
                                       f"got {type(sweep).__name__}")
    if isinstance(key, bool) or not (isinstance(key, (int, np.integer)) or hasattr(key, "dtype")):
        raise checks.ArgumentTypeError(f"monte_carlo: key must be a PRNG key or an int seed, got {key!r}")
    if isinstance(key, (int, np.integer)):
        key = jax.random.PRNGKey(key)
    fn = _float_leaves_to_arrays(fn)
    where, values = (None, None) if sweep is None else sweep
    if where is not None:
        values = jax.tree_util.tree_map(jnp.asarray, values)
    traced = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves((fn, key, values)))
    progress = progress and not traced

    devices = jax.devices()
    # With jax.distributed, jax.devices() spans every process: the seeds are split over all of them and the
    # outputs gathered back, so every process returns the whole result. A traced call (a gradient) cannot
    # gather inside the trace: it stays on this process's devices, each process computing the same thing.
    multi = jax.process_count() > 1
    if multi and traced:
        devices, multi = jax.local_devices(), False
    if shard is None:
        shard = multi or (len(devices) > 1 and n >= AUTO_SHARD_MIN_SEEDS)
    multi = multi and shard
    n_dev = len(devices) if shard else 1
    batch = min(chunk or n, n)
    batch = math.ceil(batch / n_dev) * n_dev
    seeds = np.arange(offset, offset + n, dtype=np.int64)
    pad = (-n) % batch
    seeds = np.concatenate([seeds, np.repeat(seeds[-1:], pad)])
    if seeds[-1] >= 2**32:
        raise ValueError("seed indices must fit in uint32")
    n_batches = len(seeds) // batch
    seed_axis = 0 if where is None else 1

    rollout = isinstance(fn, Rollout)
    if rollout and index:
        raise ValueError("index=True calls fn(key, i); a Rollout is a function of the key alone")
    call = _m_call_indexed if index else _m_call
    if rollout:
        every = fn.save_every if fn.save is not None else 1
        tc = time_chunk or (_progress_chunk(fn.steps, every) if progress else fn.steps)
        tc = max(every, (tc // every) * every)
        sizes = [tc] * (fn.steps // tc) + ([fn.steps % tc] if fn.steps % tc else [])
    # one bar, process 0's; the chunking above must not depend on it (every process runs the same programs)
    bar = Progress(n_batches * (fn.steps if rollout else 1), desc=desc,
                   enabled=progress and jax.process_index() == 0)

    def wait(x):
        if not traced:
            jax.block_until_ready(x)  # dispatch is asynchronous: wait so the bar tells the truth
        return x

    carry_sharding = None
    if n_dev > 1:
        from jax.sharding import NamedSharding, PartitionSpec

        carry_sharding = NamedSharding(device_mesh(devices), PartitionSpec(*([None] * seed_axis), "seeds"))

    outs, first = [], None
    for b in range(n_batches):
        if multi:
            idx = _global_indices(seeds[b * batch:(b + 1) * batch], devices)
        else:
            idx = jnp.asarray(seeds[b * batch:(b + 1) * batch], dtype=jnp.uint32)
        if n_dev > 1 and not multi:
            from jax.sharding import NamedSharding, PartitionSpec

            idx = jax.device_put(idx, NamedSharding(device_mesh(devices), PartitionSpec("seeds")))
        if not rollout or len(sizes) == 1 or detail is not None or index:
            # the whole horizon at once: one program, one dispatch
            out = wait(_call_batch(call, fn, where, values, key, idx, None, 0, detail))
            if multi:
                out = _gather(out, devices)
            if detail is not None:
                if b == 0:
                    first = out[1]
                out = out[0]
            outs.append(out)
            bar.update(fn.steps if rollout else 1)
            continue
        # The initial state leaves that do not depend on the seed (counters, zeros) would come out replicated,
        # while the advance's outputs are split over the seeds: the second chunk would then see other input
        # shardings than the first and compile the loop again. Lay them out as the advance will.
        state = _call_batch(_m_init, fn, where, values, key, idx, None, 0, out_sharding=carry_sharding)
        saved = []
        for size in sizes:
            state, s = _call_batch(_m_advance, fn, where, values, key, idx, state, size)
            saved.append((_gather(wait(s), devices) if multi else wait(s)) if s is not None else None)
            if s is None:
                wait(state)
            bar.update(size)
        mets = _call_batch(_m_finalize, fn, where, values, key, idx, state, 0)
        if multi:
            state, mets = _gather((state, mets), devices)
        outs.append(Solution(state, _concat(saved, seed_axis + 1), mets, state.result))
    bar.close()

    out = _concat(outs, seed_axis)
    if pad:
        out = jax.tree_util.tree_map(lambda a: jax.lax.slice_in_dim(a, 0, n, axis=seed_axis), out)
    return out if detail is None else (out, first)
