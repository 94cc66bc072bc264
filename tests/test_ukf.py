"""Unscented Kalman filter: the Kalman filter on a linear model, a plain NumPy UKF on a nonlinear one, and a
plain scan of its step equal to the offline filter (``recorded.kalman_filter``: u_k shifted to sample k + 1)."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.recorded import kalman_filter
from jaxdip.estimators.ukf import UnscentedKalmanFilter


def unscented_filter(ys, m0, P0, Q, R, f, h, us, **kw):
    return kalman_filter(UnscentedKalmanFilter(f, h, Q, R, P0, m0, **kw), ys, us)

H_PEND = 0.05


def f_pend(x, u):
    # a damped pendulum driven by u, explicit Euler over H_PEND
    return jnp.stack([x[0] + H_PEND * x[1], x[1] + H_PEND * (-9.81 * jnp.sin(x[0]) - 0.3 * x[1] + u[0])])


def h_pend(x):
    return jnp.stack([jnp.sin(x[0]), x[0] * x[1]])


def numpy_ukf(ys, us, m0, P0, Q, R, f, h, alpha=3.0**0.5, beta=2.0, kappa=1.0):
    """Textbook UKF with loops over the sigma points (van der Merwe's scaled transform)."""
    d = len(m0)
    lam = alpha**2 * (d + kappa) - d
    wm = np.array([lam / (d + lam)] + [1 / (2 * (d + lam))] * (2 * d))
    wc = wm.copy()
    wc[0] += 1 - alpha**2 + beta

    def points(m, P):
        L = np.linalg.cholesky(P)
        c = np.sqrt(d + lam)
        return [m] + [m + c * L[:, i] for i in range(d)] + [m - c * L[:, i] for i in range(d)]

    m, P = np.array(m0, float), np.array(P0, float)
    means, covs, ll = [], [], 0.0
    for k in range(len(ys)):
        X = points(m, P)
        Y = [np.asarray(h(x)) for x in X]
        yhat = sum(w * yy for w, yy in zip(wm, Y))
        S = R + sum(w * np.outer(yy - yhat, yy - yhat) for w, yy in zip(wc, Y))
        Pxy = sum(w * np.outer(x - m, yy - yhat) for w, x, yy in zip(wc, X, Y))
        K = Pxy @ np.linalg.inv(S)
        e = ys[k] - yhat
        m, P = m + K @ e, P - K @ S @ K.T
        ll += -0.5 * (e @ np.linalg.solve(S, e) + np.log(np.linalg.det(S)) + len(e) * np.log(2 * np.pi))
        means.append(m)
        covs.append(P)
        X = points(m, P)
        Xn = [np.asarray(f(x, us[k])) for x in X]
        m = sum(w * x for w, x in zip(wm, Xn))
        P = Q + sum(w * np.outer(x - m, x - m) for w, x in zip(wc, Xn))
    return np.array(means), np.array(covs), ll


def pendulum_data(T=60, seed=0):
    rng = np.random.default_rng(seed)
    Q, R = np.diag([1e-5, 1e-3]), np.diag([1e-3, 4e-3])
    us = 0.5 * np.sin(0.2 * np.arange(T))[:, None]
    x = np.array([0.6, 0.0])
    ys = []
    for k in range(T):
        ys.append(np.asarray(h_pend(x)) + rng.multivariate_normal(np.zeros(2), R))
        x = np.asarray(f_pend(x, us[k])) + rng.multivariate_normal(np.zeros(2), Q)
    return np.array(ys), us, Q, R


def test_ukf_equals_a_plain_numpy_ukf():
    ys, us, Q, R = pendulum_data()
    m0, P0 = np.array([0.5, 0.1]), np.diag([0.05, 0.1])
    res = unscented_filter(ys, m0, P0, Q, R, f_pend, h_pend, us)
    ref_m, ref_P, ref_ll = numpy_ukf(ys, us, m0, P0, Q, R, f_pend, h_pend)
    np.testing.assert_allclose(res.mean, ref_m, rtol=0, atol=1e-10 * np.max(np.abs(ref_m)))
    np.testing.assert_allclose(res.cov, ref_P, rtol=0, atol=1e-10 * np.max(np.abs(ref_P)))
    np.testing.assert_allclose(float(res.log_likelihood), ref_ll, rtol=1e-10)
    # and the nonlinearity matters here: the EKF gives other numbers
    ekf = kalman_filter(ExtendedKalmanFilter(Q, R, P0, m0, f=f_pend, h=h_pend), ys, us)
    assert np.max(np.abs(np.asarray(ekf.mean) - ref_m)) > 1e-4


def test_ukf_on_a_linear_model_is_the_kalman_filter():
    rng = np.random.default_rng(3)
    d, p, T = 4, 2, 80
    Phi = np.linalg.qr(rng.normal(size=(d, d)))[0] * 0.97
    W, C = rng.normal(size=(d, 1)), rng.normal(size=(p, d))
    Q, R = np.diag(rng.uniform(0.01, 0.1, d)), np.diag(rng.uniform(0.05, 0.2, p))
    us = rng.normal(size=(T, 1))
    ys = rng.normal(size=(T, p))
    m0, P0 = rng.normal(size=d), np.eye(d)
    kf = kalman_filter(KalmanFilter(Phi, W, C, Q, R, P0, m0), ys, us)
    for alpha, beta, kappa in ((3.0**0.5, 2.0, 1.0), (0.5, 2.0, 0.0)):
        uk = unscented_filter(ys, m0, P0, Q, R, lambda x, u: Phi @ x + W @ u, lambda x: C @ x, us,
                              alpha=alpha, beta=beta, kappa=kappa)
        for a, b in ((uk.mean, kf.mean), (uk.cov, kf.cov), (uk.pred_mean, kf.pred_mean), (uk.pred_cov, kf.pred_cov)):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * np.max(np.abs(np.asarray(b))))
        np.testing.assert_allclose(float(uk.log_likelihood), float(kf.log_likelihood), rtol=1e-10)


def _run_engine(est, ys, us_prev, x0):
    key = jax.random.PRNGKey(0)

    def body(st, inp):
        k, y, u = inp
        st, out, aux = est.step(st, y, u, key, k)
        return st, (out, aux)

    return jax.lax.scan(body, est.init(key, x0), (jnp.arange(ys.shape[0]), ys, us_prev))[1]


def test_scan_of_the_step_equals_the_offline_filter():
    ys, us, Q, R = pendulum_data(T=40, seed=1)
    m0, P0 = np.array([0.5, 0.1]), np.diag([0.05, 0.1])
    us_prev = np.concatenate([np.zeros((1, 1)), us[:-1]])  # sample j brings u_{j-1}
    est = UnscentedKalmanFilter(f_pend, h_pend, Q, R, P0, jnp.asarray(m0))
    xs, aux = jax.jit(lambda a, b: _run_engine(est, a, b, jnp.zeros(2)))(jnp.asarray(ys), jnp.asarray(us_prev))
    Ps = aux.cov
    ref = unscented_filter(ys, m0, P0, Q, R, f_pend, h_pend, us)
    np.testing.assert_allclose(xs, ref.mean, rtol=0, atol=1e-12 * np.max(np.abs(np.asarray(ref.mean))))
    np.testing.assert_allclose(Ps, ref.cov, rtol=0, atol=1e-12 * np.max(np.abs(np.asarray(ref.cov))))
