"""Observers of the reaction-wheel pendulum (Aranovskiy et al.): HOMD (10)-(13), Luenberger (9), bias observers
(17), (21), (24), against independent references (NumPy, scipy's solve_ivp, closed forms)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import homd
from jaxdip.estimators import luenberger as lu
from jaxdip.estimators.recorded import run
from jaxdip.plants import rwp

P = rwp.RWP()
J = P.Jp + P.mp * P.lp**2 + P.mr * P.lr**2
A1 = (P.mp * P.lp + P.mr * P.lr) * P.g / J
DT = rwp.DT
G = homd.gains(5.0, 12.0, 0.9)


def np_spow(x, a):
    return np.abs(x) ** a * np.sign(x)


# ---- the signed power ----------------------------------------------------------------------------------------


def test_spow_values_and_finite_gradients():
    xs = np.array([-2.0, -0.3, -1e-9, 0.0, 1e-9, 0.4, 3.0])
    for a in (0.8, 0.9, 1.0, 1.5):
        np.testing.assert_allclose(homd.spow(jnp.asarray(xs), a), np_spow(xs, a), rtol=1e-14, atol=0)
    dx = jax.grad(homd.spow, argnums=0)
    da = jax.grad(homd.spow, argnums=1)
    # at 0: finite (0 for a != 1, 1 for the linear case) in x, 0 in a; a naive |x|^a sgn(x) gives nan/inf
    assert float(dx(0.0, 0.9)) == 0.0 and float(dx(0.0, 1.0)) == 1.0 and float(dx(0.0, 1.5)) == 0.0
    assert float(da(0.0, 0.9)) == 0.0
    naive = jax.grad(lambda x, a: jnp.abs(x) ** a * jnp.sign(x), argnums=0)
    assert not np.isfinite(float(naive(0.0, 0.9)))
    # elsewhere: central finite differences
    h = 1e-6
    for x in (-0.7, 0.05, 2.0):
        for a in (0.8, 0.9):
            fd_x = (np_spow(x + h, a) - np_spow(x - h, a)) / (2 * h)
            fd_a = (np_spow(x, a + h) - np_spow(x, a - h)) / (2 * h)
            assert abs(float(dx(x, a)) - fd_x) < 1e-6 * max(1, abs(fd_x))
            assert abs(float(da(x, a)) - fd_a) < 1e-6 * max(1, abs(fd_a))


# ---- Proposition 1: finite-time convergence of (11) --------------------------------------------------------


def _integrate_error(alpha, e0, h=1e-3, t_end=20.0):
    g = homd.gains(5.0, 12.0, alpha)

    def step(e, _):
        f = lambda x: homd.error_rhs(g, x)  # noqa: E731
        k1 = f(e)
        k2 = f(e + 0.5 * h * k1)
        k3 = f(e + 0.5 * h * k2)
        k4 = f(e + h * k3)
        e = e + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return e, e

    _, es = jax.lax.scan(step, jnp.asarray(e0, dtype=jnp.float64), None, length=int(round(t_end / h)))
    return (np.arange(es.shape[0]) + 1) * h, np.asarray(es)


def _first_below(t, norm, eps):
    i = np.argmax(norm < eps)
    return t[i] if norm[i] < eps else np.inf


def test_homd_error_matches_reference_solver():
    """(11) as implemented (fixed-step RK4) against scipy's adaptive solver at tight tolerance."""
    t, es = _integrate_error(0.9, [0.1, -0.3], h=1e-3, t_end=2.0)

    def f(_, e):
        return [e[1] - 5 * np_spow(e[0], 0.9), -12 * np_spow(e[0], 0.8)]

    ref = solve_ivp(f, (0, 2.0), [0.1, -0.3], method="LSODA", rtol=1e-11, atol=1e-13, t_eval=t[99::100])
    np.testing.assert_allclose(es[99::100], ref.y.T, atol=2e-6)


