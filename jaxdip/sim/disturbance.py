"""Input disturbance: an actuator that adds a per-trial constant offset and white noise to the commanded input.

    u_applied_k = u_k + d + w_k,   d ~ N(0, offset_std^2) drawn once per trial (at ``init``),
                                   w_k ~ N(0, white_std^2) i.i.d. per period, held over the period.

The offset stands for what a linear model of a laboratory cart leaves out and a controller sees as a constant
push (amplifier offset, uneven Coulomb friction, a tilted track); the white part for the cable, belt and friction
jitter. Both are in input units (volts for the DIP).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Actuator, param


from jaxdip._public import public_dir

__all__ = ["InputDisturbance"]
__dir__ = public_dir(globals())


class InputDisturbance(Actuator):
    """The input disturbance as an actuator: ``offset_std`` and ``white_std``, one entry per input (a scalar is
    broadcast to ``m`` inputs). The state is the per-trial offset d, drawn at ``init``; ``aux`` is d as well."""

    offset_std: jax.Array = param()  # (m,) std of the per-trial constant offset
    white_std: jax.Array = param()  # (m,) std of the per-period white disturbance

    def __init__(self, offset_std=0.0, white_std=0.0, m: int = 1):
        checks.check_int(self, "m", m, 1)
        for name, v in (("offset_std", offset_std), ("white_std", white_std)):
            checks.check_real(self, name, v)
            checks.check_scalar_or_vector(self, name, v, m, f"(one per input, m={m})")
        vec = lambda v: jnp.broadcast_to(jnp.asarray(v, dtype=jnp.float64), (m,))
        self.offset_std, self.white_std = vec(offset_std), vec(white_std)

    def __check_init__(self):
        for name in ("offset_std", "white_std"):
            checks.check_nonnegative(self, name, getattr(self, name))

    def io_sizes(self) -> dict:
        if self.offset_std.ndim != 1:
            return {}
        why = f"offset_std is {checks.fmt_shape(self.offset_std.shape)}"
        return {"in": (self.offset_std.shape[0], why), "out": (self.offset_std.shape[0], why)}

    def init(self, key, x0):
        return self.offset_std * jax.random.normal(key, self.offset_std.shape, self.offset_std.dtype)

    def step(self, state, u, key, k):
        white = self.white_std * jax.random.normal(key, self.white_std.shape, self.white_std.dtype)
        return state, u + state + white, state
