"""Discrete Kalman filter and extended Kalman filter (thesis §1.1; Stumfoll (163)-(171)).

Model x_{k+1} = F x_k + G u_k + w_k, y_k = H x_k + v_k, w ~ (0, Q), v ~ (0, R). One cycle:

    P-_{k+1} = F P+_k F^T + Q                                   (167)
    K_{k+1}  = P-_{k+1} H^T (H P-_{k+1} H^T + R)^{-1}           (168)
    x-_{k+1} = F x+_k + G u_k                                   (169)
    x+_{k+1} = x-_{k+1} + K_{k+1} (y_{k+1} - H x-_{k+1})        (170)
    P+_{k+1} = (I - K H) P-_{k+1} (I - K H)^T + K R K^T          (171, Joseph form)

Stumfoll prints P-_k on the right of (167) and K_k, y_k in (170); the indices above are the consistent reading
(the a-posteriori covariance is propagated; the gain and the measurement of the same step are used). The gain
comes from a Cholesky solve with S = H P- H^T + R, not from an explicit inverse.

Singular S. With R = 0 (or R singular) and H P- H^T of lower rank, for instance two sensors reading the same
state exactly, S is singular and a plain Cholesky gives NaN. The limit of the gain as R -> R + d I, d -> 0, is
P- H^T S^+ (the columns of P- H^T have no component along the null space of S when R = 0), so a pseudo-inverse
gain is the right answer there. The solve is guarded: when the Cholesky factor of S is not finite or its
smallest pivot is tiny (pivot^2 <= d = 1e-10 max diag S; pivot^2 >= the smallest eigenvalue of S, so this needs
cond(S) >= 1e10, where the error bound cond * eps of a plain Cholesky gain is ~1e-6 already), S + d I is
factored instead. That gain is finite and differentiable and differs from P- H^T S^+ by about
d / (smallest nonzero eigenvalue of S) plus eps / 1e-10 ~ 1e-6 relative (rounding left in the null directions
of S, amplified by 1/d); d equal to the threshold keeps the gain continuous up to a factor 2 across it.
A well-conditioned S takes the unguarded path, bit for bit.

``jitter`` (default 0) adds jitter * I to S in the gain only; the Joseph form (171) keeps the true R,
so P stays the error covariance of the estimator that uses that (slightly suboptimal) gain.

In the init/step interface sample j brings y_j and u_{j-1}: the filter predicts with u_{j-1} (for j >= 1; at
j = 0 the prior is (xhat0, P0)) and updates with y_j; the output is x+_j.

The EKF (``ekf``) replaces F, G by the local model of continuous dynamics at x+ (``local_model``: Jacobian,
matrix exponential over h, as in thesis §1.6), and propagates the mean by the same local affine model
(the exponential-Euler step, exact for linear dynamics: the EKF of a linear model is the KF).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.estimators.linearized import local_model
from jaxdip.sim.component import Component


class KFParams(NamedTuple):
    Phi: jnp.ndarray  # F (d, d)
    W: jnp.ndarray  # G (d, m)
    C: jnp.ndarray  # H (p, d)
    Q: jnp.ndarray  # (d, d) process noise covariance
    R: jnp.ndarray  # (p, p) measurement noise covariance
    P0: jnp.ndarray  # (d, d) prior covariance of xhat0
    xhat0: jnp.ndarray  # (d,)


class EKFParams(NamedTuple):
    model: Any  # the plant's parameter pytree
    C: jnp.ndarray
    Q: jnp.ndarray
    R: jnp.ndarray
    P0: jnp.ndarray
    xhat0: jnp.ndarray


class KFState(NamedTuple):
    x: jnp.ndarray  # x+ (a posteriori) after the step; the prior (xhat0) before the first one
    P: jnp.ndarray


_PIVOT_RTOL = 1e-10  # guarded innovation solve: smallest Cholesky pivot^2 relative to max diag S (see above)


def _guarded_cho_factor(S):
    """Cholesky factor of S, or of S + d I when S is singular or nearly so (d = _PIVOT_RTOL max diag S)."""
    L = jnp.linalg.cholesky(jax.lax.stop_gradient(S))
    d = _PIVOT_RTOL * jnp.max(jnp.diag(S)) + jnp.finfo(S.dtype).tiny
    piv = jnp.diag(L)
    bad = ~jnp.all(jnp.isfinite(L)) | (jnp.min(piv) ** 2 <= d)
    # factor the selected matrix, not the selected factor: a NaN factor left in a jnp.where would poison
    # gradients through the unselected branch
    S = jnp.where(bad, S + d * jnp.eye(S.shape[0], dtype=S.dtype), S)
    return jsl.cho_factor(S, lower=True)


def kf_update(x_pred, P_pred, y, C, R, jitter: float = 0.0):
    """Measurement update (168), (170), (171); ``jitter`` (>= 0, a number or an array) adds jitter * I to S
    for the gain only."""
    S = C @ P_pred @ C.T + R
    S = 0.5 * (S + S.T)
    if not (isinstance(jitter, (int, float)) and jitter == 0):  # a literal 0 leaves the graph as it was
        S = S + jitter * jnp.eye(S.shape[0], dtype=S.dtype)
    cf = _guarded_cho_factor(S)
    K = jsl.cho_solve(cf, C @ P_pred).T  # K = P- C^T S^{-1}, S and P- symmetric
    x = x_pred + K @ (y - C @ x_pred)
    IKC = jnp.eye(P_pred.shape[0], dtype=P_pred.dtype) - K @ C
    P = IKC @ P_pred @ IKC.T + K @ R @ K.T
    return x, 0.5 * (P + P.T)


def kf_predict(x, P, Phi, Wu_b, Q):
    """Time update (167), (169): x- = Phi x + (W u + b), P- = Phi P Phi^T + Q."""
    return Phi @ x + Wu_b, Phi @ P @ Phi.T + Q


def _init(params, from_truth, x0):
    x = jnp.asarray(x0 if from_truth else params.xhat0, dtype=jnp.result_type(float))
    return KFState(x, jnp.asarray(params.P0, x.dtype))


def kalman(from_truth: bool = False, jitter: float = 0.0) -> Component:
    """Discrete Kalman filter for an LTI model (``KFParams``); ``jitter``: see ``kf_update``."""

    def init(params: KFParams, key, x0):
        return _init(params, from_truth, x0)

    def step(params: KFParams, st: KFState, inp, key, k):
        y, u_prev = inp
        u_prev = jnp.reshape(u_prev, (params.W.shape[1],))
        xp, Pp = kf_predict(st.x, st.P, params.Phi, params.W @ u_prev, params.Q)
        first = k == 0
        xp, Pp = jnp.where(first, st.x, xp), jnp.where(first, st.P, Pp)
        x, P = kf_update(xp, Pp, y, params.C, params.R, jitter)
        return KFState(x, P), x

    return Component(init, step)


def ekf(f: Callable, h: float, n_inputs: int, from_truth: bool = False, expm_squarings: int = 24,
        jitter: float = 0.0) -> Component:
    """Extended Kalman filter for continuous dynamics ``f(model_params, x, u)`` sampled every ``h``
    (``expm_squarings``: see ``linearized.expm_small``; ``jitter``: see ``kf_update``)."""

    def init(params: EKFParams, key, x0):
        return _init(params, from_truth, x0)

    def step(params: EKFParams, st: KFState, inp, key, k):
        y, u_prev = inp
        u_prev = jnp.reshape(jnp.asarray(u_prev, st.x.dtype), (n_inputs,))
        lm = local_model(f, params.model, st.x, u_prev, h, with_inverse=False, max_squarings=expm_squarings)
        xp, Pp = kf_predict(st.x, st.P, lm.Phi, lm.W @ u_prev + lm.b, params.Q)
        first = k == 0
        xp, Pp = jnp.where(first, st.x, xp), jnp.where(first, st.P, Pp)
        x, P = kf_update(xp, Pp, y, params.C, params.R, jitter)
        return KFState(x, P), x

    return Component(init, step)
