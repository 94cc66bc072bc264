"""Native reaction-wheel pendulum components (plant, saturation, straight-through sensor) and the
rwp scenario loop against the init/step functions and the loop they replace: same numbers."""

import jaxdip  # noqa: F401  (float64)

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.control import StateFeedback
from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import homd
from jaxdip.plants import rwp
from jaxdip.plants.rwp import RWP
from jaxdip.scenarios import rwp as scenario
from jaxdip.sim import sensors
from jaxdip.sim.actuators import Saturation
from reference_loop import Loop, LoopParams
from reference_loop import rollout as old_rollout
from jaxdip.sim.sensors import LinearSensor

DT = rwp.DT


def test_rwp_plant_equals_pure_function():
    x, u = jnp.array([0.1, -0.3, 2.0, 5.0]), jnp.array([0.7])
    # (2)-(3) and the energy written out in NumPy with the Table 1 numbers
    mp, lp, Jp, mr, lr, Jr, k, g = 0.58, 0.10, 3.8e-3, 0.35, 0.22, 12.48e-4, 3.69e-2, 9.81
    J, ml = Jp + mp * lp**2 + mr * lr**2, mp * lp + mr * lr
    th, thd, thrd, I = 0.1, -0.3, 5.0, 0.7
    ref = [thd, -k / J * I + ml * g / J * np.sin(th), thrd, (J + Jr) * k / (J * Jr) * I - ml * g / J * np.sin(th)]
    np.testing.assert_allclose(RWP().vector_field(x, u), ref, rtol=1e-14)
    E = 0.5 * J * thd**2 + 0.5 * Jr * (thrd + thd) ** 2 + ml * g * np.cos(th)
    np.testing.assert_allclose(RWP().energy(x), E, rtol=1e-14)


def test_saturation_and_straight_through_sensor():
    sat = Saturation(jnp.array([-1.0]), jnp.array([2.0]))
    assert float(sat.step((), jnp.array([3.0]), None, 0)[1][0]) == 2.0
    kw = dict(const_bias=[0.01, 0.0], quantum=[1e-2, 0.1])
    exact, new = LinearSensor(jnp.eye(4)[:2], DT, **kw), LinearSensor(jnp.eye(4)[:2], DT, straight_through=True, **kw)
    key = jax.random.PRNGKey(0)

    def y_old(x):
        """The straight-through rule written out: the unquantised reading plus the rounding, held constant."""
        raw = LinearSensor(jnp.eye(4)[:2], DT, const_bias=kw["const_bias"])
        y = raw.step(raw.init(key, x), x, key, 0)[1]
        return y + jax.lax.stop_gradient(sensors.quantize(y, jnp.asarray(kw["quantum"])) - y)

    def y_new(x):
        return new.step(new.init(key, x), x, key, 0)[1]

    x = jnp.array([0.123, 1.0, -0.456, 0.0])
    np.testing.assert_array_equal(y_new(x), y_old(x))
    np.testing.assert_array_equal(y_new(x), exact.step(exact.init(key, x), x, key, 0)[1])  # values: quantised
    np.testing.assert_array_equal(jax.jacfwd(y_new)(x), jax.jacfwd(y_old)(x))
    np.testing.assert_array_equal(jax.jacfwd(y_new)(x), jnp.eye(4)[:2])  # the quantiser passes gradients


def _rec_fn(r):
    return jnp.stack([r.x[0], r.x[1], r.x[3], r.y[0], r.xhat[0], r.xhat[1], r.xhat[3], r.u[0]])


def test_scenario_loop_equals_old_loop():
    """The rwp-bias loop with the joint observer (d = -0.08, quantised encoders): the engine loop of
    ``jaxdip.scenarios.rwp`` against the original loop (``tests/reference_loop.py``), every recorded period, bit for bit."""
    K, n, d = rwp.K_TABLE2, 400, -0.08
    jp = bo.JointObserver.build(homd.HOMDObserver.build(DT), 0.01)
    sens = LinearSensor(jnp.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), DT, const_bias=jnp.array([d, 0.0]),
                        quantum=[rwp.PENDULUM_ANGLE_RESOLUTION, rwp.WHEEL_ANGLE_RESOLUTION])
    loop = Loop(plant=RWP(), dt=DT, sensor=sens, estimator=jp,
                controller=StateFeedback(jnp.array([[K[0], K[1], 0.0, K[2]]])),
                actuator=Saturation(jnp.array([-jnp.inf]), jnp.array([jnp.inf])), substeps=10, tail_steps=n)
    params = LoopParams(state_bound=jnp.array([np.pi / 2, np.inf, np.inf, np.inf]))
    x0 = jnp.array([0.1, 0.01, 0.02, -0.1])
    key = jax.random.fold_in(jax.random.PRNGKey(0), 3)
    c, rec = eqx.filter_jit(lambda lp, p: old_rollout(lp, p, x0, key, n, record_every=5, record_fn=_rec_fn))(loop,
                                                                                                           params)
    new = scenario.loop(jp, dt=DT, K=K, d=d)
    sol = jax.jit(lambda lp: jd.simulate(lp, x0, key, n, save=scenario.record, save_every=5,
                                         metrics={"x2": jd.metrics.Sum(scenario.x_squared)}))(new)
    np.testing.assert_array_equal(np.asarray(sol.saved), np.asarray(rec))
    np.testing.assert_allclose(np.asarray(sol.metrics["x2"]), np.asarray(c.stats.sum_x2), rtol=1e-14)
    assert int(sol.result) == int(c.diverged)


def test_case_sweep_compiles_once():
    """Several low-pass gains and angles sharing one structure: one sweep, one compilation of the batch, and a
    second sweep with new numbers reuses it; each case equals its own run to the last bit."""
    import logging

    compiled = []

    class Count(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            if "Finished XLA compilation" in msg and "_batch" in msg:
                compiled.append(msg)

    hp = homd.HOMDObserver.build(DT, substeps=2)
    base = scenario.rollout(bo.LowpassHOMD.build(hp, 0.05), steps=20, d=-0.08,
                            save_every=5, substeps=2)

    def where(r):
        return r.loop.estimator.gamma_d, r.x0.theta0

    handler, log = Count(), logging.getLogger("jax")
    log.addHandler(handler)
    old_level = log.level
    log.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles(True):
            a = jd.monte_carlo(base, 0, 2, sweep=(where, (jnp.array([0.05, 0.5, 2.0]), jnp.array([0.1, 0.05, 0.0]))))
            n_first = len(compiled)
            jd.monte_carlo(base, 0, 2, sweep=(where, (jnp.array([0.1, 0.2, 0.3]), jnp.array([0.0, 0.1, 0.2]))))
    finally:
        log.removeHandler(handler)
        log.setLevel(old_level)
    assert n_first == 1 and len(compiled) == 1, compiled
    one = eqx.tree_at(where, base, (jnp.asarray(2.0), jnp.asarray(0.0)))
    alone = jd.monte_carlo(one, 0, 2)
    np.testing.assert_allclose(np.asarray(alone.saved), np.asarray(a.saved[2]), rtol=1e-12, atol=1e-15)
