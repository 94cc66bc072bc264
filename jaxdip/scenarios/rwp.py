"""The reaction-wheel pendulum loop of Aranovskiy et al. (plant (2)-(3), Table 1, current input, 500 Hz, the
Table 1 angle quantisation, law (8)/(23) with the Table 2 gains) around any observer, as engine objects.

Shared by the ``rwp-bias`` experiment and the ``rwp`` tuning target. The sensor measures [theta + d, theta_r]
(with ``measured_velocities``: [theta + d, theta_r, theta', theta_r'], the setting of Proposition 2); the
controller is u = -K xhat with K = [k1, k2, 0, k3] on the observer's output [y - d̂, θ̂', θ̂_r, θ̂_r']; the
actuator clips the current at ``current_limit`` (``observer_current="applied"``: the controller clips it, so the
observers' models see the clipped current; by default they see the law's); the trajectory fails once
|theta| > pi/2.

Initial states (``RWPStart``): theta(0) = theta0 plus the pendulum encoder's quantisation phase U(-q/2, q/2),
theta_r(0) ~ U(0, q_r) (the wheel encoder's phase), Gaussian initial velocities. ``theta0`` is a field, so a
set of initial angles is one ``monte_carlo`` sweep.
"""

from __future__ import annotations

import math
from typing import Any, Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.control.feedback import SaturatedFeedback, StateFeedback
from jaxdip.engine import Loop, Rollout, param
from jaxdip.engine.metrics import Sum
from jaxdip.plants import rwp
from jaxdip.plants.rwp import RWP
from jaxdip.sim.actuators import Saturation
from jaxdip.sim.sensors import LinearSensor

INF = float("inf")
REC = {name: i for i, name in enumerate(["theta", "theta_dot", "thetar_dot", "y", "theta_hat", "xp2", "xr2", "I"])}


class RWPStart(eqx.Module):
    """x0 = [theta0 + qp (U - 1/2), sv N, qr U, svr N] (four independent draws from the key)."""

    theta0: jax.Array = param()
    # (std of theta', std of theta_r'): static Python floats on purpose. As constants XLA folds them into the
    # normal sampler's own scale factor; as traced arrays the product rounds differently in the last bit, and
    # the quantised, oscillating bias runs amplify that to ~1e-4 in rwp-bias's results.
    velocity_std: tuple = eqx.field(static=True, converter=lambda v: tuple(float(a) for a in v))

    def __call__(self, key):
        qp, qr = rwp.PENDULUM_ANGLE_RESOLUTION, rwp.WHEEL_ANGLE_RESOLUTION
        k1, k2, k3, k4 = jax.random.split(key, 4)
        th = self.theta0 + qp * (jax.random.uniform(k1) - 0.5)
        thr = qr * jax.random.uniform(k2)
        sv, svr = self.velocity_std
        return jnp.stack([th, sv * jax.random.normal(k3), thr, svr * jax.random.normal(k4)])


def sensor(dt: float, d: float = 0.0, measured_velocities: bool = False, quantize: bool = True,
           straight_through: bool = False) -> LinearSensor:
    """The angle encoders (Table 1 resolutions when ``quantize``) with the pendulum angle offset by ``d``;
    ``straight_through``: differentiate the quantiser as the identity (for tuning)."""
    if measured_velocities:
        Cm = jnp.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
        bias = jnp.array([d, 0.0, 0.0, 0.0])
        q = [rwp.PENDULUM_ANGLE_RESOLUTION, rwp.WHEEL_ANGLE_RESOLUTION, 0.0, 0.0]
    else:
        Cm = jnp.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
        bias = jnp.array([d, 0.0])
        q = [rwp.PENDULUM_ANGLE_RESOLUTION, rwp.WHEEL_ANGLE_RESOLUTION]
    return LinearSensor(Cm, dt, const_bias=bias, quantum=q if quantize else 0.0, straight_through=straight_through)


def loop(estimator: Any, *, dt: float = rwp.DT, substeps: int = 10, K: Sequence[float] = rwp.K_TABLE2,
         d: float = 0.0, current_limit: float = INF, measured_velocities: bool = False, quantize: bool = True,
         straight_through: bool = False, observer_current: str = "commanded") -> Loop:
    """The closed loop around ``estimator`` (an engine estimator with output [y - d̂, θ̂', θ̂_r, θ̂_r']).
    ``observer_current``: "commanded" (the estimator is given the law's current u_{k-1}) or "applied" (the
    clipped current: the limit moves into the controller)."""
    k1, k2, k3 = K
    gain = jnp.array([[k1, k2, 0.0, k3]])
    if observer_current == "applied":
        ctrl = SaturatedFeedback(gain, jnp.array([-current_limit]), jnp.array([current_limit]))
    elif observer_current == "commanded":
        ctrl = StateFeedback(gain)
    else:
        raise ValueError(f"observer_current: 'commanded' or 'applied', got {observer_current!r}")
    return Loop(
        plant=RWP(),
        sensor=sensor(dt, d, measured_velocities, quantize, straight_through),
        estimator=estimator,
        controller=ctrl,
        actuator=Saturation(jnp.array([-current_limit]), jnp.array([current_limit])),
        dt=dt,
        substeps=substeps,
        state_bound=jnp.array([math.pi / 2, INF, INF, INF]),
    )


def record(s):
    """Per saved period: theta, theta', theta_r', y_0, the output's angle, x̂_p2, x̂_r2, I (``REC`` names them)."""
    return jnp.stack([s.x[0], s.x[1], s.x[3], s.y[0], s.xhat[0], s.xhat[1], s.xhat[3], s.u[0]])


def x_squared(s):
    return s.x**2


def rollout(estimator: Any, *, steps: int, theta0: float = 0.1, velocity_std: Sequence[float] = (0.01, 0.1),
            save_every: Optional[int] = None, **loop_kw) -> Rollout:
    """One trial: ``loop(estimator, **loop_kw)`` from ``RWPStart(theta0, velocity_std)`` over ``steps``
    periods; with ``save_every``, ``record`` every ``save_every`` periods. Metric ``"x2"``: the sum of x^2
    over the live periods (a quadratic cost)."""
    lp = loop(estimator, **loop_kw)
    x0 = RWPStart(theta0, velocity_std)
    metrics = {"x2": Sum(x_squared)}
    if save_every is None:
        return Rollout(lp, x0, steps, metrics=metrics)
    return Rollout(lp, x0, steps, save=record, save_every=save_every, metrics=metrics)
