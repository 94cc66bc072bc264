"""Sensor models: y = Q( C x + constant bias + walking bias + white noise ).

The walking bias is the first-order Gauss-Markov process of Stumfoll (155), db/dt = -b/tau + w_b with w_b
white of spectral density sigma_b^2. It is discretised exactly over the sample period dt:

    b_{k+1} = a b_k + sqrt(sigma_b^2 tau / 2 (1 - a^2)) xi_k,   a = exp(-dt / tau),

so its stationary variance is sigma_b^2 tau / 2 and its autocorrelation decays as exp(-|s| / tau) at any dt.
Q is a uniform quantiser with step ``quantum`` (0 disables it), the encoders' discretisation.

``Dropout`` wraps any sensor and loses samples (a dropped packet, a missed read): a lost reading is NaN, which
the Kalman-type estimators treat as missing with ``nan_missing=True``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from typing import Any, Optional

from jaxdip.engine.keys import split_lanes
from jaxdip.engine import checks
from jaxdip.engine.roles import SAME, Sensor, param


from jaxdip._public import public_dir

__all__ = ["gauss_markov_coeffs", "gauss_markov_stationary_std", "quantize", "WhiteNoise", "LinearSensor", "Dropout",
           "DROPOUT_STREAM"]
__dir__ = public_dir(globals())


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


def check_linear_sensor(sensor) -> None:
    """The numbers of a ``LinearSensor``-like sensor (also ``TwipSensors``): finite C, noise levels >= 0, time
    constants > 0, a positive period."""
    checks.check_ndim(sensor, "C", sensor.C, (2,), "a (p, n) output matrix")
    checks.check_finite(sensor, "C", sensor.C)
    p = sensor.C.shape[0]
    for name in ("white_std", "const_bias", "gm_sigma", "gm_tau", "quantum"):
        checks.check_scalar_or_vector(sensor, name, getattr(sensor, name), p,
                                      f"(one per output: C is {checks.fmt_shape(sensor.C.shape)})")
    checks.check_finite(sensor, "const_bias", sensor.const_bias)
    for name in ("white_std", "gm_sigma", "quantum"):
        checks.check_nonnegative(sensor, name, getattr(sensor, name))
    checks.check_positive(sensor, "gm_tau", sensor.gm_tau)
    checks.check_positive(sensor, "dt", sensor.dt)


class WhiteNoise(Sensor):
    """Full-state measurement with white Gaussian noise, y = x + std * xi (``std`` scalar or per state).

    The noise is drawn from the first half of ``split(key)``, as ``LinearSensor`` draws its white noise, so
    the two give identical measurements for the same key. ``draw_dtype`` is the state's dtype by default (a
    float32 loop draws float32); ``"float32"`` in a float64 loop draws xi in float32 and casts it to float64:
    another random stream (not today's default), which passes the same statistical checks
    (tests/test_noise_streams.py) and makes the dip-lqr loop 1.11-1.15x faster on a CPU and a saturated GPU
    (docs/performance.md); its resolution (2^-24 relative) is far below any sensor's noise, and its tails end at
    5.42 sigma."""

    std: jax.Array = param()
    draw_dtype: Optional[str] = eqx.field(default=None, static=True)

    def __check_init__(self):
        checks.check_scalar_or_vector(self, "std", self.std, why="(one std for every state, or one per state)")
        checks.check_nonnegative(self, "std", self.std)
        checks.check_choice(self, "draw_dtype", self.draw_dtype, (None, "float64", "float32"))

    def io_sizes(self) -> dict:
        # full-state: y has the plant's size; a per-state std fixes that size
        if self.std.ndim == 1:
            why = f"std has {self.std.shape[0]} entries"
            return {"in": (self.std.shape[0], why), "out": (self.std.shape[0], why)}
        return {"out": (SAME, "a full-state sensor")}

    def step(self, state, x, key, k):
        k_white = split_lanes(key, 2)[0]
        draw = x.dtype if self.draw_dtype is None else jnp.dtype(self.draw_dtype)
        xi = jax.random.normal(k_white, jnp.shape(x), dtype=draw).astype(x.dtype)
        return state, x + self.std * xi, None


class LinearSensor(Sensor):
    """y = Q(C x + const_bias + walking bias + white noise), the module's model. The numbers are array fields,
    one entry per output (a scalar argument is broadcast); 0 disables the walking bias (``gm_sigma``) or the
    quantiser (``quantum``). The walking bias starts from its stationary law (``stationary_start``) or at zero;
    ``aux`` is the walking bias after the step.

    ``straight_through=True`` differentiates the quantiser as the identity (forward: the same rounded readings;
    backward: d round(y)/dy := 1). With the exact quantiser the pathwise derivative treats every reading as
    locally constant (round' = 0), which is the derivative of one sample path but misses the feedback through
    the encoders; with white noise of a fraction of a count before rounding, E[round(y + noise)] is close to y,
    so the straight-through derivative approximates the derivative of the *expected* loss."""

    C: jax.Array = param()  # (p, n) output matrix
    white_std: jax.Array = param()  # (p,) white noise standard deviation per output
    const_bias: jax.Array = param()  # (p,) constant offset
    gm_sigma: jax.Array = param()  # (p,) walking-bias driving-noise intensity sigma_b
    gm_tau: jax.Array = param()  # (p,) walking-bias time constant tau (s)
    quantum: jax.Array = param()  # (p,) quantisation step
    dt: float = eqx.field(static=True)
    stationary_start: bool = eqx.field(default=True, static=True)
    straight_through: bool = eqx.field(default=False, static=True)

    def __init__(self, C, dt: float, white_std=0.0, const_bias=0.0, gm_sigma=0.0, gm_tau=1.0, quantum=0.0,
                 stationary_start: bool = True, straight_through: bool = False):
        named = (("white_std", white_std), ("const_bias", const_bias), ("gm_sigma", gm_sigma), ("gm_tau", gm_tau),
                 ("quantum", quantum))
        for name, v in (("C", C),) + named:
            checks.check_real(self, name, v)
        checks.check_ndim(self, "C", C, (1, 2), "a (p, n) output matrix")
        C = jnp.atleast_2d(jnp.asarray(C, dtype=jnp.float64))
        for name, v in named:
            checks.check_scalar_or_vector(self, name, v, C.shape[0],
                                          f"(one per output: C is {checks.fmt_shape(C.shape)})")
        vec = lambda v: jnp.broadcast_to(jnp.asarray(v, dtype=jnp.float64), (C.shape[0],))
        self.C, self.white_std, self.const_bias = C, vec(white_std), vec(const_bias)
        self.gm_sigma, self.gm_tau, self.quantum = vec(gm_sigma), vec(gm_tau), vec(quantum)
        self.dt, self.stationary_start, self.straight_through = dt, stationary_start, straight_through

    def __check_init__(self):
        check_linear_sensor(self)

    def io_sizes(self) -> dict:
        why = f"C is {checks.fmt_shape(self.C.shape)}"
        return {"in": (self.C.shape[1], why), "out": (self.C.shape[0], why)}

    def init(self, key, x0):
        if not self.stationary_start:
            return jnp.zeros_like(self.gm_sigma)
        std0 = gauss_markov_stationary_std(self.gm_sigma, self.gm_tau)
        return std0 * jax.random.normal(key, self.gm_sigma.shape)

    def step(self, state, x, key, k):
        k_white, k_bias = jax.random.split(key)
        white = self.white_std * jax.random.normal(k_white, self.white_std.shape)
        raw = self.C @ x + self.const_bias + state + white
        if self.straight_through:
            y = raw + jax.lax.stop_gradient(quantize(jax.lax.stop_gradient(raw), self.quantum) - raw)
        else:
            y = quantize(raw, self.quantum)
        a, q_std = gauss_markov_coeffs(self.gm_sigma, self.gm_tau, self.dt)
        bias = a * state + q_std * jax.random.normal(k_bias, state.shape)
        return bias, y, bias


DROPOUT_STREAM = 0x44524F50  # fold_in(key, DROPOUT_STREAM) draws the losses; the wrapped sensor gets key itself


class Dropout(Sensor):
    """``sensor`` with lost samples: a lost reading is NaN (the whole y, or each component on its own with
    ``per_component``).

    Random losses: each period (each component) is lost with probability ``p`` (an array field), drawn from
    ``fold_in(key, DROPOUT_STREAM)`` of the period's sensor key; the wrapped sensor steps with the key itself, so
    it reads exactly what it reads unwrapped. Deterministic losses: ``pattern``, a boolean (L,) or (L, p) array
    with True = delivered, repeats with period L (period k uses ``pattern[k % L]``); with a pattern ``p`` is
    ignored. ``aux`` is (the wrapped sensor's aux, the boolean (p,) delivered mask)."""

    sensor: Any
    p: jax.Array = param()
    pattern: Optional[jax.Array] = None
    per_component: bool = eqx.field(default=False, static=True)

    def __init__(self, sensor, p=0.0, *, pattern=None, per_component: bool = False):
        if not isinstance(sensor, Sensor):
            raise checks.ArgumentTypeError(f"Dropout: sensor must be a jaxdip Sensor, got {type(sensor).__name__}")
        checks.check_real(self, "p", p)
        self.sensor, self.p, self.per_component = sensor, jnp.asarray(p, dtype=jnp.float64), per_component
        if pattern is not None:
            pattern = jnp.asarray(pattern)
            if pattern.dtype != jnp.bool_ or pattern.ndim not in (1, 2) or pattern.shape[0] == 0:
                raise checks.ArgumentError(f"Dropout: pattern must be a non-empty boolean (L,) or (L, p) array "
                                           f"(True = delivered), got {pattern.dtype} {checks.fmt_shape(pattern.shape)}")
        self.pattern = pattern

    def __check_init__(self):
        checks.check_ndim(self, "p", self.p, (0,), "a probability")
        checks.check_nonnegative(self, "p", self.p)
        if checks.is_concrete(self.p) and float(self.p) > 1.0:
            checks.fail(self, f"p must be a probability in [0, 1], got {float(self.p)}")

    def io_sizes(self) -> dict:
        return self.sensor.io_sizes()

    def init(self, key, x0):
        return self.sensor.init(key, x0)

    def step(self, state, x, key, k):
        state, y, aux = self.sensor.step(state, x, key, k)
        if self.pattern is not None:
            row = self.pattern[k % self.pattern.shape[0]]
            delivered = jnp.broadcast_to(row, jnp.shape(y))
        else:
            shape = jnp.shape(y) if self.per_component else ()
            lost = jax.random.uniform(jax.random.fold_in(key, DROPOUT_STREAM), shape) < self.p
            delivered = jnp.broadcast_to(~lost, jnp.shape(y))
        return state, jnp.where(delivered, y, jnp.nan), (aux, delivered)
