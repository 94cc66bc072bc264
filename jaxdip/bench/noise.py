"""The sensor noise of the dip-lqr loop: what drawing it costs per period under each candidate way of drawing it,
and the loop's periods/s with each, all measured in one process (rounds interleaved, medians).

    python -m jaxdip.bench.noise [--seeds 1024] [--steps 1000] [--chunk 100] [--rounds 5]

Today's stream (``threefry``): the trajectory key of seed i is ``fold_in(key, i)``; period k's sensor key is lane
0 of ``split_lanes(fold_in(fold_in(key_i, 2), k), 5)`` (``KeySchedule``), and ``WhiteNoise`` draws six normals
with ``jax.random.normal`` (threefry bits, then a float64 inverse error function) from lane 0 of that key's
``split_lanes(., 2)``. The candidates change one thing each:

- ``rbg`` / ``unsafe_rbg``: the same schedule on ``jax.random.key(seed, impl=...)`` keys;
- ``box_muller``: the same keys, float64 uniforms turned into normals by Box-Muller instead of ``erfinv``;
- ``float32``: the same keys, ``jax.random.normal`` in float32, cast to float64;
- ``block``: one draw per seed and chunk of periods, ``normal(fold_in(base, chunk), (chunk, 6))``, the loop
  reading row k of it (no per-period key derivation at all), and with it ``float32`` or ``unsafe_rbg``.

The library's own loop is timed too (``engine_rates``), with today's draw, ``unsafe_rbg`` keys, the float32 draw,
and ``NoDraw`` (y = x): the last is the bound that no way of drawing the noise can pass; and three of them
again with the DIP's sin and cos in vectorised operations (``DIP(trig="vectorised")``).

``CANDIDATES`` maps each name to ``(key impl, draw, block)``; ``noise`` draws a (seeds, steps, 6) array of one
candidate's stream, which the tests (tests/test_noise_streams.py) check statistically against today's. Timings
on a CPU are CPU seconds of this process (``time.process_time``), so other load on the machine enters less than
in wall time; on an accelerator they are wall seconds. Not part of the test suite.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.engine.keys import split_lanes
from jaxdip.plants.dip import DIP
from jaxdip.scenarios.dip_lqr import TABLE_3_1_Q

NOISE_STD = jnp.array([1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2])  # dip-lqr's sensor
DT = 0.001


def erfinv_normal(key, shape):
    """Today's draw: ``jax.random.normal`` (float64, inverse error function)."""
    return jax.random.normal(key, shape)


