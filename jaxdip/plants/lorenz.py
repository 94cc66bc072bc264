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

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Plant as EnginePlant
from jaxdip.engine.roles import param
from jaxdip.plants.base import Plant

STATE_NAMES = ("xL", "yL", "zL")


class LorenzParams(NamedTuple):
    sigma: float = 10.0
    beta: float = 8.0 / 3.0
    rho: float = 28.0


def default_params() -> LorenzParams:
    return LorenzParams()


def f(p: LorenzParams, x, u=None):
    """Eq. (1.28). ``u`` is ignored (the Lorenz system has no input)."""
    del u
    xl, yl, zl = x[0], x[1], x[2]
    return jnp.stack([p.sigma * (yl - xl), xl * (p.rho - zl) - yl, xl * yl - p.beta * zl])


def output_matrix():
    """C of the thesis: measures yL and zL."""
    return jnp.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def equilibria(p: LorenzParams):
    """The three fixed points, one a row: the origin and (+-sqrt(beta (rho - 1)), same, rho - 1)."""
    c = jnp.sqrt(p.beta * (p.rho - 1.0))
    z = p.rho - 1.0
    return jnp.stack([jnp.zeros(3), jnp.stack([c, c, z]), jnp.stack([-c, -c, z])])


def make() -> Plant:
    return Plant(
        name="lorenz",
        state_names=STATE_NAMES,
        input_names=("u_unused",),
        default_params=default_params,
        f=f,
    )


_D = LorenzParams()._asdict()


class Lorenz(EnginePlant):
    """The Lorenz system as an engine plant: ``LorenzParams``' fields as array fields, same equations as ``f``.
    One unused input ``u_unused`` (see the module docstring)."""

    sigma: jax.Array = param(_D["sigma"])
    beta: jax.Array = param(_D["beta"])
    rho: jax.Array = param(_D["rho"])

    state_names = STATE_NAMES
    input_names = ("u_unused",)

    def vector_field(self, x, u):
        # the module has LorenzParams' field names, so it stands in for a LorenzParams
        return f(self, x, u)
