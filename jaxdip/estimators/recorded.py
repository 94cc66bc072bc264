"""Estimators over recorded data (open loop): one ``lax.scan`` of an estimator's own ``step``.

``run`` feeds any engine ``Estimator`` the samples of a recorded sequence. The offline Gaussian filter, smoother
and likelihood are that run for a Kalman-type estimator (``KalmanFilter``, ``ExtendedKalmanFilter``,
``UnscentedKalmanFilter``), read from its ``aux`` (``jaxdip.estimators.kalman.GaussianAux``):

    x_0 ~ N(xhat0, P0),   x_{k+1} = f(x_k, u_k) + w_k,   y_k = h(x_k) + v_k,

(xhat0, P0) the prior of x_0 before y_0 is seen. ``kalman_filter`` returns the filtered moments x_k | y_0..k,
the predicted ones x_k | y_0..k-1 and log p(y_0..T-1) = sum_k log N(y_k; yhat_k, S_k) (the prediction-error
decomposition); ``rts_smoother`` adds x_k | y_0..T-1 (for a nonlinear transition the usual extended RTS
smoother, with the transition Jacobians at the filtered means).

Forms (``form``): ``"covariance"`` (every Kalman-type estimator: the engine step above), ``"sqrt"`` (Cholesky
factors propagated by QR, ``jaxdip.estimators.square_root``: for float32 and ill-conditioned models) and
``"parallel"`` (associative scan, depth O(log T), ``jaxdip.estimators.parallel_kalman``). The last two take the
linear-Gaussian ``KalmanFilter`` only (not the EKF or UKF; its ``jitter`` is the covariance form's alone) and return
the same moments; the square-root form also returns the lower factors (``cov_factor``, ``pred_cov_factor``).
``mask`` (None, or boolean (T,) or (T, p), True = observed; with ``nan_missing`` NaN entries of ``ys`` count as
missing too) removes missing measurements exactly (``jaxdip.estimators._linear_gaussian``); the covariance form then
also needs a ``KalmanFilter``.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator
from jaxdip.estimators import parallel_kalman, square_root
from jaxdip.estimators._linear_gaussian import linear_gaussian
from jaxdip.estimators.kalman import smoother_gain, sym


from jaxdip._public import public_dir

__all__ = ["run", "inputs_before", "FilterResult", "SmootherResult", "kalman_filter", "log_likelihood", "rts_smoother",
           "FORMS"]
__dir__ = public_dir(globals())


def run(est: Estimator, ys, us_prev, x0, key: Optional[jax.Array] = None):
    """Feed samples j = 0..T-1 to ``est``: ``ys[j]`` = y_j and ``us_prev[j]`` = u_{j-1} (zeros for j = 0).

    ``x0`` is what ``init`` receives as the true initial state (used by ``FromTruth``, ``InitialError`` and the
    estimators that read it). Keys: ``fold_in(key, 0)`` at init, ``fold_in(key, j + 1)`` at sample j. Returns
    (final state, outputs (T, ...), aux (T, ...)).
    """
    key = jax.random.PRNGKey(0) if key is None else key
    state = est.init(jax.random.fold_in(key, 0), x0)
    ys = jnp.asarray(ys)
    us_prev = jnp.asarray(us_prev)

    def body(st, inp):
        j, y, u = inp
        st, out, aux = est.step(st, y, u, jax.random.fold_in(key, j + 1), j)
        return st, (out, aux)

    js = jnp.arange(ys.shape[0], dtype=jnp.int32)
    state, (outs, auxes) = jax.lax.scan(body, state, (js, ys, us_prev))
    return state, outs, auxes


def inputs_before(us, T: int, dtype=None):
    """u_{j-1} for j = 0..T-1 from u_0..u_{T-1} (``us`` (T, m), or None for no input): zeros first."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    if us is None:
        return jnp.zeros((T, 1), dtype)
    us = jnp.asarray(us, dtype).reshape(T, -1)
    return jnp.concatenate([jnp.zeros_like(us[:1]), us[:-1]])


class FilterResult(NamedTuple):
    mean: jax.Array  # (T, d) E[x_k | y_0..k]
    cov: jax.Array  # (T, d, d)
    pred_mean: jax.Array  # (T, d) E[x_k | y_0..k-1] (pred_mean[0] = xhat0)
    pred_cov: jax.Array  # (T, d, d)
    log_likelihood: jax.Array  # () log p(y_0..T-1)
    log_likelihood_terms: jax.Array  # (T,) log p(y_k | y_0..k-1)
    cov_factor: Optional[jax.Array] = None  # (T, d, d) lower N, cov = N N^T (form "sqrt" only)
    pred_cov_factor: Optional[jax.Array] = None


class SmootherResult(NamedTuple):
    mean: jax.Array  # (T, d) E[x_k | y_0..T-1]
    cov: jax.Array  # (T, d, d)
    filtered: FilterResult
    cov_factor: Optional[jax.Array] = None  # (T, d, d) lower N, cov = N N^T (form "sqrt" only)


FORMS = ("covariance", "sqrt", "parallel")


def _factor_product(N):
    return N @ jnp.swapaxes(N, -1, -2)


def _with_offset(f: FilterResult, offset) -> FilterResult:
    ll = f.log_likelihood_terms + offset
    return f._replace(log_likelihood=jnp.sum(ll), log_likelihood_terms=ll)


