"""Missing measurements, feedthrough and the forms of R in the offline KF / RTS / likelihood and the engine
estimators, against the brute-force joint Gaussian of the whole sequence with the missing rows removed (NumPy)."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

import jax.numpy as jnp

from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.recorded import kalman_filter, rts_smoother
from jaxdip.estimators.ukf import UnscentedKalmanFilter

T, D, P, M = 7, 3, 3, 2


def _model(seed, time_varying):
    rng = np.random.default_rng(seed)
    n = T if time_varying else 1

    def spd(k, scale):
        A = rng.normal(size=(n, k, k))
        return scale * (A @ A.transpose(0, 2, 1) / k + 0.3 * np.eye(k))

    mod = dict(Phi=0.9 * np.eye(D) + 0.3 * rng.normal(size=(n, D, D)), W=rng.normal(size=(n, D, M)),
               C=rng.normal(size=(n, P, D)), Dm=rng.normal(size=(n, P, M)), Q=spd(D, 0.2), R=spd(P, 0.5))
    if not time_varying:
        mod = {k: v[0] for k, v in mod.items()}
    mod.update(m0=rng.normal(size=D), P0=spd(D, 1.0)[0], us=rng.normal(size=(T, M)))
    return mod, rng.normal(size=(T, P))


def _at(a, k):
    return a[k] if a.ndim == 3 else a


def _joint(mod):
    """Mean and covariance of X = (x_0..x_{T-1}), and Y = Cb X + db + V, V ~ N(0, Rb), with the natural indexing
    x_{k+1} = Phi_k x_k + W_k u_k + w_k, y_k = C_k x_k + D_k u_k + v_k."""
    L = np.zeros((T * D, T * D))
    cov_E = np.zeros((T * D, T * D))
    cov_E[:D, :D] = mod["P0"]
    for i in range(T - 1):
        cov_E[(i + 1) * D:(i + 2) * D, (i + 1) * D:(i + 2) * D] = _at(mod["Q"], i)
    mean = np.zeros(T * D)
    x = mod["m0"].copy()
    for k in range(T):
        mean[k * D:(k + 1) * D] = x
        x = _at(mod["Phi"], k) @ x + _at(mod["W"], k) @ mod["us"][k]
    for j in range(T):
        M_ = np.eye(D)
        for k in range(j, T):
            L[k * D:(k + 1) * D, j * D:(j + 1) * D] = M_
            M_ = _at(mod["Phi"], k) @ M_
    Cb = np.zeros((T * P, T * D))
    Rb = np.zeros((T * P, T * P))
    db = np.zeros(T * P)
    for k in range(T):
        Cb[k * P:(k + 1) * P, k * D:(k + 1) * D] = _at(mod["C"], k)
        Rb[k * P:(k + 1) * P, k * P:(k + 1) * P] = _at(mod["R"], k)
        db[k * P:(k + 1) * P] = _at(mod["Dm"], k) @ mod["us"][k]
    return mean, L @ cov_E @ L.T, Cb, Rb, db


def _reference(mod, ys, obs):
    """Filtered (x_k | observed y_0..k), predicted (| y_0..k-1) and smoothed moments, and log p(observed y)."""
    mean, cov_X, Cb, Rb, db = _joint(mod)
    flat_obs = obs.ravel()

    def cond(k, upto):
        sl = slice(k * D, (k + 1) * D)
        rows = np.flatnonzero(flat_obs[:upto * P])
        if rows.size == 0:
            return mean[sl], cov_X[sl, sl]
        Cy = Cb[rows]
        Syy = Cy @ cov_X @ Cy.T + Rb[np.ix_(rows, rows)]
        Sxy = cov_X[sl] @ Cy.T
        K = np.linalg.solve(Syy, Sxy.T).T
        return mean[sl] + K @ (ys.ravel()[rows] - db[rows] - Cy @ mean), cov_X[sl, sl] - K @ Sxy.T

    rows = np.flatnonzero(flat_obs)
    ll = multivariate_normal((Cb @ mean + db)[rows], (Cb @ cov_X @ Cb.T + Rb)[np.ix_(rows, rows)]).logpdf(
        ys.ravel()[rows]) if rows.size else 0.0
    return ([cond(k, k + 1) for k in range(T)], [cond(k, k) for k in range(T)], [cond(k, T) for k in range(T)], ll)


def _kf(mod, **kw):
    return KalmanFilter(mod["Phi"], mod["W"], mod["C"], mod["Q"], mod["R"], mod["P0"], mod["m0"], **kw)


def _assert_matches(sm, ref, tol=1e-12):
    filt_ref, pred_ref, smooth_ref, ll_ref = ref
    fi = sm.filtered
    for k in range(T):
        for got_m, got_P, (m_ref, P_ref) in ((fi.mean, fi.cov, filt_ref[k]), (fi.pred_mean, fi.pred_cov, pred_ref[k]),
                                             (sm.mean, sm.cov, smooth_ref[k])):
            scale = max(1.0, np.abs(P_ref).max())
            np.testing.assert_allclose(got_m[k], m_ref, rtol=0, atol=tol * scale)
            np.testing.assert_allclose(got_P[k], P_ref, rtol=0, atol=tol * scale)
    assert abs(float(fi.log_likelihood) - ll_ref) <= tol * max(1.0, abs(ll_ref))


def _random_mask(rng):
    obs = rng.random((T, P)) < 0.6
    obs[2] = False  # a fully missing step
    obs[T - 2:] = False  # a fully missing tail
    obs[0, 0] = True
    return obs


@pytest.mark.parametrize("time_varying", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_masked_filter_smoother_likelihood_equal_the_joint_gaussian_without_missing_rows(time_varying, seed):
    mod, ys = _model(seed, time_varying)
    obs = _random_mask(np.random.default_rng(seed + 10))
    ref = _reference(mod, ys, obs)
    kf = _kf(mod)
    _assert_matches(rts_smoother(kf, ys, mod["us"], mask=obs, D=mod["Dm"]), ref)
    # the same through NaN entries, and through a (T,) mask of whole steps combined with NaNs
    ys_nan = np.where(obs, ys, np.nan)
    _assert_matches(rts_smoother(kf, ys_nan, mod["us"], nan_missing=True, D=mod["Dm"]), ref)
    steps = obs.any(axis=1)
    _assert_matches(rts_smoother(kf, np.where(steps[:, None], ys_nan, 0.0), mod["us"], mask=steps,
                                 nan_missing=True, D=mod["Dm"]), ref)


def test_engine_estimators_with_nan_missing_equal_the_masked_offline_filter():
    mod, ys = _model(4, False)
    obs = _random_mask(np.random.default_rng(5))
    ys_nan = np.where(obs, ys, np.nan)
    ref = _reference(dict(mod, Dm=np.zeros((P, M))), ys, obs)
    for est in (_kf(mod, nan_missing=True),
                ExtendedKalmanFilter(mod["Q"], mod["R"], mod["P0"], mod["m0"], f=_lin_f, C=mod["C"], n_inputs=M,
                                     nan_missing=True)):
        f = kalman_filter(_with_phi(est, mod), ys_nan, mod["us"])
        for k in range(T):
            np.testing.assert_allclose(f.mean[k], ref[0][k][0], atol=1e-10)
        assert abs(float(f.log_likelihood) - ref[3]) < 1e-10 * abs(ref[3])
    ukf = UnscentedKalmanFilter(_lin_f, _lin_h, mod["Q"], mod["R"], mod["P0"], mod["m0"], n_inputs=M,
                                nan_missing=True)
    f = kalman_filter(_with_phi(ukf, mod), ys_nan, mod["us"])
    for k in range(T):
        np.testing.assert_allclose(f.mean[k], ref[0][k][0], atol=1e-9)
        np.testing.assert_allclose(f.cov[k], ref[0][k][1], atol=1e-9)
    assert abs(float(f.log_likelihood) - ref[3]) < 1e-9 * abs(ref[3])


_LIN = {}


def _lin_f(x, u):
    return _LIN["Phi"] @ x + _LIN["W"] @ u


def _lin_h(x):
    return _LIN["C"] @ x


def _with_phi(est, mod):
    _LIN.update(Phi=jnp.asarray(mod["Phi"]), W=jnp.asarray(mod["W"]), C=jnp.asarray(mod["C"]))
    return est


def test_unmasked_results_are_bit_identical_with_an_all_true_mask():
    mod, ys = _model(6, True)
    kf = _kf(mod)
    a = rts_smoother(kf, ys, mod["us"])
    b = rts_smoother(kf, ys, mod["us"], mask=np.ones(T, bool))
    np.testing.assert_allclose(b.mean, a.mean, rtol=0, atol=1e-13)
    assert abs(float(a.filtered.log_likelihood - b.filtered.log_likelihood)) < 1e-12


@pytest.mark.parametrize("form", ["scalar", "diagonal"])
def test_R_as_scalar_or_diagonal_is_the_full_matrix(form):
    mod, ys = _model(7, False)
    r = np.array([0.3, 0.7, 1.1]) if form == "diagonal" else np.array(0.4)
    full = np.diag(r) if form == "diagonal" else 0.4 * np.eye(P)
    ll = [float(kalman_filter(_kf(dict(mod, R=R)), ys, mod["us"]).log_likelihood) for R in (r, full)]
    assert ll[0] == ll[1]
    ekf = ExtendedKalmanFilter(mod["Q"], r, mod["P0"], mod["m0"], f=_lin_f, h=_lin_h, n_inputs=M)
    np.testing.assert_array_equal(ekf.R, full)
    ukf = UnscentedKalmanFilter(_lin_f, _lin_h, mod["Q"], r, mod["P0"], mod["m0"], n_inputs=M)
    np.testing.assert_array_equal(ukf.R, full)


def test_bad_mask_and_feedthrough_arguments_are_refused():
    mod, ys = _model(8, False)
    kf = _kf(mod)
    with pytest.raises(ArgumentTypeError, match="boolean"):
        kalman_filter(kf, ys, mod["us"], mask=np.ones(T))
    with pytest.raises(ArgumentError, match="mask must be"):
        kalman_filter(kf, ys, mod["us"], mask=np.ones((T, P + 1), bool))
    with pytest.raises(ArgumentError, match="needs the inputs"):
        kalman_filter(kf, ys, None, D=mod["Dm"])
    with pytest.raises(ArgumentError, match="R as a vector"):
        _kf(dict(mod, R=np.ones(P + 1)))


def test_masking_is_exact_at_tiny_variances():
    # a missing component's fill follows the observed scale: with a fill of 1 next to variances of 1e-12 the
    # guarded factorisation would perturb the observed block (67% error in P, measured)
    s = 1e-12
    mod, ys = _model(0, False)
    mod = dict(mod, Q=mod["Q"] * s, R=mod["R"] * s, P0=mod["P0"] * s, m0=mod["m0"] * np.sqrt(s),
               us=mod["us"] * np.sqrt(s))
    obs = _random_mask(np.random.default_rng(10))
    filt_ref, _, smooth_ref, ll_ref = _reference(mod, ys * np.sqrt(s), obs)
    sm = rts_smoother(_kf(mod), ys * np.sqrt(s), mod["us"], mask=obs, D=mod["Dm"])
    for k in range(T):
        for got, (m_ref, P_ref) in ((sm.filtered, filt_ref[k]), (sm, smooth_ref[k])):
            np.testing.assert_allclose(got.cov[k], P_ref, rtol=0, atol=1e-12 * np.abs(P_ref).max())
            np.testing.assert_allclose(got.mean[k], m_ref, rtol=0, atol=1e-12 * np.sqrt(np.abs(P_ref).max()))
    assert abs(float(sm.filtered.log_likelihood) - ll_ref) <= 1e-12 * abs(ll_ref)
