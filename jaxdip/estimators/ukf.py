"""The unscented Kalman filter as an engine estimator (run over recorded data by ``jaxdip.estimators.recorded``).

Model: x_0 ~ N(xhat0, P0), x_{k+1} = f(x_k, u_k) + w_k, y_k = h(x_k) + v_k, with
w ~ N(0, Q), v ~ N(0, R); (xhat0, P0) is the prior of x_0 before y_0.

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
factored by the guarded Cholesky of the Kalman kernel (``jaxdip.estimators.kalman.condition``), which gives
log N(y; yhat, S) as well.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, param, dtype_of
from jaxdip.estimators.kalman import GaussianAux, KFState, as_covariance, condition, sym
from jaxdip.estimators.kf import output_size

from jaxdip._public import public_dir

__all__ = ["DEFAULT_ALPHA", "DEFAULT_BETA", "DEFAULT_KAPPA", "SigmaWeights", "sigma_weights", "sigma_points",
           "unscented_transform", "ukf_predict", "ukf_update", "UnscentedKalmanFilter"]
__dir__ = public_dir(globals())

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
    L = jnp.linalg.cholesky(sym(P))
    D = sw.scale * L.T  # rows: the scaled columns of L
    return jnp.concatenate([m[None], m + D, m - D])


def unscented_transform(fn: Callable, m, P, sw: SigmaWeights):
    """(mean, covariance, cross-covariance with x) of fn(x), x ~ N(m, P), by the sigma points."""
    X = sigma_points(m, P, sw)
    Y = jax.vmap(fn)(X)
    ym = sw.wm @ Y
    dY, dX = Y - ym, X - m
    return ym, sym((sw.wc[:, None] * dY).T @ dY), (sw.wc[:, None] * dX).T @ dY


def ukf_predict(m, P, f: Callable, u, Q, sw: SigmaWeights):
    mp, Pp, _ = unscented_transform(lambda x: f(x, u), m, P, sw)
    return mp, sym(Pp + Q)


def ukf_update(m, P, y, h: Callable, R, sw: SigmaWeights, observed=None):
    """Condition N(m, P) on y = h(x) + v: (mean, cov, log N(y; yhat, S)); ``observed`` as in
    ``kalman.update``."""
    yhat, Pyy, Pxy = unscented_transform(h, m, P, sw)
    return condition(m, P, y, yhat, Pyy, Pxy, R, observed)


class UnscentedKalmanFilter(Estimator):
    """UKF for x_{k+1} = f(x_k, u_k) + w, y_k = h(x_k) + v, as an engine estimator.

    Same timing and ``aux`` (a ``GaussianAux``) as ``KalmanFilter``: sample j brings y_j and u_{j-1}; from j = 1
    on the filter predicts with u_{j-1}, then updates with y_j; (xhat0, P0) is the prior of x_0 before y_0.
    ``h``, ``f`` static (compared by identity); ``alpha``, ``beta``, ``kappa`` array fields (traced). ``R`` and
    ``nan_missing``: as in ``KalmanFilter``.
    """

    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    alpha: jax.Array = param()
    beta: jax.Array = param()
    kappa: jax.Array = param()
    f: Callable = eqx.field(static=True)
    h: Callable = eqx.field(static=True)
    n_inputs: int = eqx.field(static=True)
    nan_missing: bool = eqx.field(default=False, static=True)

    def __init__(self, f: Callable, h: Callable, Q, R, P0, xhat0=None, *, n_inputs: int = 1, alpha=DEFAULT_ALPHA,
                 beta=DEFAULT_BETA, kappa=DEFAULT_KAPPA, nan_missing: bool = False):
        for name, v in (("Q", Q), ("R", R), ("P0", P0), ("xhat0", xhat0)):
            if v is not None:
                checks.check_real(self, name, v)
        if not callable(f) or not callable(h):
            raise checks.ArgumentTypeError(f"UnscentedKalmanFilter: f and h must be functions, "
                                           f"got {type(f).__name__} and {type(h).__name__}")
        checks.check_square(self, "P0", P0)
        self.f, self.h, self.Q, self.P0 = f, h, Q, P0
        self.xhat0 = jnp.zeros(jnp.shape(P0)[0]) if xhat0 is None else xhat0
        self.R, self.nan_missing = as_covariance(R, lambda: output_size(None, h, self.xhat0)), nan_missing
        self.alpha, self.beta, self.kappa, self.n_inputs = alpha, beta, kappa, n_inputs

    def __check_init__(self):
        d = self.P0.shape[0]
        why = f"for a {d}-state model (P0 is {checks.fmt_shape(self.P0.shape)})"
        checks.check_covariance(self, "Q", self.Q, d, why)
        checks.check_covariance(self, "P0", self.P0, d)
        checks.check_square(self, "R", self.R)
        checks.check_psd(self, "R", self.R)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
        checks.check_int(self, "n_inputs", self.n_inputs, 0)
        checks.check_positive(self, "alpha", self.alpha)
        for name in ("beta", "kappa"):
            checks.check_finite(self, name, getattr(self, name))

    def io_sizes(self) -> dict:
        return {"in": (self.R.shape[0], f"R is {checks.fmt_shape(self.R.shape)}"),
                "out": (self.P0.shape[0], f"P0 is {checks.fmt_shape(self.P0.shape)}"),
                "u": (self.n_inputs, f"n_inputs={self.n_inputs}")}

    def init(self, key, x0):
        x = jnp.asarray(self.xhat0, dtype=dtype_of(x0))
        return KFState(x, jnp.asarray(self.P0, x.dtype))

    def step(self, state, y, u_prev, key, k):
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.x.dtype), (self.n_inputs,))
        sw = sigma_weights(state.x.shape[0], self.alpha, self.beta, self.kappa)
        xp, Pp = ukf_predict(state.x, state.P, self.f, u_prev, self.Q, sw)
        first = k == 0
        xp, Pp = jnp.where(first, state.x, xp), jnp.where(first, state.P, Pp)
        observed = ~jnp.isnan(y) if self.nan_missing else None
        x, P, ll = ukf_update(xp, Pp, y, self.h, self.R, sw, observed)
        return KFState(x, P), x, GaussianAux(P, xp, Pp, ll)
