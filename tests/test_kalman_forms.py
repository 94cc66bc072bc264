"""The square-root and parallel-in-time forms of the offline Kalman filter, RTS smoother and log-likelihood
(``form=`` of ``jaxdip.estimators.recorded``) against the covariance form (itself checked against the brute-force
joint Gaussian in test_recorded.py), against a brute-force joint Gaussian with missing data, and in float32 against
a float64 reference."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

import jax
import jax.numpy as jnp

from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.recorded import kalman_filter, log_likelihood, rts_smoother

T, D, P, M = 25, 4, 2, 1
FORMS = ("sqrt", "parallel")


def _spd(rng, k, scale, lead=()):
    A = rng.normal(size=lead + (k, k))
    return scale * (A @ np.swapaxes(A, -1, -2) / k + 0.3 * np.eye(k))


def _model(seed, time_varying=False, rank1_q=False):
    """A random stable model (spectral radius 0.95), its data and inputs."""
    rng = np.random.default_rng(seed)
    lead = (T,) if time_varying else ()
    A = rng.normal(size=lead + (D, D))
    Phi = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)), axis=-1)[..., None, None]
    W, C = rng.normal(size=lead + (D, M)), rng.normal(size=lead + (P, D))
    Q, R = _spd(rng, D, 0.2, lead), _spd(rng, P, 0.5, lead)
    if rank1_q:  # singular Q: noise through one direction only (the square-root form's eigh fallback)
        w = rng.normal(size=D)
        Q = 0.3 * np.outer(w, w)
    kf = KalmanFilter(Phi, W, C, Q, R, _spd(rng, D, 1.0), rng.normal(size=D))
    return kf, rng.normal(size=(T, P)), rng.normal(size=(T, M))


_smoother = {f: jax.jit(lambda kf, ys, us, mask=None, f=f: rts_smoother(kf, ys, us, mask=mask, form=f))
             for f in ("covariance",) + FORMS}


def _compare(a, b, tol=1e-10):
    fa, fb = a.filtered, b.filtered
    for name, x, y in (("mean", fa.mean, fb.mean), ("cov", fa.cov, fb.cov), ("pred_mean", fa.pred_mean, fb.pred_mean),
                       ("pred_cov", fa.pred_cov, fb.pred_cov), ("ll terms", fa.log_likelihood_terms,
                                                                  fb.log_likelihood_terms),
                       ("ll", fa.log_likelihood, fb.log_likelihood), ("smoothed mean", a.mean, b.mean),
                       ("smoothed cov", a.cov, b.cov)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=0, atol=tol, err_msg=name)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("time_varying", [False, True])
def test_forms_equal_the_covariance_form(form, time_varying):
    for seed in range(10 if not time_varying else 4):
        kf, ys, us = _model(seed, time_varying)
        _compare(_smoother[form](kf, ys, us), _smoother["covariance"](kf, ys, us))


@pytest.mark.parametrize("form", FORMS)
def test_singular_process_noise(form):
    kf, ys, us = _model(11, rank1_q=True)
    assert np.linalg.matrix_rank(np.asarray(kf.Q)) == 1
    _compare(_smoother[form](kf, ys, us), _smoother["covariance"](kf, ys, us), tol=1e-9)


def _hand_masked(kf, ys, mask):
    """The masked model written out here: missing rows of C zeroed, R's missing rows/columns replaced by the
    identity's, residuals zeroed (and 0.5 log 2 pi per missing component added to the log-likelihood)."""
    C = np.where(mask[:, :, None], np.broadcast_to(np.asarray(kf.C), (T, P, D)), 0.0)
    R = np.broadcast_to(np.asarray(kf.R), (T, P, P)).copy()
    for k in range(T):
        for i in np.flatnonzero(~mask[k]):
            R[k, i, :] = R[k, :, i] = 0.0
            R[k, i, i] = 1.0
    masked = KalmanFilter(kf.Phi, kf.W, C, kf.Q, R, kf.P0, kf.xhat0)
    return masked, np.where(mask, ys, 0.0), 0.5 * np.log(2 * np.pi) * np.sum(~mask)


