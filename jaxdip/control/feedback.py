"""Static state feedback u = u_ref - K (xhat - x_ref), its saturated form, and a constant (open-loop) input."""

from __future__ import annotations

import jax
import jax.numpy as jnp

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
        K = jnp.atleast_2d(jnp.asarray(K, dtype=jnp.float64))
        m, n = K.shape
        self.K = K
        self.x_ref = jnp.zeros(n) if x_ref is None else x_ref
        self.u_ref = jnp.zeros(m) if u_ref is None else u_ref

    def step(self, state, xhat, key, k):
        return state, self.u_ref - self.K @ (xhat - self.x_ref), None


class ConstantInput(Controller):
    """u = ``u`` whatever the estimate (an open loop; a plant without input gets zeros)."""

    u: jax.Array = param()

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

    def step(self, state, xhat, key, k):
        return state, jnp.clip(self.u_ref - self.K @ (xhat - self.x_ref), self.u_min, self.u_max), None
