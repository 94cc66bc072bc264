"""``FunctionPlant``: a plain JAX function as a plant of the engine, without writing a class.

A continuous vector field ``xdot = f(x, u)`` (integrated like every plant: RK4 sub-steps under a zero-order hold)
or a discrete map ``x_next = g(x, u)`` (one sample period), with the states' and inputs' names. Parameters the
function should be differentiable in go into ``params`` (any pytree of numbers), and the function then takes them
as its third argument: ``f(x, u, params)``. See docs/engine.md, "A plain function as a plant".
"""

from __future__ import annotations

from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Plant

from jaxdip._public import public_dir

__all__ = ["FunctionPlant"]
__dir__ = public_dir(globals())


def _names(names) -> tuple[str, ...]:
    return (names,) if isinstance(names, str) else tuple(names)


def _arrays(params):
    # numbers become arrays on construction, so they are traced (differentiable, sweepable) and never folded into
    # the compiled program as constants; eqx.tree_at and vmap may later put tracers here unchanged
    return None if params is None else jax.tree_util.tree_map(lambda v: jnp.array(v, dtype=jnp.asarray(v).dtype), params)


class FunctionPlant(Plant):
    """A plant from a plain function: ``FunctionPlant(f, state_names=("x", "phi", ...), input_names=("F",),
    params=None, discrete=False)``.

    ``f(x, u)`` (or ``f(x, u, params)`` when ``params`` is given) returns x' for a continuous plant and x_{k+1}
    for a discrete one (``discrete=True``: one sample period per call, ``dt`` and ``substeps`` unused). ``f``,
    the names and ``discrete`` are static (part of the compile-cache key: define ``f`` once, at module level,
    so repeated builds reuse the compiled loop); ``params`` is traced, so ``jax.grad`` and ``monte_carlo``'s
    sweeps reach it, e.g. ``eqx.tree_at(lambda p: p.params["l"], plant, 0.6)``. ``equilibrium()`` is the origin.
    """

    fn: Callable = eqx.field(static=True)
    state_names: tuple[str, ...] = eqx.field(static=True, converter=_names)
    params: Any = eqx.field(default=None, converter=_arrays)
    input_names: tuple[str, ...] = eqx.field(default=("u",), static=True, converter=_names)
    discrete: bool = eqx.field(default=False, static=True)

    def __check_init__(self):
        if not callable(self.fn):
            raise TypeError(f"FunctionPlant: fn must be a function f(x, u), got {type(self.fn).__name__}")
        for what, names in (("state_names", self.state_names), ("input_names", self.input_names)):
            if not names or not all(isinstance(s, str) for s in names) or len(set(names)) != len(names):
                raise ValueError(f"FunctionPlant: {what} must be distinct strings, one per {what[:-6]}, got {names}")

    @property
    def continuous(self) -> bool:  # type: ignore[override]  # a field here, a class attribute on Plant
        return not self.discrete

    def _f(self, x, u):
        return self.fn(x, u) if self.params is None else self.fn(x, u, self.params)

    def vector_field(self, x, u) -> jax.Array:
        if self.discrete:
            raise TypeError("FunctionPlant(discrete=True) is a map: it has step(x, u), not a vector field")
        return self._f(x, u)

    def step(self, x, u) -> jax.Array:
        """The discrete map's next state (``discrete=True`` only)."""
        if not self.discrete:
            raise TypeError("FunctionPlant(discrete=False) is a vector field: it has vector_field(x, u), not step")
        return self._f(x, u)

    def period(self, x, u, dt: float, substeps: int) -> jax.Array:
        if self.discrete:
            return self._f(x, jnp.asarray(u))
        return super().period(x, u, dt, substeps)  # RK4 sub-steps under a zero-order hold, as every plant
