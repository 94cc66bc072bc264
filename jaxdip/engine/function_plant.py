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
import numpy as np

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant

from jaxdip._public import public_dir

__all__ = ["FunctionPlant"]
__dir__ = public_dir(globals())


def _names(what: str) -> Callable[[Any], tuple]:
    # a converter per field, so that a number where names go is refused naming the field (checked further in
    # ``__check_init__``, which sees the tuple)
    def convert(names) -> tuple:
        if isinstance(names, str):
            return (names,)
        try:
            return tuple(names)
        except TypeError:
            raise checks.ArgumentTypeError(f"FunctionPlant: {what} must be a string or a sequence of strings, "
                                           f"got {names!r}") from None
    return convert


def _arrays(params):
    # numbers become arrays on construction, so they are traced (differentiable, sweepable) and never folded into
    # the compiled program as constants; eqx.tree_at and vmap may later put tracers here unchanged
    if params is None:
        return None
    for path, v in jax.tree_util.tree_flatten_with_path(params)[0]:
        checks.check_real("FunctionPlant", f"params{jax.tree_util.keystr(path)}", v)
    return jax.tree_util.tree_map(lambda v: jnp.array(v, dtype=jnp.asarray(v).dtype), params)


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
    state_names: tuple[str, ...] = eqx.field(static=True, converter=_names("state_names"))
    params: Any = eqx.field(default=None, converter=_arrays)
    input_names: tuple[str, ...] = eqx.field(default=("u",), static=True, converter=_names("input_names"))
    discrete: bool = eqx.field(default=False, static=True)

    def __check_init__(self):
        if not callable(self.fn):
            raise checks.ArgumentTypeError(f"FunctionPlant: fn must be a function f(x, u), "
                                           f"got {type(self.fn).__name__}")
        if not isinstance(self.discrete, (bool, np.bool_)):
            raise checks.ArgumentTypeError(f"FunctionPlant: discrete must be True or False, got {self.discrete!r}")
        for what, names in (("state_names", self.state_names), ("input_names", self.input_names)):
            one = what[:-6]
            if not names:
                checks.fail(self, f"{what} must name at least one {one}, got {names}")
            if not all(isinstance(s, str) for s in names):
                raise checks.ArgumentTypeError(f"FunctionPlant: {what} must be strings, one per {one}, got {names}")
            if not all(s.strip() for s in names):
                checks.fail(self, f"{what} must be non-empty strings, got {names}")
            if len(set(names)) != len(names):
                dup = sorted({s for s in names if names.count(s) > 1})
                checks.fail(self, f"{what} must be distinct, one per {one}, got {names} ({', '.join(dup)} repeated)")

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
