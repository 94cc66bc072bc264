"""``simulate``: the only place a closed loop is scanned over time.

One sample period k, in the order the laboratory loops run:

    y_k        = sensor(x_k)
    xhat_k     = estimator(y_k, u_{k-1})
    u_k        = controller(xhat_k)
    ua_k       = actuator(u_k)
    x_{k+1}    = plant over dt with ua_k held (RK4 sub-steps under ZOH), plus process noise

Randomness, from the trajectory's key ``key`` (seed i of a Monte Carlo run has ``key = fold_in(base, i)``):
the component states start from ``split(fold_in(key, 1), 4)`` (sensor, estimator, controller, actuator) and
period k uses ``split(fold_in(fold_in(key, 2), k), 5)`` (sensor, estimator, controller, actuator, process
noise); ``KeySchedule`` holds this convention. Results therefore do not depend on how a run is chunked in
time or batched over seeds. (The driver draws a random initial state from ``fold_in(key, 0)``.)

Failure is data: once x_{k+1} is non-finite or leaves the bound ``|x - plant.equilibrium()| <= state_bound``,
the trajectory's ``result`` code is set (``RESULTS``), the plant state is frozen at the last good x_k, and the
metrics stop accumulating from period k on (the period that produced the bad state is not counted). The
components keep stepping on the frozen state, as in the original loop.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any, Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import metrics as _metrics
from jaxdip.engine.keys import split_lanes
from jaxdip.engine import checks
from jaxdip.engine.loop_checks import PRECISIONS, check_loop
from jaxdip.engine.roles import Identity, _as_float_array, param


from jaxdip._public import public_dir

__all__ = ["RESULTS", "PRECISIONS", "as_precision", "with_precision", "KeySchedule", "Loop", "Aux", "Sample", "State",
           "Solution", "init_state", "simulate"]
__dir__ = public_dir(globals())


class RESULTS(enum.IntEnum):
    """Per-trajectory outcome codes (stored as int32 in ``Solution.result``)."""

    ok = 0
    nonfinite = 1  # the plant state became NaN or infinite
    out_of_bounds = 2  # |x - equilibrium| exceeded state_bound in some component


class KeySchedule(eqx.Module):
    """How a trajectory's key is divided among the roles: the library's convention (module docstring).

    Subclass it only to reproduce an older random stream exactly when moving code onto the engine; every
    trajectory of a new experiment should use this default."""

    def init(self, key):
        """Keys of the sensor, estimator, controller and actuator ``init``."""
        return split_lanes(jax.random.fold_in(key, 1), 4)

    def base(self, key):
        """The per-trajectory key the period keys are folded from (computed once, outside the scan)."""
        return jax.random.fold_in(key, 2)

    def period(self, base, k):
        """Keys of the sensor, estimator, controller, actuator and process noise at period ``k``
        (``split(fold_in(base, k), 5)``, as separate keys: see ``split_lanes``)."""
        return split_lanes(jax.random.fold_in(base, k), 5)


def _optional_array(v):
    return None if v is None else _as_float_array(v)


class Loop(eqx.Module):
    """A closed loop: its components (each with its own hyperparameters) and the sampling structure.

    ``dt`` and ``substeps`` are static; ``process_noise_std`` (std of Gaussian noise added to the state after
    every period, scalar or per state), ``state_bound`` (per state or scalar) and ``norm_bound`` (on the
    Euclidean norm of the deviation) are traced leaves. ``keys``
    divides the trajectory's key among the roles (leave the default). ``precision`` ("float64" or "float32",
    static) is the dtype ``simulate`` runs the loop in: with "float32" it casts the loop's floating leaves, x0
    and the reducers and the whole period, metrics and ``Solution`` are float32 (``with_precision`` sets it on
    every loop of a pytree).
    """

    plant: Any
    sensor: Any
    estimator: Any
    controller: Any
    dt: float = eqx.field(static=True)
    actuator: Any = eqx.field(default_factory=Identity)
    substeps: int = eqx.field(default=10, static=True)
    # None (the default) leaves the noise draw and the norm test out of the program; a value is traced
    process_noise_std: Optional[jax.Array] = eqx.field(default=None, converter=_optional_array)
    state_bound: jax.Array = param(jnp.inf)
    keys: KeySchedule = eqx.field(default_factory=KeySchedule)
    # a bound on the Euclidean norm of x - equilibrium (the failure rule of the thesis's Procedure 1: a state
    # norm above it ends a simulation); crossing it counts as out_of_bounds, like state_bound
    norm_bound: Optional[jax.Array] = eqx.field(default=None, converter=_optional_array)
    # draw every period's process noise before the periods' loop, vectorised over the periods: the same
    # numbers. Worth it when a batch shares its key (an ensemble judged on one noise sequence): the shared
    # draw inside the loop is not batched, and as hundreds of tiny unfused operations per period it cost 3.6x
    # the rest of the eki-dip search's period (docs/performance.md). Memory: steps x n numbers per key.
    noise_ahead: bool = eqx.field(default=False, static=True)
    # "float32" runs the whole period (plant, noise, components, metrics) in float32: ``simulate`` casts the
    # loop's floating leaves and x0. Designs (Riccati, MHE weights) are made in float64 before the loop exists.
    precision: str = eqx.field(default="float64", static=True)

    def __check_init__(self):
        check_loop(self)

    @property
    def dtype(self) -> jnp.dtype:
        """The floating dtype the loop runs in (``precision``)."""
        return jnp.dtype(self.precision)


class Aux(NamedTuple):
    sensor: Any
    estimator: Any
    controller: Any
    actuator: Any


class Sample(NamedTuple):
    """What one period exposes to ``save`` and to the metrics."""

    k: jax.Array  # period index
    t: jax.Array  # k * dt
    x: jax.Array  # true state at the start of the period
    y: Any  # measurement
    xhat: jax.Array  # estimate handed to the controller
    u: jax.Array  # controller output, shape (m,)
    u_applied: jax.Array  # actuator output, what the plant receives
    aux: Aux  # the components' auxiliary outputs


class State(NamedTuple):
    """Everything a trajectory carries from one period to the next; resume a run from it."""

    k: jax.Array
    x: jax.Array
    sensor: Any
    estimator: Any
    controller: Any
    actuator: Any
    u_prev: jax.Array
    result: jax.Array  # RESULTS code
    failed_at: jax.Array  # index of the first bad state (-1 while ok)
    failed_x: jax.Array  # the first bad state itself (what crossed which bound); zeros while ok
    metrics: Any  # reducer states


class Solution(NamedTuple):
    final: State
    saved: Any  # save(sample) at periods start.k, start.k + save_every, ...; None without save
    metrics: Any  # finalized metrics (same structure as the ``metrics`` argument)
    result: jax.Array  # RESULTS code


def _process_noise(k_proc, shape, dtype):
    return jax.random.normal(k_proc, shape, dtype)


def _period(loop: Loop, st: State, base, noise=None):
    """One period without failure handling: (new component states, x_{k+1}, u_k, sample). ``noise``: this
    period's standard normal process noise drawn ahead (``Loop.noise_ahead``), else drawn here."""
    k_sens, k_est, k_ctrl, k_act, k_proc = loop.keys.period(base, st.k)
    s_sens, y, a_sens = loop.sensor.step(st.sensor, st.x, k_sens, st.k)
    s_est, xhat, a_est = loop.estimator.step(st.estimator, y, st.u_prev, k_est, st.k)
    s_ctrl, u, a_ctrl = loop.controller.step(st.controller, xhat, k_ctrl, st.k)
    u = jnp.reshape(u, (loop.plant.m,))
    s_act, u_applied, a_act = loop.actuator.step(st.actuator, u, k_act, st.k)
    x_next = loop.plant.period(st.x, u_applied, loop.dt, loop.substeps)
    if loop.process_noise_std is not None:
        if noise is None:
            noise = _process_noise(k_proc, st.x.shape, st.x.dtype)
        x_next = x_next + loop.process_noise_std * noise
    t = st.k.astype(st.x.dtype) * loop.dt  # int32 k times a Python float would be float64
    sample = Sample(st.k, t, st.x, y, xhat, u, u_applied, Aux(a_sens, a_est, a_ctrl, a_act))
    return (s_sens, s_est, s_ctrl, s_act), x_next, u, sample


