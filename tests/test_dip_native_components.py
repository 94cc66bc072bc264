"""The DIP's encoders, the input disturbance, the power-series and relaxed-projection controllers as
engine Modules give the numbers of their init/step versions with the same parameters, bit for bit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.control.power_series import power_series_controller, ps_params
from jaxdip.control.projection import relaxed_projection_controller, rp_params
from jaxdip.control.spd import P_v
from jaxdip.plants import dip
from jaxdip.sim import dip_sensors
from jaxdip.sim.disturbance import InputDisturbance, input_disturbance, input_disturbance_params
from jaxdip.tune import straight_through_sensor

T = 200
RNG = np.random.default_rng(3)
XS = jnp.asarray(0.05 * RNG.normal(size=(T, 6)))
KEYS = jax.random.split(jax.random.PRNGKey(4), T)


def run_old(comp, params, inputs, x0):
    def body(s, inp):
        k, key, v = inp
        s, out = comp.step(params, s, v, key, k)
        return s, out

    return jax.lax.scan(body, comp.init(params, jax.random.PRNGKey(5), x0), (jnp.arange(T), KEYS, inputs))[1]


def run_new(mod, inputs, x0, estimator=False):
    def body(s, inp):
        k, key, v = inp
        s, out, aux = mod.step(s, *v, key, k) if estimator else mod.step(s, v, key, k)
        return s, out

    return jax.lax.scan(body, mod.init(jax.random.PRNGKey(5), x0), (jnp.arange(T), KEYS, inputs))[1]


@pytest.mark.parametrize("straight_through", [False, True])
def test_encoders_equal_linear_sensor(straight_through):
    names = dip.STATE_NAMES
    enc = dip_sensors.encoders(1e-3, names, noise_counts=0.7, straight_through=straight_through)
    old = (straight_through_sensor if straight_through else dip_sensors.encoder_sensor)(1e-3)
    ref = jax.jit(run_old, static_argnums=0)(old, dip_sensors.encoder_params(names, noise_counts=0.7), XS, XS[0])
    got = jax.jit(run_new)(enc, XS, XS[0])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))
    counts = np.asarray(got) / np.asarray(enc.quantum)
    assert np.allclose(counts, np.round(counts), atol=1e-9)  # whole counts either way
    if straight_through:  # the derivative of a reading with respect to the state is the identity, not 0
        g = jax.grad(lambda x: enc.step(enc.init(KEYS[0], x), x, KEYS[1], 0)[1].sum())(XS[0])
        np.testing.assert_array_equal(np.asarray(g), [1, 1, 1, 0, 0, 0])


def test_input_disturbance_equals_its_component():
    p = input_disturbance_params(0.3, 2.0)
    us = jnp.asarray(RNG.normal(size=(T, 1)))
    ref = jax.jit(run_old, static_argnums=0)(input_disturbance(), p, us, XS[0])
    got = jax.jit(run_new)(InputDisturbance(0.3, 2.0), us, XS[0])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))


def test_power_series_equals_its_component():
    Q = np.diag([80.0, 100.0, 300.0, 0.0, 0.0, 0.0])
    old_plant = dip.make("printed")
    ref = jax.jit(run_old, static_argnums=0)(power_series_controller(old_plant),
                                              ps_params(old_plant, old_plant.default_params(), Q, 0.5), XS, XS[0])
    ps = jd.control.PowerSeries.design(dip.DIP(), Q, 0.5)
    got = jax.jit(run_new)(ps, XS, XS[0])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))


@pytest.mark.parametrize("kind", ["continuous", "discrete"])
def test_relaxed_projection_equals_its_component(kind):
    old_plant = dip.make("printed")
    A, B = jd.linearize(dip.DIP())
    c = np.asarray(jd.control.lqr(A, B, np.eye(6), 1.0)[0])[0]
    P = P_v(c / np.linalg.norm(c), 1e6)
    ref = jax.jit(run_old, static_argnums=0)(relaxed_projection_controller(old_plant, kind),
                                              rp_params(P, 40.0, old_plant.default_params(), alpha=0.5), XS, XS[0])
    got = jax.jit(run_new)(jd.control.RelaxedProjection(dip.DIP(), P, 40.0, alpha=0.5, kind=kind), XS, XS[0])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ref))
