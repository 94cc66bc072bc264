"""Analytic results of Aranovskiy et al. (jaxdip.theory.rwp) against independent references: NumPy solves and
eigenvalues, a NumPy Routh table, scipy's solve_ivp on the continuous closed loop, closed-loop simulations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import equinox as eqx

import jaxdip as jd
from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import homd
from jaxdip.plants import rwp
from jaxdip.scenarios import rwp as scenario
from jaxdip.theory import rwp as T

P = rwp.RWP()
K = rwp.K_TABLE2
J = P.Jp + P.mp * P.lp**2 + P.mr * P.lr**2
A1 = (P.mp * P.lp + P.mr * P.lr) * P.g / J
Bcol = np.array([0.0, -P.k / J, P.k / J + P.k / P.Jr])
Ared = np.array([[0, 1, 0], [A1, 0, 0], [-A1, 0, 0.0]])
Kn = np.array(K)


def routh_first_column(coeffs):
    """First column of the Routh table of a polynomial (descending coefficients), plain NumPy."""
    c = np.asarray(coeffs, float)
    n = len(c)
    rows = [c[0::2].copy(), c[1::2].copy()]
    width = len(rows[0])
    rows = [np.pad(r, (0, width - len(r))) for r in rows]
    for _ in range(n - 2):
        a, b = rows[-2], rows[-1]
        new = np.zeros(width)
        for j in range(width - 1):
            new[j] = (b[0] * a[j + 1] - a[0] * b[j + 1]) / b[0]
        rows.append(new)
    return np.array([r[0] for r in rows])


# ---- equilibria -----------------------------------------------------------------------------------------------


def test_equilibrium_7_and_16_against_numpy():
    M = Ared - np.outer(Bcol, Kn)
    for d in (-0.08, 0.03):
        x7 = np.linalg.solve(M, np.outer(Bcol, Kn) @ [d, 0, 0])
        np.testing.assert_allclose(np.asarray(T.equilibrium_biased_feedback(P, K, d)), x7, atol=1e-12)
        np.testing.assert_allclose(x7, [0, 0, -d * K[0] / K[2]], atol=1e-9)
        assert abs(float(T.thetar_dot_biased_feedback(K, d)) - x7[2]) < 1e-9
        ep2 = float(T.homd_steady_error(5.0, 12.0, 0.9, A1, d))
        x16 = np.linalg.solve(M, np.outer(Bcol, Kn) @ [d, ep2, -ep2])
        np.testing.assert_allclose(x16, [0, 0, ep2 * (K[2] - K[1]) / K[2] - d * K[0] / K[2]], atol=1e-9)
        assert abs(float(T.thetar_dot_biased_homd(K, d, ep2)) - x16[2]) < 1e-9
    # the paper's numbers for d = -0.08: e_p2^0 ≈ -1.43 (measured), theta_r' ≈ 138
    ep2 = float(T.homd_steady_error(5.0, 12.0, 0.9, A1, -0.08))
    assert abs(ep2 - (-1.43)) < 0.03
    assert abs(float(T.thetar_dot_biased_homd(K, -0.08, ep2)) - 138.0) < 1.0


@pytest.fixture(scope="module")
def biased_homd_run():
    """Closed loop (2)-(3) + (10) + (12) + law (8) at 500 Hz with the Table 1 quantisation and d = -0.08."""
    dt = rwp.DT
    loop = scenario.loop(homd.HOMDObserver.build(dt), dt=dt, K=K, d=-0.08)
    n = int(8.0 / dt)
    sol = jax.jit(lambda lp: jd.simulate(lp, jnp.array([0.05, 0.0, 0.0, 0.0]), jax.random.PRNGKey(0), n,
                                         save=_x_and_xhat))(loop)
    return np.asarray(sol.saved[0]), np.asarray(sol.saved[1]), bool(sol.result != jd.RESULTS.ok)


def _x_and_xhat(s):
    return s.x, s.xhat


def _bias_error(s):
    return s.y[0] - s.xhat[0] + 0.01


def test_simulated_bias_steady_state_matches_15_16(biased_homd_run):
    x, xh, div = biased_homd_run
    assert not div
    tail = slice(-1000, None)  # last 2 s
    ep2_sim = (xh[tail, 1] - x[tail, 1]).mean()
    wdot_sim = x[tail, 3].mean()
    ep2 = float(T.homd_steady_error(5.0, 12.0, 0.9, A1, -0.08))
    wdot = float(T.thetar_dot_biased_homd(K, -0.08, ep2))
    assert abs(ep2_sim - ep2) < 0.05 * abs(ep2)
    assert abs(wdot_sim - wdot) < 0.05 * abs(wdot)
    assert abs(x[tail, 0].mean()) < 1e-3  # the pendulum itself is upright


# ---- Proposition 2 ----------------------------------------------------------------------------------------------


def test_characteristic_polynomials_as_printed():
    M = Ared - np.outer(Bcol, Kn)
    m = [float(v) for v in T.char_coeffs(P, K)]
    np.testing.assert_allclose(np.poly(M)[1:], m, rtol=1e-12)
    for g in (0.05, 0.5, 3.0, 20.0):
        F = np.asarray(T.lowpass_F(P, K, g))
        b = [float(v) for v in T.lowpass_char_coeffs(P, K, g)]
        np.testing.assert_allclose(np.poly(F)[1:], b, rtol=1e-10)
        # the F printed in the paper (0 instead of -γ_d on the diagonal) does not have that polynomial
        F_printed = F.copy()
        F_printed[3, 3] = 0.0
        assert np.max(np.abs(np.poly(F_printed)[1:] - b) / np.abs(b)) > 1e-3


def test_gamma_bar_routh_equals_eigenvalue_route():
    gb = T.gamma_bar_routh(P, K)
    ge = T.gamma_bar_eig(P, K)
    assert abs(gb.gamma_bar - ge) < 1e-6
    assert gb.gamma_bar_1 == pytest.approx(-P.k * K[2] / P.Jr)
    assert gb.gamma_bar == gb.gamma_bar_2 < gb.gamma_bar_1
    # an independent Routh table of det(sI - F) just below / above
    for f, stable in ((0.99, True), (1.01, False)):
        col = routh_first_column(np.poly(np.asarray(T.lowpass_F(P, K, f * gb.gamma_bar))))
        assert np.all(col > 0) == stable
        assert (np.max(np.linalg.eigvals(np.asarray(T.lowpass_F(P, K, f * gb.gamma_bar))).real) < 0) == stable


def _continuous_lowpass_loop(gamma, d=-0.01, t_end=120.0):
    """Nonlinear plant (2)-(3), exact velocities, bias observer (17), law (18); scipy reference integration."""

    def f(t, z):
        th, thd, thr, thrd, dh = z
        I = -(K[0] * (th + d - dh) + K[1] * thd + K[2] * thrd)
        s = A1 * np.sin(th)
        return [thd, -P.k / J * I + s, thrd, (J + P.Jr) * P.k / (J * P.Jr) * I - s, gamma * (th + d - dh)]

    ts = np.linspace(0, t_end, 6001)
    sol = solve_ivp(f, (0, t_end), [0.0, 0, 0, 0, 0], t_eval=ts, method="LSODA", rtol=1e-9, atol=1e-12)
    return ts, sol.y[4] - d


def _growth(ts, err, window=6.0):
    n = int(window / (ts[1] - ts[0]))
    return np.log(np.abs(err[-n:]).max() / np.abs(err[n:2 * n]).max()) / (ts[-n] - ts[n])


def test_simulations_around_gamma_bar_continuous():
    gb = T.gamma_bar_routh(P, K).gamma_bar
    for f in (0.95, 1.05):
        ts, err = _continuous_lowpass_loop(f * gb)
        rate = _growth(ts, err)
        re = np.max(np.linalg.eigvals(np.asarray(T.lowpass_F(P, K, f * gb))).real)
        assert np.sign(rate) == np.sign(re) == (1 if f > 1 else -1)
        assert abs(rate - re) < 0.3 * abs(re)


def test_simulations_around_gamma_bar_sampled_loop():
    """The jaxdip loop at 500 Hz with the low-pass observer on measured velocities, law (18)."""
    gb = T.gamma_bar_routh(P, K).gamma_bar
    dt = rwp.DT
    loop = scenario.loop(bo.LowpassMeasured.build(dt, gb), dt=dt, K=K, d=-0.01,
                         measured_velocities=True, quantize=False)
    loop = eqx.tree_at(lambda lp: lp.state_bound, loop, jnp.inf)  # measure the growth, do not stop at pi/2
    n = int(100.0 / dt)

    def run(g):
        lp = eqx.tree_at(lambda lp: lp.estimator.gamma_d, loop, g)
        return jd.simulate(lp, jnp.zeros(4), jax.random.PRNGKey(0), n, save=_bias_error, save_every=10).saved

    recs = jax.jit(jax.vmap(run))(jnp.array([0.9 * gb, 1.1 * gb]))
    ts = np.arange(recs.shape[1]) * dt * 10
    below, above = (_growth(ts, np.asarray(r)) for r in recs)
    assert below < 0 < above


def test_lowpass_with_differentiators_linear_matrix_against_autodiff():
    """The hand-built α = 1 matrix against jacfwd of the loop's own components (plant + (17) + (10) + (12))."""
    hp = homd.HOMDObserver.build(rwp.DT, pend=(5.0, 12.0, 1.0), wheel=(5.0, 12.0, 1.0))
    for g in (0.05, 0.5):
        lp = bo.LowpassHOMD.build(hp, g)

        def f(z):
            X, xi = z[:4], z[4:]
            y = jnp.stack([X[0], X[2]])
            u = -(K[0] * (y[0] - xi[4]) + K[1] * xi[1] + K[2] * xi[3])
            return jnp.concatenate([rwp.f(P, X, u[None]), bo.lowpass_rhs(lp, xi, y, u[None])])

        Jfull = np.asarray(jax.jacfwd(f)(jnp.zeros(9)))
        ev_full = np.linalg.eigvals(Jfull)
        ev_full = np.sort_complex(ev_full[np.abs(ev_full) > 1e-9])  # drop the free wheel angle's zero
        M, _ = T.lowpass_homd_linear_matrix(P, K, (5.0, 12.0), (5.0, 12.0), g)
        np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(M)), ev_full, rtol=1e-8, atol=1e-8)
    assert 0.5 < T.gamma_bar_lowpass_homd_linear(P, K, (5.0, 12.0), (5.0, 12.0), grid=200) < 1.0