def _step(loop: Loop, metrics, base, st: State, noise=None):
    comps, x_next, u, sample = _period(loop, st, base, noise)
    with jax.ensure_compile_time_eval():  # a constant in the loop's dtype, not a float64 zeros in the program
        eq = loop.plant.equilibrium().astype(x_next.dtype)
    dev = x_next - eq
    out = jnp.any(jnp.abs(dev) > loop.state_bound)
    if loop.norm_bound is not None:
        out = out | (jnp.linalg.norm(dev) > loop.norm_bound)
    code = jnp.where(~jnp.all(jnp.isfinite(x_next)), RESULTS.nonfinite,
                     jnp.where(out, RESULTS.out_of_bounds, RESULTS.ok))
    was_ok = st.result == RESULTS.ok
    result = jnp.where(was_ok, code, st.result).astype(jnp.int32)
    fails_now = was_ok & (code != RESULTS.ok)
    failed_at = jnp.where(fails_now, st.k + 1, st.failed_at)
    failed_x = jnp.where(fails_now, x_next, st.failed_x)
    live = result == RESULTS.ok  # this period counts only if the trajectory is still alive after it
    new = State(
        k=st.k + 1,
        x=jnp.where(live, x_next, st.x),
        sensor=comps[0],
        estimator=comps[1],
        controller=comps[2],
        actuator=comps[3],
        u_prev=u,
        result=result,
        failed_at=failed_at,
        failed_x=failed_x,
        metrics=_metrics.update(metrics, st.metrics, sample, live),
    )
    return new, sample


