"""Estimators over recorded data (open loop): one ``lax.scan`` of an estimator's own ``step``.

``run`` feeds any engine ``Estimator`` the samples of a recorded sequence. The offline Gaussian filter, smoother
and likelihood are that run for a Kalman-type estimator (``KalmanFilter``, ``ExtendedKalmanFilter``,
``UnscentedKalmanFilter``), read from its ``aux`` (``jaxdip.estimators.kalman.GaussianAux``):

    x_0 ~ N(xhat0, P0),   x_{k+1} = f(x_k, u_k) + w_k,   y_k = h(x_k) + v_k,

(xhat0, P0) the prior of x_0 before y_0 is seen. ``kalman_filter`` returns the filtered moments x_k | y_0..k,
the predicted ones x_k | y_0..k-1 and log p(y_0..T-1) = sum_k log N(y_k; yhat_k, S_k) (the prediction-error
decomposition); ``rts_smoother`` adds x_k | y_0..T-1 (for a nonlinear transition the usual extended RTS
smoother, with the transition Jacobians at the filtered means).

Missing data. ``mask`` (None, or a boolean (T,) or (T, p) array, True = observed) and ``nan_missing`` (NaN
entries of ys are missing too) remove measurements exactly: the filter runs with those entries set to NaN and
the estimator's ``nan_missing`` on (``jaxdip.estimators.kalman.mask_measurement``), so the filtered and smoothed
moments and the likelihood are those of the observed entries only; a fully missing step is a prediction.

Feedthrough. ``D`` ((p, m), or (T, p, m) over time) adds D_k u_k to the measurement, y_k = h(x_k) + D_k u_k + v_k:
the recorded y_k - D_k u_k is filtered. It belongs to recorded data: in a closed loop y_k is read before u_k is
decided, so an engine estimator has no u_k to feed through.

Forms (``form``): ``"covariance"`` (every Kalman-type estimator: the engine step above), ``"sqrt"`` (Cholesky
factors propagated by QR, ``jaxdip.estimators.square_root``: for float32 and ill-conditioned models) and
``"parallel"`` (associative scan, depth O(log T), ``jaxdip.estimators.parallel_kalman``). The last two take the
linear-Gaussian ``KalmanFilter`` only (not the EKF or UKF; its ``jitter`` is the covariance form's alone) and return
the same moments; the square-root form also returns the lower factors (``cov_factor``, ``pred_cov_factor``).
``mask``, ``nan_missing`` and ``D`` work in every form; the square-root and parallel forms remove a missing
component by the same exact rule (``jaxdip.estimators._linear_gaussian``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator
from jaxdip.estimators import parallel_kalman, square_root
from jaxdip.estimators._linear_gaussian import linear_gaussian, resolve_mask
from jaxdip.estimators.kalman import smoother_gain, sym


from jaxdip._public import public_dir

__all__ = ["run", "run_estimator", "EstimatorRun", "inputs_before", "observed_mask", "FilterResult",
           "SmootherResult", "kalman_filter", "log_likelihood", "rts_smoother", "FORMS"]
__dir__ = public_dir(globals())


def run(est: Estimator, ys, us_prev, x0, key: Optional[jax.Array] = None, keys=None):
    """Feed samples j = 0..T-1 to ``est``: ``ys[j]`` = y_j and ``us_prev[j]`` = u_{j-1} (zeros for j = 0).

    ``x0`` is what ``init`` receives as the true initial state (used by ``FromTruth``, ``InitialError`` and the
    estimators that read it). Keys: ``fold_in(key, 0)`` at init, ``fold_in(key, j + 1)`` at sample j, or
    ``keys = (init_key, step_keys)`` taken as they are (``step_keys`` (T, ...): a loop's own keys, so that a
    recorded run repeats an estimator that draws, e.g. ``InitialError``). Returns (final state, outputs
    (T, ...), aux (T, ...)).
    """
    ys = jnp.asarray(ys)
    us_prev = jnp.asarray(us_prev)
    js = jnp.arange(ys.shape[0], dtype=jnp.int32)
    if keys is None:
        key = jax.random.PRNGKey(0) if key is None else key
        keys = (jax.random.fold_in(key, 0), jax.vmap(lambda j: jax.random.fold_in(key, j + 1))(js))
    init_key, step_keys = keys
    state = est.init(init_key, x0)

    def body(st, inp):
        j, y, u, kj = inp
        st, out, aux = est.step(st, y, u, kj, j)
        return st, (out, aux)

    state, (outs, auxes) = jax.lax.scan(body, state, (js, ys, us_prev, step_keys))
    return state, outs, auxes


class EstimatorRun(NamedTuple):
    xhat: Any  # (T, ...) or (B, T, ...): what the estimator hands out at each sample
    aux: Any  # its aux at each sample (covariances, window trajectories, ...)
    final: Any  # its state after the last sample (to continue a run)


def run_estimator(est: Estimator, ys, us=None, *, x0=None, key: Optional[jax.Array] = None,
                  keys=None) -> EstimatorRun:
    """An engine estimator over a recorded sequence, exactly as a closed loop runs it.

    ``ys`` (T, p): y_k. ``us`` (T, m): u_k, the input applied after sample k (it drives x_k -> x_{k+1}; in a
    ``jd.Loop`` the controller's output ``Sample.u``); at sample k the estimator gets u_{k-1} (zeros at k = 0),
    as in the loop. ``None``: no input. ``x0`` (n,): what ``init`` receives as the true initial state (default
    the estimator's ``xhat0``). Keys: ``fold_in(key, 0)`` at init and ``fold_in(key, k + 1)`` at sample k, or
    ``keys = (init_key, step_keys)`` (step_keys (T, 2)), a loop's own keys. A leading batch axis on ``ys``
    ((B, T, p)) runs B sequences by ``vmap``; ``us``, ``x0`` and ``keys`` then carry it too (an ``x0`` of shape
    (n,) or a single ``key`` is shared).
    """
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    if ys.ndim not in (2, 3):
        raise checks.ArgumentError(f"run_estimator: ys must be (T, p) or (B, T, p), got shape {ys.shape}")
    T = ys.shape[-2]
    if x0 is None:
        if not hasattr(est, "xhat0"):
            raise checks.ArgumentError(f"run_estimator: {type(est).__name__} has no xhat0; give x0, the true initial "
                                "state that its init receives")
        x0 = est.xhat0
    x0 = jnp.asarray(x0, ys.dtype)
    if us is not None:
        us = jnp.asarray(us, ys.dtype)
        if us.ndim != ys.ndim or us.shape[:-1] != ys.shape[:-1]:
            raise checks.ArgumentError(f"run_estimator: us must be {'(B, T, m)' if ys.ndim == 3 else '(T, m)'} with the "
                                f"leading shape {ys.shape[:-1]} of ys, got shape {us.shape}")

    def one(y, u, x, k, ks):
        st, out, aux = run(est, y, inputs_before(u, T, ys.dtype), x, k, ks)
        return EstimatorRun(out, aux, st)

    if ys.ndim == 2:
        return one(ys, us, x0, key, keys)
    axes = (0, None if us is None else 0, 0 if x0.ndim == 2 else None, None, None if keys is None else 0)
    return jax.vmap(one, in_axes=axes)(ys, us, x0, key, keys)


def inputs_before(us, T: int, dtype=None):
    """u_{j-1} for j = 0..T-1 from u_0..u_{T-1} (``us`` (T, m), or None for no input): zeros first."""
    dtype = jnp.result_type(float) if dtype is None else dtype
    if us is None:
        return jnp.zeros((T, 1), dtype)
    us = jnp.asarray(us, dtype).reshape(T, -1)
    return jnp.concatenate([jnp.zeros_like(us[:1]), us[:-1]])


def observed_mask(ys, mask=None, nan_missing: bool = False) -> Optional[jax.Array]:
    """The (T, p) boolean array of observed entries of ``ys`` (T, p) from ``mask`` ((T,) or (T, p), True =
    observed) and, with ``nan_missing``, the non-NaN entries; None when neither is given (all observed). One
    rule for every form (``jaxdip.estimators._linear_gaussian.resolve_mask``)."""
    return resolve_mask(observed_mask, ys, mask, nan_missing)


def _fed_through(ys, us, D):
    """ys (T, p) as a float array, less the feedthrough D_k u_k when ``D`` is given."""
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    if ys.ndim != 2:
        raise checks.ArgumentError(f"ys must be (T, p), got shape {checks.fmt_shape(ys.shape)}")
    if D is not None:
        if us is None:
            raise checks.ArgumentError("D (feedthrough) needs the inputs us, got us=None")
        D = jnp.asarray(D, ys.dtype)
        u = jnp.asarray(us, ys.dtype).reshape(ys.shape[0], -1)
        ys = ys - (jnp.einsum("tpm,tm->tp", D, u) if D.ndim == 3 else u @ D.T)
    return ys


def _prepared(est: Estimator, ys, us, mask, nan_missing: bool, D):
    """(est, ys) with the feedthrough taken off ys and the missing entries set to NaN for a missing-aware est."""
    ys = _fed_through(ys, us, D)
    observed = observed_mask(ys, mask, nan_missing)
    if observed is None:
        return est, ys
    if not hasattr(est, "nan_missing"):
        raise checks.ArgumentTypeError(f"mask / nan_missing need a Kalman-type estimator (KalmanFilter, "
                                       f"ExtendedKalmanFilter, UnscentedKalmanFilter), got {type(est).__name__}")
    if not est.nan_missing:
        est = dataclasses.replace(est, nan_missing=True)
    return est, jnp.where(observed, ys, jnp.nan)


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
    cross_cov: Optional[jax.Array] = None  # (T-1, d, d) Cov(x_{k+1}, x_k | y_0..T-1) = Ps_{k+1} G_k^T
    gain: Optional[jax.Array] = None  # (T-1, d, d) the smoother gains G_k
    cov_factor: Optional[jax.Array] = None  # (T, d, d) lower N, cov = N N^T (form "sqrt" only)


FORMS = ("covariance", "sqrt", "parallel")


def _factor_product(N):
    return N @ jnp.swapaxes(N, -1, -2)


def _with_offset(f: FilterResult, offset) -> FilterResult:
    ll = f.log_likelihood_terms + offset
    return f._replace(log_likelihood=jnp.sum(ll), log_likelihood_terms=ll)


def _linear_form(owner, est, ys, us, mask, nan_missing, D, form):
    """(model, its FilterResult, the form's own output) for the square-root and parallel forms."""
    ys = _fed_through(ys, us, D)
    lg = linear_gaussian(owner, est, ys, us, mask, nan_missing)
    if form == "sqrt":
        o = square_root.sqrt_filter(lg)
        f = FilterResult(o.mean, _factor_product(o.factor), o.pred_mean, _factor_product(o.pred_factor),
                         jnp.sum(o.log_likelihood_terms), o.log_likelihood_terms, o.factor, o.pred_factor)
    else:
        o = parallel_kalman.parallel_filter(lg)
        f = FilterResult(o.mean, o.cov, o.pred_mean, o.pred_cov, jnp.sum(o.log_likelihood_terms),
                         o.log_likelihood_terms)
    return lg, _with_offset(f, lg.ll_offset), o


def kalman_filter(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False, D=None,
                  form: str = "covariance") -> FilterResult:
    """The Kalman-type estimator ``est`` over a whole sequence ``ys`` (T, p); ``us[k]`` (T, m) drives
    x_k -> x_{k+1} (None: no input). ``mask``, ``nan_missing``, ``D``, ``form``: module doc."""
    checks.check_choice(kalman_filter, "form", form, FORMS)
    if form != "covariance":
        return _linear_form(kalman_filter, est, ys, us, mask, nan_missing, D, form)[1]
    est, ys = _prepared(est, ys, us, mask, nan_missing, D)
    _, mean, aux = run(est, ys, inputs_before(us, ys.shape[0], ys.dtype), jnp.asarray(est.xhat0, ys.dtype))
    ll = aux.log_likelihood
    return FilterResult(mean, aux.cov, aux.prior, aux.prior_cov, jnp.sum(ll), ll)


def log_likelihood(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False, D=None,
                   form: str = "covariance") -> jax.Array:
    """log p(y_0..T-1) of the model of ``est`` (of the observed entries only, with a mask)."""
    return kalman_filter(est, ys, us, mask=mask, nan_missing=nan_missing, D=D, form=form).log_likelihood


def rts_smoother(est: Estimator, ys, us=None, *, mask=None, nan_missing: bool = False, D=None,
                 form: str = "covariance") -> SmootherResult:
    """Rauch-Tung-Striebel smoother (extended for a nonlinear transition) after ``kalman_filter``:

        G_k  = P_k F_k^T (P-_{k+1})^{-1}
        ms_k = m_k + G_k (ms_{k+1} - m-_{k+1}),     Ps_k = P_k + G_k (Ps_{k+1} - P-_{k+1}) G_k^T.

    ``est`` needs ``transition_jacobian(x, u, k)`` (the KF and the EKF have it). ``mask``, ``nan_missing``,
    ``D``, ``form``: module doc; the square-root and parallel forms are ``square_root.sqrt_smoother`` and
    ``parallel_kalman.parallel_smoother`` (without ``cross_cov`` and ``gain``).
    """
    checks.check_choice(rts_smoother, "form", form, FORMS)
    if form == "sqrt":
        lg, filt, o = _linear_form(rts_smoother, est, ys, us, mask, nan_missing, D, form)
        ms, Ns = square_root.sqrt_smoother(lg, o)
        return SmootherResult(ms, _factor_product(Ns), filt, cov_factor=Ns)
    if form == "parallel":
        lg, filt, o = _linear_form(rts_smoother, est, ys, us, mask, nan_missing, D, form)
        return SmootherResult(*parallel_kalman.parallel_smoother(lg, o), filt)
    filt = kalman_filter(est, ys, us, mask=mask, nan_missing=nan_missing, D=D)
    T = filt.mean.shape[0]
    us_ = jnp.zeros((T, 1), filt.mean.dtype) if us is None else jnp.asarray(us, filt.mean.dtype).reshape(T, -1)
    Fs = jax.vmap(est.transition_jacobian)(filt.mean, us_, jnp.arange(T))

    def body(carry, inp):
        ms_next, Ps_next = carry
        m, P, F, mp_next, Pp_next = inp
        G = smoother_gain(P, F, Pp_next)
        ms = m + G @ (ms_next - mp_next)
        Ps = sym(P + G @ (Ps_next - Pp_next) @ G.T)
        return (ms, Ps), (ms, Ps, Ps_next @ G.T, G)

    last = (filt.mean[-1], filt.cov[-1])
    inputs = (filt.mean[:-1], filt.cov[:-1], Fs[:-1], filt.pred_mean[1:], filt.pred_cov[1:])
    _, (ms, Ps, cross, gains) = jax.lax.scan(body, last, inputs, reverse=True)
    ms = jnp.concatenate([ms, last[0][None]])
    Ps = jnp.concatenate([Ps, last[1][None]])
    return SmootherResult(ms, Ps, filt, cross, gains)
