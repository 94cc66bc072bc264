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

import enum
import numbers
from typing import Any, Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import metrics as _metrics
from jaxdip.engine.keys import split_lanes
from jaxdip.engine import checks
from jaxdip.engine.roles import SAME, Identity, Plant, _as_float_array, param


from jaxdip._public import public_dir

__all__ = ["RESULTS", "PRECISIONS", "as_precision", "KeySchedule", "Loop", "Aux", "Sample", "State", "Solution", "init_state", "simulate"]
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


PRECISIONS = ("float64", "float32")


def _optional_array(v):
    return None if v is None else _as_float_array(v)


class Loop(eqx.Module):
    """A closed loop: its components (each with its own hyperparameters) and the sampling structure.

    ``dt`` and ``substeps`` are static; ``process_noise_std`` (std of Gaussian noise added to the state after
    every period, scalar or per state), ``state_bound`` (per state or scalar) and ``norm_bound`` (on the
    Euclidean norm of the deviation) are traced leaves. ``keys``
    divides the trajectory's key among the roles (leave the default).
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
        _check_loop(self)

    @property
    def dtype(self) -> jnp.dtype:
        """The floating dtype the loop runs in (``precision``)."""
        return jnp.dtype(self.precision)


def _sizes(c) -> dict:
    sizes = getattr(c, "io_sizes", None)
    return sizes() if callable(sizes) else {}


def _count(k, noun: str) -> str:
    return f"{k} {noun}" if k == 1 else f"{k} {noun}s"


def _part(role: str, c) -> str:
    return f"the {role} {type(c).__name__}"


def _check_loop(loop: Loop) -> None:
    """The parts of a loop against each other (sizes each part knows from its fields: ``io_sizes``), and the
    loop's own numbers. Run when the loop is built, before anything is traced."""
    plant = loop.plant
    if not isinstance(plant, Plant):
        raise checks.ArgumentTypeError(f"Loop: plant must be a jaxdip Plant (or DiscretePlant), "
                                       f"got {type(plant).__name__}")
    # the other roles are duck-typed (``Identity`` is a full-state sensor as well as the ideal actuator): a part
    # needs init and step
    for role, c in (("sensor", loop.sensor), ("estimator", loop.estimator), ("controller", loop.controller),
                    ("actuator", loop.actuator)):
        if not (callable(getattr(c, "init", None)) and callable(getattr(c, "step", None))):
            raise checks.ArgumentTypeError(f"Loop: {role} must be a component with init and step (a jaxdip "
                                           f"{role.capitalize()}), got {type(c).__name__}")
    if isinstance(loop.dt, bool) or not isinstance(loop.dt, numbers.Real) or not (0 < loop.dt < float("inf")):
        checks.fail("Loop", f"dt must be a positive finite number of seconds, got {loop.dt!r}")
    checks.check_int("Loop", "substeps", loop.substeps, 1)
    checks.check_choice("Loop", "precision", loop.precision, PRECISIONS)
    n, m = plant.n, plant.m
    pname = f"the plant {type(plant).__name__}"
    for name, v in (("process_noise_std", loop.process_noise_std), ("state_bound", loop.state_bound),
                    ("norm_bound", loop.norm_bound)):
        if v is None:
            continue
        if checks.shape_of(v) not in ((), (n,)) and name != "norm_bound":
            checks.fail("Loop", f"{name} must be a scalar or ({n},) for {pname} ({n} states), "
                        f"got {checks.fmt_shape(checks.shape_of(v))}")
        if name == "process_noise_std":
            checks.check_nonnegative("Loop", name, v)
        else:
            checks.check_positive("Loop", name, v, allow_inf=True)

    def mismatch(what_a, size_a, why_a, what_b, size_b, why_b):
        a = f" ({why_a})" if why_a else ""
        b = f" ({why_b})" if why_b else ""
        checks.fail("Loop", f"{what_a} {size_a}{a} but {what_b} {size_b}{b}")

    sens = _sizes(loop.sensor)
    if "in" in sens and sens["in"][0] != n:
        mismatch(f"{_part('sensor', loop.sensor)} reads", _count(sens['in'][0], "state"), sens["in"][1],
                 f"{pname} has", _count(n, "state"), "")
    p, p_why = sens.get("out", (None, ""))
    if p == SAME:
        p, p_why = n, "a full-state sensor"
    est = _sizes(loop.estimator)
    if "in" in est and p is not None and est["in"][0] != p:
        mismatch(f"{_part('sensor', loop.sensor)} gives", _count(p, "output"), p_why,
                 f"{_part('estimator', loop.estimator)} expects", _count(est['in'][0], "measurement"), est["in"][1])
    if "u" in est and est["u"][0] != m:
        mismatch(f"{pname} has", _count(m, "input"), "", f"{_part('estimator', loop.estimator)} expects",
                 _count(est['u'][0], "input"), est["u"][1])
    nh, nh_why = est.get("out", (None, ""))
    if nh == SAME:
        nh, nh_why = (p, p_why) if p is not None else (est["in"] if "in" in est else (None, ""))
    ctrl = _sizes(loop.controller)
    if "in" in ctrl and nh is not None and ctrl["in"][0] != nh:
        mismatch(f"{_part('estimator', loop.estimator)} gives", _count(nh, "estimated state"), nh_why,
                 f"{_part('controller', loop.controller)} expects", _count(ctrl['in'][0], "state"), ctrl["in"][1])
    if "out" in ctrl and ctrl["out"][0] not in (SAME, m):
        mismatch(f"{_part('controller', loop.controller)} gives", _count(ctrl['out'][0], "input"), ctrl["out"][1],
                 f"{pname} has", _count(m, "input"), "")
    act = _sizes(loop.actuator)
    for key in ("in", "out"):
        if key in act and act[key][0] not in (SAME, m):
            mismatch(f"{_part('actuator', loop.actuator)} {'reads' if key == 'in' else 'gives'}",
                     _count(act[key][0], "input"), act[key][1], f"{pname} has", _count(m, "input"), "")


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
    sample = Sample(st.k, st.k.astype(st.x.dtype) * loop.dt, st.x, y, xhat, u, u_applied, Aux(a_sens, a_est, a_ctrl, a_act))
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
        if isinstance(a, jax.Array) and jnp.issubdtype(a.dtype, jnp.floating) and a.dtype != dtype:
            return a.astype(dtype)
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