def _check_x0(owner: str, loop: Loop, x0) -> None:
    checks.check_real(owner, "x0", x0)
    n = loop.plant.n
    checks.check_shape(owner, "x0", x0, (n,), f"for the plant {type(loop.plant).__name__} ({n} states)")
    checks.check_finite(owner, "x0", x0)


def _cast(tree, dtype):
    def leaf(a):
        # JAX and NumPy arrays (a user's np.array field); Python floats are weakly typed and follow the loop
        if isinstance(a, (jax.Array, np.ndarray)) and jnp.issubdtype(a.dtype, jnp.floating) and a.dtype != dtype:
            return jnp.asarray(a, dtype)
        return a

    return jax.tree_util.tree_map(leaf, tree)


def as_precision(tree: Any, dtype: Any = None) -> Any:
    """``tree`` with its floating array leaves in ``dtype`` (a ``Loop``: in its own ``precision``); keys,
    integers and Python numbers are left alone, and a float64 tree comes back as it is."""
    if dtype is None:
        dtype = tree.dtype
    if tree is None or jnp.dtype(dtype) == jnp.float64:
        return tree
    return _cast(tree, jnp.dtype(dtype))


def with_precision(tree: Any, precision: str) -> Any:
    """``tree`` (a ``Loop``, a ``Rollout``, any pytree holding loops) with every loop in it set to
    ``precision`` ("float64" or "float32"); nothing else changes. How an experiment runs its Monte Carlo loops
    in float32 while its designs stay float64."""
    checks.check_choice("with_precision", "precision", precision, PRECISIONS)

    def one(node):
        if isinstance(node, Loop) and node.precision != precision:
            return dataclasses.replace(node, precision=precision)
        return node

    return jax.tree_util.tree_map(one, tree, is_leaf=lambda node: isinstance(node, Loop))