def _masked_kf(est, lg):
    """The KalmanFilter of the masked model (C, R stacked over time), run on the masked data."""
    return type(est)(lg.Phi, lg.W, lg.C, lg.Q, lg.R, lg.P0, lg.xhat0, est.jitter)


def _linear_form(owner, est, ys, us, mask, nan_missing, form):
    """(model, its FilterResult, the form's own output) for the sqrt and parallel forms."""
    lg = linear_gaussian(owner, est, ys, us, mask, nan_missing)
    if form == "sqrt":
        o = square_root.sqrt_filter(lg)
        f = FilterResult(o.mean, _factor_product(o.factor), o.pred_mean, _factor_product(o.pred_factor),
                         jnp.sum(o.log_likelihood_terms), o.log_likelihood_terms, o.factor, o.pred_factor)
    elif form == "parallel":
        o = parallel_kalman.parallel_filter(lg)
        f = FilterResult(o.mean, o.cov, o.pred_mean, o.pred_cov, jnp.sum(o.log_likelihood_terms),
                         o.log_likelihood_terms)
    else:
        o = None
        f = kalman_filter(_masked_kf(est, lg), lg.ys, lg.us)
    return lg, _with_offset(f, lg.ll_offset), o


def kalman_filter(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False,
                  form: str = "covariance") -> FilterResult:
    """The Kalman-type estimator ``est`` over a whole sequence ``ys`` (T, p); ``us[k]`` (T, m) drives
    x_k -> x_{k+1} (None: no input). ``mask``, ``nan_missing``, ``form``: see the module doc."""
    checks.check_choice(kalman_filter, "form", form, FORMS)
    if form == "covariance" and mask is None and not nan_missing:
        ys = jnp.asarray(ys, dtype=jnp.result_type(float))
        _, mean, aux = run(est, ys, inputs_before(us, ys.shape[0], ys.dtype), jnp.asarray(est.xhat0, ys.dtype))
        ll = aux.log_likelihood
        return FilterResult(mean, aux.cov, aux.prior, aux.prior_cov, jnp.sum(ll), ll)
    return _linear_form(kalman_filter, est, ys, us, mask, nan_missing, form)[1]


def log_likelihood(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False,
                   form: str = "covariance") -> jax.Array:
    """log p(y_0..T-1) of the model of ``est`` (of the observed components only, with a ``mask``)."""
    return kalman_filter(est, ys, us, mask=mask, nan_missing=nan_missing, form=form).log_likelihood


def rts_smoother(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False,
                 form: str = "covariance") -> SmootherResult:
    """Rauch-Tung-Striebel smoother (extended for a nonlinear transition) after ``kalman_filter``:

        G_k  = P_k F_k^T (P-_{k+1})^{-1}
        ms_k = m_k + G_k (ms_{k+1} - m-_{k+1}),     Ps_k = P_k + G_k (Ps_{k+1} - P-_{k+1}) G_k^T.

    ``mask``, ``nan_missing``, ``form``: see the module doc; the square-root and parallel forms are
    ``square_root.sqrt_smoother`` and ``parallel_kalman.parallel_smoother``.
    ``est`` needs ``transition_jacobian(x, u, k)`` (the KF and the EKF have it).
    """
    checks.check_choice(rts_smoother, "form", form, FORMS)
    if form == "sqrt":
        lg, filt, o = _linear_form(rts_smoother, est, ys, us, mask, nan_missing, form)
        ms, Ns = square_root.sqrt_smoother(lg, o)
        return SmootherResult(ms, _factor_product(Ns), filt, Ns)
    if form == "parallel":
        lg, filt, o = _linear_form(rts_smoother, est, ys, us, mask, nan_missing, form)
        return SmootherResult(*parallel_kalman.parallel_smoother(lg, o), filt)
    if mask is not None or nan_missing:
        lg, filt, _ = _linear_form(rts_smoother, est, ys, us, mask, nan_missing, form)
        return rts_smoother(_masked_kf(est, lg), lg.ys, lg.us)._replace(filtered=filt)
    filt = kalman_filter(est, ys, us)
    T = filt.mean.shape[0]
    us_ = jnp.zeros((T, 1), filt.mean.dtype) if us is None else jnp.asarray(us, filt.mean.dtype).reshape(T, -1)
    Fs = jax.vmap(est.transition_jacobian)(filt.mean, us_, jnp.arange(T))

    def body(carry, inp):
        ms_next, Ps_next = carry
        m, P, F, mp_next, Pp_next = inp
        G = smoother_gain(P, F, Pp_next)
        ms = m + G @ (ms_next - mp_next)
        Ps = sym(P + G @ (Ps_next - Pp_next) @ G.T)
        return (ms, Ps), (ms, Ps)

    last = (filt.mean[-1], filt.cov[-1])
    inputs = (filt.mean[:-1], filt.cov[:-1], Fs[:-1], filt.pred_mean[1:], filt.pred_cov[1:])
    _, (ms, Ps) = jax.lax.scan(body, last, inputs, reverse=True)
    ms = jnp.concatenate([ms, last[0][None]])
    Ps = jnp.concatenate([Ps, last[1][None]])
    return SmootherResult(ms, Ps, filt)
