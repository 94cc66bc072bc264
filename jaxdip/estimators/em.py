"""Expectation-maximisation for the noise covariances (and optionally Phi, C) of a linear-Gaussian model.

Model (``KalmanFilter``, time-invariant): x_0 ~ N(xhat0, P0), x_{k+1} = Phi x_k + W u_k + w_k, w ~ N(0, Q),
y_k = C x_k + D u_k + v_k, v ~ N(0, R), over one sequence ys (T, p) or a batch (B, T, p) sharing the model.

E-step: the RTS smoother (``jaxdip.estimators.recorded.rts_smoother``) gives ms_k = E[x_k | Y], Ps_k and the
lag-one covariances X_k = Cov(x_{k+1}, x_k | Y) = Ps_{k+1} G_k^T. M-step (Shumway and Stoffer), closed form, each
maximising the expected complete-data log-likelihood, so the marginal likelihood never decreases:

    Phi = sum_k E[(x_{k+1} - W u_k) x_k^T] (sum_k E[x_k x_k^T])^{-1}                    (with "Phi" in update)
    Q   = 1/(T-1) sum_k [r_k r_k^T + Ps_{k+1} - Phi X_k^T - X_k Phi^T + Phi Ps_k Phi^T],  r_k = ms_{k+1} - Phi ms_k - W u_k
    C   = sum_k (y_k - D u_k) ms_k^T (sum_k E[x_k x_k^T])^{-1}                            (with "C"; no missing data)
    R   = 1/T sum_k E[v_k v_k^T | Y]

(sums over the B sequences too, and the divisors times B). With missing components (``mask``, ``nan_missing``)
the residual v_k = (v_o, v_m) has an unobserved part; given v_o, v_m ~ N(R_mo R_oo^{-1} v_o, R_mm - R_mo R_oo^{-1}
R_om), so E[v v^T | Y] = A E[v_o v_o^T | Y] A^T + [0, 0; 0, R_mm - R_mo R_oo^{-1} R_om] with A = [I; R_mo R_oo^{-1}],
and E[v_o v_o^T | Y] = (y_o - C_o ms_k)(y_o - C_o ms_k)^T + C_o Ps_k C_o^T. A fully missing step contributes R.
Phi is updated before Q and C before R, which is the joint maximisation over each pair.

Stopping rule: the relative increase of the log-likelihood (ll_i - ll_{i-1}) / |ll_i| <= ``tol`` (status
``"converged"``), ``max_iter`` M-steps (``"max_iterations"``) or a non-finite log-likelihood (``"not_finite"``).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import checks
from jaxdip.estimators.kalman import sym
from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.recorded import observed_mask, rts_smoother

from jaxdip._public import public_dir

__all__ = ["EMResult", "em_step", "fit_em"]
__dir__ = public_dir(globals())

_UPDATABLE = ("Phi", "Q", "C", "R")


class EMResult(NamedTuple):
    model: KalmanFilter  # the filter with the fitted matrices
    log_likelihood: np.ndarray  # log p(Y) of the model before each M-step and at the end: (iterations + 1,)
    iterations: int  # M-steps taken
    status: str  # "converged", "max_iterations" or "not_finite"


def _batched(kf: KalmanFilter, ys, us, mask, nan_missing: bool):
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    if ys.ndim == 2:
        ys = ys[None]
        us = None if us is None else jnp.asarray(us)[None]
        mask = None if mask is None else jnp.asarray(mask)[None]
    if ys.ndim != 3:
        raise checks.ArgumentError(f"ys must be (T, p) or (B, T, p), got shape {checks.fmt_shape(ys.shape)}")
    B, T, _ = ys.shape
    us = jnp.zeros((B, T, kf.n_inputs), ys.dtype) if us is None else jnp.asarray(us, ys.dtype).reshape(B, T, -1)
    def observed(y, m):  # the recorded data's one mask rule, all True where nothing is missing
        o = observed_mask(y, m, nan_missing)
        return jnp.ones(y.shape, bool) if o is None else o

    obs = jax.vmap(observed)(ys, mask) if mask is not None else jax.vmap(lambda y: observed(y, None))(ys)
    return ys, us, obs


def _check(kf: KalmanFilter, update: Sequence[str]):
    if not isinstance(kf, KalmanFilter):
        raise checks.ArgumentTypeError(f"EM needs a KalmanFilter (a linear-Gaussian model), got {type(kf).__name__}")
    bad = [u for u in update if u not in _UPDATABLE]
    if bad or not update:
        raise checks.ArgumentError(f"update must name some of {_UPDATABLE}, got {tuple(update)!r}")
    for name in ("Phi", "W", "C", "Q", "R"):
        if getattr(kf, name).ndim != 2:
            raise checks.ArgumentError(f"EM fits a time-invariant model: {name} must be a matrix, got shape "
                                       f"{checks.fmt_shape(getattr(kf, name).shape)}")


def _estep(kf, y, u, obs, D):
    sm = rts_smoother(kf, y, u, mask=obs, D=D)
    return sm.mean, sm.cov, sm.cross_cov, sm.filtered.log_likelihood


def _mstep(kf: KalmanFilter, ys, us, obs, D, update):
    ms, Ps, X, ll = jax.vmap(lambda y, u, o: _estep(kf, y, u, o, D))(ys, us, obs)
    B, T, _ = ys.shape
    Dm = jnp.zeros((ys.shape[-1], us.shape[-1]), ys.dtype) if D is None else jnp.asarray(D, ys.dtype)
    Exx = Ps + jnp.einsum("bti,btj->btij", ms, ms)  # E[x_k x_k^T]
    Phi, W, C, Q, R = kf.Phi, kf.W, kf.C, kf.Q, kf.R
    if "Phi" in update:
        lhs = jnp.einsum("bti,btj->ij", ms[:, 1:] - us[:, :-1] @ W.T, ms[:, :-1]) + jnp.sum(X, (0, 1))
        Phi = jnp.linalg.solve(jnp.sum(Exx[:, :-1], (0, 1)), lhs.T).T
    if "Q" in update:
        r = ms[:, 1:] - ms[:, :-1] @ Phi.T - us[:, :-1] @ W.T
        PX = jnp.einsum("ij,btkj->btik", Phi, X)  # Phi X_k^T
        E = (jnp.einsum("bti,btj->btij", r, r) + Ps[:, 1:] - PX - jnp.swapaxes(PX, -1, -2)
             + jnp.einsum("ij,btjk,lk->btil", Phi, Ps[:, :-1], Phi))
        Q = sym(jnp.sum(E, (0, 1)) / (B * (T - 1)))
    yd = jnp.where(obs, ys, 0.0) - us @ Dm.T
    if "C" in update:
        C = jnp.linalg.solve(jnp.sum(Exx, (0, 1)), jnp.einsum("bti,btj->ij", yd, ms).T).T
    if "R" in update:
        R = sym(jnp.sum(jax.vmap(jax.vmap(lambda o, v, P: _residual_second_moment(o, v, P, C, R)))(
            obs, yd - ms @ C.T, Ps), (0, 1)) / (B * T))
    new = dataclasses.replace(kf, Phi=Phi, C=C, Q=Q, R=R)
    return new, jnp.sum(ll)


def _residual_second_moment(o, v, P, C, R):
    """E[v v^T | Y] of v = y - C x - D u at one step with observed components ``o`` (module doc)."""
    of = o.astype(R.dtype)
    oo = o[:, None] & o[None, :]
    v0 = jnp.where(o, v, 0.0)
    E0 = jnp.outer(v0, v0) + jnp.where(oo, C @ P @ C.T, 0.0)
    Rinv = jnp.where(oo, jnp.linalg.inv(jnp.where(oo, R, 0.0) + jnp.diag(1.0 - of)), 0.0)  # R_oo^{-1}, embedded
    A = jnp.diag(of) + (1.0 - of)[:, None] * (R @ Rinv)
    return A @ E0 @ A.T + jnp.outer(1.0 - of, 1.0 - of) * (R - R @ Rinv @ R)


def em_step(kf: KalmanFilter, ys, us=None, *, mask=None, nan_missing: bool = False, D=None,
            update: Sequence[str] = ("Q", "R")):
    """One EM iteration: (the model after the M-step, log p(Y) of ``kf``)."""
    _check(kf, update)
    ys, us, obs = _batched(kf, ys, us, mask, nan_missing)
    if "C" in update and not bool(jnp.all(obs)):
        raise checks.ArgumentError("EM updates C only from fully observed data (no mask, no NaN)")
    update = tuple(update)
    return jax.jit(lambda m: _mstep(m, ys, us, obs, D, update))(kf)


def fit_em(kf: KalmanFilter, ys, us=None, *, mask=None, nan_missing: bool = False, D=None,
           update: Sequence[str] = ("Q", "R"), tol: float = 1e-10, max_iter: int = 500) -> EMResult:
    """EM from ``kf`` until the relative log-likelihood increase is <= ``tol`` or ``max_iter`` M-steps
    (module doc). ``update``: the matrices fitted, among "Phi", "Q", "C", "R"; the others stay as in ``kf``."""
    _check(kf, update)
    checks.check_int("fit_em", "max_iter", max_iter, 1)
    checks.check_positive("fit_em", "tol", tol)
    ys, us, obs = _batched(kf, ys, us, mask, nan_missing)
    if "C" in update and not bool(jnp.all(obs)):
        raise checks.ArgumentError("EM updates C only from fully observed data (no mask, no NaN)")
    update = tuple(update)
    step = jax.jit(lambda m: _mstep(m, ys, us, obs, D, update))
    lls, status, model = [], "max_iterations", kf
    for i in range(max_iter + 1):
        new, ll = step(model)
        ll = float(ll)
        lls.append(ll)
        if not np.isfinite(ll):
            status = "not_finite"
            break
        if i > 0 and ll - lls[-2] <= tol * abs(ll):
            status = "converged"
            break
        if i == max_iter:
            break
        model = new
    return EMResult(model, np.asarray(lls), len(lls) - 1, status)