def test_homd_error_reaches_zero_in_finite_time():
    """Settling time to eps converges as eps -> 0 for α = 0.9 (finite time); for α = 1 it grows like ln(1/eps)."""
    t, es = _integrate_error(0.9, [0.1, 0.0])
    n = np.abs(es).max(axis=1)
    T = {eps: _first_below(t, n, eps) for eps in (1e-6, 1e-10, 1e-14, 1e-20)}
    assert T[1e-20] < 3.5  # reaches (numerically) zero at a finite time
    assert T[1e-20] - T[1e-14] < 0.15 < T[1e-10] - T[1e-6]  # each 1e-6 decade costs less and less time
    assert n[t > T[1e-20]].max() < 1e-18  # and stays there (the RK4 chattering floor is ~1e-26)
    t1, es1 = _integrate_error(1.0, [0.1, 0.0])
    n1 = np.abs(es1).max(axis=1)
    T1 = {eps: _first_below(t1, n1, eps) for eps in (1e-14, 1e-20)}
    assert T1[1e-20] - T1[1e-14] > 3.0  # exponential: ln(1e6)/2.5 ≈ 5.5 s per six decades
    assert n1[np.searchsorted(t1, T[1e-20])] > 1e-8


def test_homd_settling_time_scales_by_homogeneity():
    """Weighted homogeneity of degree α - 1: T(λ e1, λ^α e2) = λ^(1-α) T(e1, e2) (finite time), checked at a
    threshold far below both initial sizes."""
    eps = 1e-22
    T = []
    for lam in (1.0, 1e-2):
        t, es = _integrate_error(0.9, [0.1 * lam, 0.2 * lam**0.9], h=2e-4, t_end=6.0)
        T.append(_first_below(t, np.abs(es).max(axis=1), eps))
    assert abs(T[1] / T[0] - 1e-2 ** 0.1) < 0.05


# ---- the differentiators on sampled data -------------------------------------------------------------------


def _np_plant(t, z, I):
    """(2)-(3) in NumPy (the reference for the JAX plant is tests/test_plants_other.py)."""
    s = A1 * np.sin(z[0])
    return [z[1], -P.k / J * I + s, z[3], (J + P.Jr) * P.k / (J * P.Jr) * I - s]


