"""Metrics as reducers over the periods of one trajectory: ``init`` / ``update`` / ``finalize``.

A reducer is an ``equinox.Module`` with

    state  = init(template)          # template: the Sample of one period as shapes (jax.ShapeDtypeStruct)
    state  = update(state, sample)   # one period
    result = finalize(state)         # a pytree of arrays

so long horizons need no stored trajectory. The engine calls ``update`` every period and keeps the old state
where the trajectory has failed (failure is decided after the period: the period that produced a bad state
is not counted), so every reducer counts the live periods only. ``Window`` restricts any reducer to a range of
period indices. Reducers compose as any pytree of them: ``metrics={"x": Moments("x"), "tail": Window(...)}``.

``of`` selects what a reducer sees: the name of a ``Sample`` field (``"x"``, ``"u"``, ``"xhat"``, ...) or a
function of the sample (``lambda s: s.xhat - s.x``). Names and module-level functions are hashable by value
or identity and so keep a compiled program reusable; a lambda written inside a builder is a new object per
call, which costs one compilation per build.
"""

from __future__ import annotations

import abc
from typing import Callable, Optional, Union

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import param

from jaxdip._public import public_dir

# not listed: init, update and finalize, the engine's own helpers over a pytree of reducers
__all__ = ["Selector", "Reducer", "Sum", "Moments", "RMS", "MaxAbs", "TimeToBand", "Window"]
__dir__ = public_dir(globals())

Selector = Union[str, Callable]


def _select(of: Selector, sample):
    return getattr(sample, of) if isinstance(of, str) else of(sample)


def _zeros(of: Selector, template, dtype=None):
    s = jax.eval_shape(lambda t: _select(of, t), template)
    if dtype is None:  # a float64 or float32 loop's own dtype; counters (k) accumulate as floats
        dtype = s.dtype if jnp.issubdtype(s.dtype, jnp.floating) else jnp.result_type(float)
    return jnp.zeros(s.shape, dtype)


_SAMPLE_FIELDS = ("k", "t", "x", "y", "xhat", "u", "u_applied", "aux")  # the fields of ``simulate.Sample``


class Reducer(eqx.Module):
    def __check_init__(self):
        # a misspelt field name would otherwise surface as an AttributeError deep inside the traced loop
        of = getattr(self, "of", None)
        if of is not None and not callable(of) and of not in _SAMPLE_FIELDS:
            checks.fail(self, f"of must be a Sample field {_SAMPLE_FIELDS} or a function of the sample, got {of!r}")

    @abc.abstractmethod
    def init(self, template):
        ...

    @abc.abstractmethod
    def update(self, state, sample):
        ...

    @abc.abstractmethod
    def finalize(self, state):
        ...


def _count(c):
    # periods counted, at least one, so a trajectory that failed at once gives zeros instead of NaN
    return jnp.maximum(c, 1)


class Sum(Reducer):
    """Sum over the live periods (a cost: pass ``of=lambda s: dt * stage_cost(s.x, s.u)``)."""

    of: Selector = eqx.field(static=True)

    def init(self, template):
        return _zeros(self.of, template)

    def update(self, state, sample):
        return state + _select(self.of, sample)

    def finalize(self, state):
        return state


class Moments(Reducer):
    """Time moments per component: ``count``, ``mean``, ``var``, ``mean_abs``, ``var_abs`` (the variance of
    |v|), ``mean_sq``. Computed from running sums as sum/count, and var = mean_sq - mean^2."""

    of: Selector = eqx.field(static=True)

    def init(self, template):
        z = _zeros(self.of, template)
        return (jnp.zeros((), jnp.int32), z, z, z)

    def update(self, state, sample):
        c, s1, s2, sa = state
        v = _select(self.of, sample)
        return (c + 1, s1 + v, s2 + v**2, sa + jnp.abs(v))

    def finalize(self, state):
        c, s1, s2, sa = state
        n = _count(c)
        mean, msq, mabs = s1 / n, s2 / n, sa / n
        return {"count": c, "mean": mean, "var": msq - mean**2, "mean_abs": mabs, "var_abs": msq - mabs**2,
                "mean_sq": msq}


