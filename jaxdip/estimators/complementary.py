"""Complementary filter for a tilt angle from a gyroscope and an accelerometer (Stumfoll §4.3.1, eq. (37)).

    (37)  theta_k = alpha (theta_{k-1} + g_k dt) + (1 - alpha) theta_a,k

g_k is the gyroscope's rate and theta_a,k the accelerometer's tilt (36), both read at sample k; alpha = 0.99 on
the robot. The gyro path is integrated and high-passed, the accelerometer path low-passed, with the same pole
alpha, so the two transfer functions add up to the identity: a noiseless, bias-free pair (g = true rate,
theta_a = true angle) of a ramp is reproduced exactly. Properties the tests check:

* a constant angle with zero rate is approached as theta_k - theta_a = alpha^k (theta_0 - theta_a);
* a constant gyro bias b gives the steady offset alpha b dt / (1 - alpha);
* white noise of variance s^2 on theta_a gives stationary variance s^2 (1 - alpha) / (1 + alpha).

Initialisation (the thesis does not say): with ``init_from_angle`` (the default) the first output is the first
accelerometer angle, as a robot started at rest would set it; otherwise the filter starts from theta = 0 and
(37) is applied from the first sample on (its time constant is dt alpha / (1 - alpha), about 1 s at 10 ms).
Works elementwise on arrays of channels.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from jaxdip.sim.component import Component


class ComplementaryParams(NamedTuple):
    alpha: jnp.ndarray  # weight of the integrated gyro path (0.99)
    dt: jnp.ndarray  # sample period (s)


def complementary_params(alpha=0.99, dt=0.01) -> ComplementaryParams:
    return ComplementaryParams(jnp.asarray(alpha, dtype=jnp.float64), jnp.asarray(dt, dtype=jnp.float64))


def complementary_update(theta, rate, angle, alpha, dt):
    """(37): one filter step from theta_{k-1} with the gyro rate and the accelerometer angle of sample k."""
    return alpha * (theta + rate * dt) + (1.0 - alpha) * angle


def complementary_filter(init_from_angle: bool = True, size: int | None = None) -> Component:
    """Loop component: input ``(rate, angle)`` of sample k, output theta_k. State: theta_{k-1}."""

    def init(params: ComplementaryParams, key, x0):
        return jnp.zeros(() if size is None else (size,), dtype=jnp.float64)

    def step(params: ComplementaryParams, theta, inp, key, k):
        rate, angle = inp
        new = complementary_update(theta, rate, angle, params.alpha, params.dt)
        if init_from_angle:
            new = jnp.where(k == 0, angle, new)
        return new, new

    return Component(init, step)


def tilt_prefilter(angle_index: int = 2, rate_index: int = 3, init_from_angle: bool = True) -> Component:
    """(37) applied inside a measurement vector: channel ``angle_index`` (theta_a) is replaced by the filtered
    tilt, using channel ``rate_index`` (the gyro) as the rate; other channels pass unchanged.

    Chain it after a sensor (``jaxdip.sim.component.chain``) to reproduce the robot's pre-filtering (§4.3.1).
    """
    cf = complementary_filter(init_from_angle)

    def init(params: ComplementaryParams, key, x0):
        return cf.init(params, key, x0)

    def step(params: ComplementaryParams, theta, y, key, k):
        theta, out = cf.step(params, theta, (y[rate_index], y[angle_index]), key, k)
        return theta, y.at[angle_index].set(out)

    return Component(init, step)
