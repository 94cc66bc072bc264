"""``jaxdip.simulate`` against a plain Python loop, on failure, under grad, resumed, fanned out, and against the
original loop (``tests/reference_loop.py``) for the components it replaces."""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.sim import actuators, sensors

DT, SUBSTEPS = 0.01, 4
simulate = eqx.filter_jit(jd.simulate)


class Pendulum(jd.Plant):
    """Inverted pendulum with a torque input, written as a user would."""

    a: jax.Array = jd.param(9.81)  # g / l
    c: jax.Array = jd.param(0.2)  # viscous damping
    state_names = ("phi", "phi_dot")
    input_names = ("tau",)

    def vector_field(self, x, u):
        return jnp.stack([x[1], self.a * jnp.sin(x[0]) - self.c * x[1] + u[0]])


def np_field(p, x, u):
    return np.array([x[1], p.a * math.sin(x[0]) - p.c * x[1] + u[0]])


def np_period(p, x, u, dt=DT, substeps=SUBSTEPS):
    h = dt / substeps
    for _ in range(substeps):
        k1 = np_field(p, x, u)
        k2 = np_field(p, x + 0.5 * h * k1, u)
        k3 = np_field(p, x + 0.5 * h * k2, u)
        k4 = np_field(p, x + h * k3, u)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def make_loop(gain_sign=1.0, bound=(0.8, np.inf), u_max=30.0):
    plant = Pendulum()
    A, B = jd.linearize(plant)
    model = jd.zoh(A, B, DT)
    K, _, _ = jd.control.lqr(A, B, np.diag([10.0, 1.0]), 0.1)
    kf = jd.estimators.KalmanFilter(model.Phi, model.W, np.eye(2), 1e-5 * np.eye(2), np.diag([1e-4, 2.5e-3]),
                                    1e-2 * np.eye(2))
    sat = actuators.Saturation(jnp.array([-u_max]), jnp.array([u_max]))
    return jd.Loop(plant=plant, sensor=jd.sensors.WhiteNoise(jnp.array([0.01, 0.05])), estimator=kf,
                   controller=jd.control.StateFeedback(gain_sign * K), actuator=sat, dt=DT, substeps=SUBSTEPS,
                   process_noise_std=1e-3, state_bound=jnp.asarray(bound))


N, TAIL = 120, 40
METRICS = {
    "x": jd.metrics.Moments("x"),
    "err": jd.metrics.RMS(lambda s: s.xhat - s.x),
    "cost": jd.metrics.Sum(lambda s: DT * (s.x @ s.x + 0.1 * s.u @ s.u)),
    "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=N - TAIL),
    "band": jd.metrics.TimeToBand(lambda s: s.x[0], band=0.05),
}


def reference(loop, x0, key, steps):
    """The loop written out period by period in Python: components stepped one call at a time, RK4, failure
    codes and the metrics in NumPy."""
    ks = jax.random.split(jax.random.fold_in(key, 1), 4)
    x = np.asarray(x0, dtype=float)
    comps = [loop.sensor, loop.estimator, loop.controller, loop.actuator]
    st = [c.init(kk, jnp.asarray(x)) for c, kk in zip(comps, ks)]
    # one compiled call per component and period (eager op-by-op dispatch would take seconds)
    sensor, estimator, controller, actuator = (eqx.filter_jit(c.step) for c in comps)
    u_prev = np.zeros(1)
    result, failed_at, failed_x = 0, -1, np.zeros(2)
    rows = []
    bound = np.asarray(loop.state_bound)
    for k in range(steps):
        kk = jax.random.split(jax.random.fold_in(jax.random.fold_in(key, 2), k), 5)
        kj = jnp.int32(k)  # an array, so the compiled steps are reused
        st[0], y, _ = sensor(st[0], jnp.asarray(x), kk[0], kj)
        st[1], xhat, _ = estimator(st[1], y, jnp.asarray(u_prev), kk[1], kj)
        st[2], u, _ = controller(st[2], xhat, kk[2], kj)
        u = np.asarray(u).reshape(1)
        st[3], ua, _ = actuator(st[3], jnp.asarray(u), kk[3], kj)
        xn = np_period(loop.plant, x, np.asarray(ua)) + float(loop.process_noise_std) * np.asarray(
            jax.random.normal(kk[4], (2,)))
        if result == 0:
            if not np.all(np.isfinite(xn)):
                result, failed_at, failed_x = 1, k + 1, xn
            elif np.any(np.abs(xn) > bound):
                result, failed_at, failed_x = 2, k + 1, xn
        rows.append(dict(k=k, x=x.copy(), xhat=np.asarray(xhat), u=u, live=result == 0))
        if result == 0:
            x = xn
        u_prev = u
    live = [r for r in rows if r["live"]]
    X = np.array([r["x"] for r in live]).reshape(-1, 2)
    E = np.array([r["xhat"] - r["x"] for r in live]).reshape(-1, 2)
    U = np.array([r["u"] for r in live]).reshape(-1, 1)
    n = max(len(live), 1)
    tail = np.array([np.abs(r["x"]) for r in live if r["k"] >= steps - TAIL]).reshape(-1, 2)
    outside = [r["k"] for r in live if abs(r["x"][0]) > 0.05]
    metrics = {
        "x": {"count": len(live), "mean": X.sum(0) / n, "var": (X**2).sum(0) / n - (X.sum(0) / n) ** 2,
              "mean_abs": np.abs(X).sum(0) / n, "mean_sq": (X**2).sum(0) / n},
        "err": np.sqrt((E**2).sum(0) / n),
        "cost": DT * (np.sum(X**2) + 0.1 * np.sum(U**2)),
        "tail": tail.max(0) if len(tail) else np.zeros(2),
        "band": {"step": (outside[-1] + 1) if outside else 0,
                 "settled": bool(live) and (not outside or outside[-1] < live[-1]["k"])},
    }
    return rows, metrics, result, (failed_at, failed_x), x


