"""TimeVaryingMHE: equal to the LTI WeightedMHE on an LTI model, to a NumPy normal-equations solution of every
window (and of the whole prior chain) on a time-varying model, to a certified QP solution under box and affine
constraints; f and h given as maps linearise exactly when they are linear."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from qp_reference import kkt_reference

import jaxdip as jd
from jaxdip.control.riccati import dare
from jaxdip.engine.checks import ArgumentError
from jaxdip.estimators import WeightedMHE
from jaxdip.estimators.varying_mhe import TimeVaryingMHE
from jaxdip.sim.discretize import zoh

A_C = np.array([[0.0, 1.0, 0.0], [-2.0, -0.3, 1.0], [0.0, 0.0, -0.5]])
B_C = np.array([[0.0], [1.0], [0.5]])
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
Q, R = np.diag([1e-3, 1e-2, 1e-3]), np.diag([0.05, 0.1])


@pytest.mark.parametrize("N, anchor", [(4, 0), (3, 2)])
def test_equals_the_lti_weighted_mhe(N, anchor):
    m = zoh(A_C, B_C, 0.1)
    P = np.asarray(dare(jnp.asarray(m.Phi).T, C.T, Q, R))
    Wv, Ww, Wa = np.linalg.inv(R), np.linalg.inv(Q), np.linalg.inv(P)
    lti = WeightedMHE(m, C, Wv, Wa, 0.8, proc_weight=Ww, N=N, anchor=anchor, prior="filtered")
    tv = TimeVaryingMHE(Wv, Ww, Wa, 0.8, Phi=m.Phi, W=m.W, C=C, N=N, anchor=anchor)
    rng = np.random.default_rng(0)
    ys, us = rng.normal(size=(40, 2)), rng.normal(size=(40, 1))
    a, b = jd.run_estimator(lti, ys, us, x0=np.zeros(3)), jd.run_estimator(tv, ys, us, x0=np.zeros(3))
    assert np.abs(np.asarray(a.xhat)).max() > 0.1
    np.testing.assert_allclose(b.xhat, a.xhat, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(b.aux.window[N:, -1], b.xhat[N:])  # the estimate is the window's last state
    np.testing.assert_allclose(b.aux.window, a.aux.window, rtol=0, atol=1e-10)


def test_hard_model_window_follows_the_model():
    """WeightedMHE's hard-model window (the unknown is z_a): its rows obey z_{i+1} = Phi z_i + W u_i, its anchor
    row is the solved z_a and its last row the estimate."""
    m = zoh(A_C, B_C, 0.1)
    N, a = 3, 1
    est = WeightedMHE(m, C, np.eye(2), np.eye(3), 0.5, N=N, anchor=a)
    rng = np.random.default_rng(5)
    ys, us = rng.normal(size=(12, 2)), rng.normal(size=(12, 1))
    r = jd.run_estimator(est, ys, us, x0=np.zeros(3))
    Z, Phi, W = np.asarray(r.aux.window), np.asarray(m.Phi), np.asarray(m.W)
    for j in range(N, 12):
        u_win = us[j - N:j]  # u_{j-N} .. u_{j-1}
        np.testing.assert_allclose(Z[j, 1:], Z[j, :-1] @ Phi.T + u_win @ W.T, rtol=0, atol=1e-12)
        np.testing.assert_allclose(Z[j, -1], r.xhat[j], rtol=0, atol=1e-12)
    assert not Z[:N].any() and np.abs(Z[N:]).max() > 0.1


def _tv_model(rng, T, d=3, p=2, m=1):
    Phi = np.eye(d) + 0.2 * rng.normal(size=(T, d, d))
    Phi[:, 0, :] = 0.0  # a singular transition: the window needs no inverse
    Phi[:, 0, 1] = 1.0
    return Phi, rng.normal(size=(T, d, m)), rng.normal(size=(T, p, d))


def _numpy_tv_mhe(Phi, W, C, Wv, Ww, Wa, gamma, N, a, x0, ys, us):
    """Every sample's estimate by the normal equations H Z = g of its window, assembled term by term, with the
    filtered prior chain (predictions from the previous unconstrained estimates). Returns (xhat, windows, priors)."""
    T, d = len(ys), x0.shape[0]
    xcur, xchain, preds = x0.copy(), x0.copy(), []
    out, windows, priors = [], [], []
    for k in range(T):
        if k > 0:
            xcur = Phi[k - 1] @ xcur + W[k - 1] @ us[k - 1]
            xchain = Phi[k - 1] @ xchain + W[k - 1] @ us[k - 1]
        preds.append(xchain)
        if k >= N:
            t0 = k - N
            H, g = np.zeros(((N + 1) * d,) * 2), np.zeros((N + 1) * d)
            blk = lambda i: slice(i * d, (i + 1) * d)
            H[blk(a), blk(a)] += Wa / gamma
            g[blk(a)] += Wa @ preds[t0 + a] / gamma
            for i in range(N + 1):
                Ci = C[t0 + i]
                H[blk(i), blk(i)] += Ci.T @ Wv @ Ci
                g[blk(i)] += Ci.T @ Wv @ ys[t0 + i]
            for i in range(N):
                F, drive = Phi[t0 + i], W[t0 + i] @ us[t0 + i]
                H[blk(i), blk(i)] += F.T @ Ww @ F
                H[blk(i), blk(i + 1)] -= F.T @ Ww
                H[blk(i + 1), blk(i)] -= Ww @ F
                H[blk(i + 1), blk(i + 1)] += Ww
                g[blk(i)] -= F.T @ Ww @ drive
                g[blk(i + 1)] += Ww @ drive
            Z = np.linalg.solve(H, g).reshape(N + 1, d)
            xcur = xchain = Z[-1]
            windows.append(Z)
            priors.append(preds[t0 + a])
        out.append(xcur)
    return np.array(out), np.array(windows), np.array(priors)


def test_time_varying_equals_window_least_squares():
    rng = np.random.default_rng(1)
    T, N, a, gamma = 30, 4, 1, 0.7
    Phi, W, Cs = _tv_model(rng, T)
    Wv, Ww, Wa = np.diag([20.0, 10.0]), np.diag([100.0, 50.0, 200.0]), np.eye(3)
    x0 = np.array([0.3, -0.1, 0.2])
    ys, us = rng.normal(size=(T, 2)), rng.normal(size=(T, 1))
    est = TimeVaryingMHE(Wv, Ww, Wa, gamma, Phi=Phi, W=W, C=Cs, N=N, anchor=a, xhat0=x0)
    run = jd.run_estimator(est, ys, us)
    ref, windows, priors = _numpy_tv_mhe(Phi, W, Cs, Wv, Ww, Wa, gamma, N, a, x0, ys, us)
    scale = np.abs(ref).max()
    assert scale > 0.5
    np.testing.assert_allclose(run.xhat, ref, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(run.aux.window[N:], windows, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(run.aux.prior[N:], priors, rtol=0, atol=1e-9 * scale)


def test_maps_linearise_exactly_when_linear():
    rng = np.random.default_rng(2)
    Phi, W, Cs = _tv_model(rng, 1)
    Phi, W, Cm = Phi[0], W[0], Cs[0]
    kw = dict(N=3, xhat0=np.array([0.1, 0.0, -0.1]))
    weights = (np.eye(2) * 10.0, np.eye(3) * 100.0, np.eye(3))
    mat = TimeVaryingMHE(*weights, Phi=Phi, W=W, C=Cm, **kw)
    fun = TimeVaryingMHE(*weights, f=lambda x, u: Phi @ x + W @ u, h=lambda x: Cm @ x, **kw)
    ys, us = rng.normal(size=(20, 2)), rng.normal(size=(20, 1))
    np.testing.assert_allclose(jd.run_estimator(fun, ys, us).xhat, jd.run_estimator(mat, ys, us).xhat,
                               rtol=0, atol=1e-10)


def test_constrained_windows_equal_a_certified_qp():
    """Box on z[2] and an affine row z[0] + z[1] <= 0.05 on every window state: each window's solution equals
    the certified QP minimiser of the same stacked problem, and some rows are active."""
    rng = np.random.default_rng(3)
    T, N = 10, 3
    Phi, W, Cs = _tv_model(rng, T)
    est = TimeVaryingMHE(np.diag([20.0, 10.0]), np.diag([100.0, 50.0, 200.0]), np.eye(3), 1.0, Phi=Phi, W=W,
                         C=Cs, N=N, lower=np.array([-np.inf, -np.inf, -0.05]), upper=np.array([np.inf, np.inf, 0.05]),
                         A_c=np.array([[1.0, 1.0, 0.0]]), b_c=np.array([0.05]))
    ys, us = rng.normal(size=(T, 2)), rng.normal(size=(T, 1))
    step = jax.jit(est.step)
    st = est.init(None, np.zeros(3))
    G, lo, hi = (np.asarray(v) for v in est.constraint_matrix())
    active = 0
    for k in range(T):
        st, _, aux = step(st, ys[k], us[k - 1] if k else np.zeros(1), None, k)
        if k < N:
            continue
        A, b = (np.asarray(v) for v in est.stacked(aux.prior, st.ybuf, st.ubuf, st.Cbuf, st.Phibuf, st.Wbuf, st.cbuf))
        Z, n_act = kkt_reference(A, b, G, lo, hi, np.zeros(A.shape[1]))
        active += n_act
        np.testing.assert_allclose(np.asarray(aux.window).reshape(-1), Z, rtol=0, atol=1e-8)
        assert float(aux.violation) < 1e-8
    assert active >= 5


def test_bad_arguments_are_named():
    w = (np.eye(2), np.eye(3), np.eye(3))
    with pytest.raises(ArgumentError, match="either as Phi"):
        TimeVaryingMHE(*w, C=C, N=2)
    with pytest.raises(ArgumentError, match="anchor"):
        TimeVaryingMHE(*w, Phi=np.eye(3), C=C, N=2, anchor=2)
    with pytest.raises(ArgumentError, match="C must be"):
        TimeVaryingMHE(*w, Phi=np.eye(3), C=np.eye(3), N=2)


def test_weighted_mhe_converges_to_the_stationary_kalman_filter():
    """What the docs claim of WeightedMHE.from_noise (filtered prior, anchor 0, Wa = P^{-1} from the filtering
    DARE): it is *not* the stationary Kalman filter, it converges to it. Each window is the stationary filter run
    from the window's prior, so the difference d_j of the two estimates obeys d_j = [(I - K C) Phi]^{N+1} d_{j-N-1}
    exactly (the first N estimates are the model's propagation, not filter updates) and decays at that rate."""
    m = zoh(A_C, B_C, 0.1)
    Phi, W = np.asarray(m.Phi), np.asarray(m.W)
    P = np.asarray(dare(jnp.asarray(Phi).T, C.T, Q, R))
    K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    N, T = 3, 120
    x0 = np.array([1.0, -0.5, 0.3])
    mhe = WeightedMHE.from_noise(m, C, Q, R, N=N, xhat0=x0)
    rng = np.random.default_rng(4)
    ys, us = rng.normal(size=(T, 2)), rng.normal(size=(T, 1))
    xm = np.asarray(jd.run_estimator(mhe, ys, us).xhat)
    xk, x = [], x0
    for k in range(T):  # the stationary (fixed-gain) Kalman filter from the same xhat0
        xp = x if k == 0 else Phi @ x + W @ us[k - 1]
        x = xp + K @ (ys[k] - C @ xp)
        xk.append(x)
    d = xm - np.array(xk)
    F = np.linalg.matrix_power((np.eye(3) - K @ C) @ Phi, N + 1)
    np.testing.assert_allclose(d[N + 1:], d[:-N - 1] @ F.T, rtol=0, atol=1e-12)
    rho = max(abs(np.linalg.eigvals((np.eye(3) - K @ C) @ Phi)))
    print(f"|d_0| {np.abs(d[0]).max():.2e}, |d_{T - 1}| {np.abs(d[-1]).max():.2e}, rate per sample {rho:.3f}")
    assert np.abs(d[:N]).max() > 1e-2 and np.abs(d[-1]).max() < 1e-6 * np.abs(d[:N]).max()
