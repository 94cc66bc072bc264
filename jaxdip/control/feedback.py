"""Static state feedback u = u_ref - K (xhat - x_ref), its saturated form, and a constant (open-loop) input."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Controller, param


from jaxdip._public import public_dir

__all__ = ["StateFeedback", "ConstantInput", "SaturatedFeedback"]
__dir__ = public_dir(globals())


class StateFeedback(Controller):
    """u = u_ref - K (xhat - x_ref); x_ref and u_ref default to zero."""

    K: jax.Array = param()
    x_ref: jax.Array = param()
    u_ref: jax.Array = param()

    def __init__(self, K, x_ref=None, u_ref=None):
        for name, v in (("K", K), ("x_ref", x_ref), ("u_ref", u_ref)):
            if v is not None:
                checks.check_real(self, name, v)
        checks.check_ndim(self, "K", K, (1, 2), "an (m, n) gain (u = -K x)")
        K = jnp.atleast_2d(jnp.asarray(K, dtype=jnp.float64))
        m, n = K.shape
        self.K = K
        self.x_ref = jnp.zeros(n) if x_ref is None else x_ref
        self.u_ref = jnp.zeros(m) if u_ref is None else u_ref

    def __check_init__(self):
        m, n = self.K.shape
        why = f"(K is {checks.fmt_shape(self.K.shape)})"
        checks.check_finite(self, "K", self.K)
        checks.check_shape(self, "x_ref", self.x_ref, (n,), why)
        checks.check_shape(self, "u_ref", self.u_ref, (m,), why)
        checks.check_finite(self, "x_ref", self.x_ref)
        checks.check_finite(self, "u_ref", self.u_ref)

    def io_sizes(self) -> dict:
        why = f"K is {checks.fmt_shape(self.K.shape)}"
        return {"in": (self.K.shape[-1], why), "out": (self.K.shape[-2], why)}

    def step(self, state, xhat, key, k):
        return state, self.u_ref - self.K @ (xhat - self.x_ref), None


class ConstantInput(Controller):
    """u = ``u`` whatever the estimate (an open loop; a plant without input gets zeros)."""

    u: jax.Array = param()

    def __check_init__(self):
        checks.check_scalar_or_vector(self, "u", self.u, why="(one entry per plant input)")
        checks.check_finite(self, "u", self.u)

    def io_sizes(self) -> dict:
        return {"out": (self.u.shape[0], f"u has {self.u.shape[0]} entries")} if self.u.ndim == 1 else {}

    def step(self, state, xhat, key, k):
        return state, self.u, None


class SaturatedFeedback(StateFeedback):
    """u = clip(u_ref - K (xhat - x_ref), u_min, u_max): the clip inside the controller, so the u_{k-1} an
    estimator is given is the input actually applied (a ``Saturation`` actuator would hand it the unclipped u)."""

    u_min: jax.Array = param()
    u_max: jax.Array = param()

    def __init__(self, K, u_min, u_max, x_ref=None, u_ref=None):
        super().__init__(K, x_ref, u_ref)
        self.u_min, self.u_max = u_min, u_max

    def __check_init__(self):
        checks.check_limits(self, "u_min", self.u_min, "u_max", self.u_max)
        m = self.K.shape[0]
        for name in ("u_min", "u_max"):
            checks.check_scalar_or_vector(self, name, getattr(self, name), m, f"(K is {checks.fmt_shape(self.K.shape)})")

    def step(self, state, xhat, key, k):
        return state, jnp.clip(self.u_ref - self.K @ (xhat - self.x_ref), self.u_min, self.u_max), None
