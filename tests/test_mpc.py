"""The QP solver (jaxdip.control.qp) against cvxpy, its status codes and implicit gradients; the linear MPC
(jaxdip.control.mpc) against the discrete LQR, inside simulate / monte_carlo, and its closed-loop gradients
against finite differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.control.mpc import LinearMPC, condense
from jaxdip.control.qp import QPCode, solve_qp
from jaxdip.control.designs import dlqr
from jaxdip.engine.checks import ArgumentError
from jaxdip.plants import dip

INF = np.inf


def _random_qps(rng, count, n=6, r=10):
    """Feasible strictly convex QPs: a random point z0 is strictly inside every row; some rows one-sided."""
    out = []
    for _ in range(count):
        F = rng.normal(size=(n, n))
        H = F @ F.T + 0.1 * np.eye(n)
        q = 3.0 * rng.normal(size=n)
        G = rng.normal(size=(r, n))
        s0 = G @ (0.1 * rng.normal(size=n))
        lo, hi = s0 - rng.uniform(0.05, 1, r), s0 + rng.uniform(0.05, 1, r)
        lo[rng.uniform(size=r) < 0.3] = -INF
        hi[rng.uniform(size=r) < 0.3] = INF
        out.append((H, q, G, lo, hi))
    return [np.stack(a) for a in zip(*out)]


def _cvxpy(H, q, G, lo, hi):
    cp = pytest.importorskip("cvxpy")
    z = cp.Variable(H.shape[0])
    fl, fh = np.isfinite(lo), np.isfinite(hi)
    cp.Problem(cp.Minimize(0.5 * cp.quad_form(z, cp.psd_wrap(H)) + q @ z),
               [G[fl] @ z >= lo[fl], G[fh] @ z <= hi[fh]]).solve(
        solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12)
    return z.value


def test_qp_matches_cvxpy_on_200_random_problems():
    H, q, G, lo, hi = _random_qps(np.random.default_rng(0), 200)
    sol = jax.jit(jax.vmap(solve_qp))(H, q, G, lo, hi)
    assert np.all(np.asarray(sol.status) == QPCode.SOLVED)
    active_rows = 0
    for i in range(200):
        ref = _cvxpy(H[i], q[i], G[i], lo[i], hi[i])
        np.testing.assert_allclose(np.asarray(sol.z[i]), ref, atol=1e-7 * max(1.0, np.abs(ref).max()), rtol=0)
        active_rows += int(np.sum(np.asarray(sol.active[i])))
    assert active_rows > 200  # the problems do exercise the constraints


def test_qp_status_infeasible_and_iteration_limit():
    H, q = np.eye(2), np.array([1.0, -1.0])
    # x1 >= 1 and x1 <= 0 on two rows: no feasible point
    sol = solve_qp(H, q, np.array([[1.0, 0.0], [1.0, 0.0]]), np.array([1.0, -INF]), np.array([INF, 0.0]))
    assert int(sol.status) == QPCode.INFEASIBLE
    sol = solve_qp(H, q, np.eye(2), np.array([1.0, 0.0]), np.array([0.0, 1.0]))  # lo > hi on a row
    assert int(sol.status) == QPCode.INFEASIBLE
    Hs, qs, Gs, los, his = _random_qps(np.random.default_rng(1), 8)
    full = jax.vmap(solve_qp)(Hs, qs, Gs, los, his)
    i = int(np.argmax(np.asarray(full.iterations)))
    assert int(full.iterations[i]) >= 2
    short = solve_qp(Hs[i], qs[i], Gs[i], los[i], his[i], max_iter=1)
    assert int(short.status) == QPCode.MAX_ITERATIONS


def test_qp_warm_start_same_answer_fewer_iterations():
    H, q, G, lo, hi = (a[0] for a in _random_qps(np.random.default_rng(2), 1, n=8, r=16))
    first = solve_qp(H, q, G, lo, hi)
    q2 = q + 1e-3
    cold = solve_qp(H, q2, G, lo, hi)
    warm = solve_qp(H, q2, G, lo, hi, warm=(first.active, first.side))
    np.testing.assert_allclose(np.asarray(warm.z), np.asarray(cold.z), atol=1e-12)
    assert int(first.iterations) >= 1 and int(warm.iterations) < int(cold.iterations)
    # a wrong warm start (every row, sides made up) is refused for a cold one: same answer
    bad = solve_qp(H, q2, G, lo, hi, warm=(np.ones(16, bool), -np.ones(16)))
    np.testing.assert_allclose(np.asarray(bad.z), np.asarray(cold.z), atol=1e-12)


def test_qp_implicit_gradient_matches_finite_differences():
    H, q, G, lo, hi = (a[3] for a in _random_qps(np.random.default_rng(3), 4))
    w = np.random.default_rng(4).normal(size=H.shape[0])

    def f(theta):  # every kind of data moves with theta
        Ht = H + theta[0] * np.diag(np.arange(1.0, 7.0))
        return w @ solve_qp(Ht, q + theta[1], G * (1 + theta[2]), lo + theta[3], hi - theta[3]).z

    th = jnp.zeros(4)
    assert int(np.sum(np.asarray(solve_qp(H, q, G, lo, hi).active))) >= 1
    g = jax.jit(jax.grad(f))(th)
    gf = jax.jit(jax.jacfwd(f))(th)
    eps = 1e-6
    fd = jax.vmap(lambda e: (f(th + e) - f(th - e)) / (2 * eps))(eps * jnp.eye(4))
    np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.asarray(gf), np.asarray(g), rtol=1e-10, atol=1e-12)


def test_qp_bad_input():
    with pytest.raises(ArgumentError, match="q"):
        solve_qp(np.eye(2), np.zeros(3), np.eye(2), np.zeros(2), np.ones(2))
    with pytest.raises(ArgumentError, match="warm"):
        solve_qp(np.eye(2), np.zeros(2), np.eye(2), np.zeros(2), np.ones(2), warm=(np.zeros(3, bool), np.ones(3)))


def test_condense_matches_a_simulation():
    rng = np.random.default_rng(5)
    A, B = rng.normal(size=(3, 3)) * 0.5, rng.normal(size=(3, 2))
    x0, U = rng.normal(size=3), rng.normal(size=(4, 2))
    Sx, Su = condense(jnp.asarray(A), jnp.asarray(B), 4)
    xs, x = [], x0
    for k in range(4):
        x = A @ x + B @ U[k]
        xs.append(x)
    np.testing.assert_allclose(np.asarray(Sx @ x0 + Su @ U.ravel()), np.concatenate(xs), rtol=1e-12, atol=1e-12)


def _dip_mpc(u_max=6.0, horizon=10, dt=0.01, **kw):
    Q = jnp.diag(jnp.array([30.0, 350.0, 100.0, 0.0, 0.0, 0.0]))
    return LinearMPC.for_plant(dip.DIP(), dt, Q, jnp.array([[0.1]]), horizon, u_min=-u_max, u_max=u_max, **kw)


def test_unconstrained_mpc_is_the_dlqr_gain():
    c = _dip_mpc(u_max=INF)
    K, _, _ = dlqr(c.A, c.B, c.Q, c.R)
    X = np.random.default_rng(6).normal(size=(5, 6)) * 0.05
    u = jax.jit(jax.vmap(lambda x: c.step(c.init(None, x), x, None, 0)[1]))(jnp.asarray(X))
    np.testing.assert_allclose(np.asarray(u), -X @ np.asarray(K).T, rtol=1e-9, atol=1e-10)


def test_mpc_respects_limits_and_soft_state_limits():
    x_max = np.array([0.02, INF, INF, INF, INF, INF])
    c = _dip_mpc(u_max=2.0, x_min=-x_max, x_max=x_max, slack_weight=1e8)
    x = jnp.array([0.0, 0.08, -0.05, 0.0, 0.0, 0.0])
    sol = c.solve(x)
    assert int(sol.status) == QPCode.SOLVED
    U = np.asarray(sol.z[:10])
    assert np.all(np.abs(U) <= 2.0 + 1e-12) and np.any(np.isclose(np.abs(U), 2.0))
    Sx, Su = condense(c.A, c.B, 10)
    xc = np.asarray(Sx @ x + Su @ sol.z[:10])[0::6]
    slack = np.asarray(sol.z[10:])
    np.testing.assert_allclose(np.maximum(np.abs(xc) - 0.02, 0.0), slack, atol=1e-9)


def _loop(ctrl, dt=0.01):
    return jd.Loop(plant=dip.DIP(), sensor=jd.Identity(), estimator=jd.Passthrough(), controller=ctrl, dt=dt,
                   substeps=2)


def test_mpc_in_monte_carlo_equals_lqr_when_limits_do_not_bind():
    c = _dip_mpc(u_max=1e3, horizon=8)
    K, _, _ = dlqr(c.A, c.B, c.Q, c.R)
    metrics = {"u": jd.metrics.MaxAbs("u"), "x": jd.metrics.MaxAbs("x")}
    x0 = jd.Ball(jnp.zeros(6), 0.01)
    run = lambda ctrl: jd.monte_carlo(jd.Rollout(_loop(ctrl), x0, 50, metrics=metrics), jax.random.PRNGKey(0), 16)
    a, b = run(c), run(jd.control.StateFeedback(K))
    np.testing.assert_allclose(np.asarray(a.metrics["x"]), np.asarray(b.metrics["x"]), rtol=1e-8)
    assert np.all(np.asarray(a.result) == jd.RESULTS.ok)


def test_mpc_closed_loop_gradient_matches_finite_differences():
    base = _dip_mpc(u_max=3.0, horizon=6)
    x0 = jnp.array([0.0, 0.06, -0.04, 0.0, 0.0, 0.0])
    cost = jd.metrics.Sum(lambda s: s.x[:3] @ s.x[:3] + 0.01 * s.u @ s.u)

    def J(theta):
        c = eqx.tree_at(lambda m: (m.Q, m.R), base, (base.Q * jnp.exp(theta[0]) + jnp.diag(
            jnp.array([0.0, 0.0, 0.0, theta[1], 0.0, 0.0])), base.R * jnp.exp(theta[2])))
        sol = jd.simulate(_loop(c), x0, jax.random.PRNGKey(0), 40, metrics={"J": cost})
        return sol.metrics["J"]

    th = jnp.array([0.0, 0.5, 0.0])
    sol = jd.simulate(_loop(base), x0, jax.random.PRNGKey(0), 40, save=lambda s: s.u)
    assert np.any(np.isclose(np.abs(np.asarray(sol.saved)), 3.0))  # the limit binds on the way
    g = jax.jit(jax.grad(J))(th)
    eps = 1e-5
    fd = jax.jit(jax.vmap(lambda e: (J(th + e) - J(th - e)) / (2 * eps)))(eps * jnp.eye(3))
    np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-5, atol=1e-9)


def test_mpc_bad_input():
    with pytest.raises(ArgumentError, match="horizon"):
        _dip_mpc(horizon=0)
    with pytest.raises(ArgumentError, match="x_max"):
        _dip_mpc(x_max=np.ones(3))
    with pytest.raises(ArgumentError, match="u_min"):
        _dip_mpc(u_max=-1.0)
