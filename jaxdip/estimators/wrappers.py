"""Estimator wrappers that change when or from where an estimator starts, not what it computes.

``InitialError(inner, std)``: the estimator starts from x0 + std * N(0, I) (x0 the true initial state), drawn
from its init key; ``inner`` must start from the x0 it is given (``from_truth=True``). Estimators that receive
the same init key (the members of a ``FanOut``) therefore start from the same perturbed estimate.

``Delayed(inner)``: the output at sample j is the inner estimator's output at j - 1 (at j = 0: the initial
estimate). For a predictor whose output at j is its estimate of x_{j+1}, the delayed output at j is its
estimate of x_j made one sample earlier, the quantity to compare with x_j.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator, param


class InitialError(Estimator):
    """``inner`` started from x0 + std * N(0, I) drawn from the init key; ``aux`` is ``inner``'s aux."""

    inner: Any
    std: jax.Array = param()

    def init(self, key, x0):
        x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
        return self.inner.init(key, x0 + self.std * jax.random.normal(key, x0.shape))

    def step(self, state, y, u_prev, key, k):
        return self.inner.step(state, y, u_prev, key, k)


class Delayed(Estimator):
    """The output of ``inner`` held for one sample; the initial output is the x0 given to ``init``.
    ``aux`` is ``inner``'s aux of the current sample."""

    inner: Any

    def init(self, key, x0):
        x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
        return self.inner.init(key, x0), x0

    def step(self, state, y, u_prev, key, k):
        inner_state, held = state
        inner_state, out, aux = self.inner.step(inner_state, y, u_prev, key, k)
        return (inner_state, out), held, aux
