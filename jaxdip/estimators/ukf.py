"""Unscented Kalman filter: a batch form over whole sequences and an engine estimator.

Model as in ``jaxdip.estimators.lgssm``: x_0 ~ N(m0, P0), x_{k+1} = f(x_k, u_k) + w_k, y_k = h(x_k) + v_k, with
w ~ N(0, Q), v ~ N(0, R); (m0, P0) is the prior of x_0 before y_0.

Sigma points (the scaled unscented transform of van der Merwe and Wan): for N(m, P) in d dimensions,
lambda = alpha^2 (d + kappa) - d, points m and m +- sqrt(d + lambda) L_i (L the lower Cholesky factor of P, L_i its
columns), mean weights lambda / (d + lambda) and 1 / (2 (d + lambda)), covariance weights the same except the
centre's, which gets + 1 - alpha^2 + beta. The defaults alpha = sqrt(3), beta = 2, kappa = 1 are dynamax's
(``UKFHyperParams``): lambda = 3 (d + 1) - d > 0, so every weight is positive for any d and the covariances
stay positive semi-definite. Through a linear map the transform is exact (any alpha, beta, kappa), so on a linear
model the UKF is the Kalman filter (tested to 1e-10).

One cycle: predict by pushing the sigma points of the filtered N(m, P) through f(., u_k) and adding Q; update by
drawing new sigma points from the predicted N(m-, P-), pushing them through h, and conditioning on
S = P_yy + R, P_xy: K = P_xy S^{-1}, m = m- + K (y - yhat), P = P- - K S K^T. The innovation covariance is
factored by the guarded Cholesky of ``jaxdip.estimators.kalman`` and gives log N(y; yhat, S) as well.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.engine.roles import Estimator, param
from jaxdip.estimators.kalman import KFState, _guarded_cho_factor
from jaxdip.estimators.lgssm import FilterResult, _LOG_2PI, _per_step, _sym

DEFAULT_ALPHA, DEFAULT_BETA, DEFAULT_KAPPA = 3.0**0.5, 2.0, 1.0


class SigmaWeights(NamedTuple):
    scale: jax.Array  # sqrt(d + lambda)
    wm: jax.Array  # (2 d + 1,) mean weights
    wc: jax.Array  # (2 d + 1,) covariance weights


def sigma_weights(d: int, alpha=DEFAULT_ALPHA, beta=DEFAULT_BETA, kappa=DEFAULT_KAPPA) -> SigmaWeights:
    lam = alpha**2 * (d + kappa) - d
    w = jnp.full(2 * d + 1, 0.5 / (d + lam))
    wm = w.at[0].set(lam / (d + lam))
    wc = w.at[0].set(lam / (d + lam) + 1.0 - alpha**2 + beta)
    return SigmaWeights(jnp.sqrt(d + lam), wm, wc)


def sigma_points(m, P, sw: SigmaWeights):
    """(2 d + 1, d): m, then m + scale L_i, then m - scale L_i."""
    L = jnp.linalg.cholesky(_sym(P))
    D = sw.scale * L.T  # rows: the scaled columns of L
    return jnp.concatenate([m[None], m + D, m - D])


def unscented_transform(fn: Callable, m, P, sw: SigmaWeights):
    """(mean, covariance, cross-covariance with x) of fn(x), x ~ N(m, P), by the sigma points."""
    X = sigma_points(m, P, sw)
    Y = jax.vmap(fn)(X)
    ym = sw.wm @ Y
    dY, dX = Y - ym, X - m
    return ym, _sym((sw.wc[:, None] * dY).T @ dY), (sw.wc[:, None] * dX).T @ dY


def ukf_predict(m, P, f: Callable, u, Q, sw: SigmaWeights):
    mp, Pp, _ = unscented_transform(lambda x: f(x, u), m, P, sw)
    return mp, _sym(Pp + Q)


def ukf_update(m, P, y, h: Callable, R, sw: SigmaWeights):
    """Condition N(m, P) on y = h(x) + v: (mean, cov, log N(y; yhat, S))."""
    yhat, Pyy, Pxy = unscented_transform(h, m, P, sw)
    S = _sym(Pyy + R)
    cf = _guarded_cho_factor(S)
    K = jsl.cho_solve(cf, Pxy.T).T
    e = y - yhat
    L = cf[0]
    z = jsl.solve_triangular(L, e, lower=True)
    ll = -0.5 * (z @ z + 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diag(L)))) + e.shape[0] * _LOG_2PI)
    return m + K @ e, _sym(P - K @ S @ K.T), ll


def unscented_filter(ys, m0, P0, Q, R, f: Callable, h: Callable, us=None, *, alpha=DEFAULT_ALPHA,
                     beta=DEFAULT_BETA, kappa=DEFAULT_KAPPA) -> FilterResult:
    """UKF over a whole sequence ``ys`` (T, p) by ``lax.scan``: ``f(x, u) -> x_next``, ``h(x) -> y``, inputs
    ``us`` (T, m) (u_k drives x_k -> x_{k+1}); ``Q``, ``R`` one matrix or a stack over T. Same result type as
    ``lgssm.kalman_filter`` (filtered and predicted moments, log-likelihood)."""
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    T = ys.shape[0]
    m0 = jnp.asarray(m0, ys.dtype)
    us = jnp.zeros((T, 1), ys.dtype) if us is None else jnp.asarray(us, ys.dtype).reshape(T, -1)
    Qs, Rs = _per_step(Q, T, 2), _per_step(R, T, 2)
    sw = sigma_weights(m0.shape[0], alpha, beta, kappa)

    def body(carry, k):
        mp, Pp = carry
        mf, Pf, ll = ukf_update(mp, Pp, ys[k], h, Rs[k], sw)
        mn, Pn = ukf_predict(mf, Pf, f, us[k], Qs[k], sw)
        return (mn, Pn), (mf, Pf, mp, Pp, ll)

    _, (mf, Pf, mp, Pp, ll) = jax.lax.scan(body, (m0, jnp.asarray(P0, ys.dtype)), jnp.arange(T))
    return FilterResult(mf, Pf, mp, Pp, jnp.sum(ll), ll)


class NonlinearUKF(Estimator):
    """UKF for x_{k+1} = f(x_k, u_k) + w (or Phi x_k + W u_k + w), y_k = h(x_k) + v, as an engine estimator.

    Same timing as ``KalmanFilter`` and ``NonlinearEKF``: sample j brings y_j and u_{j-1}; from j = 1 on the filter
    predicts with u_{j-1}, then updates with y_j. ``h``, ``f`` static (compared by identity); ``alpha``, ``beta``,
    ``kappa`` array fields (traced). ``aux`` is the posterior covariance. A run over a recorded sequence equals
    ``unscented_filter`` with the same maps.
    """

    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    alpha: jax.Array = param()
    beta: jax.Array = param()
    kappa: jax.Array = param()
    Phi: Optional[jax.Array]
    W: Optional[jax.Array]
    h: Callable = eqx.field(static=True)
    f: Optional[Callable] = eqx.field(static=True)
    n_inputs: int = eqx.field(static=True)
    from_truth: bool = eqx.field(static=True)

    def __init__(self, h: Callable, Q, R, P0, xhat0=None, *, Phi=None, W=None, f: Optional[Callable] = None,
                 n_inputs: int = 1, from_truth: bool = False, alpha=DEFAULT_ALPHA, beta=DEFAULT_BETA,
                 kappa=DEFAULT_KAPPA):
        if (f is None) == (Phi is None):
            raise ValueError("give exactly one of Phi (linear dynamics) and f (nonlinear dynamics)")
        d = jnp.shape(P0)[0]
        self.h, self.f, self.Q, self.R, self.P0 = h, f, Q, R, P0
        self.xhat0 = jnp.zeros(d) if xhat0 is None else xhat0
        self.alpha, self.beta, self.kappa = alpha, beta, kappa
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
        sw = sigma_weights(state.x.shape[0], self.alpha, self.beta, self.kappa)
        if self.f is None:  # linear dynamics: the transform is exact, so the KF prediction
            xp, Pp = self.Phi @ state.x + self.W @ u_prev, _sym(self.Phi @ state.P @ self.Phi.T + self.Q)
        else:
            xp, Pp = ukf_predict(state.x, state.P, self.f, u_prev, self.Q, sw)
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, Pp)
        x, P, _ = ukf_update(xp, Pp, y, self.h, self.R, sw)
        return KFState(x, P), x, P