def save_x_xhat_u(s):
    return s.x, s.xhat, s.u


def check_against_reference(loop, x0, key):
    sol = simulate(loop, x0, key, N, save=save_x_xhat_u, metrics=METRICS)
    rows, ref, result, (failed_at, failed_x), x_final = reference(loop, x0, key, N)
    for j, name in enumerate(("x", "xhat", "u")):
        np.testing.assert_allclose(np.asarray(sol.saved[j]), np.array([r[name] for r in rows]), rtol=1e-12,
                                   atol=1e-12)
    m = sol.metrics
    for k in ("mean", "var", "mean_abs", "mean_sq"):
        np.testing.assert_allclose(m["x"][k], ref["x"][k], rtol=1e-12, atol=1e-14)
    assert int(m["x"]["count"]) == ref["x"]["count"]
    np.testing.assert_allclose(m["err"], ref["err"], rtol=1e-12)
    np.testing.assert_allclose(m["cost"], ref["cost"], rtol=1e-12)
    np.testing.assert_allclose(m["tail"], ref["tail"], rtol=1e-12, atol=1e-15)
    assert int(m["band"]["step"]) == ref["band"]["step"]
    assert bool(m["band"]["settled"]) == ref["band"]["settled"]
    assert int(sol.result) == result and int(sol.final.failed_at) == failed_at
    np.testing.assert_allclose(np.asarray(sol.final.failed_x), failed_x, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.asarray(sol.final.x), x_final, rtol=1e-12, atol=1e-15)
    return sol, rows


def test_simulate_equals_python_loop():
    loop = make_loop()
    sol, rows = check_against_reference(loop, jnp.array([0.15, -0.3]), jax.random.PRNGKey(11))
    assert int(sol.result) == jd.RESULTS.ok
    assert int(sol.metrics["x"]["count"]) == N  # the test must exercise the whole horizon and the tail window
    assert 0 < int(sol.metrics["band"]["step"]) < N


def test_diverging_loop_is_frozen_and_coded():
    loop = make_loop(gain_sign=-1.0)
    sol, rows = check_against_reference(loop, jnp.array([0.15, -0.3]), jax.random.PRNGKey(4))
    assert int(sol.result) == jd.RESULTS.out_of_bounds
    at = int(sol.final.failed_at)
    assert 0 < at < N
    xs = np.asarray(sol.saved[0])
    np.testing.assert_array_equal(xs[at:], np.broadcast_to(xs[at - 1 + 1], xs[at:].shape))
    assert np.all(np.abs(xs[at:, 0]) <= 0.8)
    # the period that produced the bad state is the first one left out of the metrics
    assert int(sol.metrics["x"]["count"]) == at - 1


class Blowup(jd.DiscretePlant):
    gain: jax.Array = jd.param(1e120)
    state_names = ("x",)

    def step(self, x, u):
        return self.gain * x + u


def test_nonfinite_state_is_its_own_code():
    loop = jd.Loop(plant=Blowup(), sensor=jd.sensors.WhiteNoise(0.0), estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(jnp.zeros((1, 1))), dt=1.0)
    sol = simulate(loop, jnp.array([1.0]), jax.random.PRNGKey(0), 8, save=lambda s: s.x,
                      metrics=jd.metrics.MaxAbs("x"))
    # 1 -> 1e120 -> 1e240 -> inf: the state at index 3 is the first non-finite one
    assert int(sol.result) == jd.RESULTS.nonfinite
    assert int(sol.final.failed_at) == 3 and float(sol.final.failed_x[0]) == np.inf
    np.testing.assert_array_equal(np.asarray(sol.saved[3:, 0]), 1e240)
    assert float(sol.metrics[0]) == 1e120  # periods 0 and 1 counted (x = 1, 1e120); period 2 made inf


