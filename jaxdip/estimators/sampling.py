"""Posterior sampling of the state path: forward-filter backward-sample (FFBS, Carter and Kohn; Frühwirth-Schnatter).

For the linear-Gaussian model of ``KalmanFilter`` the joint posterior p(x_0..T-1 | y_0..T-1) factors backwards,

    x_{T-1} ~ N(m_{T-1}, P_{T-1}),
    x_k | x_{k+1} ~ N(m_k + G_k (x_{k+1} - m-_{k+1}),  P_k - G_k P-_{k+1} G_k^T),   G_k = P_k F_k^T (P-_{k+1})^{-1},

with (m_k, P_k) the filtered and (m-_{k+1}, P-_{k+1}) the predicted moments of ``recorded.kalman_filter`` and
G_k the Rauch-Tung-Striebel gain. The draws' mean and covariance at each k are the RTS smoother's, and their
lag-one covariance is the smoother's ``cross_cov``. For an ``ExtendedKalmanFilter`` the same recursion with the
Jacobians at the filtered means samples the linearised posterior (an approximation). Missing data (``mask``,
``nan_missing``) and feedthrough (``D``) are those of ``jaxdip.estimators.recorded``.

The gains and the factors of the conditional covariances do not depend on the draw: they are computed once, and
the draws are one backward ``lax.scan`` over (n, d) blocks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator
from jaxdip.estimators.kalman import guarded_cho_factor, smoother_gain, sym
from jaxdip.estimators.recorded import kalman_filter

from jaxdip._public import public_dir

__all__ = ["sample_posterior"]
__dir__ = public_dir(globals())


def sample_posterior(key: jax.Array, est: Estimator, ys, us=None, n_samples: int = 1, *, mask=None,
                     nan_missing: bool = False, D=None) -> jax.Array:
    """``n_samples`` draws (n, T, d) of the state path x_0..T-1 given ``ys`` (T, p) by FFBS (module doc)."""
    checks.check_int("sample_posterior", "n_samples", n_samples, 1)
    if not hasattr(est, "transition_jacobian"):
        raise checks.ArgumentTypeError(f"sample_posterior needs an estimator with transition_jacobian "
                                       f"(KalmanFilter, ExtendedKalmanFilter), got {type(est).__name__}")
    filt = kalman_filter(est, ys, us, mask=mask, nan_missing=nan_missing, D=D)
    T, d = filt.mean.shape
    us_ = jnp.zeros((T, 1), filt.mean.dtype) if us is None else jnp.asarray(us, filt.mean.dtype).reshape(T, -1)
    Fs = jax.vmap(est.transition_jacobian)(filt.mean[:-1], us_[:-1], jnp.arange(T - 1))

    def backward_law(m, P, F, mp_next, Pp_next):
        G = smoother_gain(P, F, Pp_next)
        # P - G P- G^T is PSD but may be singular (noise-free directions): the guarded factor stays finite
        return G, m - G @ mp_next, guarded_cho_factor(sym(P - G @ Pp_next @ G.T))[0]

    G, offset, L = jax.vmap(backward_law)(filt.mean[:-1], filt.cov[:-1], Fs, filt.pred_mean[1:], filt.pred_cov[1:])
    z = jax.random.normal(key, (T, n_samples, d), filt.mean.dtype)
    L_last = guarded_cho_factor(filt.cov[-1])[0]
    x_last = filt.mean[-1] + z[-1] @ L_last.T

    def body(x_next, inp):
        G_k, off_k, L_k, z_k = inp
        x = off_k + x_next @ G_k.T + z_k @ L_k.T
        return x, x

    _, xs = jax.lax.scan(body, x_last, (G, offset, jnp.tril(L), z[:-1]), reverse=True)
    return jnp.moveaxis(jnp.concatenate([xs, x_last[None]]), 0, 1)
