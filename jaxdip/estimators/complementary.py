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
The update itself (``complementary_update``) lives with the TWIP's sensors, which apply it on the robot.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import SAME, Estimator, param
from jaxdip.sim.twip_sensors import complementary_update


from jaxdip._public import public_dir

__all__ = ["ComplementaryFilter"]
__dir__ = public_dir(globals())


class ComplementaryFilter(Estimator):
    """(37) applied inside a measurement vector: channel ``angle_index`` (theta_a) is replaced by the filtered
    tilt, using channel ``rate_index`` (the gyro) as the rate; other channels pass unchanged. State:
    theta_{k-1} (zero at start); ``aux`` is theta_k. Fields: the weight ``alpha`` and the period ``dt``."""

    alpha: jax.Array = param(0.99)  # weight of the integrated gyro path
    dt: jax.Array = param(0.01)  # sample period (s)
    angle_index: int = eqx.field(default=2, static=True)
    rate_index: int = eqx.field(default=3, static=True)
    init_from_angle: bool = eqx.field(default=True, static=True)

    def __check_init__(self):
        checks.check_ndim(self, "alpha", self.alpha, (0,), "a scalar")
        checks.check_finite(self, "alpha", self.alpha)
        checks.check_positive(self, "dt", self.dt)
        checks.check_int(self, "angle_index", self.angle_index, 0)
        checks.check_int(self, "rate_index", self.rate_index, 0)

    def io_sizes(self) -> dict:
        return {"out": (SAME, "the measurement with the tilt filtered")}

    def init(self, key, x0):
        return jnp.zeros((), dtype=jnp.float64)

    def step(self, state, y, u_prev, key, k):
        angle = y[self.angle_index]
        theta = complementary_update(state, y[self.rate_index], angle, self.alpha, self.dt)
        if self.init_from_angle:
            theta = jnp.where(k == 0, angle, theta)
        return theta, y.at[self.angle_index].set(theta), theta
