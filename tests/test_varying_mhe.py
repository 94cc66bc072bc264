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


def _numpy_window(Phis, drives, Cs, ys, Wv, Ww, Wa, gamma, a, xbar):
    """min over Z of the window cost, by its normal equations H Z = g assembled term by term."""
    N, d = len(Phis), xbar.shape[0]
    H, g = np.zeros(((N + 1) * d,) * 2), np.zeros((N + 1) * d)
    blk = lambda i: slice(i * d, (i + 1) * d)
    H[blk(a), blk(a)] += Wa / gamma
    g[blk(a)] += Wa @ xbar / gamma
    for i in range(N + 1):
        H[blk(i), blk(i)] += Cs[i].T @ Wv @ Cs[i]
        g[blk(i)] += Cs[i].T @ Wv @ ys[i]
    for i in range(N):
        F, dr = Phis[i], drives[i]
        H[blk(i), blk(i)] += F.T @ Ww @ F
        H[blk(i), blk(i + 1)] -= F.T @ Ww
        H[blk(i + 1), blk(i)] -= Ww @ F
        H[blk(i + 1), blk(i + 1)] += Ww
        g[blk(i)] -= F.T @ Ww @ dr
        g[blk(i + 1)] += Ww @ dr
    return np.linalg.solve(H, g).reshape(N + 1, d)


def _numpy_mhe(transition, output, weights, N, a, x0, ys, us):
    """The estimator in NumPy. transition(x, u, k) -> (Phi, W, c) of x_k -> x_{k+1} linearised at x;
    output(y, x, k) -> (C, y') of sample k at the prediction x. The filtered prior chain runs on the previous
    unconstrained estimates. Returns (xhat, windows, priors)."""
    xcur, xchain = x0.copy(), x0.copy()
    preds, trans, outs, est, windows, priors = [], [], [], [], [], []
    for k in range(len(ys)):
        if k > 0:
            F, Wk, c = transition(xchain, us[k - 1], k - 1)
            xcur, xchain = F @ xcur + Wk @ us[k - 1] + c, F @ xchain + Wk @ us[k - 1] + c
            trans.append((F, Wk @ us[k - 1] + c))  # trans[t]: x_t -> x_{t+1}
        preds.append(xchain)
        outs.append(output(ys[k], xchain, k))
        if k >= N:
            t0 = k - N
            Z = _numpy_window([f for f, _ in trans[t0:k]], [dr for _, dr in trans[t0:k]],
                              [o[0] for o in outs[t0:]], [o[1] for o in outs[t0:]], *weights, a, preds[t0 + a])
            xcur = xchain = Z[-1]
            windows.append(Z)
            priors.append(preds[t0 + a])
        est.append(xcur)
    return np.array(est), np.array(windows), np.array(priors)


def test_time_varying_equals_window_least_squares():
    rng = np.random.default_rng(1)
    T, N, a, gamma = 30, 4, 1, 0.7
    Phi, W, Cs = _tv_model(rng, T)
    Wv, Ww, Wa = np.diag([20.0, 10.0]), np.diag([100.0, 50.0, 200.0]), np.eye(3)
    x0 = np.array([0.3, -0.1, 0.2])
    ys, us = rng.normal(size=(T, 2)), rng.normal(size=(T, 1))
    est = TimeVaryingMHE(Wv, Ww, Wa, gamma, Phi=Phi, W=W, C=Cs, N=N, anchor=a, xhat0=x0)
    run = jd.run_estimator(est, ys, us)
    ref, windows, priors = _numpy_mhe(lambda x, u, k: (Phi[k], W[k], np.zeros(3)), lambda y, x, k: (Cs[k], y),
                                      (Wv, Ww, Wa, gamma), N, a, x0, ys, us)
    scale = np.abs(ref).max()
    assert scale > 0.5
    np.testing.assert_allclose(run.xhat, ref, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(run.aux.window[N:], windows, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(run.aux.prior[N:], priors, rtol=0, atol=1e-9 * scale)


def _fd_jacobian(fun, x, eps=1e-6):
    return np.stack([(fun(x + eps * e) - fun(x - eps * e)) / (2 * eps) for e in np.eye(x.shape[0])], axis=-1)


def test_nonlinear_model_linearised_along_the_estimate():
    """A damped pendulum (f: one Euler step, h = (sin theta, theta omega)) against the NumPy estimator with
    central-difference Jacobians at the same points (the previous unconstrained estimate for f, the prediction for
    h): 1e-7, the differences' error."""
    dt = 0.05
    f_np = lambda x, u: np.array([x[0] + dt * x[1], x[1] + dt * (-9.0 * np.sin(x[0]) - 0.2 * x[1] + u[0])])
    h_np = lambda x: np.array([np.sin(x[0]), x[0] * x[1]])
    f_jx = lambda x, u: jnp.stack([x[0] + dt * x[1], x[1] + dt * (-9.0 * jnp.sin(x[0]) - 0.2 * x[1] + u[0])])
    h_jx = lambda x: jnp.stack([jnp.sin(x[0]), x[0] * x[1]])
    weights = (np.diag([400.0, 100.0]), np.diag([1e4, 1e3]), np.eye(2) * 4.0, 1.0)
    N, a, T = 4, 0, 40
    x0 = np.array([0.8, 0.0])
    rng = np.random.default_rng(6)
    us = 0.5 * rng.normal(size=(T, 1))
    xs = [np.array([1.0, -0.3])]
    for k in range(T - 1):
        xs.append(f_np(xs[-1], us[k]) + rng.normal(0, [0.01, 0.03]))
    ys = np.array([h_np(x) for x in xs]) + rng.normal(0, [0.05, 0.1], size=(T, 2))

    def transition(x, u, k):
        F, Wk = _fd_jacobian(lambda z: f_np(z, u), x), _fd_jacobian(lambda v: f_np(x, v), u)
        return F, Wk, f_np(x, u) - F @ x - Wk @ u

    def output(y, x, k):
        Ck = _fd_jacobian(h_np, x)
        return Ck, y - h_np(x) + Ck @ x

    ref, windows, _ = _numpy_mhe(transition, output, weights, N, a, x0, ys, us)
    est = TimeVaryingMHE(*weights, f=f_jx, h=h_jx, N=N, anchor=a, xhat0=x0)
    run = jd.run_estimator(est, ys, us)
    np.testing.assert_allclose(run.xhat, ref, rtol=0, atol=1e-7)
    np.testing.assert_allclose(run.aux.window[N:], windows, rtol=0, atol=1e-7)
    truth = np.array(xs)
    assert np.sqrt(np.mean((ref[N:] - truth[N:]) ** 2)) < 0.3 * np.sqrt(np.mean((x0 - truth[N:]) ** 2))


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