class RMS(Reducer):
    """Root mean square over the live periods, per component (e.g. ``of=lambda s: s.xhat - s.x``)."""

    of: Selector = eqx.field(static=True)

    def init(self, template):
        return (jnp.zeros((), jnp.int32), _zeros(self.of, template))

    def update(self, state, sample):
        c, s2 = state
        return (c + 1, s2 + _select(self.of, sample) ** 2)

    def finalize(self, state):
        c, s2 = state
        return jnp.sqrt(s2 / _count(c))


class MaxAbs(Reducer):
    """Largest |v| over the live periods, per component (0 if none was counted)."""

    of: Selector = eqx.field(static=True)

    def init(self, template):
        return _zeros(self.of, template)

    def update(self, state, sample):
        return jnp.maximum(state, jnp.abs(_select(self.of, sample)))

    def finalize(self, state):
        return state


class TimeToBand(Reducer):
    """When |v| enters ``band`` for good, per component.

    ``step``: the first period index from which |v| <= band at every counted period (0 if always inside);
    ``settled``: whether |v| was inside at the last counted period. Multiply ``step`` by ``dt`` for a time.
    """

    of: Selector = eqx.field(static=True)
    band: jax.Array = param(0.0)

    def __check_init__(self):
        checks.check_nonnegative(self, "band", self.band)

    def init(self, template):
        z = _zeros(self.of, template, jnp.int32) - 1
        return (z, jnp.full((), -1, jnp.int32))

    def update(self, state, sample):
        last_out, _ = state
        outside = jnp.abs(_select(self.of, sample)) > self.band
        return (jnp.where(outside, sample.k, last_out), jnp.asarray(sample.k, jnp.int32))

    def finalize(self, state):
        last_out, last_k = state
        return {"step": last_out + 1, "settled": last_out < last_k}


class Window(Reducer):
    """``reducer`` restricted to the periods ``start <= k < stop`` (absolute period indices, so a run split
    into chunks sees the same window; ``stop=None``: to the end)."""

    reducer: Reducer
    start: int = eqx.field(default=0, static=True)
    stop: Optional[int] = eqx.field(default=None, static=True)

    def __check_init__(self):
        if not isinstance(self.reducer, Reducer):
            raise checks.ArgumentTypeError(f"Window: reducer must be a metrics reducer, got {type(self.reducer).__name__}")
        # period indices are static (the window is part of the compiled program): Python integers. A negative
        # start is allowed: ``start=n - tail`` with a tail longer than a short run counts every period
        checks.check_int(self, "start", self.start)
        if self.stop is not None:
            checks.check_int(self, "stop", self.stop)
        if self.stop is not None and not self.stop > self.start:
            checks.fail(self, f"stop must be > start={self.start} (or None: to the end), got {self.stop}")

    def init(self, template):
        return self.reducer.init(template)

    def update(self, state, sample):
        new = self.reducer.update(state, sample)
        inside = sample.k >= self.start
        if self.stop is not None:
            inside = inside & (sample.k < self.stop)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(inside, a, b), new, state)

    def finalize(self, state):
        return self.reducer.finalize(state)


# ---- a pytree of reducers -----------------------------------------------------------------------------------


def _is_reducer(x) -> bool:
    return isinstance(x, Reducer)


def init(metrics, template):
    return jax.tree_util.tree_map(lambda r: r.init(template), metrics, is_leaf=_is_reducer)


def update(metrics, states, sample, live):
    """One period of every reducer; where ``live`` is false the old states are kept."""
    if metrics is None:
        return states

    def one(r, s):
        new = r.update(s, sample)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(live, a, b), new, s)

    return jax.tree_util.tree_map(one, metrics, states, is_leaf=_is_reducer)


def finalize(metrics, states):
    if metrics is None:
        return None
    return jax.tree_util.tree_map(lambda r, s: r.finalize(s), metrics, states, is_leaf=_is_reducer)
