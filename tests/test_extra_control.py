"""Extra control (Stumfoll §6.2): a NumPy reference of one step, the error system with the true F1, F2, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm

import equinox as eqx

import jaxdip as jd
from jaxdip.control import extra_control as ec
from jaxdip.control.twip_lqr import twip_dlqr
from jaxdip.plants import twip
from jaxdip.scenarios import twip_extra as S
from jaxdip.scenarios.twip_initial import thesis_x0


def _params(**kw):
    d = twip_dlqr(twip.TWIP(), Q=(1.0, 1.0, 0.1, 0.1), R=1.0, dt=0.01)
    return ec.ExtraControl.design(d.K, d.A, d.B, **kw)


def _numpy_step(p, s, x, k):
    """Plain NumPy transcription of (182)-(183), (84), (91), (93), (98), (101), (109)-(114) (module doc)."""
    f = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    A1, A2, A3, A4, B1, B2 = (float(getattr(p, n)) for n in ("A1", "A2", "A3", "A4", "B1", "B2"))
    dt, v = float(p.dt), float(p.v_d)
    M = np.array([[A2, B1], [A4, B2]])
    x3d, u_d = -np.linalg.solve(M, np.array([A1, A3]) * v)
    xd = np.array([float(p.x1d0) + v * k * dt, v, x3d, 0.0])
    umax = float(p.u_max)
    u_nom = np.clip(float(p.ff) * u_d - (f(p.K) @ (x - xd))[0], -umax, umax)
    beta = float(p.beta)  # flat variant: errors of y = x1 - beta x3 and y' = x2 - beta x4
    e1, e2 = x[0] - xd[0] - beta * (x[2] - xd[2]), x[1] - xd[1] - beta * x[3]
    P1 = np.array([1.0, *x, e1, e2, xd[0], xd[1], float(s.u_prev)])
    ph11 = np.tanh(f(s.V1).T @ P1)
    ph12 = np.tanh(f(s.W11).T @ ph11)
    F1 = f(s.W12) @ ph12
    xb3 = x3d + (-float(p.k1) * e2 - e1 - F1) / float(p.a_virtual)
    a = dt / (float(p.tau_d) + dt)
    xb4 = float(s.xbar4_prev) + a * ((xb3 - float(s.xbar3_prev)) / dt - float(s.xbar4_prev))
    eb2, eb3, eb4 = e2, x[2] - xb3, x[3] - xb4
    P2 = np.array([1.0, *x, e1, e2, eb3, eb4, xd[0], xd[1], u_nom])
    ph21 = np.tanh(f(s.V2).T @ P2)
    ph22 = np.tanh(f(s.W21).T @ ph21)
    F2 = f(s.W22) @ ph22
    ue = np.clip((-float(p.k2) * eb4 - F2 - eb3) / B2, -umax, umax)
    u = np.clip(u_nom + ue, -umax, umax)
    g = [float(p.gamma11), float(p.gamma12), float(p.gamma21), float(p.gamma22)]
    sg = [float(p.sigma11), float(p.sigma12), float(p.sigma21), float(p.sigma22)]
    W11 = f(s.W11) + dt * (-g[0] * (np.outer(ph11, f(s.W11).T @ ph11 + f(p.b1) * eb2) + sg[0] * f(s.W11)))
    W12 = f(s.W12) + dt * (g[1] * (ph12 * eb2 - sg[1] * f(s.W12)))
    W21 = f(s.W21) + dt * (-g[2] * (np.outer(ph21, f(s.W21).T @ ph21 + f(p.b2) * eb4) + sg[2] * f(s.W21)))
    W22 = f(s.W22) + dt * (g[3] * (ph22 * eb4 - sg[3] * f(s.W22)))
    return u, u_nom, ue, W11, W12, W21, W22, xb3, xb4


@pytest.mark.parametrize("virtual", ["printed", "effective", "flat"])
def test_one_step_matches_numpy(virtual):
    p = _params(virtual=virtual, gamma=0.3, sigma=0.05, v_scale=0.5)
    p = eqx.tree_at(lambda c: (c.gamma12, c.sigma21), p, (jnp.asarray(0.7), jnp.asarray(0.02)))
    comp = p
    key = jax.random.PRNGKey(3)
    s = comp.init(key, jnp.zeros(4))
    ks = jax.random.split(jax.random.PRNGKey(4), 4)
    # a mid-run state: non-zero adapted weights and history
    s = s._replace(W11=0.3 * jax.random.normal(ks[0], (10, 10)), W12=0.5 * jax.random.normal(ks[1], (10,)),
                   W21=0.3 * jax.random.normal(ks[2], (10, 10)), W22=0.5 * jax.random.normal(ks[3], (10,)),
                   xbar3_prev=jnp.asarray(0.02), xbar4_prev=jnp.asarray(-0.1), started=jnp.asarray(True),
                   u_prev=jnp.asarray(0.4))
    x = np.array([0.31, 0.12, 0.03, -0.05])
    k = 37
    s2, u, aux = eqx.filter_jit(lambda c, *a: c.step(*a))(comp, s, jnp.asarray(x), key, k)
    assert np.all(np.asarray(aux.state.W11) == np.asarray(s2.W11))
    np.testing.assert_allclose(np.asarray(aux.xd), np.asarray(ec.desired_state(p, k * p.dt)), rtol=0, atol=1e-15)
    ref = _numpy_step(p, s, x, k)
    got = (u[0], s2.u_nom, s2.u_e, s2.W11, s2.W12, s2.W21, s2.W22, s2.xbar3, s2.xbar4_prev)
    assert abs(float(ref[2])) < float(p.u_max)  # the extra control is not saturated here
    for name, a, b in zip(("u", "u_nom", "u_e", "W11", "W12", "W21", "W22", "xbar3", "xbar4"), got, ref):
        np.testing.assert_allclose(np.asarray(a), b, rtol=0, atol=1e-12, err_msg=name)
    # the update moved the weights (a test that cannot fail is a defect)
    assert float(jnp.max(jnp.abs(s2.W11 - s.W11))) > 1e-6 and float(jnp.max(jnp.abs(s2.W22 - s.W22))) > 1e-6


def test_error_system_with_true_F_decays_as_linear_part():
    """With F1hat = F1 (96) and F2hat = F2 (104) the error system is linear; check its solution.

    To make F1 a function of the state (not of u, an algebraic loop), the test plant is (87) with B1 = 0:
    then xbar3 depends on (x1, x2, t), xbar4 = d xbar3/dt on (x1, x2, x3, t) and F2 on (x, t, u_nom), all
    computed exactly by forward-mode differentiation along the flow. The law's own functions
    ``virtual_tilt`` and ``extra_law`` are used; the control is continuous (evaluated inside RK4).
    Exact error dynamics: e1' = e2, e2' = -e1 - k1 e2 + A2 ebar3, ebar3' = ebar4, ebar4' = -ebar3 - k2 ebar4
    ((106) plus the coupling A2 ebar3 that (97) drops; same eigenvalues).
    """
    A = np.array([[0, 1, 0, 0], [0, -0.4, 2.0, 0], [0, 0, 0, 1], [0, -0.3, 5.0, 0]], float)
    B = np.array([[0.0], [0.0], [0.0], [1.5]])
    K = np.array([[-1.0, -2.0, 30.0, 6.0]])
    p = ec.ExtraControl.design(K, A, B, k1=2.0, k2=3.0, v_d=0.1, u_max=np.inf)
    A1, A2, A3, A4, B1, B2 = (p.A1, p.A2, p.A3, p.A4, p.B1, p.B2)
    d1 = lambda x: 0.3 * x[1] * jnp.sin(2.0 * x[0])  # noqa: E731  smooth unmatched term in x1, x2
    d2 = lambda x: 0.2 * x[1] ** 2 + 0.1 * jnp.sin(x[2])  # noqa: E731
    x3d, u_d = ec.desired_constants(p)

    def xd(t):
        return ec.desired_state(p, t)

    def flow_wo_u(x):  # x' without the input (B1 = 0); x4' set to 0: xbar3 and xbar4 do not depend on x4
        return jnp.stack([x[1], A1 * x[1] + A2 * x[2] + d1(x), x[3], 0.0 * x[3]])

    def F1(x, t):  # (96) with B1 = 0 and x2d' = 0
        return A1 * x[1] + A2 * x3d + d1(x)

    def xbar3(x, t):
        e = x - xd(t)
        return ec.virtual_tilt(p, e[0], e[1], x3d, F1(x, t))

    def ddt(fun):
        return lambda x, t: jax.jvp(fun, (x, t), (flow_wo_u(x), jnp.ones(())))[1]

    xbar4 = ddt(xbar3)
    xbar4_dot = ddt(xbar4)

    def control(x, t):
        u_nom = u_d - (p.K @ (x - xd(t)))[0]
        F2 = A3 * x[1] + A4 * x[2] + B2 * u_nom + d2(x) - xbar4_dot(x, t)  # (104)
        return u_nom + ec.extra_law(p, x[2] - xbar3(x, t), x[3] - xbar4(x, t), F2)

    def f(x, t):
        u = control(x, t)
        return jnp.stack([x[1], A1 * x[1] + A2 * x[2] + B1 * u + d1(x), x[3], A3 * x[1] + A4 * x[2] + B2 * u + d2(x)])

    def errors(x, t):
        e = x - xd(t)
        return jnp.stack([e[0], e[1], x[2] - xbar3(x, t), x[3] - xbar4(x, t)])

    h, n = 2e-3, 4000

    def rk4(carry, _):
        x, t = carry
        k1 = f(x, t)
        k2 = f(x + h / 2 * k1, t + h / 2)
        k3 = f(x + h / 2 * k2, t + h / 2)
        k4 = f(x + h * k3, t + h)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return (x, t + h), errors(x, t + h)

    x0 = jnp.array([0.5, 0.2, 0.05, -0.1])
    _, E = jax.jit(lambda x0: jax.lax.scan(rk4, (x0, jnp.zeros(())), None, length=n))(x0)
    E = np.asarray(E)
    e0 = np.asarray(errors(x0, 0.0))
    k1, k2, a2 = float(p.k1), float(p.k2), float(A2)
    M = np.array([[0, 1, 0, 0], [-1, -k1, a2, 0], [0, 0, 0, 1], [0, 0, -1, -k2]])
    ts = h * np.arange(1, n + 1)
    pred = np.stack([expm(M * t) @ e0 for t in ts[199::200]])
    np.testing.assert_allclose(E[199::200], pred, rtol=0, atol=1e-8 * np.abs(e0).max())
    assert np.abs(E[-1]).max() < 0.25 * np.abs(e0).max()  # it does decay (slowest eigenvalue -0.38 at k2 = 3)
    # (106) as printed (no A2 ebar3 coupling) has the same eigenvalues but not the same solution
    M106 = M.copy()
    M106[1, 2] = 0.0
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(M)), np.sort_complex(np.linalg.eigvals(M106)))
    assert np.abs(E[399] - expm(M106 * ts[399]) @ e0).max() > 1e-3


def _J(virtual, duration=1.0, n_seeds=1, case="param", system="extra"):
    """(theta -> mean score over seeds 0..n_seeds-1, theta0) over k1, k2 and the learning rates."""
    lp = S.loop(case, system, S.controller(virtual=virtual))
    names = ("k1", "k2", "gamma11", "gamma12", "gamma21", "gamma22")
    n = int(round(duration / 0.01))

    def J(theta):
        q = eqx.tree_at(lambda m: tuple(getattr(m.controller, k) for k in names), lp,
                        tuple(theta[i] for i in range(len(names))))
        return jnp.mean(S.scores_at(q, thesis_x0(), 0.1, n, jax.random.PRNGKey(0), range(n_seeds))[0])

    return J, jnp.stack([getattr(lp.controller, k) for k in names]), names


@pytest.mark.parametrize("virtual", ["printed", "flat"])
def test_score_gradient_matches_finite_differences(virtual):
    Jt, theta0, names = _J(virtual)
    Jj = jax.jit(Jt)
    g = np.asarray(jax.jit(jax.grad(Jt))(theta0))
    assert np.all(np.isfinite(g)) and np.abs(g).max() > 0
    for i in range(len(names)):
        hh = 1e-6 * max(1.0, abs(float(theta0[i])))
        e = jnp.zeros(len(names)).at[i].set(hh)
        fd = (float(Jj(theta0 + e)) - float(Jj(theta0 - e))) / (2 * hh)
        assert abs(g[i] - fd) <= 1e-4 * max(abs(fd), 1e-2 * np.abs(g).max()), (names[i], g[i], fd)


def test_unmodeled_dynamics_and_backlash_wiring():
    c = S.controller()
    lp = S.loop("unmodeled_unstable", "lqr", c)
    assert float(lp.plant.g1) == 0.75 and float(lp.plant.g2) == 0.4 and float(lp.controller.extra) == 0.0
    x = jnp.array([0.3, 0.2, 0.1, 0.0])
    d1, d2 = lp.plant.unmodeled(x)
    assert math.isclose(float(d1), 0.75 * 0.2 * math.sin(180 / math.pi * 0.3)) and math.isclose(float(d2), 0.4 * 0.04)
    u = jnp.array([0.7])
    ref = twip.f(twip.TWIP.table("8.2"), x, u) + jnp.array([0.0, float(d1), 0.0, float(d2)])
    np.testing.assert_allclose(np.asarray(lp.plant.vector_field(x, u)), np.asarray(ref), rtol=1e-15, atol=1e-15)
    assert float(S.loop("unmodeled_unstable", "nominal", c).plant.g1) == 0.0
    assert float(S.loop("unmodeled_unstable", "nominal", c).plant.km) == float(twip.TWIP().km)
    lb = S.loop("deadzone_backlash", "extra", c)
    assert math.isclose(float(lb.sensor.d_plus), 0.1 * math.pi / 180) and float(lb.actuator.d_plus) == 0.5
    assert float(lb.controller.extra) == 1.0
    assert float(S.loop("param", "extra", c).sensor.d_plus) == 0.0


def test_native_components_equal_the_old_functions():
    """Deadzone = actuators.deadzone; OutputBacklash = actuators.backlash on phi (the TWIP plant against NumPy:
    tests/test_plants_other.py)."""
    from jaxdip.sim import actuators as A

    key = jax.random.PRNGKey(5)
    xs = jax.random.normal(key, (50, 4)) * jnp.array([1.0, 1.0, 0.5, 2.0])
    us = 11.0 * jax.random.normal(jax.random.fold_in(key, 1), (50, 1))
    dz = A.Deadzone(-0.5, 0.5)
    np.testing.assert_array_equal(np.asarray(dz.step((), us[:, 0], key, 0)[1]),
                                  np.asarray(A.deadzone(us[:, 0], -0.5, 0.5)))
    bl = A.OutputBacklash(1.0, -0.01, 0.01)
    st, psi, u_prev = bl.init(key, xs[0]), jnp.zeros(1), jnp.zeros(1)
    for x in xs * 0.02:
        st, y, a = bl.step(st, x, key, 0)
        psi = A.backlash(psi, u_prev, x[2:3], 1.0, -0.01, 0.01)
        u_prev = x[2:3]
        assert float(y[2]) == float(psi[0]) == float(a) and np.all(np.asarray(y)[[0, 1, 3]] == np.asarray(x)[[0, 1, 3]])


def test_sweep_over_rows_compiles_once_and_equals_a_row_alone():
    """Rows of one structure (cases x systems) run as one monte_carlo sweep: traced once; each row's seeds
    equal that row run alone to rounding (the deadzone-free rows here)."""
    c = S.controller()
    rows = [("param", "lqr"), ("param", "extra"), ("unmodeled", "extra"), ("unmodeled_unstable", "nominal")]
    loops = [S.loop(a, b, c) for a, b in rows]
    traces = [0]

    def counted(sample):
        traces[0] += 1
        return sample.x[2]

    run = S.scored(loops[0], thesis_x0(), 0.1, 50, save=counted)
    out = jd.monte_carlo(run, jax.random.PRNGKey(0), 3, offset=1, sweep=S.sweep_of(loops))
    assert traces[0] == 1 and out[0].shape == (4, 3)
    alone = jd.monte_carlo(eqx.tree_at(lambda r: r.rollout.loop, run, loops[2]), jax.random.PRNGKey(0), 3, offset=1)
    np.testing.assert_allclose(np.asarray(out[0][2]), np.asarray(alone[0]), rtol=1e-12)
    assert len(set(np.round(np.asarray(out[0][:, 0]), 6))) == 4  # the rows differ


def test_score_counts_the_frozen_state_after_a_fall():
    """A seed that falls keeps its last good state for the remaining samples: the score sums
    ||x_frozen - x_d,k|| over them (Table 8.3's sum over every sample), checked against the recorded states."""
    lp = S.loop("unmodeled_unstable", "extra", S.controller(virtual="printed"))
    run = S.scored(lp, thesis_x0(), 0.0, 400, save=lambda s: s.x)
    score, failed, xs = jd.monte_carlo(run, jax.random.PRNGKey(0), 1)
    assert bool(failed[0])
    xd = ec.desired_state(lp.controller, jnp.arange(400) * 0.01)
    ref = float(jnp.sum(jnp.linalg.norm(xs[0] - xd, axis=-1)))
    assert math.isclose(float(score[0]), ref, rel_tol=1e-12)


def test_flat_law_keeps_unmodeled_unstable_up_where_lqr_falls():
    """Fig. 8.18's claim on 16 seeds over the full 20 s: LQR alone falls in some seeds, the derived ("flat") law
    with k1 = 10 keeps every one up; as printed (93) every seed falls (see the module docs for why)."""
    loops = [S.loop("unmodeled_unstable", "lqr", S.controller()),
             S.loop("unmodeled_unstable", "extra", S.controller(k1=10.0)),
             S.loop("unmodeled_unstable", "extra", S.controller(virtual="printed"))]
    x0 = thesis_x0()
    d_lqr, d_k10, d_pr = (np.asarray(S.scores_at(lp, x0, 0.1, 2000, jax.random.PRNGKey(0), range(16))[1])
                          for lp in loops)
    assert 0 < d_lqr.sum() < 16 and d_k10.sum() == 0 and d_pr.all()


def test_virtual_sign_reverses_only_the_inverted_gain_and_is_validated():
    from jaxdip import config as C
    import experiments.twip_extra_control as X

    d = twip_dlqr(twip.TWIP(), Q=(1.0, 1.0, 0.1, 0.1), R=1.0, dt=0.01)
    A1, A2, A3, A4, B1, B2 = ec.model_coefficients(d.A, d.B)
    for virtual, gain in (("printed", A2), ("effective", A2 - B1 * A4 / B2)):
        for sign in (1.0, -1.0):
            p = ec.ExtraControl.design(d.K, d.A, d.B, virtual=virtual, virtual_sign=sign)
            np.testing.assert_allclose(float(p.a_virtual), sign * float(gain), rtol=1e-14)
    # the tilt counted the other way (x3, x4 -> -x3, -x4) flips A2 and the effective gain together: the
    # printed law's wrong sign is not a coordinate convention
    flip = np.diag([1.0, 1.0, -1.0, -1.0])
    Af, Bf = flip @ np.asarray(d.A) @ flip, flip @ np.asarray(d.B)
    a1, a2, a3, a4, b1, b2 = ec.model_coefficients(jnp.asarray(Af), jnp.asarray(Bf))
    assert np.sign(float(a2 - b1 * a4 / b2)) / np.sign(float(a2)) == np.sign(float(A2 - B1 * A4 / B2)) / np.sign(float(A2))
    with pytest.raises(C.ConfigError) as e:
        C.load(X.TwipExtraControlConfig, sets=["virtual_sign=0.5"])
    assert e.value.key == "virtual_sign"
    cfg = C.load(X.TwipExtraControlConfig, sets=['variants=["virtual=printed; virtual_sign=-1.0"]'])
    assert X.variant_config(cfg, cfg.variants[0]).virtual_sign == -1.0
    with pytest.raises(C.ConfigError):
        C.load(X.TwipExtraControlConfig, sets=["backlash_law=other"])