def init_state(loop: Loop, x0, key, metrics=None) -> State:
    """The state before period 0 of the trajectory with key ``key`` starting at ``x0`` (in the loop's
    ``precision``)."""
    loop = as_precision(loop)
    x0 = jnp.asarray(x0, dtype=loop.dtype)
    k_sens, k_est, k_ctrl, k_act = loop.keys.init(key)
    st = State(
        k=jnp.zeros((), jnp.int32),
        x=x0,
        sensor=loop.sensor.init(k_sens, x0),
        estimator=loop.estimator.init(k_est, x0),
        controller=loop.controller.init(k_ctrl, x0),
        actuator=loop.actuator.init(k_act, x0),
        u_prev=jnp.zeros(loop.plant.m, x0.dtype),
        result=jnp.asarray(RESULTS.ok, jnp.int32),
        failed_at=jnp.full((), -1, jnp.int32),
        failed_x=jnp.zeros_like(x0),
        metrics=None,
    )
    if metrics is None:
        return st
    # the reducers size their states from the shapes of one period's sample (traced abstractly, not run)
    template = jax.eval_shape(lambda s, b: _period(loop, s, b)[3], st, loop.keys.base(key))
    return st._replace(metrics=_metrics.init(metrics, template))


def simulate(loop: Loop, x0, key, steps: int, *, save: Optional[Callable] = None, save_every: int = 1,
             metrics: Any = None, start: Optional[State] = None) -> Solution:
    """Run ``steps`` periods of ``loop`` for one trajectory. Pure: no jit, no host callbacks inside.

    x0: initial true state (ignored when ``start`` is given). key: the trajectory's PRNG key.
    save: ``save(sample) -> pytree`` recorded at the first period of every block of ``save_every`` periods
    (``steps`` must be a multiple of ``save_every``); ``None`` records nothing.
    metrics: a reducer (``jaxdip.engine.metrics``) or a dict/tuple of them; their finalized values come back
    in ``Solution.metrics``.
    start: a ``State`` (``Solution.final`` of an earlier call with the same loop, key and metrics) to continue
    from; periods are counted from ``start.k``, so a run split into calls equals one uninterrupted call.

    ``vmap`` over keys, x0, or any array leaf of ``loop``; ``jax.grad`` through it.
    """
    checks.check_int("simulate", "steps", steps, 0)
    checks.check_int("simulate", "save_every", save_every, 1)
    if not isinstance(loop, Loop):
        raise checks.ArgumentTypeError(f"simulate: loop must be a jaxdip Loop, got {type(loop).__name__}")
    if start is None:
        _check_x0("simulate", loop, x0)
    # the reducers' own arrays (a weight Q) too, so they accumulate in the loop's precision
    loop, start, metrics = as_precision(loop), as_precision(start, loop.dtype), as_precision(metrics, loop.dtype)
    st = init_state(loop, x0, key, metrics) if start is None else start
    base = loop.keys.base(key)
    if save is not None and steps % save_every:
        checks.fail("simulate", f"steps must be a multiple of save_every={save_every}, got {steps}")
    ahead = None
    if loop.noise_ahead and loop.process_noise_std is not None:
        # period k's key as in the loop (so the numbers are those drawn inside it), all periods at once
        ahead = jax.vmap(lambda k: _process_noise(loop.keys.period(base, k)[4], st.x.shape, st.x.dtype))(
            st.k + jnp.arange(steps, dtype=st.k.dtype))

    def step(c, noise=None):
        return _step(loop, metrics, base, c, noise)

    if save is None:
        st, saved = jax.lax.scan(lambda c, nz: (step(c, nz)[0], None), st, ahead, length=steps)
    else:
        if save_every == 1:
            def block(c, nz):
                c, sample = step(c, nz)
                return c, save(sample)
        else:
            # one copy of the period in the program (compile time grows with copies): the record of the
            # block's first period is carried through the block's loop
            rec0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype),
                                          jax.eval_shape(lambda c: save(step(c)[1]), st))

            def block(c, nz):
                def inner(j, carry):
                    ci, rec = carry
                    ci, sample = step(ci, None if nz is None else nz[j])
                    rec = jax.tree_util.tree_map(lambda a, b: jnp.where(j == 0, a, b), save(sample), rec)
                    return ci, rec

                return jax.lax.fori_loop(0, save_every, inner, (c, rec0))

            if ahead is not None:
                ahead = ahead.reshape((steps // save_every, save_every) + ahead.shape[1:])
        st, saved = jax.lax.scan(block, st, ahead, length=steps // save_every)
    return Solution(st, saved, _metrics.finalize(metrics, st.metrics), st.result)
