"""Native Lorenz plant and linear sensor against their equations written by hand, the linearised CPX/SCPX and
EKF with the estimator wrappers, and the one-loop comparison's wiring."""

import jaxdip  # noqa: F401  (float64)

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.estimators import Ahead, Delayed, ExtendedKalmanFilter, FromTruth, InitialError, LinearizedCPX
from jaxdip.plants import lorenz
from jaxdip.plants.lorenz import Lorenz
from jaxdip.scenarios import lorenz_mhe as S
from jaxdip.engine.integrate import rk4_zoh
from jaxdip.sim.sensors import LinearSensor

H = 0.001


@jax.jit
def _data(seed=0):
    """A noisy Lorenz trajectory of 60 samples every H (the old pure functions)."""
    p = Lorenz()
    key = jax.random.PRNGKey(seed)

    def step(x, k):
        y = lorenz.output_matrix() @ x + 5.0 * jax.random.normal(jax.random.fold_in(key, k), (2,))
        x_next = rk4_zoh(lorenz.f, p, x, jnp.zeros(1), H, 1) + 0.1 * jax.random.normal(
            jax.random.fold_in(key, 10**6 + k), (3,))
        return x_next, (x, y)

    _, (xs, ys) = jax.lax.scan(step, jnp.array([-8.0, 7.0, 27.0]), jnp.arange(60))
    return xs, ys


@jax.jit
def _run_new(est, x0, ys):
    st = est.init(jax.random.PRNGKey(0), x0)

    def step(st, ky):
        k, y = ky
        st, o, a = est.step(st, y, jnp.zeros(1), jax.random.PRNGKey(1), k)
        return st, (o, a)

    return jax.lax.scan(step, st, (jnp.arange(ys.shape[0]), ys))[1]


def test_lorenz_plant_is_eq_1_28():
    """The field and its Jacobian against (1.28) written out (sigma = 10, beta = 8/3, rho = 28)."""
    x = jnp.array([1.0, -2.0, 20.0])
    s, b, r = 10.0, 8.0 / 3.0, 28.0
    np.testing.assert_allclose(Lorenz().vector_field(x, jnp.zeros(1)), [s * (-3.0), 1.0 * (r - 20.0) + 2.0,
                                                                       -2.0 - b * 20.0], rtol=1e-15)
    A, _ = jd.linearize(Lorenz(), x)
    np.testing.assert_allclose(A, [[-s, s, 0.0], [r - 20.0, -1.0, -1.0], [-2.0, 1.0, -b]], rtol=1e-15)


def test_linearized_cpx_prediction_is_one_model_step_ahead():
    xs, ys = _data()
    Cm, z3 = lorenz.output_matrix(), jnp.zeros(3)
    for gamma, keep in ((0.5, None), (50.0, 2)):
        cur = FromTruth(LinearizedCPX(gamma, Lorenz(), Cm, z3, h=H, keep=keep, expm_squarings=3))
        new, aux = _run_new(Ahead(cur), xs[0], ys)
        current, _ = _run_new(cur, xs[0], ys)
        np.testing.assert_array_equal(aux.xhat, current)  # the wrapper changes the output only
        np.testing.assert_array_equal(new, aux.ahead)
        # the output is the prediction: one model step of the current estimate ahead
        assert float(jnp.max(jnp.abs(new[-1] - aux.xhat[-1]))) < 0.1
        assert float(jnp.max(jnp.abs(new[-1] - aux.xhat[-1]))) > 0


def test_ekf_from_truth_covariance_stays_positive():
    xs, ys = _data()
    Cm, z3 = lorenz.output_matrix(), jnp.zeros(3)
    Q, R, P0 = 0.01 * jnp.eye(3), 25.0 * jnp.eye(2), jnp.eye(3)
    new, aux = _run_new(FromTruth(ExtendedKalmanFilter(Q, R, P0, z3, model=Lorenz(), dt=H, C=Cm, expm_squarings=3)),
                        xs[0], ys)
    assert np.all(np.linalg.eigvalsh(np.asarray(aux.cov[-1])) > 0)
    assert np.abs(np.asarray(new[0]) - np.asarray(xs[0])).max() < 15  # started at the truth, updated once


