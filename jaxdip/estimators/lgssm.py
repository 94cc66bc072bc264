"""Batch Kalman filtering and RTS smoothing of whole sequences, with covariances and the log marginal likelihood.

Model (time index k = 0 .. T-1; the dynamax convention, so results compare directly):

    x_0 ~ N(m0, P0),
    x_{k+1} = Phi_k x_k + W_k u_k + w_k,      w_k ~ N(0, Q_k)        (or f(x_k, u_k) + w_k)
    y_k     = C_k x_k + v_k,                   v_k ~ N(0, R_k)        (or h(x_k) + v_k)

so (m0, P0) is the prior of x_0 *before* y_0 is seen (unlike the online ``KalmanFilter``, whose first sample is
an update of xhat0 too: the same thing). Every matrix may be one array (time-invariant) or a stack with a
leading axis of length T (time-varying; the transition entry T-1 is never used).

``kalman_filter`` returns the filtered moments x_k | y_0..k, the predicted ones x_k | y_0..k-1 and the log
marginal likelihood log p(y_0..T-1) = sum_k log N(y_k; yhat_k, S_k). ``rts_smoother`` adds x_k | y_0..T-1.

Nonlinear maps (EKF/EKS): ``h(x)`` and ``f(x, u)`` are linearised by forward-mode autodiff at the predicted
mean (measurement) and at the filtered mean (transition); the mean goes through the nonlinear map itself. For a
linear h or f this is the KF to rounding. The smoother uses the transition Jacobians of the filter pass (the
usual extended RTS smoother).

Solves. The innovation covariance S_k and the predicted covariance in the smoother gain are factored by the
guarded Cholesky of ``jaxdip.estimators.kalman`` (singular or nearly singular S gets d I added, d = 1e-10 max
diag S; a well-conditioned S takes the plain path), so a degenerate model gives finite numbers and gradients.
The covariance update is the Joseph form. log det S comes from the same factor.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.estimators.kalman import _guarded_cho_factor

_LOG_2PI = 1.8378770664093453


class FilterResult(NamedTuple):
    mean: jax.Array  # (T, d) E[x_k | y_0..k]
    cov: jax.Array  # (T, d, d)
    pred_mean: jax.Array  # (T, d) E[x_k | y_0..k-1] (pred_mean[0] = m0)
    pred_cov: jax.Array  # (T, d, d)
    log_likelihood: jax.Array  # () log p(y_0..T-1)
    log_likelihood_terms: jax.Array  # (T,) log p(y_k | y_0..k-1)


class SmootherResult(NamedTuple):
    mean: jax.Array  # (T, d) E[x_k | y_0..T-1]
    cov: jax.Array  # (T, d, d)
    filtered: FilterResult


def _per_step(a, T: int, ndim: int):
    """Broadcast a time-invariant array to a stack of T; a stack (ndim + 1 axes) is kept."""
    a = jnp.asarray(a, dtype=jnp.result_type(float))
    if a.ndim == ndim:
        return jnp.broadcast_to(a, (T,) + a.shape)
    if a.ndim == ndim + 1 and a.shape[0] == T:
        return a
    raise ValueError(f"expected an array of {ndim} axes or a stack of {T} of them, got shape {a.shape}")


def _sym(P):
    return 0.5 * (P + P.T)


def gaussian_update(m, P, y, H, yhat, R):
    """Measurement update of N(m, P) by y ~ N(yhat + H (x - m), R): returns (mean, cov, log N(y; yhat, S))."""
    S = _sym(H @ P @ H.T + R)
    cf = _guarded_cho_factor(S)
    K = jsl.cho_solve(cf, H @ P).T
    e = y - yhat
    mean = m + K @ e
    IKH = jnp.eye(P.shape[0], dtype=P.dtype) - K @ H
    cov = _sym(IKH @ P @ IKH.T + K @ R @ K.T)
    L = cf[0]
    z = jsl.solve_triangular(L, e, lower=True)
    logdet = 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diag(L))))
    ll = -0.5 * (z @ z + logdet + e.shape[0] * _LOG_2PI)
    return mean, cov, ll


def _prepare(ys, m0, P0, Phi, W, C, Q, R, us, f, h):
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    T, p = ys.shape
    m0 = jnp.asarray(m0, dtype=ys.dtype)
    d = m0.shape[0]
    us = jnp.zeros((T, 1), ys.dtype) if us is None else jnp.asarray(us, dtype=ys.dtype).reshape(T, -1)
    m = us.shape[1]
    Qs = _per_step(Q, T, 2)
    Rs = _per_step(R, T, 2)
    Phis = Ws = None
    if f is None:
        Phis = _per_step(Phi, T, 2)
        W = jnp.zeros((d, m), ys.dtype) if W is None else jnp.asarray(W, dtype=ys.dtype)
        Ws = _per_step(W.reshape(d, m) if W.ndim == 1 else W, T, 2)
    Cs = _per_step(C, T, 2) if h is None else None
    return ys, us, m0, jnp.asarray(P0, ys.dtype), Phis, Ws, Cs, Qs, Rs


def kalman_filter(ys, m0, P0, Q, R, Phi=None, C=None, W=None, us=None, *,
                  f: Optional[Callable] = None, h: Optional[Callable] = None) -> FilterResult:
    """Kalman filter (EKF with ``f``/``h``) over a whole sequence ``ys`` (T, p) by ``lax.scan``.

    Linear parts: ``Phi`` (d, d), ``C`` (p, d), ``W`` (d, m) with inputs ``us`` (T, m); each may be a stack over
    T. Nonlinear parts replace them: ``f(x, u) -> x_next``, ``h(x) -> y``. ``Q``, ``R``: covariances (or stacks).
    """
    if (f is None) == (Phi is None):
        raise ValueError("give exactly one of Phi (linear dynamics) and f (nonlinear dynamics)")
    if (h is None) == (C is None):
        raise ValueError("give exactly one of C (linear measurement) and h (nonlinear measurement)")
    ys, us, m0, P0, Phis, Ws, Cs, Qs, Rs = _prepare(ys, m0, P0, Phi, W, C, Q, R, us, f, h)
    T = ys.shape[0]
    idx = jnp.arange(T)

    def body(carry, k):
        mp, Pp = carry
        if h is None:
            H = Cs[k]
            yhat = H @ mp
        else:
            H = jax.jacfwd(h)(mp)
            yhat = h(mp)
        mf, Pf, ll = gaussian_update(mp, Pp, ys[k], H, yhat, Rs[k])
        if f is None:
            F = Phis[k]
            mn = F @ mf + Ws[k] @ us[k]
        else:
            F = jax.jacfwd(f, argnums=0)(mf, us[k])
            mn = f(mf, us[k])
        Pn = _sym(F @ Pf @ F.T + Qs[k])
        return (mn, Pn), (mf, Pf, mp, Pp, ll, F)

    _, (mf, Pf, mp, Pp, ll, _) = jax.lax.scan(body, (m0, P0), idx)
    return FilterResult(mf, Pf, mp, Pp, jnp.sum(ll), ll)


def _transition_jacobians(filt: FilterResult, Phi, us, f, T: int):
    if f is None:
        return _per_step(Phi, T, 2)
    return jax.vmap(jax.jacfwd(f, argnums=0))(filt.mean, us)


def rts_smoother(ys, m0, P0, Q, R, Phi=None, C=None, W=None, us=None, *,
                 f: Optional[Callable] = None, h: Optional[Callable] = None) -> SmootherResult:
    """Rauch-Tung-Striebel smoother (extended with ``f``/``h``): filter forward, then backward

        G_k  = P_k F_k^T (P-_{k+1})^{-1}
        ms_k = m_k + G_k (ms_{k+1} - m-_{k+1}),     Ps_k = P_k + G_k (Ps_{k+1} - P-_{k+1}) G_k^T.
    """
    filt = kalman_filter(ys, m0, P0, Q, R, Phi, C, W, us, f=f, h=h)
    T = filt.mean.shape[0]
    us_ = jnp.zeros((T, 1)) if us is None else jnp.asarray(us, dtype=filt.mean.dtype).reshape(T, -1)
    Fs = _transition_jacobians(filt, Phi, us_, f, T)

    def body(carry, inp):
        ms_next, Ps_next = carry
        m, P, F, mp_next, Pp_next = inp
        cf = _guarded_cho_factor(Pp_next)
        G = jsl.cho_solve(cf, F @ P).T  # P F^T (P-)^{-1}, P and P- symmetric
        ms = m + G @ (ms_next - mp_next)
        Ps = _sym(P + G @ (Ps_next - Pp_next) @ G.T)
        return (ms, Ps), (ms, Ps)

    last = (filt.mean[-1], filt.cov[-1])
    inputs = (filt.mean[:-1], filt.cov[:-1], Fs[:-1], filt.pred_mean[1:], filt.pred_cov[1:])
    _, (ms, Ps) = jax.lax.scan(body, last, inputs, reverse=True)
    ms = jnp.concatenate([ms, last[0][None]])
    Ps = jnp.concatenate([Ps, last[1][None]])
    return SmootherResult(ms, Ps, filt)


def log_likelihood(ys, m0, P0, Q, R, Phi=None, C=None, W=None, us=None, *,
                   f: Optional[Callable] = None, h: Optional[Callable] = None) -> jax.Array:
    """log p(y_0..T-1) of the model (the filter's prediction-error decomposition)."""
    return kalman_filter(ys, m0, P0, Q, R, Phi, C, W, us, f=f, h=h).log_likelihood
