"""Complementary filter (37) against its closed-form responses, and the TWIP sensor chain of §7.4.

The Gauss-Markov walking bias (stationary variance, autocorrelation time), the quantiser and the saturation
have their own tests in tests/test_sensors.py."""

import numpy as np
import jax
import jax.numpy as jnp

from jaxdip.estimators.complementary import ComplementaryFilter
from jaxdip.sim.twip_sensors import TwipSensors, complementary_update, table_7_1

ALPHA, DT = 0.99, 0.01


def run_cf(rates, angles, init_from_angle=True, alpha=ALPHA):
    """The filter on the measurement [angle, rate] (angle_index 0, rate_index 1); returns the filtered angles."""
    comp = ComplementaryFilter(alpha, DT, angle_index=0, rate_index=1, init_from_angle=init_from_angle)

    def body(th, inp):
        k, r, a = inp
        th, y, _ = comp.step(th, jnp.stack([a, r]), None, None, k)
        return th, y[0]

    _, out = jax.lax.scan(body, comp.init(None, None), (jnp.arange(len(rates)), jnp.asarray(rates),
                                                         jnp.asarray(angles)))
    return np.asarray(out)


def test_update_is_equation_37():
    assert complementary_update(0.1, 2.0, 0.3, ALPHA, DT) == ALPHA * (0.1 + 2.0 * DT) + (1 - ALPHA) * 0.3


def test_constant_angle_is_approached_geometrically():
    n = 300
    out = run_cf(np.zeros(n), np.full(n, 0.2), init_from_angle=False)
    k = np.arange(n) + 1  # theta_{-1} = 0, first output after one update
    np.testing.assert_allclose(out, 0.2 * (1 - ALPHA**k), rtol=1e-12)
    # started from the accelerometer, it is exact from the first sample
    np.testing.assert_allclose(run_cf(np.zeros(n), np.full(n, 0.2)), 0.2, rtol=1e-14)


def test_noiseless_ramp_is_reproduced_exactly():
    """The gyro and accelerometer paths add up to the identity: a true angle ramp with its true rate passes."""
    n = 500
    w = 0.7
    angle = 0.05 + w * DT * np.arange(n)
    out = run_cf(np.full(n, w), angle)
    np.testing.assert_allclose(out, angle, rtol=0, atol=1e-13)


def test_gyro_bias_gives_the_predicted_offset():
    n = 3000
    b = 0.02  # rad/s
    out = run_cf(np.full(n, b), np.zeros(n))
    offset = ALPHA * b * DT / (1 - ALPHA)
    np.testing.assert_allclose(out[-1], offset, rtol=1e-10)
    assert abs(out[100] - offset) > 0.1 * offset  # it takes time: the filter's pole is alpha


def test_accelerometer_white_noise_is_attenuated_as_predicted():
    rng = np.random.default_rng(0)
    n = 400_000
    s = 2e-3
    out = run_cf(np.zeros(n), s * rng.normal(size=n))
    var = out[1000:].var()
    pred = s**2 * (1 - ALPHA) / (1 + ALPHA)
    # samples are correlated over ~1/(1-alpha) = 100 steps: about n/100 effective samples
    rel_se = np.sqrt(2 / (n / (1 + ALPHA) * (1 - ALPHA)))
    assert abs(var / pred - 1) < 4 * rel_se, (var, pred)


def test_filter_replaces_only_the_angle_channel():
    comp = ComplementaryFilter(ALPHA, DT, angle_index=2, rate_index=3)
    y = jnp.array([1.0, 2.0, 0.3, 0.5])
    st = comp.init(None, None)
    st, out0, _ = comp.step(st, y, None, None, 0)
    st, out1, _ = comp.step(st, y, None, None, 1)
    np.testing.assert_allclose(np.asarray(out0), [1.0, 2.0, 0.3, 0.5])
    np.testing.assert_allclose(np.asarray(out1), [1.0, 2.0, ALPHA * (0.3 + 0.5 * DT) + (1 - ALPHA) * 0.3, 0.5])


def _sensor_run(sens, xs):
    st = sens.init(jax.random.PRNGKey(1), xs[0])

    def body(st, inp):
        k, x = inp
        return sens.step(st, x, jax.random.fold_in(jax.random.PRNGKey(2), k), k)[:2]

    _, ys = jax.lax.scan(body, st, (jnp.arange(xs.shape[0]), jnp.asarray(xs)))
    return np.asarray(ys)


def test_noiseless_twip_sensor_encoder_and_filter():
    """With the inertial noise off: the position is quantised, the velocity is the difference of quantised
    positions over dt (0 at the first sample), the filtered tilt follows a smooth angle, the gyro is exact."""
    q = 0.000147
    sens = TwipSensors.table_7_1(DT, tilt_white_std=0.0, tilt_gm_sigma=0.0, tilt_gm_tau=1.0, gyro_white_std=0.0,
                                 gyro_gm_sigma=0.0, gyro_gm_tau=1.0, encoder_quantum=q, cf_alpha=ALPHA)
    n = 300
    t = np.arange(n) * DT
    xs = np.stack([0.3 * np.sin(t), 0.3 * np.cos(t), 0.1 * t, np.full(n, 0.1)], 1)
    ys = _sensor_run(sens, xs)
    pq = q * np.round(xs[:, 0] / q)
    np.testing.assert_allclose(ys[:, 0], pq, rtol=0, atol=1e-15)
    assert np.abs(ys[:, 0] - xs[:, 0]).max() <= q / 2 + 1e-15
    np.testing.assert_allclose(ys[1:, 1], np.diff(pq) / DT, rtol=0, atol=1e-11)
    assert ys[0, 1] == 0.0
    np.testing.assert_allclose(ys[:, 2], xs[:, 2], rtol=0, atol=1e-13)  # a ramp with its true rate
    np.testing.assert_allclose(ys[:, 3], xs[:, 3], rtol=0, atol=0)


def test_twip_sensor_noise_levels_of_table_7_1():
    """White noise of the Table 7.1 variances on the raw tilt and gyro channels; the walking biases start at
    zero (calibrated at start-up) and wander by about sigma_b sqrt(t)."""
    t71 = table_7_1()
    comp = TwipSensors.table_7_1(DT, cf_alpha=0.0)  # alpha = 0: the tilt channel is the raw theta_a
    n_seeds, n = 2000, 50

    def one(key):
        st = comp.init(key, jnp.zeros(4))

        def body(st, k):
            return comp.step(st, jnp.zeros(4), jax.random.fold_in(key, k), k)[:2]

        st, ys = jax.lax.scan(body, st, jnp.arange(n))
        return ys, st[0].bias

    ys, bias = jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(0), n_seeds))
    ys, bias = np.asarray(ys), np.asarray(bias)
    # first sample: the bias is exactly zero, so the spread is the white noise alone
    for ch, name in ((2, "tilt"), (3, "gyro")):
        s = ys[:, 0, ch].std()
        assert abs(s / t71[f"{name}_white_std"] - 1) < 4 / np.sqrt(2 * n_seeds), (name, s)
        # bias after n samples: var = sigma_b^2 tau / 2 (1 - exp(-2 n dt / tau)) ~ sigma_b^2 n dt
        tau = t71[f"{name}_gm_tau"]
        pred = t71[f"{name}_gm_sigma"] ** 2 * tau / 2 * (1 - np.exp(-2 * n * DT / tau))
        assert abs(bias[:, ch].var() / pred - 1) < 4 * np.sqrt(2 / n_seeds), name
    assert np.all(ys[:, :, 0] == 0) and np.all(ys[:, :, 1] == 0)  # the encoders have no noise
