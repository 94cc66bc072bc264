"""Sensor models: y = Q( C x + constant bias + walking bias + white noise ).

The walking bias is the first-order Gauss-Markov process of Stumfoll (155), db/dt = -b/tau + w_b with w_b
white of spectral density sigma_b^2. It is discretised exactly over the sample period dt:

    b_{k+1} = a b_k + sqrt(sigma_b^2 tau / 2 (1 - a^2)) xi_k,   a = exp(-dt / tau),

so its stationary variance is sigma_b^2 tau / 2 and its autocorrelation decays as exp(-|s| / tau) at any dt.
Q is a uniform quantiser with step ``quantum`` (0 disables it), the encoders' discretisation.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.keys import split_lanes
from jaxdip.engine.roles import Sensor, param
from jaxdip.sim.component import Component


class SensorParams(NamedTuple):
    C: jnp.ndarray  # (p, n) output matrix
    white_std: jnp.ndarray  # (p,) white noise standard deviation per output
    const_bias: jnp.ndarray  # (p,) constant offset
    gm_sigma: jnp.ndarray  # (p,) walking-bias driving-noise intensity sigma_b (0 disables)
    gm_tau: jnp.ndarray  # (p,) walking-bias time constant tau (s)
    quantum: jnp.ndarray  # (p,) quantisation step (0 disables)


def sensor_params(C, white_std=0.0, const_bias=0.0, gm_sigma=0.0, gm_tau=1.0, quantum=0.0) -> SensorParams:
    C = jnp.atleast_2d(jnp.asarray(C, dtype=jnp.float64))
    p = C.shape[0]

    def vec(v):
        return jnp.broadcast_to(jnp.asarray(v, dtype=jnp.float64), (p,))

    return SensorParams(C, vec(white_std), vec(const_bias), vec(gm_sigma), vec(gm_tau), vec(quantum))


def full_state_params(n, white_std=0.0, **kw) -> SensorParams:
    return sensor_params(jnp.eye(n), white_std, **kw)


def gauss_markov_coeffs(sigma_b, tau, dt):
    a = jnp.exp(-dt / tau)
    q_std = jnp.sqrt(sigma_b**2 * tau / 2.0 * (1.0 - a**2))
    return a, q_std


def gauss_markov_stationary_std(sigma_b, tau):
    return jnp.sqrt(sigma_b**2 * tau / 2.0)


def quantize(y, quantum):
    """Round to the nearest multiple of ``quantum``; identity where quantum is 0."""
    safe = jnp.where(quantum > 0, quantum, 1.0)
    return jnp.where(quantum > 0, safe * jnp.round(y / safe), y)


def linear_sensor(dt: float, stationary_start: bool = True) -> Component:
    """Sensor component; the walking bias starts from its stationary law (or at zero)."""

    def init(params: SensorParams, key, x0):
        std0 = gauss_markov_stationary_std(params.gm_sigma, params.gm_tau)
        b0 = std0 * jax.random.normal(key, params.gm_sigma.shape) if stationary_start else jnp.zeros_like(std0)
        return b0

    def step(params: SensorParams, bias, x, key, k):
        k_white, k_bias = jax.random.split(key)
        white = params.white_std * jax.random.normal(k_white, params.white_std.shape)
        y = quantize(params.C @ x + params.const_bias + bias + white, params.quantum)
        a, q_std = gauss_markov_coeffs(params.gm_sigma, params.gm_tau, dt)
        bias = a * bias + q_std * jax.random.normal(k_bias, bias.shape)
        return bias, y

    return Component(init, step)


class WhiteNoise(Sensor):
    """Full-state measurement with white Gaussian noise, y = x + std * xi (``std`` scalar or per state).

    The noise is drawn from the first half of ``split(key)``, as ``linear_sensor`` draws its white noise, so
    the two give identical measurements for the same key."""

    std: jax.Array = param()

    def step(self, state, x, key, k):
        k_white = split_lanes(key, 2)[0]
        return state, x + self.std * jax.random.normal(k_white, jnp.shape(x)), None


class LinearSensor(Sensor):
    """``linear_sensor`` as an engine sensor: ``SensorParams``' fields as array fields (build them with
    ``LinearSensor.of(sensor_params(...), dt)``), y = Q(C x + const_bias + walking bias + white noise).
    ``aux`` is the walking bias after the step. Numbers identical to ``linear_sensor(dt, stationary_start)``.
    ``straight_through=True`` differentiates the quantiser as the identity (values unchanged; why: the
    docstring of ``jaxdip.tune.objective``)."""

    C: jax.Array = param()
    white_std: jax.Array = param()
    const_bias: jax.Array = param()
    gm_sigma: jax.Array = param()
    gm_tau: jax.Array = param()
    quantum: jax.Array = param()
    dt: float = eqx.field(static=True)
    stationary_start: bool = eqx.field(default=True, static=True)
    straight_through: bool = eqx.field(default=False, static=True)

    @classmethod
    def of(cls, params: SensorParams, dt: float, stationary_start: bool = True,
           straight_through: bool = False) -> "LinearSensor":
        return cls(*params, dt=dt, stationary_start=stationary_start, straight_through=straight_through)

    def init(self, key, x0):
        return linear_sensor(self.dt, self.stationary_start).init(self, key, x0)

    def step(self, state, x, key, k):
        if not self.straight_through:
            state, y = linear_sensor(self.dt, self.stationary_start).step(self, state, x, key, k)
            return state, y, state
        raw = eqx.tree_at(lambda s: s.quantum, self, jnp.zeros_like(self.quantum))
        state, y_raw = linear_sensor(self.dt, self.stationary_start).step(raw, state, x, key, k)
        y_q = quantize(jax.lax.stop_gradient(y_raw), self.quantum)
        return state, y_raw + jax.lax.stop_gradient(y_q - y_raw), state
