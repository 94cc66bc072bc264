"""Continuous-time observers run by a sampled loop: RK4 sub-steps between two samples.

A continuous observer is ``xi' = rhs(params, xi, y(t), u)`` with ``y(t)`` the measurement and ``u`` the input. In
the loop, the estimator of period k receives ``(y_k, u_{k-1})`` at t_k. ``u_{k-1}`` is exactly the input the plant
received on [t_{k-1}, t_k) (zero-order hold), so the observer integrates that interval with ``u_{k-1}`` held and
``y`` reconstructed from the samples:

* ``hold="foh"`` (default): y(t) interpolated linearly between y_{k-1} and y_k. Both samples are known at t_k,
  so this is causal; it is the most faithful reconstruction of a smooth signal from its samples.
* ``hold="zoh"``: y_{k-1} held over the interval, i.e. the integration a real-time implementation does at
  t_{k-1} before y_k arrives (prediction form).

On the first sample (k = 0) there is no previous sample: the observer is initialised from y_0 by ``init_xi``
instead (positions from the measurement, velocities zero, bias estimates at their initial values).

The observer's output is what the controller reads (``out(obs, xi, y_k)``); for the reaction-wheel
observers it is a 4-vector shaped like the plant state, so the loop's estimation-error statistics apply.
"""

from __future__ import annotations

import functools
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, dtype_of

from jaxdip._public import public_dir

__all__ = ["HOLDS", "integrate_interval", "SampledObserver"]
__dir__ = public_dir(globals())

HOLDS = ("foh", "zoh")


def integrate_interval(rhs: Callable, params, xi, y0, y1, u, dt: float, substeps: int, hold: str = "foh"):
    """Integrate ``xi' = rhs(params, xi, y(t), u)`` over one period [0, dt] with RK4 sub-steps.

    ``y(t) = y0 + (t/dt)(y1 - y0)`` for ``hold="foh"``, ``y(t) = y0`` for ``hold="zoh"``.
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    h = dt / substeps
    dy = (y1 - y0) if hold == "foh" else jnp.zeros_like(y0)

    def y_at(t):
        return y0 + (t / dt) * dy

    def rk4(i, x):
        t = i.astype(x.dtype) * h  # an int32 index times a Python float would be float64
        k1 = rhs(params, x, y_at(t), u)
        k2 = rhs(params, x + 0.5 * h * k1, y_at(t + 0.5 * h), u)
        k3 = rhs(params, x + 0.5 * h * k2, y_at(t + 0.5 * h), u)
        k4 = rhs(params, x + h * k3, y_at(t + h), u)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return jax.lax.fori_loop(0, substeps, rk4, xi)


@functools.lru_cache(maxsize=None)
def _program(rhs: Callable) -> Callable:
    # an observer class's rhs (a module-level function) as a program of its own: RK4 calls it four times a
    # sub-step, and each call would trace its Python again; traced once per shapes, inlined by XLA (the same
    # compiled code), as the plants' right-hand sides are (jaxdip.engine.roles.rhs)
    return eqx.filter_jit(rhs)


class SampledObserver(Estimator):
    """A continuous observer as an engine estimator, state ``(xi, y_prev)``.

    Subclasses give the observer's pure functions as ``staticmethod``s ``rhs(obs, xi, y, u)``, ``init_xi(obs, y0)``
    (the state from the first sample) and ``out(obs, xi, y)`` (the estimate), called with the observer itself,
    whose fields are the gains, and the sizes ``n_xi`` (observer state) and ``n_y`` (measurement) as class
    attributes. ``dt``, ``substeps`` and ``hold`` are static. ``aux`` is the observer state xi after the step
    (velocity and bias estimates)."""

    dt: float = eqx.field(static=True)
    substeps: int = eqx.field(default=10, static=True, kw_only=True)
    hold: str = eqx.field(default="foh", static=True, kw_only=True)

    n_xi = 0
    n_y = 0

    def __check_init__(self):
        checks.check_choice(self, "hold", self.hold, HOLDS)
        checks.check_int(self, "substeps", self.substeps, 1)
        checks.check_positive(self, "dt", self.dt)

    def io_sizes(self) -> dict:
        cls = type(self)
        return {"in": (cls.n_y, f"{cls.__name__} reads {cls.n_y} values")} if cls.n_y else {}

    def init(self, key, x0):
        dtype = dtype_of(x0)  # the loop's: float32 in a float32 loop
        return jnp.zeros(self.n_xi, dtype), jnp.zeros(self.n_y, dtype)

    def step(self, state, y, u_prev, key, k):
        cls = type(self)
        xi, y_prev = state
        y = jnp.asarray(y)
        u = jnp.reshape(jnp.asarray(u_prev), (-1,))
        xi_int = integrate_interval(_program(cls.rhs), self, xi, y_prev, y, u, self.dt, self.substeps, self.hold)
        xi_new = jnp.where(k == 0, cls.init_xi(self, y), xi_int)
        return (xi_new, y), cls.out(self, xi_new, y), xi_new