def box_muller(key, shape):
    """Standard normals from float64 uniforms by Box-Muller: pairs (r cos t, r sin t), r = sqrt(-2 log(1 - u1))
    (1 - u1 lies in (0, 1], so the log is finite), t = 2 pi u2."""
    n = math.prod(shape)
    u = jax.random.uniform(key, (2, (n + 1) // 2))
    r = jnp.sqrt(-2.0 * jnp.log1p(-u[0]))
    t = 2.0 * jnp.pi * u[1]
    return jnp.concatenate([r * jnp.cos(t), r * jnp.sin(t)])[:n].reshape(shape)


def float32_normal(key, shape):
    """``jax.random.normal`` in float32 (threefry bits and ``erfinv`` at single precision), cast to float64."""
    return jax.random.normal(key, shape, dtype=jnp.float32).astype(jnp.float64)


class Candidate(NamedTuple):
    impl: str  # the key implementation (jax.random.key's impl)
    draw: Callable  # (key, shape) -> float64 standard normals
    block: bool  # one draw per chunk of periods instead of per period


CANDIDATES = {
    "threefry": Candidate("threefry2x32", erfinv_normal, False),
    "rbg": Candidate("rbg", erfinv_normal, False),
    "unsafe_rbg": Candidate("unsafe_rbg", erfinv_normal, False),
    "box_muller": Candidate("threefry2x32", box_muller, False),
    "float32": Candidate("threefry2x32", float32_normal, False),
    "block": Candidate("threefry2x32", erfinv_normal, True),
    "block_float32": Candidate("threefry2x32", float32_normal, True),
    "block_unsafe_rbg": Candidate("unsafe_rbg", erfinv_normal, True),
}


def seed_keys(name: str, seeds: int, seed: int = 0):
    """The trajectory keys ``fold_in(key, i)``, i < seeds: raw uint32 keys for threefry (as the library's
    ``PRNGKey``), typed keys for the rbg implementations."""
    impl = CANDIDATES[name].impl
    base = jax.random.PRNGKey(seed) if impl == "threefry2x32" else jax.random.key(seed, impl=impl)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(seeds))


def period_normals(c: Candidate, key, k):
    """Period k's six normals of one trajectory (per-period candidates): today's key schedule, then ``c.draw``."""
    k_sens = split_lanes(jax.random.fold_in(jax.random.fold_in(key, 2), k), 5)[0]
    return c.draw(split_lanes(k_sens, 2)[0], (6,))


def chunk_normals(c: Candidate, key, j, chunk: int):
    """Chunk j's (chunk, 6) normals of one trajectory (block candidates)."""
    return c.draw(jax.random.fold_in(jax.random.fold_in(key, 2), j), (chunk, 6))


def noise(name: str, seeds: int, steps: int, *, chunk: int = 100, seed: int = 0) -> np.ndarray:
    """The (seeds, steps, 6) standard normals candidate ``name`` gives the sensor."""
    c, keys = CANDIDATES[name], seed_keys(name, seeds, seed)
    if c.block:
        n_chunks = -(-steps // chunk)
        z = jax.vmap(lambda key: jax.vmap(lambda j: chunk_normals(c, key, j, chunk))(jnp.arange(n_chunks)))(keys)
        return np.asarray(z.reshape(seeds, n_chunks * chunk, 6)[:, :steps])
    return np.asarray(jax.vmap(lambda key: jax.vmap(lambda k: period_normals(c, key, k))(jnp.arange(steps)))(keys))


def _program(name: str, steps: int, chunk: int, with_plant: bool):
    """A jitted (keys, x0) -> final states: ``steps`` periods of y = x + std z, u = -K y, one RK4 step of the
    printed DIP (``with_plant``), or of x <- x + std z alone (the noise's own cost), vmapped over the seeds."""
    c = CANDIDATES[name]
    plant = DIP()
    K, _, _ = jd.control.lqr(*jd.linearize(plant), np.diag(TABLE_3_1_Q), 0.1)
    K = jnp.asarray(K)

    def advance(x, z):
        y = x + NOISE_STD * z
        if not with_plant:
            return y
        return plant.period(x, -(K @ y), DT, 1)

    def one(key, x0):
        if c.block:
            def outer(x, j):
                zs = chunk_normals(c, key, j, chunk)
                return jax.lax.scan(lambda x, z: (advance(x, z), None), x, zs)[0], None
            return jax.lax.scan(outer, x0, jnp.arange(steps // chunk))[0]

        def body(x, k):
            return advance(x, period_normals(c, key, k)), None
        return jax.lax.scan(body, x0, jnp.arange(steps))[0]

    return jax.jit(jax.vmap(one))


def _clock() -> Callable[[], float]:
    return time.process_time if jax.default_backend() == "cpu" else time.perf_counter


def measure(names, seeds: int = 1024, steps: int = 1000, chunk: int = 100, rounds: int = 5) -> dict:
    """ns per seed-period (median CPU time over ``rounds`` interleaved rounds) of the noise alone and of the loop
    with it, per candidate."""
    if steps % chunk:
        raise ValueError(f"steps ({steps}) must be a multiple of chunk ({chunk})")
    x0 = jnp.tile(jnp.array([0.0, 0.03, -0.02, 0.0, 0.0, 0.0]), (seeds, 1))
    progs = {}
    for name in names:
        keys = seed_keys(name, seeds)
        for part in ("noise", "loop"):
            f = _program(name, steps, chunk, part == "loop")
            jax.block_until_ready(f(keys, x0))  # compile and warm
            progs[name, part] = (f, keys)
    times: dict = {k: [] for k in progs}
    clock = _clock()
    for _ in range(rounds):
        for k, (f, keys) in progs.items():
            t = clock()
            jax.block_until_ready(f(keys, x0))
            times[k].append(clock() - t)
    per = 1e9 / (seeds * steps)
    return {name: {part: statistics.median(times[name, part]) * per for part in ("noise", "loop")}
            for name in names}


class NoDraw(jd.Sensor):
    """y = x, drawing nothing: the loop without any sensor noise, the bound a cheaper draw cannot pass."""

    def step(self, state, x, key, k):
        return state, x, None


def engine_rates(seeds: int = 1024, steps: int = 1000, rounds: int = 5) -> dict:
    """ns per seed-period (median CPU time, interleaved rounds) of the library's own dip-lqr loop
    (``jd.monte_carlo`` of the scenario's rollout, one RK4 step, no recording): today's keys, ``unsafe_rbg`` keys
    (a typed key given to ``monte_carlo``: the whole key schedule on that generator),
    ``WhiteNoise(draw_dtype="float32")``, and ``NoDraw`` (no noise at all: what any draw could gain at most), all
    with the C library's sin and cos (the loop before dip-lqr's defaults changed); then the first, the third and
    the fourth again with ``DIP(trig="vectorised")`` (the last but one is the loop dip-lqr runs now)."""
    from jaxdip.scenarios.dip_lqr import dip_lqr

    def loop(trig, draw):
        return dip_lqr(duration=steps * DT, substeps=1, record_every=None, trig=trig, noise_draw=draw)

    def no_draw(r):
        return eqx.tree_at(lambda r: r.loop.sensor, r, NoDraw())

    r = loop("library", "loop")
    cases = {"threefry": (r, jax.random.PRNGKey(0)), "unsafe_rbg": (r, jax.random.key(0, impl="unsafe_rbg")),
             "float32": (loop("library", "float32"), jax.random.PRNGKey(0)),
             "no_draw": (no_draw(r), jax.random.PRNGKey(0)),
             "vectorised_trig": (loop("vectorised", "loop"), jax.random.PRNGKey(0)),
             "vectorised_trig_float32": (loop("vectorised", "float32"), jax.random.PRNGKey(0)),
             "vectorised_trig_no_draw": (no_draw(loop("vectorised", "loop")), jax.random.PRNGKey(0))}
    progs = {name: jax.jit(lambda key, r=rollout: jd.monte_carlo(r, key, seeds).metrics)
             for name, (rollout, _) in cases.items()}
    for name, f in progs.items():
        jax.block_until_ready(f(cases[name][1]))
    times: dict = {name: [] for name in cases}
    clock = _clock()
    for _ in range(rounds):
        for name, f in progs.items():
            t = clock()
            jax.block_until_ready(f(cases[name][1]))
            times[name].append(clock() - t)
    return {name: statistics.median(v) * 1e9 / (seeds * steps) for name, v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--chunk", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    res = measure(list(CANDIDATES), args.seeds, args.steps, args.chunk, args.rounds)
    ref = res["threefry"]
    print(f"{jax.devices()[0].platform}, {args.seeds} seeds x {args.steps} periods, chunk {args.chunk}, "
          f"median of {args.rounds} interleaved rounds, "
          f"{'CPU' if jax.default_backend() == 'cpu' else 'wall'} ns per seed-period")
    print(f"{'candidate':<18}{'noise ns':>10}{'x today':>9}{'loop ns':>10}{'periods/s':>12}{'x today':>9}")
    for name, r in res.items():
        print(f"{name:<18}{r['noise']:>10.1f}{ref['noise'] / r['noise']:>9.2f}{r['loop']:>10.1f}"
              f"{1e9 / r['loop']:>12.3g}{ref['loop'] / r['loop']:>9.2f}")
    eng = engine_rates(args.seeds, args.steps, args.rounds)
    print("the library's loop (jd.monte_carlo of the dip-lqr rollout), ns per seed-period")
    for name, v in eng.items():
        print(f"{name:<24}{v:>10.1f}{1e9 / v:>12.3g}{eng['threefry'] / v:>9.2f}")


if __name__ == "__main__":
    main()
