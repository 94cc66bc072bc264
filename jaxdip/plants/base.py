"""The plant interface shared by every model.

A plant is a frozen bundle of pure functions over a parameter pytree, in the gymnax style: the same code
vmaps over seeds and over plant parameters. Continuous plants provide ``f(params, x, u) -> xdot``; discrete
plants provide ``step(params, x, u) -> x_next`` and leave ``f`` as None.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import jax.numpy as jnp


class Plant(NamedTuple):
    name: str
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    default_params: Callable[[], Any]
    f: Optional[Callable] = None  # continuous dynamics xdot = f(params, x, u)
    step: Optional[Callable] = None  # discrete map x_{k+1} = step(params, x, u)
    energy: Optional[Callable] = None  # total mechanical energy, where it is defined
    equilibrium: Optional[Callable[[Any], jnp.ndarray]] = None  # operating point (defaults to the origin)

    @property
    def n(self) -> int:
        return len(self.state_names)

    @property
    def m(self) -> int:
        return len(self.input_names)

    @property
    def continuous(self) -> bool:
        return self.f is not None

    def index(self, name: str) -> int:
        """Position of a state by name: weights and noise levels are mapped by name, never by position."""
        try:
            return self.state_names.index(name)
        except ValueError:
            raise KeyError(f"plant {self.name!r} has no state {name!r}; states are {self.state_names}") from None

    def x_eq(self, params) -> jnp.ndarray:
        if self.equilibrium is not None:
            return self.equilibrium(params)
        return jnp.zeros(self.n)