def _plant_data(T_end=2.5, K=(-582.0, -83.0, -1.2), x0=(0.05, 0.0, 0.0, 0.0)):
    """Closed loop (2)-(3) under sampled state feedback u_k = -K x_k, integrated by solve_ivp per period."""
    n = int(round(T_end / DT))
    x = np.array(x0, float)
    xs, us, sols = [], [], []
    for _ in range(n):
        u = -(K[0] * x[0] + K[1] * x[1] + K[2] * x[3])
        xs.append(x.copy())
        us.append(u)
        sol = solve_ivp(_np_plant, (0, DT), x, args=(u,),
                        method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
        sols.append(sol.sol)
        x = sol.y[:, -1]
    return np.array(xs), np.array(us), sols


@pytest.fixture(scope="module")
def plant_data():
    return _plant_data()


def test_rwp_homd_matches_continuous_observer_on_noiseless_data(plant_data):
    """The sampled observer (FOH, RK4 sub-steps) against (10)+(12) integrated by solve_ivp with the exact
    continuous theta(t), theta_r(t); and the velocity estimates converge to the true velocities."""
    xs, us, sols = plant_data
    ys = xs[:, [0, 2]]
    us_prev = np.concatenate([[0.0], us[:-1]])[:, None]
    _, out, _ = run(homd.HOMDObserver.build(DT, substeps=20), ys, us_prev, jnp.zeros(4))
    out = np.asarray(out)

    # independent NumPy reference: start at y_0 with zero velocities, integrate period by period
    def rhs(t, xi, k):
        z = sols[k](t)
        th, thr = z[0], z[2]
        I = us[k]
        ep, er = xi[0] - th, xi[2] - thr
        acc_p = -P.k / J * I + A1 * np.sin(th)
        acc_r = (J + P.Jr) * P.k / (J * P.Jr) * I - A1 * np.sin(th)
        return [xi[1] - 5 * np_spow(ep, 0.9), acc_p - 12 * np_spow(ep, 0.8),
                xi[3] - 5 * np_spow(er, 0.9), acc_r - 12 * np_spow(er, 0.8)]

    xi = np.array([ys[0, 0], 0.0, ys[0, 1], 0.0])
    ref = [xi.copy()]
    for k in range(len(us) - 1):
        xi = solve_ivp(rhs, (0, DT), xi, args=(k,), method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
        ref.append(xi.copy())
    ref = np.array(ref)
    np.testing.assert_allclose(out[:, 1], ref[:, 1], atol=2e-4)
    np.testing.assert_allclose(out[:, 3], ref[:, 3], atol=2e-3)
    late = slice(int(1.8 / DT), None)
    assert np.abs(out[late, 1] - xs[late, 1]).max() < 1e-4
    assert np.abs(out[late, 3] - xs[late, 3]).max() < 1e-3


def test_luenberger_error_dynamics_are_the_linear_differentiators():
    L, wp, wr = lu.matched_gain(P, G, G, 1.0, 10.0)
    A, B, C = (np.asarray(m) for m in lu.full_linear_model(P))
    E = A - np.asarray(L) @ C
    np.testing.assert_allclose(E[:2, 2:], 0, atol=1e-12)
    np.testing.assert_allclose(E[2:, :2], 0, atol=1e-12)
    for blk, w in ((E[:2, :2], wp), (E[2:, 2:], wr)):
        np.testing.assert_allclose(np.poly(blk), [1, 5 * w, 12 * w**2], rtol=1e-12)
    # B of (9) is the column of (2)-(3)
    np.testing.assert_allclose(B[:, 0], [0, -P.k / J, 0, P.k / J + P.k / P.Jr], rtol=1e-14)


def test_rise_time_matching():
    """Linear rise time against the closed form expm solution; the matched ω equalises the rise times."""
    lin = homd.gains(5.0, 12.0, 1.0)
    tr = lu.velocity_step_rise_time(lin, 1.0)
    M = np.array([[-5.0, 1.0], [-12.0, 0.0]])
    lam, V = np.linalg.eig(M)
    c = np.linalg.solve(V, [0.0, -1.0])
    ts = np.arange(1, 300001) * 1e-5
    xhat2 = 1.0 + ((V[1] * c)[None, :] * np.exp(np.outer(ts, lam))).sum(axis=1).real
    assert abs(xhat2[12345] - 1.0 - (expm(M * ts[12345]) @ [0.0, -1.0])[1]) < 1e-12
    t10 = ts[np.argmax(xhat2 >= 0.1)]
    t90 = ts[np.argmax(xhat2 >= 0.9)]
    assert abs(tr - (t90 - t10)) < 2.1e-4
    w = lu.matched_omega(G, 1.0)
    scaled = homd.gains(5.0 * w, 12.0 * w**2, 1.0)
    assert abs(lu.velocity_step_rise_time(scaled, 1.0) - lu.velocity_step_rise_time(G, 1.0)) < 1e-3


# ---- bias propagation (14)-(15) ----------------------------------------------------------------------------


def test_biased_differentiator_settles_at_15():
    """(14) for constant theta: the equilibrium velocity error is (15) (solve_ivp reference)."""
    from jaxdip.theory import rwp as T

    d, th = -0.08, 0.05

    def f(_, e):
        return [e[1] - 5 * np_spow(e[0] - d, 0.9), A1 * np.cos(th) * d - 12 * np_spow(e[0] - d, 0.8)]

    sol = solve_ivp(f, (0, 30.0), [0.0, 0.0], method="LSODA", rtol=1e-11, atol=1e-13)
    ref = float(T.homd_steady_error(5.0, 12.0, 0.9, A1, d, np.cos(th)))
    assert abs(sol.y[1, -1] - ref) < 1e-6 * abs(ref)


# ---- bias observers ------------------------------------------------------------------------------------------


def test_lowpass_observer_is_a_first_order_filter():
    """(17) on a constant measurement: d̂(t) = y (1 - exp(-γ_d t)) exactly (up to RK4 error)."""
    y = -0.08
    n = 500
    ys = np.tile([y, 0.0, 0.0, 0.0], (n, 1))
    _, out, _ = run(bo.LowpassMeasured.build(DT, 0.5), ys, np.zeros((n, 1)), jnp.zeros(4))
    dhat = ys[:, 0] - np.asarray(out)[:, 0]
    t = np.arange(n) * DT
    np.testing.assert_allclose(dhat, y * (1 - np.exp(-0.5 * t)), atol=1e-12)


def test_reduced_order_observer_rate_22():
    """(21) with the pendulum at rest upright (theta = 0, I = 0) and y = d: ẑ3' = L0 a1 (sin d - cos d ẑ3), so
    ẑ3 -> tan d ≈ d at the rate L0 a1 cos d of (22)."""
    d, L0 = -0.08, 0.05
    n = 1000
    ys = np.tile([d, 0.0, 0.0, 0.0], (n, 1))
    _, out, _ = run(bo.ReducedOrderMeasured.build(DT, P, L0), ys, np.zeros((n, 1)), jnp.zeros(4))
    z3 = ys[:, 0] - np.asarray(out)[:, 0]
    t = np.arange(n) * DT
    rate = L0 * A1 * np.cos(d)
    np.testing.assert_allclose(z3, np.tan(d) * (1 - np.exp(-rate * t)), atol=1e-10)


def test_joint_observer_error_dynamics_25():
    """(24) minus the true dynamics equals (25) plus the linearisation remainder a1 (sin y - cos(y) d - sin θ)."""
    L0 = 0.01
    hp = homd.HOMDObserver.build(DT)
    prm = bo.JointObserver.build(hp, L0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        th, thd, d = rng.normal(0, [0.2, 1.0, 0.1])
        xi = jnp.asarray(np.concatenate([rng.normal(0, [0.2, 1.0, 10.0]), [0.0, 0.0]]))
        I = rng.normal(0, 2.0)
        y = th + d
        dxi = np.asarray(bo.joint_rhs(prm, xi, jnp.array([y, 0.0]), jnp.array([I])))
        z3 = L0 * (float(xi[2]) - float(xi[1]))
        e1, e2, e3 = float(xi[0]) - th, float(xi[1]) - thd, z3 - d
        thdd = -P.k / J * I + A1 * np.sin(th)
        sdot = np.array([dxi[0] - thd + L0 * (dxi[2] - dxi[1]), dxi[1] - thdd, L0 * (dxi[2] - dxi[1])])
        pred = np.array(bo.joint_error_rhs(hp.pend, L0, A1 * np.cos(y), jnp.array([e1 + e3, e2, e3])))
        pred[1] += A1 * (np.sin(y) - np.cos(y) * d - np.sin(th))
        np.testing.assert_allclose(sdot, pred, rtol=1e-9, atol=1e-9)


def test_gradients_reach_observer_hyperparameters():
    """d(loss)/d(L0, α_p, k_p1) of the joint observer over fixed data: finite and equal to central differences."""
    xs, us = np.zeros((250, 4)), np.zeros((250, 1))
    t = np.arange(250) * DT
    xs[:, 0] = 0.02 * np.sin(3 * t)
    d = -0.05
    ys = np.stack([xs[:, 0] + d, np.zeros(250)], axis=1)
    # the true theta'' = a1 sin(theta) - (k/J) I  =>  choose I so that theta follows the sine
    us[:, 0] = (A1 * np.sin(xs[:, 0]) + 0.02 * 9 * np.sin(3 * t)) * J / P.k
    us_prev = np.concatenate([[[0.0]], us[:-1]])

    def loss(theta):
        L0, alpha, k1 = theta
        hp = homd.HOMDObserver.build(DT, substeps=4)
        hp = eqx.tree_at(lambda h: h.pend, hp, homd.HOMDGains(k1, jnp.asarray(12.0), alpha))
        _, out, _ = run(bo.JointObserver.build(hp, L0), ys, us_prev, jnp.zeros(4))
        return jnp.mean((ys[:, 0] - out[:, 0] - d) ** 2)

    theta = jnp.array([0.05, 0.9, 5.0])
    g = np.asarray(jax.grad(loss)(theta))
    assert np.all(np.isfinite(g))
    f = jax.jit(loss)
    for i, h in enumerate((1e-5, 1e-6, 1e-5)):
        e = np.zeros(3)
        e[i] = h
        fd = (float(f(theta + e)) - float(f(theta - e))) / (2 * h)
        assert abs(g[i] - fd) <= 1e-4 * abs(fd) + 1e-10, (i, g[i], fd)
