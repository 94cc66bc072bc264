"""The DIP's encoders, the input disturbance, the power-series and relaxed-projection controllers as
engine Modules against their models written out by hand (keys, quantiser, the laws in NumPy)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.control.power_series import third_order_term
from jaxdip.control.spd import P_v
from jaxdip.plants import dip
from jaxdip.sim import dip_sensors
from jaxdip.sim.disturbance import InputDisturbance

T = 200
RNG = np.random.default_rng(3)
XS = jnp.asarray(0.05 * RNG.normal(size=(T, 6)))
KEYS = jax.random.split(jax.random.PRNGKey(4), T)


def run_new(mod, inputs, x0, estimator=False):
    def body(s, inp):
        k, key, v = inp
        s, out, aux = mod.step(s, *v, key, k) if estimator else mod.step(s, v, key, k)
        return s, out

    return jax.lax.scan(body, mod.init(jax.random.PRNGKey(5), x0), (jnp.arange(T), KEYS, inputs))[1]


@pytest.mark.parametrize("straight_through", [False, True])
def test_encoders_are_noisy_quantised_readings(straight_through):
    """y_k = q round((x_measured + 0.7 q xi_k) / q), xi_k from the first half of split(key_k), by hand."""
    names = dip.STATE_NAMES
    enc = dip_sensors.encoders(1e-3, names, noise_counts=0.7, straight_through=straight_through)
    q = np.asarray(dip_sensors.DEFAULT_QUANTA)
    xi = np.asarray(jax.vmap(lambda k: jax.random.normal(jax.random.split(k)[0], (3,)))(KEYS))
    raw = np.asarray(XS)[:, :3] + 0.7 * q * xi
    ref = q * np.round(raw / q)
    got = jax.jit(run_new)(enc, XS, XS[0])
    np.testing.assert_allclose(np.asarray(got), ref, rtol=0, atol=1e-15)
    counts = np.asarray(got) / np.asarray(enc.quantum)
    assert np.allclose(counts, np.round(counts), atol=1e-9)  # whole counts either way
    if straight_through:  # the derivative of a reading with respect to the state is the identity, not 0
        g = jax.grad(lambda x: enc.step(enc.init(KEYS[0], x), x, KEYS[1], 0)[1].sum())(XS[0])
        np.testing.assert_array_equal(np.asarray(g), [1, 1, 1, 0, 0, 0])


def test_input_disturbance_is_offset_plus_white_noise():
    """u + d + 2 w_k with d = 0.3 xi drawn from the init key once and w_k from each period's key, by hand."""
    us = jnp.asarray(RNG.normal(size=(T, 1)))
    d = 0.3 * np.asarray(jax.random.normal(jax.random.PRNGKey(5), (1,)))
    w = np.asarray(jax.vmap(lambda k: jax.random.normal(k, (1,)))(KEYS))
    got = jax.jit(run_new)(InputDisturbance(0.3, 2.0), us, XS[0])
    np.testing.assert_allclose(np.asarray(got), np.asarray(us) + d + 2.0 * w, rtol=1e-15, atol=1e-15)


def test_power_series_is_law_3_5():
    """u = -R^-1 B^T [P x - (A^T - P B R^-1 B^T)^-1 P f3(x)] assembled in NumPy (f3: ``third_order_term``, checked
    against finite differences in tests/test_control.py); P solves the CARE (residual checked)."""
    Q = np.diag([80.0, 100.0, 300.0, 0.0, 0.0, 0.0])
    plant = dip.DIP()
    ps = jd.control.PowerSeries.design(plant, Q, 0.5)
    P, A, B, R = (np.asarray(m) for m in (ps.P, ps.A, ps.B, ps.R))
    assert np.abs(A.T @ P + P @ A - P @ B @ np.linalg.solve(R, B.T) @ P + Q).max() < 1e-8 * np.abs(P).max()
    got = np.asarray(jax.jit(run_new)(ps, XS, XS[0]))
    f3 = jax.jit(lambda x: third_order_term(lambda z: plant.vector_field(z, jnp.zeros(1)), x))
    for k in range(0, T, 20):
        x = np.asarray(XS[k])
        corr = np.linalg.solve(A.T - P @ B @ np.linalg.solve(R, B.T), P @ np.asarray(f3(XS[k])))
        ref = -np.linalg.solve(R, B.T @ (P @ x - corr))
        np.testing.assert_allclose(got[k], ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("kind", ["continuous", "discrete"])
def test_relaxed_projection_is_2_14_or_2_10(kind):
    """(2.14) or (2.10) with the weight (2.18) gamma / |x|^alpha in NumPy, f(x) and g(x) from the DIP's field
    (g by a central difference: the field is affine in u)."""
    plant = dip.DIP()
    A, B = jd.linearize(plant)
    c = np.asarray(jd.control.lqr(A, B, np.eye(6), 1.0)[0])[0]
    P = np.asarray(P_v(c / np.linalg.norm(c), 1e6))
    got = np.asarray(jax.jit(run_new)(jd.control.RelaxedProjection(plant, jnp.asarray(P), 40.0, alpha=0.5,
                                                                   kind=kind), XS, XS[0]))
    field = jax.jit(lambda x, u: plant.vector_field(x, u))
    for k in range(0, T, 20):
        x = np.asarray(XS[k])
        fx = np.asarray(field(XS[k], jnp.zeros(1)))
        gx = (np.asarray(field(XS[k], jnp.ones(1))) - np.asarray(field(XS[k], -jnp.ones(1)))) / 2
        g_k = 40.0 / np.linalg.norm(x) ** 0.5
        rhs = g_k * gx @ P @ x + gx @ P @ fx if kind == "continuous" else gx @ P @ (fx - x / (1.0 + g_k))
        np.testing.assert_allclose(got[k], [-rhs / (gx @ P @ gx)], rtol=1e-8)
