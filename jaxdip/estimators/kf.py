"""The discrete Kalman filter as an engine estimator (``jaxdip.estimators.kalman`` holds the equations)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator, param
from jaxdip.estimators.kalman import KFState, kf_predict, kf_update


class KalmanFilter(Estimator):
    """KF for x_{k+1} = Phi x_k + W u_k + w, y_k = C x_k + v, w ~ (0, Q), v ~ (0, R).

    Sample j brings y_j and u_{j-1}: predict with u_{j-1} (from j = 1 on; at j = 0 the prior is (xhat0, P0),
    or (x0, P0) with ``from_truth``), update with y_j, output x+_j. ``aux`` is the posterior covariance P+_j.
    Numbers identical to ``kalman.kalman()``.
    """

    Phi: jax.Array = param()
    W: jax.Array = param()
    C: jax.Array = param()
    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    from_truth: bool = eqx.field(default=False, static=True)

    def __init__(self, Phi, W, C, Q, R, P0, xhat0=None, from_truth: bool = False):
        self.Phi, self.C, self.Q, self.R, self.P0 = Phi, C, Q, R, P0
        self.W = jnp.reshape(jnp.asarray(W), (jnp.shape(Phi)[0], -1))
        self.xhat0 = jnp.zeros(jnp.shape(Phi)[0]) if xhat0 is None else xhat0
        self.from_truth = from_truth

    def init(self, key, x0):
        x = jnp.asarray(x0 if self.from_truth else self.xhat0, dtype=jnp.result_type(float))
        return KFState(x, jnp.asarray(self.P0, x.dtype))

    def step(self, state, y, u_prev, key, k):
        u_prev = jnp.reshape(u_prev, (self.W.shape[1],))
        xp, Pp = kf_predict(state.x, state.P, self.Phi, self.W @ u_prev, self.Q)
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, Pp)
        x, P = kf_update(xp, Pp, y, self.C, self.R)
        return KFState(x, P), x, P