@pytest.mark.parametrize("form", ("covariance",) + FORMS)
def test_mask_equals_the_hand_masked_covariance_form(form):
    for seed in range(3):
        kf, ys, us = _model(20 + seed)
        mask = np.random.default_rng(seed).random((T, P)) > 0.35
        got = _smoother[form](kf, ys, us, jnp.asarray(mask))
        masked, ys0, offset = _hand_masked(kf, ys, mask)
        ref = _smoother["covariance"](masked, ys0, us)
        np.testing.assert_allclose(got.mean, ref.mean, rtol=0, atol=1e-10)
        np.testing.assert_allclose(got.cov, ref.cov, rtol=0, atol=1e-10)
        np.testing.assert_allclose(got.filtered.mean, ref.filtered.mean, rtol=0, atol=1e-10)
        np.testing.assert_allclose(got.filtered.log_likelihood, ref.filtered.log_likelihood + offset, rtol=0,
                                   atol=1e-10)


def _joint_observed_loglik(kf, ys, us, mask):
    """log p(observed y) from the joint Gaussian of (y_0..y_{T-1}) (time-invariant model), NumPy."""
    Phi, W, C, Q, R = (np.asarray(getattr(kf, n)) for n in ("Phi", "W", "C", "Q", "R"))
    means, covs = [np.asarray(kf.xhat0)], []
    for k in range(T - 1):
        means.append(Phi @ means[-1] + W @ us[k])
    cov_x = np.zeros((T * D, T * D))
    Pk = np.asarray(kf.P0)
    for k in range(T):
        if k:
            Pk = Phi @ Pk @ Phi.T + Q
        # Cov(x_j, x_k) = Phi^(k-j) P_j for j <= k
        cov_x[k * D:(k + 1) * D, k * D:(k + 1) * D] = Pk
        covs.append(Pk)
    for j in range(T):
        A = np.eye(D)
        for k in range(j + 1, T):
            A = Phi @ A
            cov_x[k * D:(k + 1) * D, j * D:(j + 1) * D] = A @ covs[j]
            cov_x[j * D:(j + 1) * D, k * D:(k + 1) * D] = (A @ covs[j]).T
    Cb = np.kron(np.eye(T), C)
    mean_y = Cb @ np.concatenate(means)
    cov_y = Cb @ cov_x @ Cb.T + np.kron(np.eye(T), R)
    keep = mask.reshape(-1)
    return multivariate_normal(mean_y[keep], cov_y[np.ix_(keep, keep)]).logpdf(ys.reshape(-1)[keep])


@pytest.mark.parametrize("form", FORMS)
def test_masked_log_likelihood_is_the_joint_gaussian_of_the_observed(form):
    kf, ys, us = _model(30)
    mask = np.random.default_rng(3).random((T, P)) > 0.4
    mask[5] = False  # a sample with nothing observed
    ref = _joint_observed_loglik(kf, ys, us, mask)
    ll = jax.jit(lambda ys, mask: log_likelihood(kf, ys, us, mask=mask, form=form))
    np.testing.assert_allclose(float(ll(ys, jnp.asarray(mask))), ref, rtol=1e-11)
    rows = mask.all(axis=1) | (np.arange(T) % 3 == 0)  # whole samples dropped
    np.testing.assert_allclose(float(ll(ys, jnp.repeat(jnp.asarray(rows)[:, None], P, 1))),
                               _joint_observed_loglik(kf, ys, us, np.repeat(rows[:, None], P, 1)), rtol=1e-11)


def test_mask_forms_of_the_argument():
    """NaN entries with ``nan_missing`` are a (T, p) mask; a (T,) mask is the same for every component."""
    kf, ys, us = _model(31)
    mask = np.random.default_rng(4).random((T, P)) > 0.4
    rows = np.arange(T) % 3 == 0
    ll = jax.jit(lambda ys, mask: log_likelihood(kf, ys, us, mask=mask, form="sqrt"))
    ys_nan = np.where(mask, ys, np.nan)
    np.testing.assert_allclose(float(log_likelihood(kf, ys_nan, us, nan_missing=True, form="sqrt")),
                               float(ll(ys, jnp.asarray(mask))), rtol=0, atol=1e-12)
    both = log_likelihood(kf, ys_nan, us, mask=jnp.asarray(rows), nan_missing=True, form="sqrt")
    np.testing.assert_allclose(float(both), float(ll(ys, jnp.asarray(mask & rows[:, None]))), rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(log_likelihood(kf, ys, us, mask=jnp.asarray(rows), form="sqrt")),
                               float(ll(ys, jnp.repeat(jnp.asarray(rows)[:, None], P, 1))), rtol=0, atol=1e-12)


