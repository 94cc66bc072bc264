"""Input disturbance: an actuator that adds a per-trial constant offset and white noise to the commanded input.

    u_applied_k = u_k + d + w_k,   d ~ N(0, offset_std^2) drawn once per trial (at ``init``),
                                   w_k ~ N(0, white_std^2) i.i.d. per period, held over the period.

The offset stands for what a linear model of a laboratory cart leaves out and a controller sees as a constant
push (amplifier offset, uneven Coulomb friction, a tilted track); the white part for the cable, belt and friction
jitter. Both are in input units (volts for the DIP).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Actuator, param
from jaxdip.sim.component import Component


class InputDisturbanceParams(NamedTuple):
    offset_std: jnp.ndarray  # (m,) std of the per-trial constant offset
    white_std: jnp.ndarray  # (m,) std of the per-period white disturbance


def input_disturbance_params(offset_std=0.0, white_std=0.0, m: int = 1) -> InputDisturbanceParams:
    vec = lambda v: jnp.broadcast_to(jnp.asarray(v, dtype=jnp.float64), (m,))
    return InputDisturbanceParams(vec(offset_std), vec(white_std))


def input_disturbance() -> Component:
    def init(p: InputDisturbanceParams, key, x0):
        return p.offset_std * jax.random.normal(key, p.offset_std.shape)

    def step(p: InputDisturbanceParams, offset, u, key, k):
        return offset, u + offset + p.white_std * jax.random.normal(key, p.white_std.shape)

    return Component(init, step)


class InputDisturbance(Actuator):
    """The input disturbance as an engine actuator: ``InputDisturbanceParams``' fields, one entry per input.

    The state is the per-trial offset d, drawn at ``init``; ``aux`` is d as well."""

    offset_std: jax.Array = param()
    white_std: jax.Array = param()

    def __init__(self, offset_std=0.0, white_std=0.0, m: int = 1):
        p = input_disturbance_params(offset_std, white_std, m)
        self.offset_std, self.white_std = p.offset_std, p.white_std

    def init(self, key, x0):
        return input_disturbance().init(self, key, x0)

    def step(self, state, u, key, k):
        offset, out = input_disturbance().step(self, state, u, key, k)
        return offset, out, offset