def test_resume_equals_one_call():
    loop = make_loop()
    x0, key = jnp.array([0.1, 0.2]), jax.random.PRNGKey(5)
    kw = dict(save=lambda s: s.x, save_every=4, metrics=METRICS)
    whole = simulate(loop, x0, key, N, **kw)
    a = simulate(loop, x0, key, 40, **kw)
    b = simulate(loop, None, key, N - 40, start=a.final, **kw)
    np.testing.assert_array_equal(np.concatenate([a.saved, b.saved]), whole.saved)
    for u, v in zip(jax.tree_util.tree_leaves(b.metrics), jax.tree_util.tree_leaves(whole.metrics)):
        np.testing.assert_array_equal(u, v)
    with pytest.raises(ValueError, match="multiple of save_every"):
        jd.simulate(loop, x0, key, 10, **kw)


def test_noise_drawn_ahead_is_the_noise_drawn_in_the_loop():
    """``Loop.noise_ahead`` draws every period's process noise before the loop: the Python reference (noise
    drawn period by period) holds, and every save mode, a resumed run and a batch sharing one key give the
    numbers of the in-loop draw (to the last bits: XLA fuses the two programs differently)."""
    loop = dataclasses.replace(make_loop(), noise_ahead=True)
    x0, key = jnp.array([0.15, -0.3]), jax.random.PRNGKey(11)
    check_against_reference(loop, x0, key)
    base = make_loop()
    # blocks of save_every periods (the noise reshaped per block), resumed after 40 periods
    kw = {"save": save_x_xhat_u, "save_every": 4, "metrics": METRICS}
    whole = simulate(base, x0, key, N, **kw)
    first = simulate(loop, x0, key, 40, **kw)
    rest = simulate(loop, None, key, N - 40, start=first.final, **kw)
    for u, v in zip(jax.tree_util.tree_leaves(rest.metrics), jax.tree_util.tree_leaves(whole.metrics)):
        np.testing.assert_allclose(u, v, rtol=1e-13, atol=1e-16)
    for j in range(3):
        np.testing.assert_allclose(np.concatenate([first.saved[j], rest.saved[j]]), whole.saved[j], rtol=1e-13,
                                   atol=1e-16)
    # an ensemble judged on one noise sequence: gains batched, the key shared
    gains = jnp.array([0.9, 1.0, 1.1])

    def run(lp, g):
        lp = eqx.tree_at(lambda q: q.controller.K, lp, g * lp.controller.K)
        return simulate(lp, x0, key, N, save=lambda s: s.x).saved

    np.testing.assert_allclose(jax.jit(jax.vmap(lambda g: run(loop, g)))(gains),
                               jax.jit(jax.vmap(lambda g: run(base, g)))(gains), rtol=1e-13, atol=1e-16)


def test_grad_wrt_estimator_hyperparameter_matches_central_differences():
    loop = make_loop()
    x0, key = jnp.array([0.15, -0.3]), jax.random.PRNGKey(2)

    def cost(log_r):
        # scale of the KF's assumed measurement noise R (an estimator hyperparameter, not the true noise)
        lp = eqx.tree_at(lambda l: l.estimator.R, loop, jnp.exp(log_r) * loop.estimator.R)
        sol = simulate(lp, x0, key, 80, metrics={"cost": METRICS["cost"], "err": METRICS["err"]})
        return sol.metrics["cost"] + jnp.sum(sol.metrics["err"] ** 2)

    g = jax.jit(jax.grad(cost))(0.3)
    f = jax.jit(cost)
    h = 1e-4
    fd = (f(0.3 + h) - f(0.3 - h)) / (2 * h)
    assert abs(float(g)) > 1e-6  # the hyperparameter matters
    np.testing.assert_allclose(float(g), float(fd), rtol=1e-6)


def test_vmap_over_a_leaf_equals_separate_runs():
    loop = make_loop()
    x0, key = jnp.array([0.15, -0.3]), jax.random.PRNGKey(2)
    scales = jnp.array([0.5, 1.0, 4.0])

    def run(s):
        lp = eqx.tree_at(lambda l: l.estimator.R, loop, s * loop.estimator.R)
        return jd.simulate(lp, x0, key, 50, metrics=METRICS["err"]).metrics

    batched = jax.jit(jax.vmap(run))(scales)
    one = jax.jit(run)
    for i, s in enumerate(scales):
        np.testing.assert_allclose(batched[i], one(s), rtol=1e-13)


