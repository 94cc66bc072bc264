"""The closed loop jaxdip ran before the engine (``jaxdip.engine``), kept frozen as a reference: tests check that
the engine reproduces it. Not part of the library. Its own scan, key schedule and statistics; the components are
the engine's roles, stepped here (their ``aux`` is dropped), and they travel in ``Loop``, which the callers pass
through ``eqx.filter_jit`` so their numbers are traced as the engine's are.

The generic closed loop: plant, sensor, estimator, controller and actuator in one ``lax.scan``.

One sample period k, in the order the laboratory loops run:

    y_k      = sensor(x_k)
    xhat_k   = estimator(y_k, u_{k-1})
    u_k      = controller(xhat_k)
    x_{k+1}  = plant over dt with actuator(u_k) held, plus process noise

Randomness: step k of a trajectory uses ``fold_in(run_key, k)``, so results do not depend on how the scan
is chunked (progress bars) or batched. A trajectory whose state becomes non-finite or leaves the bound is
marked diverged at that step and frozen; its statistics stop accumulating.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp

import jaxdip as jd


class Loop(NamedTuple):
    """The closed loop's components (engine roles) and its timing."""

    plant: jd.Plant
    dt: float
    sensor: jd.Sensor
    estimator: jd.Estimator
    controller: jd.Controller
    actuator: jd.Actuator = jd.Identity()
    substeps: int = 10
    tail_steps: int = 0  # length of the final window whose max |x| decides "stabilised"


class LoopParams(NamedTuple):
    """The loop's noise and bound."""

    process_noise_std: Any = 0.0  # std of Gaussian noise added to the state after each period
    state_bound: Any = jnp.inf  # |x - x_eq| above this (per state) counts as divergence


class Stats(NamedTuple):
    """Running per-trajectory sums, so long horizons need no stored trajectory."""

    count: jnp.ndarray
    sum_x: jnp.ndarray
    sum_x2: jnp.ndarray
    sum_absx: jnp.ndarray
    max_absx: jnp.ndarray
    sum_err2: jnp.ndarray  # squared estimation error per state
    sum_u: jnp.ndarray
    sum_u2: jnp.ndarray
    sum_absu: jnp.ndarray
    max_absu: jnp.ndarray
    tail_max_absx: jnp.ndarray


class Carry(NamedTuple):
    k: jnp.ndarray
    x: jnp.ndarray
    sensor: Any
    estimator: Any
    controller: Any
    actuator: Any
    u_prev: jnp.ndarray
    diverged: jnp.ndarray
    diverged_at: jnp.ndarray
    stats: Stats


class Record(NamedTuple):
    x: jnp.ndarray
    xhat: jnp.ndarray
    u: jnp.ndarray
    y: jnp.ndarray


def _zero_stats(n, m):
    z = jnp.zeros(n)
    zu = jnp.zeros(m)
    return Stats(jnp.zeros((), jnp.int32), z, z, z, z, z, zu, zu, zu, zu, z)


def init_carry(loop: Loop, params: LoopParams, x0, seed_key) -> Carry:
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    k_sens, k_est, k_ctrl, k_act = jax.random.split(jax.random.fold_in(seed_key, 1), 4)
    m = loop.plant.m
    return Carry(
        k=jnp.zeros((), jnp.int32),
        x=x0,
        sensor=loop.sensor.init(k_sens, x0),
        estimator=loop.estimator.init(k_est, x0),
        controller=loop.controller.init(k_ctrl, x0),
        actuator=loop.actuator.init(k_act, x0),
        u_prev=jnp.zeros(m),
        diverged=jnp.zeros((), bool),
        diverged_at=jnp.full((), -1, jnp.int32),
        stats=_zero_stats(loop.plant.n, m),
    )


