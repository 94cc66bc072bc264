"""The discrete Kalman filter as an engine estimator (``jaxdip.estimators.kalman`` holds the equations)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator, param
from jaxdip.estimators.kalman import KFState, kf_predict, kf_update
from jaxdip.estimators.linearized import local_model


OUTPUTS = ("posterior", "prior", "delayed")


class KalmanFilter(Estimator):
    """KF for x_{k+1} = Phi x_k + W u_k + w, y_k = C x_k + v, w ~ (0, Q), v ~ (0, R).

    Sample j brings y_j and u_{j-1}: predict with u_{j-1} (from j = 1 on; at j = 0 the prior is (xhat0, P0),
    or (x0, P0) with ``from_truth``), update with y_j, output x+_j. ``aux`` is the posterior covariance P+_j.
    Numbers identical to ``kalman.kalman()``.

    ``output`` (static) picks what is handed out at sample j (the filter itself is the same):
      "posterior"  x+_j (updated with y_j);
      "prior"      the prediction x-_j = Phi x+_{j-1} + W u_{j-1} (xhat0 at j = 0), from y_0 .. y_{j-1}: a
                   one-step predictor, the information of a predictor-form observer such as the DMSO;
      "delayed"    Stumfoll's (170) as printed: the filter at sample j is updated with y_{j-1} (with C xhat0,
                   a zero innovation, at j = 0), its posterior handed out.
    """

    Phi: jax.Array = param()
    W: jax.Array = param()
    C: jax.Array = param()
    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    from_truth: bool = eqx.field(default=False, static=True)
    output: str = eqx.field(default="posterior", static=True)

    def __init__(self, Phi, W, C, Q, R, P0, xhat0=None, from_truth: bool = False, output: str = "posterior"):
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.output = output
        self.Phi, self.C, self.Q, self.R, self.P0 = Phi, C, Q, R, P0
        self.W = jnp.reshape(jnp.asarray(W), (jnp.shape(Phi)[0], -1))
        self.xhat0 = jnp.zeros(jnp.shape(Phi)[0]) if xhat0 is None else xhat0
        self.from_truth = from_truth

    def init(self, key, x0):
        x = jnp.asarray(x0 if self.from_truth else self.xhat0, dtype=jnp.result_type(float))
        st = KFState(x, jnp.asarray(self.P0, x.dtype))
        if self.output == "delayed":
            return st, self.C @ jnp.asarray(self.xhat0, jnp.float64)
        return st

    def step(self, state, y, u_prev, key, k):
        if self.output == "delayed":
            st, y_prev = state
            st, x, P = self._filter(st, y_prev, u_prev, k)
            return (st, jnp.asarray(y, jnp.float64)), x, P
        if self.output == "prior":
            u = jnp.reshape(jnp.asarray(u_prev, state.x.dtype), (self.W.shape[1],))
            prior = jnp.where(k == 0, state.x, self.Phi @ state.x + self.W @ u)
            st, _, P = self._filter(state, y, u_prev, k)
            return st, prior, P
        return self._filter(state, y, u_prev, k)

    def _filter(self, state, y, u_prev, k):
        u_prev = jnp.reshape(u_prev, (self.W.shape[1],))
        xp, Pp = kf_predict(state.x, state.P, self.Phi, self.W @ u_prev, self.Q)
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, Pp)
        x, P = kf_update(xp, Pp, y, self.C, self.R)
        return KFState(x, P), x, P


def _plant_vector_field(plant, x, u):
    return plant.vector_field(x, u)


class ExtendedKalmanFilter(Estimator):
    """EKF for an engine ``Plant`` ``model`` sampled every ``h``: relinearised at x+ every sample (Jacobian and
    matrix exponential, ``local_model``), the mean propagated by the same local affine model. The
    ``kalman.ekf`` estimator with its params (``EKFParams``' fields) as fields; ``aux`` is P+_j.
    ``jitter``: see ``kalman.kf_update`` (static: a literal 0 leaves the update as it was).

    ``output`` (static): "posterior" hands out x+_j; "prior" the one-step prediction x-_j made at j - 1 from
    x+_{j-1} (the starting estimate at j = 0), for comparing with predictors on the same time alignment. The
    filter itself is the same either way."""

    model: Any
    C: jax.Array = param()
    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    h: float = eqx.field(static=True)
    from_truth: bool = eqx.field(default=False, static=True)
    expm_squarings: int = eqx.field(default=24, static=True)
    jitter: float = eqx.field(default=0.0, static=True)
    output: str = eqx.field(default="posterior", static=True)

    def __check_init__(self):
        if self.output not in ("posterior", "prior"):
            raise ValueError(f"output must be 'posterior' or 'prior', got {self.output!r}")

    def init(self, key, x0):
        x = jnp.asarray(x0 if self.from_truth else self.xhat0, dtype=jnp.result_type(float))
        return KFState(x, jnp.asarray(self.P0, x.dtype))

    def step(self, state, y, u_prev, key, k):
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.x.dtype), (self.model.m,))
        lm = local_model(_plant_vector_field, self.model, state.x, u_prev, self.h, with_inverse=False,
                         max_squarings=self.expm_squarings)
        xp, Pp = kf_predict(state.x, state.P, lm.Phi, lm.W @ u_prev + lm.b, self.Q)
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, Pp)
        x, P = kf_update(xp, Pp, y, self.C, self.R, self.jitter)
        return KFState(x, P), (xp if self.output == "prior" else x), P
