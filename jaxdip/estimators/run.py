"""Run an estimator component over recorded data (open loop): one ``lax.scan`` over the samples."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.sim.component import Component


def filter_sequence(est: Component, params, ys, us_prev, x0, key=None):
    """Feed samples j = 0..T-1 to ``est``: ``ys[j]`` = y_j and ``us_prev[j]`` = u_{j-1} (zeros for j = 0).

    ``x0`` is what ``init`` receives as the true initial state (used by components built with
    ``from_truth=True``). Returns (final state, outputs of shape (T, ...)).
    """
    key = jax.random.PRNGKey(0) if key is None else key
    state = est.init(params, jax.random.fold_in(key, 0), x0)
    ys = jnp.asarray(ys)
    us_prev = jnp.asarray(us_prev)

    def body(st, inp):
        j, y, u = inp
        st, out = est.step(params, st, (y, u), jax.random.fold_in(key, j + 1), j)
        return st, out

    js = jnp.arange(ys.shape[0], dtype=jnp.int32)
    return jax.lax.scan(body, state, (js, ys, us_prev))
