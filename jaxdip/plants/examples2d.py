"""The two 2-D discrete-time examples of thesis §2.7 (relaxed projection control found by ensemble Kalman search).

* §2.7.1, linear, of the form (2.15):  x_{k+1} = A x_k + B u_k with
  A = [[.9974, .0539], [-.1078, 1.1591]], B = [.0013, .0539]^T  (open-loop unstable, controllable).
* §2.7.2, nonlinear, of the form (2.7): x_{k+1} = f(x_k) + g(x_k) u_k with
  f(x) = [2.2 sin(.5 x1) + .1 x2,  .1 x1^2 + 1.8 x2],  g(x) = [0, 2 + .1 cos(x2)].

Both are discrete plants (``step(x, u)``); their numbers are array fields.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import DiscretePlant, param

from jaxdip._public import public_dir

# not listed: STATE_NAMES (the plant's state_names) and the equations whose names repeat in other plant modules
# (f, energy, output_matrix): each stays reachable here, one name per concept holds for what is listed
__all__ = ["Linear", "Nonlinear"]
__dir__ = public_dir(globals())

STATE_NAMES = ("x1", "x2")


class Linear(DiscretePlant):
    """§2.7.1: x_{k+1} = A x_k + B u_k, B a 2x1 column."""

    A: jax.Array = param(((0.9974, 0.0539), (-0.1078, 1.1591)))
    B: jax.Array = param(((0.0013,), (0.0539,)))

    state_names = STATE_NAMES
    input_names = ("u",)

    def __check_init__(self):
        checks.check_shape(self, "A", self.A, (2, 2), "(the 2-state example)")
        checks.check_shape(self, "B", self.B, (2, 1), "(2 states, 1 input)")
        checks.check_physical(self, finite=("A", "B"))

    def step(self, x, u):
        return self.A @ x + self.B @ jnp.reshape(u, (-1,))


class Nonlinear(DiscretePlant):
    """§2.7.2: x_{k+1} = f(x) + g(x) u with f(x) = [a sin(w x1) + c x2, d x1^2 + e x2], g(x) = [0, g0 + g1 cos(x2)]."""

    a: jax.Array = param(2.2)
    w: jax.Array = param(0.5)
    c: jax.Array = param(0.1)
    d: jax.Array = param(0.1)
    e: jax.Array = param(1.8)
    g0: jax.Array = param(2.0)
    g1: jax.Array = param(0.1)

    state_names = STATE_NAMES
    input_names = ("u",)

    def __check_init__(self):
        for name in ("a", "w", "c", "d", "e", "g0", "g1"):
            checks.check_ndim(self, name, getattr(self, name), (0,), "a scalar")
        checks.check_physical(self, finite=("a", "w", "c", "d", "e", "g0", "g1"))

    def drift(self, x):
        """f(x) of §2.7.2."""
        x1, x2 = x[0], x[1]
        return jnp.stack([self.a * jnp.sin(self.w * x1) + self.c * x2, self.d * x1**2 + self.e * x2])

    def input_gain(self, x):
        """g(x) of §2.7.2 (a column, returned as a length-2 vector)."""
        x2 = x[1]
        return jnp.stack([jnp.zeros_like(x2), self.g0 + self.g1 * jnp.cos(x2)])

    def step(self, x, u):
        return self.drift(x) + self.input_gain(x) * jnp.reshape(u, (-1,))[0]
