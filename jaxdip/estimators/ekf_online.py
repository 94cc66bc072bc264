"""An online extended Kalman filter with a nonlinear measurement function, as an engine estimator.

Same timing as ``KalmanFilter``: sample j brings y_j and u_{j-1}; from j = 1 on the filter predicts with
u_{j-1}, then updates with y_j (at j = 0 the prior is (xhat0, P0), or (x0, P0) with ``from_truth``). The
equations are those of ``jaxdip.estimators.lgssm`` (the same ``gaussian_update``), so a run over a recorded
sequence equals ``lgssm.kalman_filter`` with the same maps.
"""

from __future__ import annotations

from typing import Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator, param
from jaxdip.estimators.kalman import KFState
from jaxdip.estimators.lgssm import gaussian_update


class NonlinearEKF(Estimator):
    """EKF for x_{k+1} = f(x_k, u_k) + w (or Phi x_k + W u_k + w), y_k = h(x_k) + v.

    ``h(x)`` and ``f(x, u)`` are static (compared by identity: pass module-level functions); their Jacobians are
    taken by forward-mode autodiff at the predicted (h) and filtered (f) means. Without ``f`` the dynamics are
    linear with the array fields ``Phi``, ``W``. ``aux`` is the posterior covariance.

    For a continuous plant with a linear output (the Lorenz study), ``ExtendedKalmanFilter`` in
    ``jaxdip.estimators.kf`` discretises the plant's vector field itself; this one takes discrete maps.
    """

    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    Phi: Optional[jax.Array]
    W: Optional[jax.Array]
    h: Callable = eqx.field(static=True)
    f: Optional[Callable] = eqx.field(static=True)
    n_inputs: int = eqx.field(static=True)
    from_truth: bool = eqx.field(static=True)

    def __init__(self, h: Callable, Q, R, P0, xhat0=None, *, Phi=None, W=None, f: Optional[Callable] = None,
                 n_inputs: int = 1, from_truth: bool = False):
        if (f is None) == (Phi is None):
            raise ValueError("give exactly one of Phi (linear dynamics) and f (nonlinear dynamics)")
        d = jnp.shape(P0)[0]
        self.h, self.f, self.Q, self.R, self.P0 = h, f, Q, R, P0
        self.xhat0 = jnp.zeros(d) if xhat0 is None else xhat0
        fl = jnp.result_type(float)
        self.Phi = None if Phi is None else jnp.asarray(Phi, fl)
        self.W = None if Phi is None else (jnp.zeros((d, n_inputs), fl) if W is None
                                           else jnp.reshape(jnp.asarray(W, fl), (d, n_inputs)))
        self.n_inputs, self.from_truth = n_inputs, from_truth

    def init(self, key, x0):
        x = jnp.asarray(x0 if self.from_truth else self.xhat0, dtype=jnp.result_type(float))
        return KFState(x, jnp.asarray(self.P0, x.dtype))

    def step(self, state, y, u_prev, key, k):
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.x.dtype), (self.n_inputs,))
        if self.f is None:
            F, xp = self.Phi, self.Phi @ state.x + self.W @ u_prev
        else:
            F, xp = jax.jacfwd(self.f, argnums=0)(state.x, u_prev), self.f(state.x, u_prev)
        Pp = F @ state.P @ F.T + self.Q
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, 0.5 * (Pp + Pp.T))
        x, P, _ = gaussian_update(xp, Pp, y, jax.jacfwd(self.h)(xp), self.h(xp), self.R)
        return KFState(x, P), x, P
