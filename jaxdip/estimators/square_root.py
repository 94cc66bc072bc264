"""Square-root Kalman filter and Rauch-Tung-Striebel smoother of a linear-Gaussian model (``KalmanFilter``):
lower Cholesky factors N (P = N N^T) are propagated by orthogonal (QR) transformations, never P itself, so the
computed covariances stay symmetric positive semidefinite and carry about twice the significant digits of the
covariance form; that is what keeps float32 and ill-conditioned problems alive. Selected by
``form="sqrt"`` in ``jaxdip.estimators.recorded``; same timing and outputs as the covariance form there.

``tria(M)`` is a lower-triangular L with L L^T = M M^T (from the QR factorisation of M^T). With square roots
sQ, sR of Q, R (``psd_factor``: Cholesky, or the symmetric root of a singular one), one cycle is

    predict:  N-_{j+1} = tria([Phi N_j, sQ])
    update:   tria([[sR, C N-], [0, N-]]) = [[Sy, 0], [Kb, N+]],   Sy Sy^T = S = C P- C^T + R,
              x+ = x- + Kb Sy^{-1} (y - C x-),   log N(y; C x-, S) from Sy,

and the smoother step (Kb N-^{-1} is the RTS gain G; X X^T = P - G P- G^T is the covariance of x_j given x_{j+1})

    tria([[Phi N_j, sQ], [N_j, 0]]) = [[N-_{j+1}, 0], [Z, X]],   G = Z N-^{-1},
    ms_j = m_j + G (ms_{j+1} - x-_{j+1}),   Ns_j = tria([X, G Ns_{j+1}]).

Only the linear-Gaussian model has a square-root form here (the EKF and UKF run in the covariance form).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.estimators._linear_gaussian import LinearGaussian, at, psd_factor

from jaxdip._public import public_dir

__all__ = ["tria", "sqrt_predict", "sqrt_update", "SqrtFilterOut", "sqrt_filter", "sqrt_smoother"]
__dir__ = public_dir(globals())

_LOG_2PI = 1.8378770664093453


def tria(M):
    """A lower-triangular L with L L^T = M M^T (M is n x k, k >= n): the transposed R of QR(M^T)."""
    return jnp.linalg.qr(M.T, mode="r").T


def sqrt_predict(m, N, Phi, c, sQ):
    """Time update: (Phi m + c, tria([Phi N, sQ]))."""
    return Phi @ m + c, tria(jnp.concatenate([Phi @ N, sQ], axis=1))


def sqrt_update(m, N, y, C, sR):
    """Measurement update of N(m, N N^T) by y ~ N(C x, sR sR^T): (m+, N+, log N(y; C m, S))."""
    p, d = C.shape
    top = jnp.concatenate([sR, C @ N], axis=1)
    bottom = jnp.concatenate([jnp.zeros((d, p), N.dtype), N], axis=1)
    L = tria(jnp.concatenate([top, bottom], axis=0))
    Sy, Kb, N_post = L[:p, :p], L[p:, :p], L[p:, p:]
    z = jsl.solve_triangular(Sy, y - C @ m, lower=True)
    ll = -0.5 * (z @ z + 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diag(Sy)))) + p * _LOG_2PI)
    return m + Kb @ z, N_post, ll


class SqrtFilterOut(NamedTuple):
    mean: jax.Array  # (T, d) filtered
    factor: jax.Array  # (T, d, d) lower factor of the filtered covariance
    pred_mean: jax.Array  # (T, d)
    pred_factor: jax.Array  # (T, d, d)
    log_likelihood_terms: jax.Array  # (T,) without the missing-data offset


def _factors(M):
    return psd_factor(M) if M.ndim == 2 else jax.vmap(psd_factor)(M)


def sqrt_filter(lg: LinearGaussian) -> SqrtFilterOut:
    """The square-root filter over the model and data ``lg`` (``jaxdip.estimators._linear_gaussian``)."""
    sQ, sR = _factors(lg.Q), _factors(lg.R)
    m0, N0 = lg.xhat0, psd_factor(lg.P0)
    first = sqrt_update(m0, N0, lg.ys[0], at(lg.C, 0), at(sR, 0))

    def body(carry, inp):
        m, N = carry
        j, y, u = inp  # sample j >= 1: predict with the transition j - 1, read y_j
        mp, Np = sqrt_predict(m, N, at(lg.Phi, j - 1), at(lg.W, j - 1) @ u, at(sQ, j - 1))
        m, N, ll = sqrt_update(mp, Np, y, at(lg.C, j), at(sR, j))
        return (m, N), (m, N, mp, Np, ll)

    T = lg.ys.shape[0]
    _, rest = jax.lax.scan(body, first[:2], (jnp.arange(1, T), lg.ys[1:], lg.us[:-1]))
    head = (first[0], first[1], m0, N0, first[2])
    return SqrtFilterOut(*(jnp.concatenate([h[None], r]) for h, r in zip(head, rest)))


def sqrt_smoother(lg: LinearGaussian, filt: SqrtFilterOut):
    """Square-root RTS smoother after ``sqrt_filter``: (means (T, d), lower factors (T, d, d))."""
    sQ = _factors(lg.Q)
    d = filt.mean.shape[1]

    def body(carry, inp):
        ms_next, Ns_next = carry
        j, m, N, u = inp
        Phi = at(lg.Phi, j)
        pre = jnp.block([[Phi @ N, at(sQ, j)], [N, jnp.zeros_like(N)]])
        L = tria(pre)
        Np, Z, X = L[:d, :d], L[d:, :d], L[d:, d:]
        G = jsl.solve_triangular(Np, Z.T, lower=True, trans="T").T  # G Np = Z
        ms = m + G @ (ms_next - (Phi @ m + at(lg.W, j) @ u))
        Ns = tria(jnp.concatenate([X, G @ Ns_next], axis=1))
        return (ms, Ns), (ms, Ns)

    T = filt.mean.shape[0]
    last = (filt.mean[-1], filt.factor[-1])
    inputs = (jnp.arange(T - 1), filt.mean[:-1], filt.factor[:-1], lg.us[:-1])
    _, (ms, Ns) = jax.lax.scan(body, last, inputs, reverse=True)
    return jnp.concatenate([ms, last[0][None]]), jnp.concatenate([Ns, last[1][None]])
