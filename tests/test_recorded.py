"""The offline KF / RTS smoother / log-likelihood (``jaxdip.estimators.recorded``) against the brute-force joint Gaussian of the whole sequence (NumPy),
the EKF against a plain NumPy EKF with finite-difference Jacobians."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

import jax
import jax.numpy as jnp

from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.recorded import kalman_filter, log_likelihood, rts_smoother

T, D, P, M = 6, 3, 2, 1


def _model(seed, time_varying):
    rng = np.random.default_rng(seed)
    n = T if time_varying else 1

    def spd(k, scale):
        A = rng.normal(size=(n, k, k))
        return scale * (A @ A.transpose(0, 2, 1) / k + 0.3 * np.eye(k))

    Phi = 0.9 * np.eye(D) + 0.3 * rng.normal(size=(n, D, D))
    W = rng.normal(size=(n, D, M))
    C = rng.normal(size=(n, P, D))
    Q, R = spd(D, 0.2), spd(P, 0.5)
    m0 = rng.normal(size=D)
    P0 = spd(D, 1.0)[0]
    us = rng.normal(size=(T, M))
    ys = rng.normal(size=(T, P))
    if not time_varying:
        Phi, W, C, Q, R = Phi[0], W[0], C[0], Q[0], R[0]
    return dict(Phi=Phi, W=W, C=C, Q=Q, R=R, m0=m0, P0=P0, us=us), ys


def _at(a, k):
    return a[k] if a.ndim == 3 else a


def _joint(mod):
    """Mean and covariance of X = (x_0..x_{T-1}) and Y = (y_0..y_{T-1}) stacked."""
    Phi, W, C, Q, R = (mod[k] for k in ("Phi", "W", "C", "Q", "R"))
    # X = L E + c with E = (x_0 - m0, w_0 .. w_{T-2}) independent
    L = np.zeros((T * D, T * D))
    cov_E = np.zeros((T * D, T * D))
    cov_E[:D, :D] = mod["P0"]
    for i in range(T - 1):
        cov_E[(i + 1) * D:(i + 2) * D, (i + 1) * D:(i + 2) * D] = _at(Q, i)
    mean = np.zeros(T * D)
    x = mod["m0"].copy()
    for k in range(T):
        mean[k * D:(k + 1) * D] = x
        x = _at(Phi, k) @ x + _at(W, k) @ mod["us"][k]
    for j in range(T):  # source block j: x_0 (j = 0) or w_{j-1}
        M_ = np.eye(D)
        for k in range(j, T):
            L[k * D:(k + 1) * D, j * D:(j + 1) * D] = M_
            M_ = _at(Phi, k) @ M_
    cov_X = L @ cov_E @ L.T
    Cb = np.zeros((T * P, T * D))
    Rb = np.zeros((T * P, T * P))
    for k in range(T):
        Cb[k * P:(k + 1) * P, k * D:(k + 1) * D] = _at(C, k)
        Rb[k * P:(k + 1) * P, k * P:(k + 1) * P] = _at(R, k)
    return mean, cov_X, Cb, Rb


def _condition(mean, cov_X, Cb, Rb, ys, k, upto):
    """Moments of x_k given y_0 .. y_{upto-1}."""
    sl = slice(k * D, (k + 1) * D)
    if upto == 0:
        return mean[sl], cov_X[sl, sl]
    rows = slice(0, upto * P)
    Cy = Cb[rows]
    Syy = Cy @ cov_X @ Cy.T + Rb[rows, rows]
    Sxy = cov_X[sl] @ Cy.T
    K = np.linalg.solve(Syy, Sxy.T).T
    return mean[sl] + K @ (ys[:upto].ravel() - Cy @ mean), cov_X[sl, sl] - K @ Sxy.T


@pytest.mark.parametrize("time_varying", [False, True])
def test_filter_smoother_likelihood_equal_the_joint_gaussian(time_varying):
    mod, ys = _model(3, time_varying)
    kf = KalmanFilter(mod["Phi"], mod["W"], mod["C"], mod["Q"], mod["R"], mod["P0"], mod["m0"])
    sm = rts_smoother(kf, ys, mod["us"])
    fi = sm.filtered
    mean, cov_X, Cb, Rb = _joint(mod)
    for k in range(T):
        for got_m, got_P, upto in ((fi.mean, fi.cov, k + 1), (fi.pred_mean, fi.pred_cov, k), (sm.mean, sm.cov, T)):
            m_ref, P_ref = _condition(mean, cov_X, Cb, Rb, ys, k, upto)
            np.testing.assert_allclose(got_m[k], m_ref, rtol=0, atol=1e-10)
            np.testing.assert_allclose(got_P[k], P_ref, rtol=0, atol=1e-10)
    y_mean = Cb @ mean
    y_cov = Cb @ cov_X @ Cb.T + Rb
    ll_ref = multivariate_normal(y_mean, y_cov).logpdf(ys.ravel())
    assert abs(float(fi.log_likelihood) - ll_ref) <= 1e-10 * max(1.0, abs(ll_ref))
    # the one-step terms are the chain rule of the same density
    for k in range(1, T + 1):
        r = slice(0, k * P)
        ref_k = multivariate_normal(y_mean[r], y_cov[r, r]).logpdf(ys[:k].ravel())
        assert abs(float(jnp.sum(fi.log_likelihood_terms[:k])) - ref_k) <= 1e-10 * max(1.0, abs(ref_k))


def test_singular_innovation_stays_finite():
    # two sensors reading the same state exactly (R = 0): S singular, the guarded solve keeps numbers finite
    Phi = np.array([[1.0, 0.1], [0.0, 1.0]])
    C = np.array([[1.0, 0.0], [1.0, 0.0]])
    ys = np.tile(np.array([[0.3, 0.3]]), (5, 1))
    sm = rts_smoother(KalmanFilter(Phi, None, C, 1e-3 * np.eye(2), np.zeros((2, 2)), np.eye(2), np.zeros(2)), ys)
    assert np.all(np.isfinite(sm.mean)) and np.all(np.isfinite(sm.cov))
    np.testing.assert_allclose(sm.filtered.mean[:, 0], 0.3, atol=1e-6)  # the exact reading is believed


def _h(x):
    return jnp.stack([jnp.sin(x[0]) + 0.5 * x[1] ** 2, x[0] * x[2]])


def _f(x, u):
    return jnp.stack([x[0] + 0.1 * x[1], x[1] - 0.1 * jnp.sin(x[0]) + 0.1 * u[0], 0.95 * x[2] + 0.05 * x[0] ** 2])


def _numpy_ekf(ys, us, m0, P0, Q, R, f, h, eps=1e-6):
    def jac(fun, x):
        cols = [(np.asarray(fun(x + eps * e)) - np.asarray(fun(x - eps * e))) / (2 * eps) for e in np.eye(x.size)]
        return np.stack(cols, axis=1)

    m, Pm = m0.copy(), P0.copy()
    means, covs, ll = [], [], 0.0
    for k in range(len(ys)):
        H = jac(h, m)
        S = H @ Pm @ H.T + R
        K = Pm @ H.T @ np.linalg.inv(S)
        e = ys[k] - np.asarray(h(m))
        ll += multivariate_normal(np.zeros(len(e)), S).logpdf(e)
        mf = m + K @ e
        Pf = (np.eye(m.size) - K @ H) @ Pm
        means.append(mf)
        covs.append(Pf)
        F = jac(lambda x: f(x, us[k]), mf)
        m, Pm = np.asarray(f(mf, us[k])), F @ Pf @ F.T + Q
    return np.array(means), np.array(covs), ll


def test_ekf_nonlinear_maps_against_numpy_ekf():
    rng = np.random.default_rng(0)
    ys = rng.normal(size=(8, 2))
    us = rng.normal(size=(8, 1))
    m0, P0 = np.array([0.2, -0.1, 0.4]), 0.5 * np.eye(3)
    Q, R = 0.01 * np.eye(3), np.diag([0.1, 0.2])
    fi = kalman_filter(ExtendedKalmanFilter(Q, R, P0, m0, f=_f, h=_h), ys, us)
    m_ref, P_ref, ll_ref = _numpy_ekf(ys, us, m0, P0, Q, R, _f, _h)
    # finite-difference Jacobians in the reference: agreement to their truncation error
    np.testing.assert_allclose(fi.mean, m_ref, atol=1e-7)
    np.testing.assert_allclose(fi.cov, P_ref, atol=1e-7)
    assert abs(float(fi.log_likelihood) - ll_ref) < 1e-7


def test_ekf_with_linear_maps_is_the_kf():
    mod, ys = _model(5, False)
    Phi, W, C = (jnp.asarray(mod[k]) for k in ("Phi", "W", "C"))
    kf = rts_smoother(KalmanFilter(Phi, W, C, mod["Q"], mod["R"], mod["P0"], mod["m0"]), ys, mod["us"])
    ekf = rts_smoother(ExtendedKalmanFilter(mod["Q"], mod["R"], mod["P0"], mod["m0"], f=lambda x, u: Phi @ x + W @ u,
                                            h=lambda x: C @ x), ys, mod["us"])
    for a, b in ((kf.mean, ekf.mean), (kf.cov, ekf.cov), (kf.filtered.log_likelihood, ekf.filtered.log_likelihood)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_likelihood_gradient_matches_finite_differences():
    mod, ys = _model(7, False)

    @jax.jit
    def ll(log_q):
        kf = KalmanFilter(mod["Phi"], mod["W"], mod["C"], jnp.exp(log_q) * mod["Q"], mod["R"], mod["P0"], mod["m0"])
        return log_likelihood(kf, ys, mod["us"])

    g = float(jax.jit(jax.grad(ll))(0.3))
    eps = 1e-5
    fd = (float(ll(0.3 + eps)) - float(ll(0.3 - eps))) / (2 * eps)
    assert abs(g - fd) < 1e-6 * max(1.0, abs(fd))
