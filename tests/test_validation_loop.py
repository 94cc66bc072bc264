"""A ``Loop`` checks its parts against each other when it is built (plant sizes, the sensor's outputs against the
estimator's measurements, the estimate against the controller's gain, the controller's and actuator's inputs
against the plant's); ``Rollout``, ``simulate`` and ``monte_carlo`` check their own arguments. Each case is
built with JAX's tracing entry points forbidden (the ``no_trace`` guard of tests/test_validation.py).

And no false alarms: the right objects still build and run, a vmapped gain sweep, ``jax.grad`` through a traced
hyperparameter and a ``monte_carlo`` sweep still work, and their numbers equal those of the same computation
done without the traced construction.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators import CPX, FromTruth, KalmanFilter
from jaxdip.sim.actuators import Saturation
from jaxdip.sim.sensors import LinearSensor, WhiteNoise
from tests.test_validation import DT, dip, kf, loop, no_trace  # noqa: F401  (fixtures)

KEY = jax.random.PRNGKey(0)

CASES = [
    ("sensor-vs-plant", lambda d: loop(d, sensor=WhiteNoise(np.full(4, 1e-3))), ArgumentError,
     r"^Loop: the sensor WhiteNoise reads 4 states \(std has 4 entries\) but the plant DIP has 6 states$"),
    ("linear-sensor-vs-plant", lambda d: loop(d, sensor=LinearSensor(np.eye(3, 4), DT)), ArgumentError,
     r"^Loop: the sensor LinearSensor reads 4 states \(C is \(3, 4\)\) but the plant DIP has 6 states"),
    ("sensor-vs-estimator", lambda d: loop(d, estimator=kf(d)), ArgumentError,
     r"^Loop: the sensor WhiteNoise gives 6 outputs \(a full-state sensor\) but the estimator KalmanFilter "
     r"expects 3 measurements \(C is \(3, 6\)\)$"),
    ("wrapped-estimator", lambda d: loop(d, estimator=FromTruth(kf(d))), ArgumentError,
     r"^Loop: the sensor WhiteNoise gives 6 outputs .* but the estimator FromTruth expects 3 measurements"),
    ("estimator-inputs", lambda d: loop(d, sensor=LinearSensor(d["C3"], DT), estimator=kf(d, W=np.zeros((6, 2)))),
     ArgumentError, r"^Loop: the plant DIP has 1 input but the estimator KalmanFilter expects 2 inputs \(W is \(6, 2\)\)"),
    ("estimator-vs-controller", lambda d: loop(d, controller=jd.control.StateFeedback(np.ones((1, 4)))),
     ArgumentError, r"^Loop: the estimator Passthrough gives 6 estimated states .* but the controller StateFeedback "
                    r"expects 4 states \(K is \(1, 4\)\)$"),
    ("controller-vs-plant", lambda d: loop(d, controller=jd.control.StateFeedback(np.ones((2, 6)))), ArgumentError,
     r"^Loop: the controller StateFeedback gives 2 inputs \(K is \(2, 6\)\) but the plant DIP has 1 input$"),
    ("actuator-vs-plant", lambda d: loop(d, actuator=Saturation(-np.ones(2), np.ones(2))), ArgumentError,
     r"^Loop: the actuator Saturation reads 2 inputs \(u_min has 2 entries\) but the plant DIP has 1 input"),
    ("fanout-disagree", lambda d: loop(d, sensor=LinearSensor(d["C3"], DT), estimator=jd.FanOut(
        {"kf": kf(d), "kf6": kf(d, C=np.eye(6), R=np.eye(6))}, drive="kf")), ArgumentError,
     r"^FanOut: estimators\['kf6'\] reads 6 values \(C is \(6, 6\)\) but estimators\['kf'\] reads 3"),
    ("fanout-drive", lambda d: jd.FanOut({"kf": kf(d)}, drive="ekf"), ArgumentError,
     r"^FanOut: drive must be one of the estimators \['kf'\], got 'ekf'"),
    ("loop-dt", lambda d: loop(d, dt=0.0), ArgumentError, r"^Loop: dt must be a positive finite number"),
    ("loop-substeps", lambda d: loop(d, substeps=0), ArgumentError, r"^Loop: substeps must be >= 1, got 0"),
    ("loop-noise", lambda d: loop(d, process_noise_std=-1e-3), ArgumentError, r"^Loop: process_noise_std must be >= 0"),
    ("loop-noise-shape", lambda d: loop(d, process_noise_std=np.ones(4)), ArgumentError,
     r"^Loop: process_noise_std must be a scalar or \(6,\) for the plant DIP"),
    ("loop-bound", lambda d: loop(d, state_bound=0.0), ArgumentError, r"^Loop: state_bound must be positive"),
    ("loop-plant-type", lambda d: loop(d, plant=lambda x, u: x), ArgumentTypeError,
     r"^Loop: plant must be a jaxdip Plant"),
    ("loop-role-type", lambda d: loop(d, estimator=d["K"]), ArgumentTypeError,
     r"^Loop: estimator must be a component with init and step \(a jaxdip Estimator\), got ndarray"),
    ("rollout-x0", lambda d: jd.Rollout(loop(d), np.zeros(4), 10), ArgumentError,
     r"^Rollout: x0 must be \(6,\) for the plant DIP \(6 states\), got \(4,\)"),
    ("rollout-ball", lambda d: jd.Rollout(loop(d), jd.Ball(np.zeros(4), 0.1), 10), ArgumentError,
     r"^Rollout: x0 must draw \(6,\) states for the plant DIP, got a Ball of \(4,\)"),
    ("rollout-steps", lambda d: jd.Rollout(loop(d), np.zeros(6), 0), ArgumentError, r"^Rollout: steps must be >= 1"),
    ("rollout-save-every", lambda d: jd.Rollout(loop(d), np.zeros(6), 10, save=lambda s: s.x, save_every=3),
     ArgumentError, r"^Rollout: steps must be a multiple of save_every=3, got 10"),
    ("ball-radius", lambda d: jd.Ball(np.zeros(6), -0.1), ArgumentError, r"^Ball: radius must be >= 0"),
    ("gaussian-std", lambda d: jd.engine.Gaussian(np.zeros(6), np.ones(3)), ArgumentError,
     r"^Gaussian: std must be a scalar or \(6,\) like mean"),
    ("simulate-x0", lambda d: jd.simulate(loop(d), np.zeros(4), KEY, 10), ArgumentError,
     r"^simulate: x0 must be \(6,\) for the plant DIP"),
    ("simulate-x0-nan", lambda d: jd.simulate(loop(d), np.full(6, np.nan), KEY, 10), ArgumentError,
     r"^simulate: x0 must be finite"),
    ("simulate-steps", lambda d: jd.simulate(loop(d), np.zeros(6), KEY, -1), ArgumentError,
     r"^simulate: steps must be >= 0, got -1"),
    ("simulate-steps-type", lambda d: jd.simulate(loop(d), np.zeros(6), KEY, 2.5), ArgumentTypeError,
     r"^simulate: steps must be an integer, got 2.5"),
    ("monte-carlo-n", lambda d: jd.monte_carlo(jd.Rollout(loop(d), np.zeros(6), 10), 0, 0), ArgumentError,
     r"^monte_carlo: n must be >= 1, got 0"),
    ("monte-carlo-key", lambda d: jd.monte_carlo(jd.Rollout(loop(d), np.zeros(6), 10), "seed", 4),
     ArgumentTypeError, r"^monte_carlo: key must be a PRNG key or an int seed, got 'seed'"),
]


@pytest.mark.parametrize("build, exc, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_wrong_loop_raises_one_named_error_before_tracing(dip, no_trace, build, exc, match):  # noqa: F811
    with pytest.raises(exc, match=match):
        build(dip)


# ---- no false alarms ----------------------------------------------------------------------------------------


def test_a_right_loop_builds_and_runs(dip):  # noqa: F811
    lp = loop(dip, sensor=LinearSensor(dip["C3"], DT, white_std=1e-4), estimator=kf(dip),
              actuator=Saturation(-10.0, 10.0), process_noise_std=1e-5, state_bound=10.0)
    sol = jd.simulate(lp, 0.01 * jnp.ones(6), KEY, 20)
    assert int(sol.result) == 0 and np.all(np.isfinite(np.asarray(sol.final.x)))
    fan = jd.FanOut({"kf": kf(dip), "from_truth": FromTruth(kf(dip))}, drive="kf")
    loop(dip, sensor=LinearSensor(dip["C3"], DT), estimator=fan)
    loop(dip, sensor=jd.Identity())  # Identity as a full-state sensor (eki-dip and the p-search use it)


def test_vmapped_gain_sweep_builds_inside_vmap(dip):  # noqa: F811
    """Components built inside vmap get tracers: shapes are checked, values are not, numbers are unchanged."""
    Ks = jnp.stack([jnp.asarray(dip["K"]), 0.9 * jnp.asarray(dip["K"])])

    def final(K):
        lp = loop(dip, controller=jd.control.StateFeedback(K))
        return jd.simulate(lp, 0.01 * jnp.ones(6), KEY, 15).final.x

    swept = jax.vmap(final)(Ks)
    for i in range(2):  # a batched matmul rounds differently from a single one: equal to rounding
        np.testing.assert_allclose(np.asarray(swept[i]), np.asarray(final(Ks[i])), rtol=1e-12, atol=1e-15)


def test_grad_through_a_traced_hyperparameter(dip):  # noqa: F811
    """jax.grad through CPX's gamma, the filter built inside the differentiated function; checked against a
    central finite difference."""
    ys = jnp.asarray(np.random.default_rng(0).normal(size=(12, 3))) * 1e-3

    def loss(gamma):
        est = CPX(gamma, dip["model"], dip["C3"], jnp.zeros(6))
        s = est.init(KEY, jnp.zeros(6))
        total = 0.0
        for k in range(ys.shape[0]):
            s, xhat, _ = est.step(s, ys[k], jnp.zeros(1), KEY, k)
            total = total + jnp.sum(xhat**2)
        return total

    g = jax.grad(loss)(0.5)
    h = 1e-5
    fd = (loss(0.5 + h) - loss(0.5 - h)) / (2 * h)
    assert np.isfinite(float(g)) and float(g) == pytest.approx(float(fd), rel=1e-5)


def test_jit_with_traced_covariances_and_lqr(dip):  # noqa: F811
    """A KalmanFilter and dlqr under jit: value checks are skipped for tracers, the results equal the eager ones."""
    Q = 1e-6 * jnp.eye(6)

    @jax.jit
    def gain_and_P0(Q):
        f = kf(dip, Q=Q)
        K = jd.control.dlqr(dip["model"].Phi, dip["model"].W, Q * 1e6, jnp.eye(1))[0]
        return K, f.init(KEY, jnp.zeros(6)).P

    K, P = gain_and_P0(Q)
    K_eager = jd.control.dlqr(dip["model"].Phi, dip["model"].W, np.eye(6), np.eye(1))[0]
    np.testing.assert_allclose(np.asarray(K), np.asarray(K_eager), rtol=1e-10)
    np.testing.assert_array_equal(np.asarray(P), 1e-2 * np.eye(6))


def test_monte_carlo_sweep_over_a_loop_leaf(dip):  # noqa: F811
    r = jd.Rollout(loop(dip, process_noise_std=1e-4), jd.Ball(jnp.zeros(6), 0.01), 10,
                   metrics={"x": jd.metrics.RMS("x")})
    values = jnp.asarray([1e-4, 2e-4])
    swept = jd.monte_carlo(r, 0, 3, sweep=(lambda r: r.loop.process_noise_std, values))
    alone = jd.monte_carlo(eqx.tree_at(lambda r: r.loop.process_noise_std, r, values[1]), 0, 3)
    np.testing.assert_allclose(np.asarray(swept.metrics["x"][1]), np.asarray(alone.metrics["x"]), rtol=1e-12)


def test_stacks_over_time_and_scalars_still_accepted(dip):  # noqa: F811
    """Documented forms that the checks must keep: a KalmanFilter with matrices stacked over time, W=None, a
    per-input W vector, scalar noise levels, a 1x1 LQR from plain floats."""
    T = 5
    m = dip["model"]
    stacked = KalmanFilter(jnp.stack([m.Phi] * T), jnp.stack([m.W] * T), jnp.stack([jnp.asarray(dip["C3"])] * T),
                           jnp.stack([1e-6 * jnp.eye(6)] * T), jnp.stack([1e-4 * jnp.eye(3)] * T), 1e-2 * np.eye(6))
    assert stacked.io_sizes()["in"][0] == 3
    KalmanFilter(m.Phi, None, dip["C3"], 1e-6 * np.eye(6), 1e-4 * np.eye(3), 1e-2 * np.eye(6))
    KalmanFilter(m.Phi, np.asarray(m.W)[:, 0], dip["C3"], 1e-6 * np.eye(6), 1e-4 * np.eye(3), 1e-2 * np.eye(6))
    K, S, _ = jd.control.lqr(-1.0, 1.0, 1.0, 1.0)
    assert float(S[0, 0]) == pytest.approx(np.sqrt(2.0) - 1.0, rel=1e-12)  # -2S - S^2 + 1 = 0