# ---- Proposition 3: the matrix inequalities (27) --------------------------------------------------------------


def test_s_M_and_lmi_matrices():
    assert T.s_M(-0.2, 0.9) == pytest.approx(np.exp(-1.0))  # the paper's s_M ≈ 0.36
    Am, AM, A1m = T.lmi_matrices(0.01, 5.0, 12.0, A1, 0.9)
    # A1 is the α-derivative of (25)'s right side at α = 1 (finite differences of the error field)
    g1 = homd.gains(5.0, 12.0, 1.0)
    s = jnp.array([0.3, -0.2, 0.05])
    ga = homd.gains(5.0, 12.0, 1.0 - 1e-6)  # f_1 - f_(1-δ) ≈ δ ln(s1^2) A1 s
    fd = (np.asarray(bo.joint_error_rhs(g1, 0.01, A1, s)) - np.asarray(bo.joint_error_rhs(ga, 0.01, A1, s))) / 1e-6
    np.testing.assert_allclose(fd, np.log(0.3**2) * A1m @ np.asarray(s), rtol=1e-4)
    np.testing.assert_allclose(AM @ np.asarray(s), np.asarray(bo.joint_error_rhs(g1, 0.01, A1, s)), rtol=1e-12)


def test_lmi_feasible_and_checked_independently():
    pytest.importorskip("cvxpy")
    r = T.solve_lmi(0.01, 0.62, -0.2, 5.0, 12.0, 0.9, A1, 0.9)
    assert r.feasible and r.margin > 0
    Q, Mm, MM = T.lmi_expressions(r.P, 0.01, 0.62, -0.2, 5.0, 12.0, A1, 0.9)
    tol = 1e-7 * np.abs(np.linalg.eigvalsh(r.P)).max()
    assert np.linalg.eigvalsh(r.P).min() > 0
    assert np.linalg.eigvalsh(0.5 * (Q + Q.T)).min() >= -tol
    assert np.linalg.eigvalsh(0.5 * (Mm + Mm.T)).max() < 0 and np.linalg.eigvalsh(0.5 * (MM + MM.T)).max() < 0
    # V = s' P s decreases along the expansion (26) wherever s1^2 < s_M^2 (sampled), for cos(z1) in [c0, 1]
    _, _, A1m = T.lmi_matrices(0.01, 5.0, 12.0, A1, 0.9)
    rng = np.random.default_rng(1)
    sM = r.s_M
    for _ in range(2000):
        s = rng.normal(size=3)
        s[0] = rng.uniform(-0.999, 0.999) * sM
        c = rng.uniform(0.9, 1.0)
        A0 = T.lmi_matrices(0.01, 5.0, 12.0, A1, c)[0]
        sdot = (A0 - A1m * np.log(s[0] ** 2) * 0.1) @ s
        assert 2 * s @ r.P @ sdot < 0
    # infeasible at μ = 0 (so the feasibility result is not vacuous), and a random P fails the check
    assert not T.solve_lmi(0.01, 0.62, 0.0, 5.0, 12.0, 0.9, A1, 0.9).feasible
    assert not T.check_lmi(np.eye(3), 0.01, 0.62, -0.2, 5.0, 12.0, A1, 0.9).feasible


def test_lmi_boundary_mu_near_paper_value():
    pytest.importorskip("cvxpy")
    mu = T.mu_max(0.01, 0.62, 5.0, 12.0, 0.9, A1, 0.9, iters=14)
    assert -0.25 < mu < -0.15  # the paper: feasible for μ <= -0.2
