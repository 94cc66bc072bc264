"""Static state feedback u = u_ref - K (xhat - x_ref) as a loop component."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Controller, param
from jaxdip.sim.component import stateless


class FeedbackParams(NamedTuple):
    K: jnp.ndarray  # (m, n)
    x_ref: jnp.ndarray  # (n,)
    u_ref: jnp.ndarray  # (m,)


def feedback_params(K, x_ref=None, u_ref=None) -> FeedbackParams:
    K = jnp.atleast_2d(jnp.asarray(K, dtype=jnp.float64))
    m, n = K.shape
    x_ref = jnp.zeros(n) if x_ref is None else jnp.asarray(x_ref, dtype=jnp.float64)
    u_ref = jnp.zeros(m) if u_ref is None else jnp.asarray(u_ref, dtype=jnp.float64)
    return FeedbackParams(K, x_ref, u_ref)


def state_feedback():
    return stateless(lambda p, xhat, key, k: p.u_ref - p.K @ (xhat - p.x_ref))


class StateFeedback(Controller):
    """u = u_ref - K (xhat - x_ref); x_ref and u_ref default to zero."""

    K: jax.Array = param()
    x_ref: jax.Array = param()
    u_ref: jax.Array = param()

    def __init__(self, K, x_ref=None, u_ref=None):
        p = feedback_params(K, x_ref, u_ref)
        self.K, self.x_ref, self.u_ref = p.K, p.x_ref, p.u_ref

    def step(self, state, xhat, key, k):
        return state, self.u_ref - self.K @ (xhat - self.x_ref), None
