"""Actuator and output nonlinearities of Stumfoll §7.5: saturation (157), deadzone (160), backlash (161)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.keys import split_lanes
from jaxdip.engine.roles import Actuator, Sensor, param


from jaxdip._public import public_dir

__all__ = ["saturate", "deadzone", "BACKLASH_LAWS", "backlash", "Saturation", "Deadzone", "OutputBacklash",
           "InputBacklash", "Chain"]
__dir__ = public_dir(globals())


def saturate(u, u_min, u_max):
    return jnp.clip(u, u_min, u_max)


def deadzone(u, d_minus, d_plus):
    """Simplified deadzone (160): inputs inside [d-, d+) produce nothing, outside they pass unchanged."""
    return jnp.where((u >= d_minus) & (u < d_plus), 0.0, u)


BACKLASH_LAWS = ("standard", "printed")


def backlash(psi, u_prev, u, m, d_minus, d_plus, law: str = "standard"):
    """One step of backlash (161) with output psi driven by input u.

    The printed law evaluates the engaged branches at u(k) while testing the direction with u(k+1) - u(k);
    that makes the output lag the input by a whole sample even when the gears are engaged, which is not what
    backlash does. ``law="standard"`` (the default): when engaged the output is m (u_{k+1} - d) with the new
    input. ``law="printed"``: (161) as printed, the engaged branches m (u_k - d) at the previous input (the
    reading test of Table 8.3's backlash row).
    """
    if law not in BACKLASH_LAWS:
        raise ValueError(f"backlash law must be one of {BACKLASH_LAWS}, got {law!r}")
    at = u if law == "standard" else u_prev
    up = m * (at - d_plus)
    down = m * (at - d_minus)
    rising = (u - u_prev > 0) & (psi <= up)
    falling = (u - u_prev < 0) & (psi >= down)
    return jnp.where(rising, up, jnp.where(falling, down, psi))


def _vector_sizes(owner, *names: str) -> dict:
    # an actuator with per-input numbers knows the input size; scalars fit any
    for name in names:
        v = getattr(owner, name)
        if v.ndim == 1:
            why = f"{name} has {v.shape[0]} entries"
            return {"in": (v.shape[0], why), "out": (v.shape[0], why)}
    return {}


class Saturation(Actuator):
    """(157) as an engine actuator: u clipped to [u_min, u_max] (per input; +-inf: no limit)."""

    u_min: jax.Array = param()
    u_max: jax.Array = param()

    def __check_init__(self):
        checks.check_limits(self, "u_min", self.u_min, "u_max", self.u_max)

    def io_sizes(self) -> dict:
        return _vector_sizes(self, "u_min", "u_max")

    def step(self, state, u, key, k):
        return state, saturate(u, self.u_min, self.u_max), None


class Deadzone(Actuator):
    """The deadzone (160) on the input: u in [d_minus, d_plus) gives 0, otherwise u passes (0, 0: no deadzone)."""

    d_minus: jax.Array = param(0.0)
    d_plus: jax.Array = param(0.0)

    def __check_init__(self):
        checks.check_limits(self, "d_minus", self.d_minus, "d_plus", self.d_plus)

    def io_sizes(self) -> dict:
        return _vector_sizes(self, "d_minus", "d_plus")

    def step(self, state, u, key, k):
        return state, deadzone(u, self.d_minus, self.d_plus), None


def _check_backlash(owner) -> None:
    # (161) with slope m > 0 (a gear ratio) and a dead band d_minus <= d_plus (both 0: no backlash)
    checks.check_limits(owner, "d_minus", owner.d_minus, "d_plus", owner.d_plus)
    a, b = checks.shape_of(owner.m), checks.shape_of(owner.d_minus)
    if a and b and a != b:
        checks.fail(owner, f"m must be a scalar or have the shape of d_minus {checks.fmt_shape(b)}, "
                           f"got {checks.fmt_shape(a)}")
    checks.check_positive(owner, "m", owner.m)


class OutputBacklash(Sensor):
    """Full-state measurement y = x with the backlash (161) on channel ``channel`` (starting engaged at zero).

    The TWIP's tilt seen through gear backlash (§8.2.4); d_minus = d_plus = 0 with m = 1 passes x unchanged.
    ``aux`` is the backlash output."""

    m: jax.Array = param(1.0)
    d_minus: jax.Array = param(0.0)
    d_plus: jax.Array = param(0.0)
    channel: int = eqx.field(default=2, static=True)
    law: str = eqx.field(default="standard", static=True)  # ``backlash``'s law: "standard" or "printed"

    def __check_init__(self):
        checks.check_int(self, "channel", self.channel, 0)
        checks.check_choice(self, "law", self.law, BACKLASH_LAWS)
        # one measured channel: one slope and one dead band (scalars, or arrays of one entry)
        for name in ("m", "d_minus", "d_plus"):
            checks.check_scalar_or_vector(self, name, getattr(self, name), 1, f"(the one channel {self.channel})")
        _check_backlash(self)

    def init(self, key, x0):
        z = jnp.zeros(1)
        return (z, z)

    def step(self, state, x, key, k):
        psi, u_prev = state
        u = x[self.channel:self.channel + 1]
        psi = backlash(psi, u_prev, u, self.m, self.d_minus, self.d_plus, self.law)
        return (psi, u), x.at[self.channel].set(psi[0]), psi[0]


class InputBacklash(Actuator):
    """The backlash (161) on the input signal (standard form, see ``backlash``), starting engaged at zero.

    Slope ``m``, dead band [d_minus, d_plus] in input units; d_minus = d_plus = 0 with m = 1 passes u. ``aux``
    is the output."""

    m: jax.Array = param(1.0)
    d_minus: jax.Array = param(0.0)
    d_plus: jax.Array = param(0.0)

    def __check_init__(self):
        checks.check_scalar_or_vector(self, "m", self.m, why="(one for every input, or one per input)")
        _check_backlash(self)

    def init(self, key, x0):
        z = jnp.zeros(jnp.shape(self.m) or (1,))
        return (z, z)

    def step(self, state, u, key, k):
        psi, u_prev = state
        psi = backlash(psi, u_prev, u, self.m, self.d_minus, self.d_plus)
        return (psi, u), psi, psi


class Chain(Actuator):
    """Actuators applied one after the other (the first sees the controller's u). Each stage gets its own key
    (``split(key, n)``, computed lane by lane: ``split_lanes``) and keeps its own state; ``aux`` is the tuple of
    the stages' aux."""

    stages: tuple

    def __init__(self, *stages: Actuator):
        for i, st in enumerate(stages):
            if not (callable(getattr(st, "init", None)) and callable(getattr(st, "step", None))):
                raise checks.ArgumentTypeError(f"Chain: stage {i} must be an actuator (init and step), "
                                               f"got {type(st).__name__}")
        self.stages = tuple(stages)

    def init(self, key, x0):
        keys = split_lanes(key, len(self.stages))
        return tuple(s.init(k, x0) for s, k in zip(self.stages, keys))

    def step(self, state, u, key, k):
        keys = split_lanes(key, len(self.stages))
        new, aux = [], []
        for s, st, kk in zip(self.stages, state, keys):
            st, u, a = s.step(st, u, kk, k)
            new.append(st)
            aux.append(a)
        return tuple(new), u, tuple(aux)