def _illconditioned_float32():
    """cond(P0) = 1e8 and two outputs reading nearly the same large-variance direction: in float32 the innovation
    covariance S = C P C^T + R (eigenvalues ~2e4 and ~1e-3) loses R, its factor from [sR, C N] does not."""
    rng = np.random.default_rng(0)
    th = 0.1
    Phi = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    C = np.array([[1.0, 0.0], [1.0, 1.0]])
    P0, R = np.diag([1e4, 1e-4]), 1e-3 * np.eye(2)
    x, ys = rng.normal(size=2) * np.sqrt(np.diag(P0)), []
    for _ in range(20):
        ys.append(C @ x + np.sqrt(1e-3) * rng.normal(size=2))
        x = Phi @ x
    mats = [np.asarray(a, np.float32) for a in (Phi, np.zeros((2, 1)), C, np.zeros((2, 2)), R, P0)]
    return mats, np.asarray(ys, np.float32)


def test_sqrt_form_survives_float32_where_the_covariance_form_does_not():
    mats, ys = _illconditioned_float32()
    assert np.linalg.cond(mats[-1]) >= 1e8
    # the reference: the same (float32-rounded) model and data, covariance form in float64
    ref = kalman_filter(KalmanFilter(*[np.float64(a) for a in mats]), np.float64(ys))
    m_ref, P_ref, ll_ref = (np.asarray(a) for a in (ref.mean, ref.cov, ref.log_likelihood))
    L = np.linalg.cholesky(P_ref)  # the covariance error is whitened by the true covariance
    errors = {}
    for form in ("covariance", "sqrt"):
        with jax.enable_x64(False):
            f = kalman_filter(KalmanFilter(*mats), ys, form=form)
            assert f.mean.dtype == jnp.float32
            m, P, ll = (np.asarray(a, np.float64) for a in (f.mean, f.cov, f.log_likelihood))
        Pw = np.linalg.solve(L, np.swapaxes(np.linalg.solve(L, P), -1, -2))
        errors[form] = np.array([np.max(np.abs(m - m_ref)), np.max(np.abs(Pw - np.eye(2))), abs(ll - ll_ref)])
    assert np.all(np.isfinite(errors["covariance"]))
    assert np.all(errors["sqrt"] * 100 <= errors["covariance"]), errors


def test_parallel_form_under_jit_and_vmap():
    kf, ys, us = _model(40)
    batch = np.stack([ys, 2 * ys, -ys])
    par = jax.jit(jax.vmap(lambda y: rts_smoother(kf, y, us, form="parallel")))(batch)
    for i in range(3):
        ref = _smoother["covariance"](kf, batch[i], us)
        np.testing.assert_allclose(par.mean[i], ref.mean, rtol=0, atol=1e-10)
        np.testing.assert_allclose(par.filtered.log_likelihood[i], ref.filtered.log_likelihood, rtol=0, atol=1e-10)


@pytest.mark.parametrize("form", FORMS)
def test_log_likelihood_gradient_equals_the_covariance_forms(form):
    kf, ys, us = _model(50)
    ys, us = ys[:8], us[:8]  # short: the gradient of the parallel form is slow to compile
    grad = lambda f: jax.jit(jax.grad(lambda k: log_likelihood(k, ys, us, form=f)))(kf)  # noqa: E731
    g, ref = grad(form), grad("covariance")
    sym = lambda a: 0.5 * (a + a.T)  # noqa: E731  (each form reads a covariance's triangles differently)
    for name in ("Phi", "W", "C", "xhat0"):
        np.testing.assert_allclose(getattr(g, name), getattr(ref, name), rtol=1e-8, atol=1e-9, err_msg=name)
    for name in ("Q", "R", "P0"):
        np.testing.assert_allclose(sym(getattr(g, name)), sym(getattr(ref, name)), rtol=1e-8, atol=1e-9,
                                   err_msg=name)


def test_bad_arguments():
    kf, ys, us = _model(60)
    with pytest.raises(ArgumentError, match="form must be one of"):
        kalman_filter(kf, ys, us, form="information")
    with pytest.raises(ArgumentError, match="form must be one of"):
        rts_smoother(kf, ys, us, form="Sqrt")
    with pytest.raises(ArgumentError, match=r"mask must be \(25, 2\)"):
        kalman_filter(kf, ys, us, mask=np.ones((T, 3), bool), form="sqrt")
    with pytest.raises(ArgumentTypeError, match="mask must be boolean"):
        kalman_filter(kf, ys, us, mask=np.ones(T), form="parallel")
    ekf = ExtendedKalmanFilter(np.eye(2), np.eye(1), np.eye(2), f=_linear_map, C=np.ones((1, 2)))
    with pytest.raises(ArgumentTypeError, match="need a KalmanFilter"):
        kalman_filter(ekf, np.zeros((5, 1)), form="sqrt")


def _linear_map(x, u):
    return 0.9 * x
