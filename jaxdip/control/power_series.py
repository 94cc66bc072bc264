"""Power-series (Garrard) control: thesis (3.5), paper (8).

For xdot = f(x) + B u with f(x) = A x + f_3(x) + O(|x|^5) (the DIP's f is odd, so there is no f_2),
the third-order approximation of the HJB solution gives

    u = -R^-1 B^T [ P x - (A^T - P B R^-1 B^T)^-1 P f_3(x) ],

P the CARE solution. f_3 is obtained by autodiff, never by hand expansion: with phi(t) = f(t x),
f_3(x) = phi'''(0) / 6 (three nested forward derivatives along x). Its linear part is the LQR gain.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxdip.control.riccati import care
from jaxdip.engine import checks
from jaxdip.engine.roles import Controller, Plant, linearize, param, rhs


from jaxdip._public import public_dir

__all__ = ["third_order_term", "PowerSeries"]
__dir__ = public_dir(globals())


def third_order_term(f, x):
    """f_3(x) = (1/6) d^3/dt^3 f(t x) at t = 0, for f: R^n -> R^n (x is the expansion's displacement)."""

    def phi(t):
        return f(t * x)

    one = jnp.ones((), x.dtype)  # a tangent of t's dtype (jvp refuses a float64 one for a float32 x)
    d1 = lambda t: jax.jvp(phi, (t,), (one,))[1]
    d2 = lambda t: jax.jvp(d1, (t,), (one,))[1]
    d3 = lambda t: jax.jvp(d2, (t,), (one,))[1]
    return d3(jnp.zeros((), dtype=x.dtype)) / 6.0


def _law(drift, p, x):
    f3 = third_order_term(drift, x)
    BRB = p.B @ jnp.linalg.solve(p.R, p.B.T)
    corr = jnp.linalg.solve(p.A.T - p.P @ BRB, p.P @ f3)
    return -jnp.linalg.solve(p.R, p.B.T @ (p.P @ x - corr))


class PowerSeries(Controller):
    """The power-series law (3.5) as an engine controller: P, A, B, R as array fields, with ``plant`` the
    controller's model of the plant (an engine ``Plant``, e.g. ``jaxdip.plants.DIP()``; its numbers are leaves too).
    ``PowerSeries.design(plant, Q, R)`` solves the CARE on the plant's linearisation at its equilibrium."""

    P: jax.Array = param()
    A: jax.Array = param()
    B: jax.Array = param()
    R: jax.Array = param()
    plant: Any

    def __check_init__(self):
        if not isinstance(self.plant, Plant):
            raise checks.ArgumentTypeError(f"PowerSeries: plant must be a jaxdip Plant, got {type(self.plant).__name__}")
        n, m = self.plant.n, self.plant.m
        why = f"for the plant {type(self.plant).__name__} ({n} states, {m} inputs)"
        checks.check_covariance(self, "P", self.P, n, why)
        checks.check_shape(self, "A", self.A, (n, n), why)
        checks.check_shape(self, "B", self.B, (n, m), why)
        checks.check_covariance(self, "R", self.R, m, why, definite=True)
        checks.check_finite(self, "A", self.A)
        checks.check_finite(self, "B", self.B)

    def io_sizes(self) -> dict:
        why = f"its plant model {type(self.plant).__name__}"
        return {"in": (self.plant.n, why), "out": (self.plant.m, why)}

    @classmethod
    def design(cls, plant, Q, R) -> "PowerSeries":
        A, B = linearize(plant)
        R = jnp.atleast_2d(jnp.asarray(R, dtype=jnp.float64))
        return cls(care(A, B, Q, R), A, B, R, plant)

    def step(self, state, xhat, key, k):
        m = self.plant.m
        return state, _law(lambda z: rhs(self.plant, z, jnp.zeros(m, xhat.dtype)), self, xhat), None
