"""Continuous-time observers run by a sampled loop: RK4 sub-steps between two samples.

A continuous observer is ``xi' = rhs(params, xi, y(t), u)`` with ``y(t)`` the measurement and ``u`` the input. In
the loop, the estimator of period k receives ``(y_k, u_{k-1})`` at t_k. ``u_{k-1}`` is exactly the input the plant
received on [t_{k-1}, t_k) (zero-order hold), so the observer integrates that interval with ``u_{k-1}`` held and
``y`` reconstructed from the samples:

* ``hold="foh"`` (default): y(t) interpolated linearly between y_{k-1} and y_k. Both samples are known at t_k,
  so this is causal; it is the most faithful reconstruction of a smooth signal from its samples.
* ``hold="zoh"``: y_{k-1} held over the interval, i.e. the integration a real-time implementation does at
  t_{k-1} before y_k arrives (prediction form).

On the first sample (k = 0) there is no previous sample: the observer is initialised from y_0 by ``init_fn``
instead (positions from the measurement, velocities zero, bias estimates at their initial values).

The observer's output is what the controller reads (``out_fn(params, xi, y_k)``); for the reaction-wheel
observers it is a 4-vector shaped like the plant state, so the loop's estimation-error statistics apply.
"""

from __future__ import annotations

from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator
from jaxdip.sim.component import Component

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
        t = i * h
        k1 = rhs(params, x, y_at(t), u)
        k2 = rhs(params, x + 0.5 * h * k1, y_at(t + 0.5 * h), u)
        k3 = rhs(params, x + 0.5 * h * k2, y_at(t + 0.5 * h), u)
        k4 = rhs(params, x + h * k3, y_at(t + h), u)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return jax.lax.fori_loop(0, substeps, rk4, xi)


def sampled_observer(rhs: Callable, init_fn: Callable, out_fn: Callable, n_xi: int, n_y: int, dt: float,
                     substeps: int = 10, hold: str = "foh") -> Component:
    """Wrap a continuous observer as a loop estimator (state ``(xi, y_prev)``, input ``(y_k, u_{k-1})``).

    ``init_fn(params, y0) -> xi``; ``out_fn(params, xi, y) -> estimate``; ``n_xi``, ``n_y``: sizes of the
    observer state and of the measurement (static).
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")

    def init(params, key, x0):
        dtype = jnp.result_type(float)
        return jnp.zeros(n_xi, dtype), jnp.zeros(n_y, dtype)

    def step(params, state, inp, key, k):
        xi, y_prev = state
        y, u = inp
        y = jnp.asarray(y)
        u = jnp.reshape(jnp.asarray(u), (-1,))
        xi_int = integrate_interval(rhs, params, xi, y_prev, y, u, dt, substeps, hold)
        xi_new = jnp.where(k == 0, init_fn(params, y), xi_int)
        return (xi_new, y), out_fn(params, xi_new, y)

    return Component(init, step)


class SampledObserver(Estimator):
    """A continuous observer as an engine estimator: ``sampled_observer`` with the params as the subclass's fields.

    Subclasses give the old pure functions as ``staticmethod``s ``rhs(params, xi, y, u)``, ``init_xi(params, y)``
    and ``out(params, xi, y)`` and the sizes ``n_xi``, ``n_y`` as class attributes; their fields carry the old
    params NamedTuple's field names, so the module itself is passed as params. ``dt``, ``substeps`` and ``hold``
    are static. ``aux`` is the observer state xi after the step (velocity and bias estimates)."""

    dt: float = eqx.field(static=True)
    substeps: int = eqx.field(default=10, static=True, kw_only=True)
    hold: str = eqx.field(default="foh", static=True, kw_only=True)

    n_xi = 0
    n_y = 0

    def _component(self) -> Component:
        cls = type(self)
        return sampled_observer(cls.rhs, cls.init_xi, cls.out, cls.n_xi, cls.n_y, self.dt, self.substeps, self.hold)

    def init(self, key, x0):
        return self._component().init(self, key, x0)

    def step(self, state, y, u_prev, key, k):
        state, out = self._component().step(self, state, (y, u_prev), key, k)
        return state, out, state[0]
