"""Weighted proximal MHE: CPX as its identity-weight special case, KF-level accuracy with the true noise weights on
the linearised DIP (Monte Carlo intervals), box constraints against scipy's bounded least squares and a case
where the bound the true state touches lowers the error."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import lsq_linear

import jaxdip as jd
from jaxdip.estimators.weighted_mhe import WeightedMHE
from jaxdip.scenarios.dip_linear import C3, DT, PROC_STD, SENSOR_STD, X0_RADIUS, LinearPlant, problem
from jaxdip.scenarios.dip_linear import loop as dip_loop
from qp_reference import kkt_reference


def dip_setup():
    return problem()[:2]


def _err(name):
    return lambda s: s.aux.estimator.xhat[name] - s.x


ERR = {"kf": _err("kf"), "mhe": _err("mhe"), "cpx": _err("cpx")}


def test_identity_weights_give_cpx():
    model, K = dip_setup()
    x0 = jnp.array([0.01, 0.02, -0.01, 0, 0, 0])
    kf = jd.estimators.KalmanFilter(model.Phi, model.W, C3, PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2),
                                    1e-4 * np.eye(6))
    for timing in (jd.estimators.Ahead, lambda e: e):  # the prediction, then the current estimate
        cpx = timing(jd.estimators.CPX(150.0, model, C3, jnp.zeros(6)))
        mhe = timing(WeightedMHE(model, C3, np.eye(3), np.eye(6), 150.0, N=2, anchor=1))
        loop = dip_loop(jd.FanOut({"kf": kf, "cpx": cpx, "mhe": mhe}, drive="kf"), model, K)
        sol = eqx.filter_jit(jd.simulate)(loop, x0, jax.random.PRNGKey(3), 300,
                                          save=lambda s: s.aux.estimator.xhat)
        a, b = np.asarray(sol.saved["cpx"]), np.asarray(sol.saved["mhe"])
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * np.max(np.abs(a)))


def _mc_rms(loop, seeds, steps, burn):
    rollout = jd.Rollout(loop, jd.Ball(jnp.zeros(6), X0_RADIUS), steps,
                         metrics={k: jd.metrics.Window(jd.metrics.Moments(v), start=burn)
                                  for k, v in ERR.items() if k in loop.estimator.estimators})
    return jd.monte_carlo(rollout, jax.random.PRNGKey(11), seeds).metrics


def _ratio_interval(a, b):
    """Ratio of means of per-seed mean squares a / b with a delta-method 95% interval (paired seeds)."""
    n = a.shape[0]
    ma, mb = a.mean(), b.mean()
    r = ma / mb
    se = np.std(a - r * b, ddof=1) / np.sqrt(n) / mb
    return r, r - 1.96 * se, r + 1.96 * se


@pytest.mark.parametrize("horizon", [10])
def test_true_weights_match_kf_velocity_error(horizon):
    model, K = dip_setup()
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    # x0 uniform in the ball of radius 0.01: covariance r^2 / (d + 2) I, so the KF's prior is the true one and
    # the KF is the optimal estimator of this loop (a wrong P0 lets the MHE beat it in the slow transient)
    P0 = X0_RADIUS**2 / 8 * np.eye(6)
    kf = jd.estimators.KalmanFilter(model.Phi, model.W, C3, Q, R, P0)
    mhe = WeightedMHE.from_noise(model, C3, Q, R, N=horizon)
    loop = dip_loop(jd.FanOut({"kf": kf, "mhe": mhe}, drive="kf"), model, K)
    m = _mc_rms(loop, 64, 1500, burn=500)
    vel = slice(3, 6)
    ms = {k: np.asarray(m[k]["mean_sq"])[:, vel].sum(axis=1) for k in ("kf", "mhe")}
    r, lo, hi = _ratio_interval(ms["mhe"], ms["kf"])
    rms_ratio = np.sqrt(np.array([r, lo, hi]))
    print("velocity RMS ratio MHE/KF", rms_ratio)
    assert rms_ratio[2] < 1.10  # the whole interval within 10% of the KF
    assert rms_ratio[0] > 0.97  # and the KF (optimal for this model) is not beaten beyond noise


# ---- box constraints -----------------------------------------------------------------------------------------

H_LOAD = 0.01
PHI_LOAD = np.array([[1.0, H_LOAD, 0.0], [0.0, 1.0, -H_LOAD], [0.0, 0.0, 1.0]])  # position, velocity, load
W_LOAD = np.array([[0.0], [H_LOAD], [0.0]])
C_LOAD = np.array([[1.0, 0.0, 0.0]])
V_STD, Y_STD = 0.02, 0.01
Q_LOAD = np.diag([1e-10, V_STD**2, 1e-8])  # the load is modelled as slowly varying; in truth it stays at 0
R_LOAD = np.array([[Y_STD**2]])


def load_mhe(box: bool, N: int = 10, **extra):
    model = jd.Discrete(PHI_LOAD, np.linalg.inv(PHI_LOAD), W_LOAD)
    kw = dict(lower=np.array([-np.inf, -np.inf, 0.0]), **extra) if box else {}
    return WeightedMHE.from_noise(model, C_LOAD, Q_LOAD, R_LOAD, N=N, **kw)


def test_box_step_equals_bounded_least_squares():
    model = jd.Discrete(PHI_LOAD, np.linalg.inv(PHI_LOAD), W_LOAD)
    mhe = WeightedMHE.from_noise(model, C_LOAD, Q_LOAD, R_LOAD, N=4, lower=np.array([-0.05, -0.2, 0.0]),
                                 upper=np.array([0.05, 0.2, 0.3]))
    rng = np.random.default_rng(0)
    A = np.asarray(mhe.stacked_matrix())
    Qm, R = np.linalg.qr(A)
    lo, hi = np.tile(np.asarray(mhe.lower), 5), np.tile(np.asarray(mhe.upper), 5)
    active = 0
    for _ in range(5):
        b = np.asarray(mhe.stacked_vector(jnp.asarray(rng.normal(0, 0.05, 3)), jnp.asarray(rng.normal(0, 0.1, (5, 1))),
                                          jnp.asarray(rng.normal(size=(4, 1)))))
        X_free = np.linalg.solve(R, Qm.T @ b)
        Rj = jnp.asarray(R)
        X, viol = mhe.constrained_solve(Rj, jnp.asarray(X_free), mhe._constraint_factor(Rj),
                                        mhe.constraint_offset(jnp.zeros((4, 1))))
        ref = lsq_linear(A, b, bounds=(lo, hi), tol=1e-14, method="bvls")
        X = np.asarray(X)
        assert np.all(X >= lo - 1e-14) and np.all(X <= hi + 1e-14)  # feasible to rounding (X = X_u - K mu)
        cost = lambda x: np.sum((A @ x - b) ** 2)
        assert cost(X) <= cost(ref.x) * (1 + 1e-12)  # at least as good as scipy's BVLS (better in its last digits)
        np.testing.assert_allclose(X, ref.x, atol=1e-8)
        assert float(viol) < 1e-9
        active += int(np.sum((ref.x <= lo + 1e-12) | (ref.x >= hi - 1e-12)))
    assert active > 0  # the bounds were binding somewhere


def _open_loop_run(key, mhes, Phi, W, C, proc_std, y_std, steps=400, burn=50, combo=None):
    """One seed of an open-loop LTI system with a known input, fed to every estimator of ``mhes``: per-state
    mean-square errors after ``burn`` samples, that of the combination ``combo @ x`` of the states, and the
    largest KKT residual of the constrained steps."""
    combo = jnp.zeros(Phi.shape[0]) if combo is None else jnp.asarray(combo)
    kw, kv = jax.random.split(key)
    d, p = Phi.shape[0], C.shape[0]
    w = proc_std * jax.random.normal(kw, (steps, d))
    v = y_std * jax.random.normal(kv, (steps, p))
    us = 0.5 * jnp.sin(0.05 * jnp.arange(steps))[:, None]  # a known input

    def body(carry, inp):
        x, sts, u_prev, k = carry
        wk, vk, u = inp
        y = C @ x + vk
        outs, new = {}, {}
        for name, est in mhes.items():
            new[name], xhat, aux = est.step(sts[name], y, u_prev, key, k)
            outs[name] = (xhat - x, aux.violation)
        return (Phi @ x + W @ u + wk, new, u, k + 1), outs

    x0 = jnp.zeros(d)
    sts = {name: est.init(key, x0) for name, est in mhes.items()}
    _, outs = jax.lax.scan(body, (x0, sts, jnp.zeros(W.shape[1]), 0), (w, v, us))
    return {name: (jnp.mean(e[burn:] ** 2, axis=0), jnp.mean((e[burn:] @ combo) ** 2), jnp.max(viol))
            for name, (e, viol) in outs.items()}


def _load_run(key, mhes, steps=400):
    res = _open_loop_run(key, mhes, PHI_LOAD, W_LOAD, C_LOAD, jnp.array([0.0, V_STD, 0.0]), Y_STD, steps)
    return {name: (ms, viol) for name, (ms, _, viol) in res.items()}


def test_bound_the_true_state_touches_lowers_the_error():
    mhes = {"free": load_mhe(False), "box": load_mhe(True)}
    res = jd.monte_carlo(lambda key: _load_run(key, mhes), jax.random.PRNGKey(5), 64)
    (ms_free, _), (ms_box, viol) = res["free"], res["box"]
    assert float(jnp.max(viol)) < 1e-8  # the active-set iterations converged at every step
    r, lo, hi = _ratio_interval(np.asarray(ms_box[:, 2]), np.asarray(ms_free[:, 2]))
    print(f"load mean-square error constrained/unconstrained {r:.3f} [{lo:.3f}, {hi:.3f}]")
    assert hi < 1.0  # lower with 95% confidence
    r, lo, hi = _ratio_interval(np.asarray(ms_box[:, 1]), np.asarray(ms_free[:, 1]))
    print(f"velocity mean-square error constrained/unconstrained {r:.4f} [{lo:.4f}, {hi:.4f}]")
    assert hi < 1.01  # and the unconstrained states are not made worse


# ---- affine constraints -------------------------------------------------------------------------------------

def _window_data(mhe, rng, d, p, m):
    N = mhe.N
    xbar = jnp.asarray(rng.normal(0, 0.05, d))
    ybuf, ubuf = jnp.asarray(rng.normal(0, 0.1, (N + 1, p))), jnp.asarray(rng.normal(size=(N, m)))
    return xbar, ybuf, ubuf


def _solve_window(mhe, xbar, ybuf, ubuf):
    A, b = np.asarray(mhe.stacked_matrix()), np.asarray(mhe.stacked_vector(xbar, ybuf, ubuf))
    Qm, R = np.linalg.qr(A)
    Rj = jnp.asarray(R)
    X, viol = mhe.constrained_solve(Rj, jnp.asarray(np.linalg.solve(R, Qm.T @ b)), mhe._constraint_factor(Rj),
                                    mhe.constraint_offset(ubuf))
    return A, b, np.asarray(X), float(viol)


A_LOAD = np.array([[1.0, 2.0, 0.0], [0.0, -1.0, 3.0]])  # position + 2 velocity <= 0.04, 3 load - velocity <= 0.5
B_LOAD = np.array([0.04, 0.5])


def test_affine_step_equals_a_certified_qp_solution():
    # full form: the unknown is the window trajectory and the rows act on each state; scipy never sees G
    model = jd.Discrete(PHI_LOAD, np.linalg.inv(PHI_LOAD), W_LOAD)
    Q = np.diag([1e-6, V_STD**2, 1e-4])  # a moderately conditioned window, so SLSQP finds the active set
    mhe = WeightedMHE.from_noise(model, C_LOAD, Q, R_LOAD, N=4, lower=np.array([-0.05, -np.inf, 0.0]),
                                 upper=np.array([np.inf, 0.2, np.inf]), A_c=A_LOAD, b_c=B_LOAD)
    rng = np.random.default_rng(1)
    E = np.vstack([-np.eye(3)[[0, 2]], np.eye(3)[[1]], A_LOAD])  # the same rows written as E z <= f
    f = np.array([0.05, 0.0, 0.2, *B_LOAD])
    G = np.kron(np.eye(5), E)
    active = 0
    for _ in range(6):
        A, b, X, viol = _solve_window(mhe, *_window_data(mhe, rng, 3, 1, 1))
        ref, n_act = kkt_reference(A, b, G, np.full(25, -np.inf), np.tile(f, 5), np.zeros(15))
        np.testing.assert_allclose(X, ref, rtol=0, atol=1e-8)
        assert viol < 1e-9
        active += n_act
    assert active > 6  # the rows were binding, affine ones included
    print("full form: active rows over 6 windows", active)


def test_constraints_in_the_hard_model_form_equal_a_certified_qp_solution():
    # hard model: z_i = Phi^(i-a) z_a + s_i, so box and affine rows on the window states are affine in z_a
    model = jd.Discrete(PHI_LOAD, np.linalg.inv(PHI_LOAD), W_LOAD)
    N, a = 4, 1
    mhe = WeightedMHE(model, C_LOAD, np.eye(1) / Y_STD**2, np.eye(3) / 0.05**2, 1.0, N=N, anchor=a,
                      lower=np.array([-0.05, -0.3, 0.0]), A_c=A_LOAD, b_c=B_LOAD)
    rng = np.random.default_rng(2)
    active = 0
    for _ in range(6):
        xbar, ybuf, ubuf = _window_data(mhe, rng, 3, 1, 1)
        A, b, X, viol = _solve_window(mhe, xbar, ybuf, ubuf)
        # the window states by simulation from z_a: z_i = T_i z_a + t_i
        T, t = {a: np.eye(3)}, {a: np.zeros(3)}
        Pi, Wl, u = np.linalg.inv(PHI_LOAD), W_LOAD[:, 0], np.asarray(ubuf)[:, 0]
        for i in range(a + 1, N + 1):
            T[i], t[i] = PHI_LOAD @ T[i - 1], PHI_LOAD @ t[i - 1] + Wl * u[i - 1]
        for i in range(a - 1, -1, -1):
            T[i], t[i] = Pi @ T[i + 1], Pi @ (t[i + 1] - Wl * u[i])
        G = np.vstack([np.vstack([-T[i], A_LOAD @ T[i]]) for i in range(N + 1)])
        f = np.concatenate([np.concatenate([np.array([0.05, 0.3, 0.0]) + t[i], B_LOAD - A_LOAD @ t[i]])
                            for i in range(N + 1)])
        ref, n_act = kkt_reference(A, b, G, np.full(G.shape[0], -np.inf), f, np.asarray(xbar))
        np.testing.assert_allclose(X, ref, rtol=0, atol=1e-8)
        assert viol < 1e-9
        active += n_act
    assert active > 3
    print("hard-model form: active rows over 6 windows", active)
    # and the engine step with these constraints (offsets from the input buffer) runs and converges
    ms, viol = _load_run(jax.random.PRNGKey(0), {"hard": mhe}, steps=80)["hard"]
    assert np.all(np.isfinite(np.asarray(ms))) and float(viol) < 1e-8


# two carts, each with an unknown load modelled as slowly varying; the loads are known to have a nonnegative sum
# (a sum of states: not a box) and in truth both are 0, so the truth sits on the constraint
PHI_2 = np.kron(np.eye(2), PHI_LOAD)
W_2 = np.vstack([W_LOAD, 0.5 * W_LOAD])
C_2 = np.kron(np.eye(2), C_LOAD)
A_SUM = np.array([[0.0, 0.0, -1.0, 0.0, 0.0, -1.0]])


def test_affine_constraint_the_truth_touches_lowers_the_error():
    model = jd.Discrete(PHI_2, np.linalg.inv(PHI_2), W_2)
    Q, R = np.kron(np.eye(2), Q_LOAD), np.kron(np.eye(2), R_LOAD)
    mhes = {name: WeightedMHE.from_noise(model, C_2, Q, R, N=10, **kw)
            for name, kw in (("free", {}), ("sum", dict(A_c=A_SUM, b_c=np.zeros(1))))}
    proc = jnp.array([0.0, V_STD, 0.0, 0.0, V_STD, 0.0])
    res = jd.monte_carlo(lambda key: _open_loop_run(key, mhes, PHI_2, W_2, C_2, proc, Y_STD, combo=-A_SUM[0]),
                         jax.random.PRNGKey(6), 64)
    (ms_free, sum_free, _), (ms_sum, sum_con, viol) = res["free"], res["sum"]
    assert float(jnp.max(viol)) < 1e-8
    # the constrained direction: the error of the loads' sum
    r, lo, hi = _ratio_interval(np.asarray(sum_con), np.asarray(sum_free))
    print(f"load-sum mean-square error constrained/unconstrained {r:.3f} [{lo:.3f}, {hi:.3f}]")
    assert hi < 1.0
    for i, name in ((2, "f1"), (5, "f2"), (1, "v1")):
        r, lo, hi = _ratio_interval(np.asarray(ms_sum[:, i]), np.asarray(ms_free[:, i]))
        print(f"{name} mean-square error constrained/unconstrained {r:.3f} [{lo:.3f}, {hi:.3f}]")


def test_gradient_through_the_closed_loop_matches_finite_differences():
    # every weight is a traced leaf: d/dgamma of the closed-loop estimation error, the QR factor included
    model, K = dip_setup()
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    mhe = WeightedMHE.from_noise(model, C3, Q, R, N=4)
    x0 = jnp.array([0.01, 0.02, -0.01, 0, 0, 0])

    @jax.jit
    def cost(log_gamma):
        loop = dip_loop(eqx.tree_at(lambda m: m.gamma, mhe, jnp.exp(log_gamma)), model, K)
        sol = jd.simulate(loop, x0, jax.random.PRNGKey(2), 200, metrics=jd.metrics.RMS(lambda s: s.xhat - s.x))
        return jnp.sum(sol.metrics**2)

    g = float(jax.jit(jax.jacfwd(cost))(0.5))
    eps = 1e-4
    fd = (float(cost(0.5 + eps)) - float(cost(0.5 - eps))) / (2 * eps)
    assert abs(g - fd) <= 1e-5 * abs(fd) and abs(fd) > 0


# ---- nonlinear output map -----------------------------------------------------------------------------------

def h_linear(x):
    return jnp.asarray(C3) @ x


def h_curved(x):
    # strongly curved angle readings: at 0.02 rad the quadratic term is 40% of the linear one
    return jnp.stack([x[0], x[1] + 20.0 * x[1] ** 2, x[2] + 20.0 * x[2] ** 2])


class CurvedSensor(jd.Sensor):
    std: jax.Array = jd.param()

    def step(self, state, x, key, k):
        return state, h_curved(x) + self.std * jax.random.normal(key, (3,)), None


def test_output_map_as_a_function_equals_the_matrix():
    model, K = dip_setup()
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    lin = WeightedMHE.from_noise(model, C3, Q, R, N=5)
    fun = WeightedMHE.from_noise(model, C3, Q, R, N=5, h=h_linear)
    loop = dip_loop(jd.FanOut({"lin": lin, "fun": fun}, drive="lin"), model, K)
    sol = eqx.filter_jit(jd.simulate)(loop, jnp.array([0.01, 0.02, -0.01, 0, 0, 0]), jax.random.PRNGKey(4), 200,
                                      save=lambda s: s.aux.estimator.xhat)
    a, b = np.asarray(sol.saved["lin"]), np.asarray(sol.saved["fun"])
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-10 * np.max(np.abs(a)))


def test_curved_output_map_matches_the_ekf():
    model, K = dip_setup()
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    P0 = X0_RADIUS**2 / 8 * np.eye(6)
    ekf = jd.estimators.ExtendedKalmanFilter(Q, R, P0, f=lambda x, u: model.Phi @ x + model.W @ u, h=h_curved)
    mhe = WeightedMHE.from_noise(model, C3, Q, R, N=10, h=h_curved)
    loop = jd.Loop(plant=LinearPlant(model.Phi, model.W), sensor=CurvedSensor(SENSOR_STD),
                   estimator=jd.FanOut({"kf": ekf, "mhe": mhe}, drive="kf"), controller=jd.control.StateFeedback(K),
                   dt=DT, substeps=1, process_noise_std=PROC_STD)
    m = _mc_rms(loop, 32, 1000, burn=300)
    ms = {k: np.asarray(m[k]["mean_sq"])[:, 3:6].sum(axis=1) for k in ("kf", "mhe")}
    r, lo, hi = np.sqrt(_ratio_interval(ms["mhe"], ms["kf"]))
    print(f"curved outputs: velocity RMS ratio MHE/EKF {r:.3f} [{lo:.3f}, {hi:.3f}]")
    assert hi < 1.10


def test_projector_window_weight_gives_scpx():
    model, K = dip_setup()
    kf = jd.estimators.KalmanFilter(model.Phi, model.W, C3, PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2),
                                    1e-4 * np.eye(6))
    keep = 4
    ref = jd.estimators.CPX(150.0, model, jnp.asarray(C3), jnp.zeros(6), keep=keep)
    mhe = WeightedMHE.scpx(model, C3, 150.0, keep)
    loop = dip_loop(jd.FanOut({"kf": kf, "scpx": ref, "mhe": mhe}, drive="kf"), model, K)
    sol = eqx.filter_jit(jd.simulate)(loop, jnp.array([0.01, 0.02, -0.01, 0, 0, 0]), jax.random.PRNGKey(3), 300,
                                      save=lambda s: s.aux.estimator.xhat)
    a, b = np.asarray(sol.saved["scpx"]), np.asarray(sol.saved["mhe"])
    # SVD path against QR path: equal to rounding amplified by the conditioning of the window
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9 * np.max(np.abs(a)))
    full = np.asarray(eqx.filter_jit(jd.simulate)(
        dip_loop(jd.FanOut({"kf": kf, "cpx": jd.estimators.CPX(150.0, model, C3, jnp.zeros(6))}, drive="kf"),
                 model, K), jnp.array([0.01, 0.02, -0.01, 0, 0, 0]), jax.random.PRNGKey(3), 300,
        save=lambda s: s.aux.estimator.xhat).saved["cpx"])
    assert np.max(np.abs(full - a)) > 1e-6 * np.max(np.abs(a))  # keep = 4 < 6 is not CPX: the test can tell