def test_fan_out_drives_with_one_and_compares_all_on_the_same_data():
    loop = make_loop()
    model = jd.zoh(*jd.linearize(loop.plant), DT)
    cpx = jd.estimators.CPX(gamma=50.0, model=model, C=np.eye(2), xhat0=np.zeros(2))
    fan = jd.FanOut({"kf": loop.estimator, "cpx": cpx}, drive="kf")
    x0, key = jnp.array([0.15, -0.3]), jax.random.PRNGKey(8)
    save = lambda s: s  # noqa: E731
    alone = simulate(loop, x0, key, 60, save=save)
    both = simulate(eqx.tree_at(lambda l: l.estimator, loop, fan), x0, key, 60, save=save)
    # the driving estimator's loop is exactly the loop without the other estimator
    np.testing.assert_array_equal(both.saved.x, alone.saved.x)
    np.testing.assert_array_equal(both.saved.aux.estimator.xhat["kf"], alone.saved.xhat)
    # the other one saw the same measurements and inputs: replay it on them, one step at a time
    s = cpx.init(None, x0)
    u_prev = jnp.zeros(1)
    step = eqx.filter_jit(cpx.step)
    for k in range(60):
        s, out, _ = step(s, both.saved.y[k], u_prev, None, jnp.int32(k))
        u_prev = both.saved.u[k]
        np.testing.assert_allclose(both.saved.aux.estimator.xhat["cpx"][k], out, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="drive"):
        jd.FanOut({"kf": loop.estimator}, drive="ekf")


def test_engine_reproduces_the_original_loop():
    """dip-lqr's loop two ways: the original loop (tests/reference_loop.py) with the general linear sensor, and the
    engine with the white-noise sensor; same key, same records."""
    from reference_loop import Loop as OldLoop
    from reference_loop import LoopParams, rollout

    plant = jd.plants.DIP()
    K, _, _ = jd.control.lqr(*jd.linearize(plant), np.diag([30.0, 350, 100, 0, 0, 0]), 0.1)
    std = jnp.array([1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2])
    bound = jnp.array([1.0, 1.5708, 1.5708, np.inf, np.inf, np.inf])
    old_loop = OldLoop(plant, 0.001, sensors.LinearSensor(np.eye(6), 0.001, white_std=std), jd.Passthrough(),
                       jd.control.StateFeedback(K))
    x0, key, n = jnp.array([0.01, -0.02, 0.03, 0.0, 0.1, 0.0]), jax.random.PRNGKey(9), 300
    _, rec = eqx.filter_jit(lambda lp, q: rollout(lp, q, x0, key, n))(old_loop, LoopParams(state_bound=bound))

    native = jd.Loop(plant=plant, sensor=jd.sensors.WhiteNoise(std), estimator=jd.Passthrough(),
                     controller=jd.control.StateFeedback(K), dt=0.001, state_bound=bound)
    sol = simulate(native, x0, key, n, save=lambda s: (s.x, s.xhat, s.u, s.y))
    for a, b in zip(sol.saved, (rec.x, rec.xhat, rec.u, rec.y)):
        # 300 closed-loop periods carry last-bit differences of two separately compiled programs
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-13)


class TwoStreams(jd.KeySchedule):
    """An older convention (as in lorenz-mhe): one init key for all, and period k's key split in two, the first
    half for the measurement, the second for the process noise."""

    def init(self, key):
        k = jax.random.fold_in(key, 1)
        return k, k, k, k

    def period(self, base, k):
        kk = jax.random.fold_in(base, k)
        eps, eta = jax.random.split(kk)
        return eps, kk, kk, kk, eta


class RawNoise(jd.Sensor):
    std: jax.Array = jd.param()

    def step(self, state, x, key, k):
        return state, x + self.std * jax.random.normal(key, x.shape), None


def test_key_schedule_decides_which_key_drives_which_noise():
    plant = Blowup(gain=1.0)  # x_{k+1} = x_k + u_k, u = 0: the increments are the process noise
    loop = jd.Loop(plant=plant, sensor=RawNoise(0.5), estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(jnp.zeros((1, 1))), dt=1.0, process_noise_std=0.1,
                   keys=TwoStreams())
    key = jax.random.PRNGKey(6)
    sol = simulate(loop, jnp.array([0.0]), key, 20, save=lambda s: (s.x, s.y))
    x, y = (np.asarray(a)[:, 0] for a in sol.saved)
    for k in range(19):
        eps, eta = jax.random.split(jax.random.fold_in(jax.random.fold_in(key, 2), k))
        np.testing.assert_allclose(y[k] - x[k], 0.5 * float(jax.random.normal(eps, (1,))[0]), rtol=1e-12)
        np.testing.assert_allclose(x[k + 1] - x[k], 0.1 * float(jax.random.normal(eta, (1,))[0]), rtol=1e-9)
