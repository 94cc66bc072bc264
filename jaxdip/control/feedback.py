"""Static state feedback u = u_ref - K (xhat - x_ref) as a loop component."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

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