def make_step(loop: Loop, n_steps: int) -> Callable:
    """One period of the loop as ``(params, seed_key, carry) -> (carry, Record)``."""
    tail_start = n_steps - loop.tail_steps

    def step(params: LoopParams, seed_key, c: Carry):
        key = jax.random.fold_in(jax.random.fold_in(seed_key, 2), c.k)
        k_sens, k_est, k_ctrl, k_act, k_proc = jax.random.split(key, 5)
        s_sens, y, _ = loop.sensor.step(c.sensor, c.x, k_sens, c.k)
        s_est, xhat, _ = loop.estimator.step(c.estimator, y, c.u_prev, k_est, c.k)
        s_ctrl, u, _ = loop.controller.step(c.controller, xhat, k_ctrl, c.k)
        u = jnp.reshape(u, (loop.plant.m,))
        s_act, u_applied, _ = loop.actuator.step(c.actuator, u, k_act, c.k)

        x_next = loop.plant.period(c.x, u_applied, loop.dt, loop.substeps)
        noise = params.process_noise_std * jax.random.normal(k_proc, c.x.shape)
        x_next = x_next + noise
        dev = jnp.abs(x_next - loop.plant.equilibrium())
        bad = ~jnp.all(jnp.isfinite(x_next)) | jnp.any(dev > params.state_bound)
        newly = bad & ~c.diverged
        diverged = c.diverged | bad
        live = ~diverged  # this period's statistics count only if the trajectory is still alive after it

        st = c.stats
        ax = jnp.abs(c.x - loop.plant.equilibrium())
        au = jnp.abs(u)
        w = live.astype(c.x.dtype)
        in_tail = (c.k >= tail_start) & live
        err = xhat - c.x
        st = Stats(
            count=st.count + live.astype(jnp.int32),
            sum_x=st.sum_x + w * c.x,
            sum_x2=st.sum_x2 + w * c.x**2,
            sum_absx=st.sum_absx + w * ax,
            max_absx=jnp.where(live, jnp.maximum(st.max_absx, ax), st.max_absx),
            sum_err2=st.sum_err2 + w * jnp.where(jnp.isfinite(err), err, 0.0) ** 2,
            sum_u=st.sum_u + w * u,
            sum_u2=st.sum_u2 + w * u**2,
            sum_absu=st.sum_absu + w * au,
            max_absu=jnp.where(live, jnp.maximum(st.max_absu, au), st.max_absu),
            tail_max_absx=jnp.where(in_tail, jnp.maximum(st.tail_max_absx, ax), st.tail_max_absx),
        )
        carry = Carry(
            k=c.k + 1,
            x=jnp.where(diverged, c.x, x_next),
            sensor=s_sens,
            estimator=s_est,
            controller=s_ctrl,
            actuator=s_act,
            u_prev=u,
            diverged=diverged,
            diverged_at=jnp.where(newly, c.k + 1, c.diverged_at),
            stats=st,
        )
        return carry, Record(c.x, xhat, u, y)

    return step


def advance(loop: Loop, n_steps: int, params: LoopParams, seed_key, carry: Carry, n: int,
            record_every: int = 0, record_fn: Optional[Callable] = None):
    """Run ``n`` periods from ``carry``; keep every ``record_every``-th Record (0: keep none).

    ``record_fn(Record) -> pytree`` selects what is kept, so a long Monte Carlo run stores only what its
    figures need.
    """
    step = make_step(loop, n_steps)
    record_fn = record_fn or (lambda r: r)

    if record_every <= 0:
        carry, _ = jax.lax.scan(lambda c, _: (step(params, seed_key, c)[0], None), carry, None, length=n)
        return carry, None
    if n % record_every:
        raise ValueError(f"chunk length {n} is not a multiple of record_every={record_every}")

    def block(c, _):
        c, rec = step(params, seed_key, c)
        c = jax.lax.fori_loop(0, record_every - 1, lambda _, ci: step(params, seed_key, ci)[0], c)
        return c, record_fn(rec)

    return jax.lax.scan(block, carry, None, length=n // record_every)


def rollout(loop: Loop, params: LoopParams, x0, seed_key, n_steps: int, record_every: int = 1,
            record_fn: Optional[Callable] = None):
    """A whole trajectory of one seed in one call (no chunking); returns (final carry, records)."""
    carry = init_carry(loop, params, x0, seed_key)
    return advance(loop, n_steps, params, seed_key, carry, n_steps, record_every, record_fn)