def test_linear_sensor_is_its_model_by_hand():
    """y = Q(C x + c + b + w) and the exact Gauss-Markov recursion of b, in NumPy from the same key draws."""
    C, white, const = np.eye(4)[:2], np.array([0.1, 0.2]), np.array([0.05, 0.0])
    sig, tau, q, dt = np.array([0.01, 0.0]), np.array([2.0, 1.0]), np.array([1e-3, 0.0]), 0.01
    new = LinearSensor(C, dt, white_std=white, const_bias=const, gm_sigma=sig, gm_tau=tau, quantum=q)
    key = jax.random.PRNGKey(4)
    sn = new.init(key, None)
    b = np.sqrt(sig**2 * tau / 2) * np.asarray(jax.random.normal(key, (2,)))  # stationary start
    np.testing.assert_allclose(sn, b, rtol=1e-15)
    a = np.exp(-dt / tau)
    for k in range(20):
        x = jnp.sin(jnp.arange(4.0) + 0.1 * k)
        kk = jax.random.fold_in(key, k)
        k_white, k_bias = jax.random.split(kk)
        raw = C @ np.asarray(x) + const + b + white * np.asarray(jax.random.normal(k_white, (2,)))
        y = np.where(q > 0, q * np.round(raw / np.where(q > 0, q, 1.0)), raw)
        b = a * b + np.sqrt(sig**2 * tau / 2 * (1 - a**2)) * np.asarray(jax.random.normal(k_bias, (2,)))
        sn, yn, aux = new.step(sn, x, kk, k)
        np.testing.assert_allclose(yn, y, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(aux, b, rtol=1e-13, atol=1e-18)


def test_wrappers_initial_error_and_delay():
    xs, ys = _data()
    inner = LinearizedCPX(0.5, Lorenz(), lorenz.output_matrix(), jnp.zeros(3), h=H)
    key = jax.random.PRNGKey(7)
    est = InitialError(Delayed(inner), 0.3)
    st = est.init(key, xs[0])
    xhat0 = xs[0] + 0.3 * jax.random.normal(key, (3,))
    np.testing.assert_array_equal(st[1], xhat0)
    plain, _ = _run_new(FromTruth(inner), xhat0, ys)
    outs = []
    for k, y in enumerate(ys[:5]):
        st, o, _ = est.step(st, y, jnp.zeros(1), key, k)
        outs.append(o)
    np.testing.assert_array_equal(outs[0], xhat0)
    np.testing.assert_allclose(jnp.stack(outs[1:]), plain[:4], rtol=1e-12)


def test_fanout_members_see_the_same_noise_as_alone():
    """The EKF inside the four-estimator FanOut gives exactly the loop with the EKF alone, and the error
    reducer equals sums computed from saved trajectories."""
    r = S.build(steps=20, save_every=1)
    key = jax.random.PRNGKey(2)
    sol = jd.monte_carlo(r, key, 2)
    ekf_alone = r.loop.estimator.estimators["ekf"]
    r1 = jd.Rollout(jd.Loop(r.loop.plant, r.loop.sensor, ekf_alone, r.loop.controller, dt=r.loop.dt,
                            substeps=r.loop.substeps, process_noise_std=r.loop.process_noise_std, keys=r.loop.keys),
                    r.x0, r.steps, save=lambda s: (s.x, s.xhat))
    alone = jd.monte_carlo(r1, key, 2)
    np.testing.assert_array_equal(alone.saved[1][:, :, 0], sol.saved[:, :, 3])
    np.testing.assert_array_equal(alone.saved[0][:, :, 0], sol.saved[:, :, 0])
    x, xh = np.asarray(alone.saved[0]), np.asarray(alone.saved[1])
    norm = np.sqrt(((xh - x) ** 2).sum(-1)).sum(-1)
    np.testing.assert_allclose(np.asarray(sol.metrics["errors"]["norm"][:, 2]), norm, rtol=1e-12)
