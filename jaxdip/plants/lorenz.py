"""Lorenz system (thesis §1.6, eq. (1.28)): the test bed of the proximal-point MHE estimators.

    xL' = sigma (yL - xL)
    yL' = xL (rho - zL) - yL
    zL' = xL yL - beta zL

with sigma = 10, beta = 8/3, rho = 28 (chaotic). State ``[xL, yL, zL]``; the measurement is
y_k = C x(t_k) + noise with C = ``output_matrix()`` (yL and zL are measured, xL is not).

The system has no input. So that it plugs into the same closed loop, sensors and estimators as the controlled
plants, it declares one input, ``u_unused``, which ``f`` accepts and ignores (pass zeros).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant, param

from jaxdip._public import public_dir

# not listed: STATE_NAMES (the plant's state_names) and the equations whose names repeat in other plant modules
# (f, energy, output_matrix): each stays reachable here, one name per concept holds for what is listed
__all__ = ["equilibria", "Lorenz"]
__dir__ = public_dir(globals())

STATE_NAMES = ("xL", "yL", "zL")


def f(p: "Lorenz", x, u=None):
    """Eq. (1.28). ``u`` is ignored (the Lorenz system has no input)."""
    del u
    xl, yl, zl = x[0], x[1], x[2]
    return jnp.stack([p.sigma * (yl - xl), xl * (p.rho - zl) - yl, xl * yl - p.beta * zl])


def output_matrix():
    """C of the thesis: measures yL and zL."""
    return jnp.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def equilibria(p: "Lorenz"):
    """The three fixed points, one a row: the origin and (+-sqrt(beta (rho - 1)), same, rho - 1)."""
    c = jnp.sqrt(p.beta * (p.rho - 1.0))
    z = p.rho - 1.0
    return jnp.stack([jnp.zeros(3), jnp.stack([c, c, z]), jnp.stack([-c, -c, z])])


class Lorenz(Plant):
    """The Lorenz system, (sigma, beta, rho) as array fields; one unused input ``u_unused`` (module doc)."""

    sigma: jax.Array = param(10.0)
    beta: jax.Array = param(8.0 / 3.0)
    rho: jax.Array = param(28.0)

    state_names = STATE_NAMES
    input_names = ("u_unused",)

    def __check_init__(self):
        checks.check_physical(self, finite=("sigma", "beta", "rho"))

    def vector_field(self, x, u):
        return f(self, x, u)
