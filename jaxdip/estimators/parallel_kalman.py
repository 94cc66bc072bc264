"""Parallel-in-time Kalman filter and RTS smoother of a linear-Gaussian model (``KalmanFilter``) by
``jax.lax.associative_scan``: depth O(log T) instead of T, the elements and operators of Särkkä &
García-Fernández (2021), "Temporal parallelization of Bayesian smoothers", IEEE TAC 66(1), Lemmas 7-10.
Selected by ``form="parallel"`` in ``jaxdip.estimators.recorded``; same timing and outputs as the covariance form.

Filter. Element k >= 1 is p(x_k | x_{k-1}, y_k) = N(A x_{k-1} + b, Cm) together with the likelihood of y_k as
a function of x_{k-1}, N_I(eta, J) (information form). With F = Phi_{k-1}, c = W_{k-1} u_{k-1}, Q = Q_{k-1},
H = C_k, R = R_k and S = H Q H^T + R, K = Q H^T S^{-1}:

    A = (I - K H) F,   b = c + K (y_k - H c),   Cm = (I - K H) Q,
    eta = F^T H^T S^{-1} (y_k - H c),   J = F^T H^T S^{-1} H F;

element 0 is the first update of the prior (xhat0, P0) by y_0 (A = 0, eta = 0, J = 0). Combining an earlier
element i with a later j, with X = I + Cm_i J_j:

    A = A_j X^{-1} A_i,   b = A_j X^{-1} (b_i + Cm_i eta_j) + b_j,   Cm = A_j X^{-1} Cm_i A_j^T + Cm_j,
    eta = A_i^T X^{-T} (eta_j - J_j b_i) + eta_i,   J = A_i^T X^{-T} J_j A_i + J_i.

The prefix combinations' (b, Cm) are the filtered moments. The predicted moments and the log-likelihood terms
log N(y_k; C_k x-_k, S_k) are then computed for all k at once from them.

Smoother. Element k < T-1 is p(x_k | y_0..k, x_{k+1}) = N(E x_{k+1} + g, L): E = P_k F^T (P-_{k+1})^{-1},
g = m_k - E (F m_k + c), L = P_k - E F P_k; the last is (0, m_{T-1}, P_{T-1}). A later element j folded into
an earlier i gives (E_i E_j, E_i g_j + g_i, E_i L_j E_i^T + L_i); the suffix combinations are the smoothed moments.

Float64 (the information-form elements lose digits in float32). Only the linear-Gaussian model has this form.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.estimators._linear_gaussian import LinearGaussian, at
from jaxdip.estimators.kalman import guarded_cho_factor, log_likelihood_of, smoother_gain, sym, update

from jaxdip._public import public_dir

__all__ = ["FilterElement", "SmootherElement", "ParallelFilterOut", "filter_elements", "combine_filter", "parallel_filter",
           "smoother_elements", "combine_smoother", "parallel_smoother"]
__dir__ = public_dir(globals())


class FilterElement(NamedTuple):
    A: jax.Array
    b: jax.Array
    C: jax.Array
    eta: jax.Array
    J: jax.Array


class SmootherElement(NamedTuple):
    E: jax.Array
    g: jax.Array
    L: jax.Array


def _element(F, c, Q, H, R, y) -> FilterElement:
    S = sym(H @ Q @ H.T + R)
    cf = guarded_cho_factor(S)
    HF = H @ F
    K = jsl.cho_solve(cf, H @ Q).T  # Q H^T S^{-1}, Q and S symmetric
    IKH = jnp.eye(F.shape[0], dtype=F.dtype) - K @ H
    e = y - H @ c
    return FilterElement(IKH @ F, c + K @ e, sym(IKH @ Q), HF.T @ jsl.cho_solve(cf, e), sym(HF.T @ jsl.cho_solve(cf, HF)))


def filter_elements(lg: LinearGaussian) -> FilterElement:
    """The T filtering elements (stacked, leading axis T) of the model and data ``lg``."""
    d = lg.xhat0.shape[0]
    m0, P0, _ = update(lg.xhat0, lg.P0, lg.ys[0], at(lg.C, 0), at(lg.C, 0) @ lg.xhat0, at(lg.R, 0))
    zero = jnp.zeros((d, d), m0.dtype)
    first = FilterElement(zero, m0, P0, jnp.zeros(d, m0.dtype), zero)
    if lg.W.ndim == 3:
        cs = jnp.einsum("tij,tj->ti", lg.W[:-1], lg.us[:-1])
    else:
        cs = lg.us[:-1] @ lg.W.T
    # transition k-1 and reading k for k = 1..T-1: a slice of a stack over time, or the constant (vmap axis None)
    trans = [(a[:-1], 0) if a.ndim == 3 else (a, None) for a in (lg.Phi, lg.Q)]
    reads = [(a[1:], 0) if a.ndim == 3 else (a, None) for a in (lg.C, lg.R)]
    (Phi, aP), (Q, aQ) = trans
    (C, aC), (R, aR) = reads
    rest = jax.vmap(_element, in_axes=(aP, 0, aQ, aC, aR, 0))(Phi, cs, Q, C, R, lg.ys[1:])
    return FilterElement(*(jnp.concatenate([f[None], r]) for f, r in zip(first, rest)))


def combine_filter(ei: FilterElement, ej: FilterElement) -> FilterElement:
    """Earlier element ``ei`` followed by later ``ej`` (one pair; vmap for stacks)."""
    X = jnp.eye(ei.A.shape[0], dtype=ei.A.dtype) + ei.C @ ej.J
    M1 = jnp.linalg.solve(X.T, ej.A.T).T  # A_j X^{-1}
    M2 = jnp.linalg.solve(X, ei.A).T  # A_i^T X^{-T}
    return FilterElement(M1 @ ei.A, M1 @ (ei.b + ei.C @ ej.eta) + ej.b, sym(M1 @ ei.C @ ej.A.T + ej.C),
                         M2 @ (ej.eta - ej.J @ ei.b) + ei.eta, sym(M2 @ ej.J @ ei.A + ei.J))


class ParallelFilterOut(NamedTuple):
    mean: jax.Array
    cov: jax.Array
    pred_mean: jax.Array
    pred_cov: jax.Array
    log_likelihood_terms: jax.Array  # without the missing-data offset


def parallel_filter(lg: LinearGaussian) -> ParallelFilterOut:
    """The filtered and predicted moments and log N(y_k; yhat_k, S_k) of every k (module doc)."""
    out = jax.lax.associative_scan(jax.vmap(combine_filter), filter_elements(lg))
    m, P = out.b, out.C
    T = m.shape[0]

    def predicted(j, m, P, u):  # x-_{j+1} from x+_j
        Phi = at(lg.Phi, j)
        return Phi @ m + at(lg.W, j) @ u, Phi @ P @ Phi.T + at(lg.Q, j)

    mp, Pp = jax.vmap(predicted)(jnp.arange(T - 1), m[:-1], P[:-1], lg.us[:-1])
    mp = jnp.concatenate([lg.xhat0[None], mp])
    Pp = jnp.concatenate([lg.P0[None], Pp])

    def term(k, mp, Pp, y):
        H = at(lg.C, k)
        return log_likelihood_of(guarded_cho_factor(sym(H @ Pp @ H.T + at(lg.R, k))), y - H @ mp)

    return ParallelFilterOut(m, P, mp, Pp, jax.vmap(term)(jnp.arange(T), mp, Pp, lg.ys))


def smoother_elements(lg: LinearGaussian, mean, cov) -> SmootherElement:
    """The T smoothing elements from the filtered moments (``mean`` (T, d), ``cov`` (T, d, d))."""
    T = mean.shape[0]

    def element(j, m, P, u):
        Phi = at(lg.Phi, j)
        E = smoother_gain(P, Phi, Phi @ P @ Phi.T + at(lg.Q, j))
        return SmootherElement(E, m - E @ (Phi @ m + at(lg.W, j) @ u), sym(P - E @ Phi @ P))

    rest = jax.vmap(element)(jnp.arange(T - 1), mean[:-1], cov[:-1], lg.us[:-1])
    last = SmootherElement(jnp.zeros_like(cov[-1]), mean[-1], cov[-1])
    return SmootherElement(*(jnp.concatenate([r, l[None]]) for r, l in zip(rest, last)))


def combine_smoother(ej: SmootherElement, ei: SmootherElement) -> SmootherElement:
    """Later element ``ej`` folded into earlier ``ei`` (the argument order of a reverse associative scan)."""
    return SmootherElement(ei.E @ ej.E, ei.E @ ej.g + ei.g, sym(ei.E @ ej.L @ ei.E.T + ei.L))


def parallel_smoother(lg: LinearGaussian, filt: ParallelFilterOut):
    """Smoothed means (T, d) and covariances (T, d, d) after ``parallel_filter``."""
    out = jax.lax.associative_scan(jax.vmap(combine_smoother), smoother_elements(lg, filt.mean, filt.cov),
                                   reverse=True)
    return out.g, out.L
