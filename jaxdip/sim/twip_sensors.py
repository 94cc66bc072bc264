"""The TWIP robot's sensors as simulated in Stumfoll §7.4 (Table 7.1).

Outputs one measurement per state of ``[x, x_dot, phi, phi_dot]`` (full state, docs/models.md), from three sensors:

* wheel encoders: the position quantised to ``encoder_quantum`` (0.000147 m: 64 counts x 30:1 gearbox, 90 mm
  wheels); the velocity is the backward difference of two quantised positions, (p_k - p_{k-1}) / dt, so its
  resolution is quantum / dt and it lags by dt / 2. At k = 0 there is no previous count and the velocity is 0.
* accelerometer tilt theta_a (36), simulated directly (as the thesis does) as phi + white noise + walking bias;
* gyroscope: phi_dot + white noise + walking bias;
* the tilt rate is the gyro reading itself. On the robot the tilt handed to the observer is the complementary
  filter (37) of the gyro rate and theta_a (``complementary_update``; ``jaxdip.estimators.complementary`` is the
  same filter as an estimator), and ``TwipSensors`` outputs that filtered tilt (``cf_alpha`` = 0: theta_a).

Both inertial errors follow (154)-(155): m = m_true + c + b + w with the constant bias c removed at start-up
(§4.3: the robot averages its first 100 readings at rest), w white of variance sigma^2 per sample, and b the
first-order Gauss-Markov walking bias of ``jaxdip.sim.sensors`` (driving noise intensity sigma_b^2, time
constant tau, discretised exactly). Because the start-up calibration absorbs whatever bias there was, the
walking bias starts at zero by default (``stationary_start=False``) and wanders from there.

Table 7.1 prints odd units; ``table_7_1`` documents the reading this library takes.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Sensor, param
from jaxdip.sim import sensors

from jaxdip._public import public_dir

__all__ = ["DEG", "TwipSensorState", "table_7_1", "complementary_update", "TwipSensors"]
__dir__ = public_dir(globals())

DEG = math.pi / 180.0


class TwipSensorState(NamedTuple):
    bias: jnp.ndarray  # walking biases of the raw channels
    p_prev: jnp.ndarray  # previous quantised position (for the velocity difference)


def table_7_1():
    """Table 7.1 in SI units, with the reading of its printed units that this library takes.

    Printed: tilt sigma_r^2 = 4.0397e-6 "rad", sigma_br^2 = 1.8929e-7 "rad/s", tau = 2160 s; gyro
    sigma_r^2 = 0.0012 "deg/s", sigma_br^2 = 1.0986e-4 "deg/s^2", tau = 1610 s. The entries are variances,
    so the units must be squares:

    * sigma_r^2 is the per-sample white-noise variance: rad^2 for the tilt (its 4.0397e-6 is the R_33 = 4e-6
      of (177), which confirms the reading) and (deg/s)^2 for the gyro (std 0.035 deg/s, the size of the
      MPU-9150's 0.06 deg/s-rms at 92 Hz; read as a standard deviation in deg/s it would be below the gyro's
      own 0.0076 deg/s resolution).
    * sigma_br^2 is the intensity of the white noise driving (155) ("w_br is white noise with variance
      sigma_br^2"): rad^2/s for the tilt and (deg/s)^2/s for the gyro. The stationary bias variances are then
      sigma_b^2 tau / 2: (0.82 deg)^2 and (0.30 deg/s)^2; over a 20 s run starting from zero the biases wander
      by about sqrt(sigma_b^2 t) = 0.11 deg and 0.047 deg/s.
    """
    return {
        "tilt_white_std": math.sqrt(4.0397e-6),  # rad
        "tilt_gm_sigma": math.sqrt(1.8929e-7),  # rad / sqrt(s)
        "tilt_gm_tau": 2160.0,  # s
        "gyro_white_std": math.sqrt(0.0012) * DEG,  # rad/s
        "gyro_gm_sigma": math.sqrt(1.0986e-4) * DEG,  # rad/s / sqrt(s)
        "gyro_gm_tau": 1610.0,  # s
        "encoder_quantum": 0.000147,  # m
    }


def complementary_update(theta, rate, angle, alpha, dt):
    """The complementary filter (37), one step from theta_{k-1} with the gyro rate and the accelerometer angle
    of sample k: theta_k = alpha (theta_{k-1} + rate dt) + (1 - alpha) angle (elementwise)."""
    return alpha * (theta + rate * dt) + (1.0 - alpha) * angle


class TwipSensors(Sensor):
    """The §7.4 sensors followed by the robot's complementary filter (37) on the tilt, as one engine sensor:
    the output is [p, v, theta_cf, gyro]_k. ``ideal`` = 1 hands out the true state instead (y = x, the noiseless
    studies), so noiseless and noisy loops share one structure. Fields: those of ``sensors.LinearSensor`` for the
    raw channels [p, unused, theta_a, gyro] (noise, walking bias, quantisation), the filter weight
    ``cf_alpha``; static: the period and the variants (walking biases from stationarity, straight-through
    encoder gradient, filter started at the first accelerometer angle).

    ``straight_through``: the encoder's value is quantised as always, but its derivative with respect to the
    true position is taken as 1 instead of the quantiser's almost-everywhere 0. The a.e. derivative is the
    exact derivative of each simulated path, yet it misses the jumps of the quantiser, which the Monte Carlo
    mean over seeds does feel (the twip-dmso gradient check measures a factor of about 2 on the DMSO's RMS
    error). With the straight-through rule the pathwise gradient is that of a quantiser whose error is
    uniform and independent of the position, which is what the quantisation error looks like once the wheel
    has crossed many counts."""

    C: jax.Array = param()
    white_std: jax.Array = param()
    const_bias: jax.Array = param()
    gm_sigma: jax.Array = param()
    gm_tau: jax.Array = param()
    quantum: jax.Array = param()
    cf_alpha: jax.Array = param(0.99)
    ideal: jax.Array = param(0.0)
    dt: float = eqx.field(default=0.01, static=True)
    stationary_start: bool = eqx.field(default=False, static=True)
    straight_through: bool = eqx.field(default=False, static=True)
    cf_init_from_angle: bool = eqx.field(default=True, static=True)

    def __check_init__(self):
        sensors.check_linear_sensor(self)
        checks.check_shape(self, "C", self.C, (4, 4), "(the raw channels [p, unused, theta_a, gyro] of the 4 states)")
        checks.check_ndim(self, "cf_alpha", self.cf_alpha, (0,), "a scalar")
        checks.check_finite(self, "cf_alpha", self.cf_alpha)

    def io_sizes(self) -> dict:
        return {"in": (4, "the TWIP's 4 states"), "out": (4, "[p, v, theta_cf, gyro]")}

    @classmethod
    def table_7_1(cls, dt: float, **kw) -> "TwipSensors":
        """Table 7.1 (``table_7_1``); ``kw`` overrides any of its entries or sets a field of this class."""
        t = {**table_7_1(), **{k: kw.pop(k) for k in list(kw) if k in table_7_1()}}
        z = 0.0
        raw = sensors.LinearSensor(
            jnp.eye(4), dt,
            white_std=jnp.array([z, z, t["tilt_white_std"], t["gyro_white_std"]]),
            gm_sigma=jnp.array([z, z, t["tilt_gm_sigma"], t["gyro_gm_sigma"]]),
            gm_tau=jnp.array([1.0, 1.0, t["tilt_gm_tau"], t["gyro_gm_tau"]]),
            quantum=jnp.array([t["encoder_quantum"], z, z, z]),
        )
        return cls(raw.C, raw.white_std, raw.const_bias, raw.gm_sigma, raw.gm_tau, raw.quantum, dt=dt, **kw)

    def init(self, key, x0):
        k_raw, _ = jax.random.split(key, 2)
        if self.stationary_start:
            std0 = sensors.gauss_markov_stationary_std(self.gm_sigma, self.gm_tau)
            b0 = std0 * jax.random.normal(k_raw, self.gm_sigma.shape)
        else:
            b0 = jnp.zeros_like(self.gm_sigma)
        return TwipSensorState(b0, jnp.zeros((), jnp.float64)), jnp.zeros((), jnp.float64)

    def step(self, state, x, key, k):
        (st, theta) = state
        k_raw, _ = jax.random.split(key, 2)
        k_white, k_bias = jax.random.split(k_raw)
        white = self.white_std * jax.random.normal(k_white, self.white_std.shape)
        m = sensors.quantize(self.C @ x + self.const_bias + st.bias + white, self.quantum)
        a, q_std = sensors.gauss_markov_coeffs(self.gm_sigma, self.gm_tau, self.dt)
        bias = a * st.bias + q_std * jax.random.normal(k_bias, st.bias.shape)
        p = m[0]
        if self.straight_through:
            p = x[0] + jax.lax.stop_gradient(p - x[0])
        v = jnp.where(k == 0, 0.0, (p - st.p_prev) / self.dt)
        theta = complementary_update(theta, m[3], m[2], self.cf_alpha, jnp.asarray(self.dt, jnp.float64))
        if self.cf_init_from_angle:
            theta = jnp.where(k == 0, m[2], theta)
        y = jnp.stack([p, v, theta, m[3]])
        return (TwipSensorState(bias, p), theta), jnp.where(self.ideal != 0, x, y), None
