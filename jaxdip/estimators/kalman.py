"""The Kalman kernel: time update, measurement update, guarded factorisation and log-likelihood (thesis §1.1;
Stumfoll (163)-(171)). Every Kalman-type filter of jaxdip (``KalmanFilter``, ``ExtendedKalmanFilter``,
``UnscentedKalmanFilter`` and the offline filter, smoother and likelihood of ``jaxdip.estimators.recorded``) is
written with these functions.

Model x_{k+1} = F x_k + G u_k + w_k, y_k = H x_k + v_k, w ~ (0, Q), v ~ (0, R). One cycle:

    P-_{k+1} = F P+_k F^T + Q                                   (167)
    K_{k+1}  = P-_{k+1} H^T (H P-_{k+1} H^T + R)^{-1}           (168)
    x-_{k+1} = F x+_k + G u_k                                   (169)
    x+_{k+1} = x-_{k+1} + K_{k+1} (y_{k+1} - H x-_{k+1})        (170)
    P+_{k+1} = (I - K H) P-_{k+1} (I - K H)^T + K R K^T          (171, Joseph form)

Stumfoll prints P-_k on the right of (167) and K_k, y_k in (170); the indices above are the consistent reading
(the a-posteriori covariance is propagated; the gain and the measurement of the same step are used). The gain
comes from a Cholesky solve with S = H P- H^T + R, not from an explicit inverse; log N(y; yhat, S) comes from
the same factor.

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

Missing measurements. ``observed`` (a boolean vector over the components of y, True = observed; None = all)
removes the missing components exactly, not by a large variance (``mask_measurement``): their rows of H, their
residual and their off-diagonal entries of R are zeroed and their diagonal entry of R set to a fill value c, so
S is block diagonal (S_obs, c I), the gain has zero columns for them, and 0.5 log(2 pi c) is added back per
missing component (log N(0; 0, c) = -0.5 log(2 pi c)), so the log-likelihood is the density of the observed
components only. ``update`` and ``condition`` take c = the largest observed diagonal entry of S (1 when none is
observed; no gradient flows through it): a fixed c = 1 next to observed variances below ~1e-10 would trip the
guard below and perturb the observed block by 1e-10 absolute (measured: 67% error in P at variances of 1e-11).
A fully missing step is a pure prediction (K = 0). Every form of the filter calls this one function.

Measurement noise. ``as_covariance`` turns R given as a scalar (r I), a vector (its diagonal) or a full matrix
into the full matrix; the estimators call it on their ``R`` before checking it.

``jitter`` (default 0) adds jitter * I to S in the gain only; the Joseph form (171) keeps the true R,
so P stays the error covariance of the estimator that uses that (slightly suboptimal) gain.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip._public import public_dir
from jaxdip.engine.checks import ArgumentError

__all__ = ["KFState", "GaussianAux", "sym", "as_covariance", "guarded_cho_factor", "log_likelihood_of", "predict",
           "mask_measurement", "mask_fill", "update", "condition", "smoother_gain"]
__dir__ = public_dir(globals())

_LOG_2PI = 1.8378770664093453
_PIVOT_RTOL = 1e-10  # guarded innovation solve: smallest Cholesky pivot^2 relative to max diag S (see above)


class KFState(NamedTuple):
    x: jax.Array  # x+ (a posteriori) after the step; the starting estimate before the first one
    P: jax.Array


class GaussianAux(NamedTuple):
    """What a Kalman-type filter reports at sample j (its ``aux``)."""

    cov: jax.Array  # P+_j
    prior: jax.Array  # x-_j, the one-step prediction from y_0..y_{j-1} (the starting estimate at j = 0)
    prior_cov: jax.Array  # P-_j
    log_likelihood: jax.Array  # log N(y_j; yhat_j, S_j)


def sym(P):
    return 0.5 * (P + P.T)


def as_covariance(R, p) -> jax.Array:
    """R as a full (p, p) matrix: a scalar r is r I, a vector (p,) the diagonal, a matrix (or a stack over time,
    (T, p, p)) is returned as it is. ``p``: an int, or a function returning it (called for a scalar R only).
    Shapes are checked by the caller (``checks.check_covariance``)."""
    R = jnp.asarray(R, dtype=jnp.result_type(float))
    if R.ndim == 0:
        return R * jnp.eye(p() if callable(p) else p, dtype=R.dtype)
    if R.ndim == 1:
        if isinstance(p, int) and R.shape[0] != p:
            raise ArgumentError(f"R as a vector (the diagonal of R) must have {p} entries, one per measurement, "
                                f"got {R.shape[0]}")
        return jnp.diag(R)
    return R


def mask_measurement(observed, y, yhat, H, R, fill=1.0):
    """Remove the components of y where ``observed`` (bool, (p,)) is False (module doc).

    Returns (y, yhat, H, R, log_correction): y and yhat zero there (a NaN in y is dropped, not propagated), the
    rows of H (an (p, d) matrix, or any array whose first axis is the measurement: the transposed
    cross-covariance of the unscented filter) zero, R with those rows and columns of ``fill`` times the
    identity, and 0.5 log(2 pi fill) times the number of missing components, to add to the log-likelihood of
    the masked system. ``mask_fill`` gives the fill that keeps S well scaled."""
    o = jnp.asarray(observed, dtype=bool)
    y = jnp.where(o, y, 0.0)
    yhat = jnp.where(o, yhat, 0.0)
    H = jnp.where(o.reshape((-1,) + (1,) * (jnp.ndim(H) - 1)), H, 0.0)
    both = o[:, None] & o[None, :]
    R = jnp.where(both, R, 0.0) + jnp.diag(jnp.where(o, 0.0, fill).astype(R.dtype))
    return y, yhat, H, R, 0.5 * (_LOG_2PI + jnp.log(fill)) * jnp.sum(~o)


def mask_fill(observed, S_diag):
    """The fill of ``mask_measurement`` for an innovation covariance with diagonal ``S_diag``: its largest
    observed entry (1 if none is observed or it is not positive), without gradient."""
    m = jnp.max(jnp.where(jnp.asarray(observed, dtype=bool), S_diag, 0.0))
    return jax.lax.stop_gradient(jnp.where(m > 0, m, 1.0))


def _plus(ll, corr):
    return ll if corr is None else ll + corr  # unmasked: the graph as it was


def guarded_cho_factor(S):
    """Cholesky factor of S, or of S + d I when S is singular or nearly so (d = _PIVOT_RTOL max diag S)."""
    L = jnp.linalg.cholesky(jax.lax.stop_gradient(S))
    d = _PIVOT_RTOL * jnp.max(jnp.diag(S)) + jnp.finfo(S.dtype).tiny
    piv = jnp.diag(L)
    bad = ~jnp.all(jnp.isfinite(L)) | (jnp.min(piv) ** 2 <= d)
    # factor the selected matrix, not the selected factor: a NaN factor left in a jnp.where would poison
    # gradients through the unselected branch
    S = jnp.where(bad, S + d * jnp.eye(S.shape[0], dtype=S.dtype), S)
    return jsl.cho_factor(S, lower=True)


def log_likelihood_of(cf, e):
    """log N(e; 0, S) from the Cholesky factor ``cf`` of S."""
    L = cf[0]
    z = jsl.solve_triangular(L, e, lower=True)
    return -0.5 * (z @ z + 2.0 * jnp.sum(jnp.log(jnp.abs(jnp.diag(L)))) + e.shape[0] * _LOG_2PI)


def predict(x, P, F, x_next, Q):
    """Time update (167), (169) with the mean ``x_next`` already propagated (F x + G u + b, or f(x, u)):
    returns (x_next, F P F^T + Q)."""
    return x_next, F @ P @ F.T + Q


def update(x_pred, P_pred, y, H, yhat, R, jitter=0.0, observed=None):
    """Measurement update (168), (170), (171) of N(x_pred, P_pred) by y ~ N(yhat + H (x - x_pred), R):
    returns (x+, P+, log N(y; yhat, S)). ``jitter`` (>= 0, a number or an array) adds jitter * I to S for the
    gain only. ``observed``: None, or a boolean (p,) (False = missing; module doc)."""
    corr = None
    if observed is not None:
        fill = mask_fill(observed, jnp.sum((H @ P_pred) * H, axis=1) + jnp.diag(R))
        y, yhat, H, R, corr = mask_measurement(observed, y, yhat, H, R, fill)
    S = H @ P_pred @ H.T + R
    S = sym(S)
    if not (isinstance(jitter, (int, float)) and jitter == 0):  # a literal 0 leaves the graph as it was
        S = S + jitter * jnp.eye(S.shape[0], dtype=S.dtype)
    cf = guarded_cho_factor(S)
    K = jsl.cho_solve(cf, H @ P_pred).T  # K = P- H^T S^{-1}, S and P- symmetric
    e = y - yhat
    x = x_pred + K @ e
    IKH = jnp.eye(P_pred.shape[0], dtype=P_pred.dtype) - K @ H
    P = IKH @ P_pred @ IKH.T + K @ R @ K.T
    return x, sym(P), _plus(log_likelihood_of(cf, e), corr)


def condition(x_pred, P_pred, y, yhat, Pyy, Pxy, R, observed=None):
    """Measurement update from moments (the unscented filter's): S = Pyy + R, K = Pxy S^{-1},
    P+ = P- - K S K^T. Returns (x+, P+, log N(y; yhat, S)). ``observed`` as in ``update``: the missing
    components' rows and columns of S = Pyy + R and columns of Pxy are removed."""
    S = Pyy + R
    corr = None
    if observed is not None:
        y, yhat, PxyT, S, corr = mask_measurement(observed, y, yhat, Pxy.T, S, mask_fill(observed, jnp.diag(S)))
        Pxy = PxyT.T
    S = sym(S)
    cf = guarded_cho_factor(S)
    K = jsl.cho_solve(cf, Pxy.T).T
    e = y - yhat
    return x_pred + K @ e, sym(P_pred - K @ S @ K.T), _plus(log_likelihood_of(cf, e), corr)


def smoother_gain(P, F, P_pred_next):
    """RTS gain G = P F^T (P-_{k+1})^{-1} by the guarded factor of P-_{k+1}."""
    return jsl.cho_solve(guarded_cho_factor(P_pred_next), F @ P).T
