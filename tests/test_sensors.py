"""Sensor noise statistics (Gauss-Markov walking bias, white noise), quantisation, and the actuator
nonlinearities (saturation, deadzone, backlash) against closed forms and plain-Python references."""

import jaxdip  # noqa: F401  (enables float64)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.sim.actuators import Deadzone, InputBacklash, Saturation, backlash, deadzone, saturate
from jaxdip.sim.sensors import LinearSensor, gauss_markov_coeffs, quantize

# ---- Gauss-Markov walking bias ----------------------------------------------------------------------------

DT = 1e-3
TAU = 0.05  # 50 samples: a 2000-step run spans 40 time constants
SIGMA_B = 0.3
N_SEEDS, N_STEPS = 4000, 2000
N_SE = 5.0  # tolerance in standard errors


def _simulate_bias(n_seeds, n_steps, stationary_start=True, base=0):
    """Run the LinearSensor with C = 0 and no white noise, so y is the walking bias itself."""
    comp = LinearSensor(np.zeros((1, 1)), DT, white_std=0.0, gm_sigma=SIGMA_B, gm_tau=TAU,
                        stationary_start=stationary_start)

    def one(key):
        k0, ks = jax.random.split(key)
        b0 = comp.init(k0, jnp.zeros(1))

        def body(b, kk):
            b, y, _ = comp.step(b, jnp.zeros(1), kk, 0)
            return b, y[0]

        return jax.lax.scan(body, b0, jax.random.split(ks, n_steps))[1]

    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(base), i))(jnp.arange(n_seeds))
    return np.asarray(jax.jit(jax.vmap(one))(keys))


@pytest.fixture(scope="module")
def bias_paths():
    return _simulate_bias(N_SEEDS, N_STEPS)


def test_gauss_markov_stationary_variance_and_mean(bias_paths):
    Y = bias_paths
    var = SIGMA_B**2 * TAU / 2
    a = np.exp(-DT / TAU)
    N = Y.size
    # time averages over AR(1) paths (independent seeds): Var(mean b^2) = 2 var^2 / N * (1 + a^2) / (1 - a^2),
    # Var(mean b) = var / N * (1 + a) / (1 - a)
    se_var = var * np.sqrt(2.0 / N * (1 + a**2) / (1 - a**2))
    se_mean = np.sqrt(var / N * (1 + a) / (1 - a))
    v = np.mean(Y**2)
    assert abs(v - var) < N_SE * se_var, (v, var, se_var)
    assert abs(Y.mean()) < N_SE * se_mean
    assert N_SE * se_var < 0.02 * var  # the test is informative: a factor-2 slip in the variance fails it
    # stationary from the first sample (stationary_start=True): variance across seeds at k = 0
    assert abs(np.mean(Y[:, 0] ** 2) - var) < N_SE * var * np.sqrt(2.0 / N_SEEDS)


@pytest.mark.parametrize("lag", [10, 50, 100])
def test_gauss_markov_autocorrelation(bias_paths, lag):
    Y = bias_paths
    a = np.exp(-DT / TAU)
    r = np.mean(Y[:, :-lag] * Y[:, lag:]) / np.mean(Y**2)
    expected = np.exp(-lag * DT / TAU)
    # Bartlett's formula for the lag-s sample autocorrelation of an AR(1) with coefficient a
    n = Y[:, lag:].size
    se = np.sqrt(((1 + a**2) * (1 - a ** (2 * lag)) / (1 - a**2) - 2 * lag * a ** (2 * lag)) / n)
    assert abs(r - expected) < N_SE * se, (r, expected, se)
    # informative: a 10% error in tau moves r by more than the tolerance
    assert abs(np.exp(-lag * DT / (1.1 * TAU)) - expected) > N_SE * se


def test_gauss_markov_zero_start_transient():
    """From b0 = 0 the variance grows as sigma_b^2 tau / 2 (1 - exp(-2 t / tau))."""
    Y = _simulate_bias(N_SEEDS, 250, stationary_start=False, base=1)
    var = SIGMA_B**2 * TAU / 2
    # the output at step k is the bias before the update, i.e. after k updates from zero
    for k in (10, 25, 50, 200):
        expected = var * (1 - np.exp(-2 * k * DT / TAU))
        got = np.mean(Y[:, k] ** 2)
        assert abs(got - expected) < N_SE * expected * np.sqrt(2.0 / N_SEEDS), (k, got, expected)
    assert np.all(Y[:, 0] == 0.0)


def test_gauss_markov_coeffs_continuous_limit():
    """db = -b/tau dt + sigma_b dW: over a short dt the discrete noise variance is sigma_b^2 dt (Euler limit)."""
    for dt in (1e-6, 1e-5):
        a, q = gauss_markov_coeffs(SIGMA_B, TAU, dt)
        assert abs(float(a) - (1 - dt / TAU)) < (dt / TAU) ** 2
        assert abs(float(q) ** 2 / (SIGMA_B**2 * dt) - 1) < 2 * dt / TAU


# ---- white noise ------------------------------------------------------------------------------------------


def test_white_noise_has_configured_std():
    stds = np.array([0.1, 0.01, 2.0])
    const = np.array([0.5, -1.0, 0.0])
    rng = np.random.default_rng(0)
    C = rng.standard_normal((3, 4))
    x = rng.standard_normal(4)
    comp = LinearSensor(C, DT, white_std=stds, const_bias=const)
    S, T = 2000, 250

    def one(key):
        k0, ks = jax.random.split(key)
        b0 = comp.init(k0, jnp.asarray(x))
        return jax.lax.scan(lambda b, kk: comp.step(b, jnp.asarray(x), kk, 0)[:2], b0, jax.random.split(ks, T))[1]

    Y = np.asarray(jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(7), S)))  # (S, T, 3)
    noise = (Y - (C @ x + const)).reshape(-1, 3)
    N = noise.shape[0]
    std = noise.std(axis=0)
    assert np.all(np.abs(std / stds - 1) < N_SE / np.sqrt(2 * N)), std
    assert np.all(np.abs(noise.mean(axis=0)) < N_SE * stds / np.sqrt(N))
    z = noise / stds
    corr = (z.T @ z) / N
    assert np.all(np.abs(corr[~np.eye(3, dtype=bool)]) < N_SE / np.sqrt(N))  # channels independent
    zz = (Y - (C @ x + const)) / stds
    lag1 = np.mean(zz[:, 1:] * zz[:, :-1], axis=(0, 1))
    assert np.all(np.abs(lag1) < N_SE / np.sqrt(N))  # white in time


# ---- quantisation -----------------------------------------------------------------------------------------


def test_quantize():
    rng = np.random.default_rng(3)
    y = rng.uniform(-10, 10, (1000, 3))
    q = np.array([0.0, 0.01, 2 * np.pi / 4096])
    out = np.asarray(quantize(jnp.asarray(y), jnp.asarray(q)))
    np.testing.assert_array_equal(out[:, 0], y[:, 0])  # quantum 0: identity, bit for bit
    for j in (1, 2):
        k = out[:, j] / q[j]
        assert np.all(np.abs(k - np.round(k)) < 1e-9)  # multiples of the step
        assert np.all(np.abs(out[:, j] - y[:, j]) <= q[j] / 2 * (1 + 1e-12))  # nearest multiple
        assert len(np.unique(np.round(k))) > 100
    # exact multiples are fixed points; a scalar quantum broadcasts
    np.testing.assert_allclose(np.asarray(quantize(jnp.arange(-5, 6) * 0.25, 0.25)), np.arange(-5, 6) * 0.25)


def test_sensor_output_is_quantised():
    q = 0.05
    comp = LinearSensor(np.eye(2), DT, white_std=0.3, gm_sigma=0.1, quantum=q)
    b = comp.init(jax.random.key(0), jnp.zeros(2))
    ys = []
    for k in range(20):
        b, y, _ = comp.step(b, jnp.array([0.123, -0.456]), jax.random.key(k + 1), k)
        ys.append(np.asarray(y))
    ys = np.array(ys) / q
    assert np.all(np.abs(ys - np.round(ys)) < 1e-9)


# ---- saturation and deadzone ------------------------------------------------------------------------------


def test_saturate():
    u = np.linspace(-20, 20, 401)
    out = np.asarray(saturate(jnp.asarray(u), -6.0, 6.0))
    np.testing.assert_array_equal(out, np.where(u < -6, -6.0, np.where(u > 6, 6.0, u)))
    # per-channel bounds, and the actuator
    comp = Saturation(jnp.array([-1.0, 0.0]), jnp.array([1.0, 5.0]))
    _, out, _ = comp.step(comp.init(None, None), jnp.array([3.0, -2.0]), None, 0)
    np.testing.assert_array_equal(np.asarray(out), [1.0, 0.0])


def test_deadzone():
    """Stumfoll (160): zero inside [d-, d+), the input unchanged outside (d+ itself passes)."""
    dm, dp = -0.3, 0.5
    u = np.concatenate([np.linspace(-2, 2, 401), [dm, dp, np.nextafter(dm, -1), np.nextafter(dp, -1)]])
    out = np.asarray(deadzone(jnp.asarray(u), dm, dp))
    expected = np.array([0.0 if dm <= v < dp else v for v in u])
    np.testing.assert_array_equal(out, expected)
    assert out[-4] == 0.0 and out[-3] == dp and out[-2] == np.nextafter(dm, -1) and out[-1] == 0.0
    comp = Deadzone(dm, dp)
    _, out, _ = comp.step(comp.init(None, None), jnp.array([0.2, 0.7]), None, 0)
    np.testing.assert_array_equal(np.asarray(out), [0.0, 0.7])


# ---- backlash ---------------------------------------------------------------------------------------------


def backlash_python(u_seq, m, d_minus, d_plus, psi0=0.0, u0=0.0):
    """Plain-Python loop of the standard backlash law documented in actuators.backlash."""
    psi, u_prev, out = psi0, u0, []
    for u in u_seq:
        up, down = m * (u - d_plus), m * (u - d_minus)
        if u > u_prev and psi <= up:
            psi = up
        elif u < u_prev and psi >= down:
            psi = down
        out.append(psi)
        u_prev = u
    return np.array(out)


def backlash_play(u_seq, m, d_minus, d_plus, w0=0.0):
    """The same law written as m times the play (hysteresis) operator: w = clamp(w_prev, u - d+, u - d-)."""
    w, out = w0, []
    for u in u_seq:
        w = min(max(w, u - d_plus), u - d_minus)
        out.append(m * w)
    return np.array(out)


def _triangle(amplitude=1.0, step=0.01, periods=3):
    up = np.arange(0.0, amplitude, step)
    cycle = np.concatenate([np.arange(amplitude, -amplitude, -step), np.arange(-amplitude, amplitude, step)])
    return np.round(np.concatenate([up, np.tile(cycle, periods), [amplitude]]), 12)


def _run_backlash(u_seq, m, d_minus, d_plus):
    comp = InputBacklash(m, d_minus, d_plus)
    state = comp.init(None, None)
    u = jnp.asarray(u_seq).reshape(len(u_seq), -1)
    _, out = jax.jit(lambda s, u: jax.lax.scan(lambda s, uk: comp.step(s, uk, None, 0)[:2], s, u))(state, u)
    return np.asarray(out)


def test_backlash_triangle_wave_hysteresis():
    m, dm, dp = 1.5, -0.2, 0.3
    u = _triangle()
    psi = _run_backlash(u, [m], [dm], [dp])[:, 0]

    np.testing.assert_allclose(psi, backlash_python(u, m, dm, dp), rtol=0, atol=1e-12)
    np.testing.assert_allclose(psi, backlash_play(u, m, dm, dp), rtol=0, atol=1e-12)

    # hand-checked shape: engaged at zero, first rise takes up the play d+ before the output moves
    first_rise = np.arange(len(u)) <= np.argmax(u)
    slack = first_rise & (u <= dp)
    assert np.all(psi[slack] == 0.0)
    engaged = first_rise & (u > dp)
    np.testing.assert_allclose(psi[engaged], m * (u[engaged] - dp), atol=1e-12)
    # after each reversal the output holds for an input travel of d+ - d-, then follows u - d-+ with slope m
    du = np.diff(u, prepend=0.0)
    peaks = np.where((du[:-1] > 0) & (du[1:] < 0))[0]
    troughs = np.where((du[:-1] < 0) & (du[1:] > 0))[0]
    assert len(peaks) >= 3 and len(troughs) >= 3
    width = dp - dm
    for i in peaks:
        held = m * (u[i] - dp)
        j = i + 1
        while u[j] > u[i] - width + 1e-9:  # in the dead band: output stays put
            assert psi[j] == pytest.approx(held, abs=1e-12)
            j += 1
        while j < len(u) and du[j] < 0:  # engaged on the way down
            assert psi[j] == pytest.approx(m * (u[j] - dm), abs=1e-12)
            j += 1
    for i in troughs:
        held = m * (u[i] - dm)
        j = i + 1
        while u[j] < u[i] + width - 1e-9:
            assert psi[j] == pytest.approx(held, abs=1e-12)
            j += 1
        while j < len(u) and du[j] > 0:
            assert psi[j] == pytest.approx(m * (u[j] - dp), abs=1e-12)
            j += 1
    # the loop is a parallelogram: the output range is m (A - d+) .. m (-A - d-)
    assert psi.max() == pytest.approx(m * (1.0 - dp)) and psi.min() == pytest.approx(m * (-1.0 - dm))


def test_backlash_vector_channels_and_irregular_input():
    """Two channels with their own parameters, a noisy non-monotone input with repeated samples."""
    rng = np.random.default_rng(5)
    u = np.cumsum(rng.standard_normal((600, 2)) * 0.05, axis=0)
    u[100:110] = u[99]  # a constant stretch: nothing moves
    m, dm, dp = np.array([1.0, 2.5]), np.array([-0.1, -0.05]), np.array([0.15, 0.02])
    psi = _run_backlash(u, m, dm, dp)
    for c in range(2):
        ref = backlash_python(u[:, c], m[c], dm[c], dp[c])
        np.testing.assert_allclose(psi[:, c], ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(psi[:, c], backlash_play(u[:, c], m[c], dm[c], dp[c]), rtol=0, atol=1e-12)
        # always within the band m (u - d+) <= psi <= m (u - d-)
        assert np.all(psi[:, c] >= m[c] * (u[:, c] - dp[c]) - 1e-12)
        assert np.all(psi[:, c] <= m[c] * (u[:, c] - dm[c]) + 1e-12)
    assert np.all(psi[100:110] == psi[99])
    # the plain function agrees with one component step
    out = backlash(jnp.array(0.0), jnp.array(0.0), jnp.array(0.5), 2.0, -0.1, 0.2)
    assert float(out) == pytest.approx(2.0 * (0.5 - 0.2))


# ---- the TWIP's sensors as one engine sensor ------------------------------------------------------------------


@pytest.mark.parametrize("variant", [dict(), dict(stationary_start=True, cf_init_from_angle=False)])
def test_twip_sensors_equal_their_pieces_composed(variant):
    """``TwipSensors`` = the raw ``LinearSensor`` channels, the encoder's difference quotient and the
    ``ComplementaryFilter`` estimator composed by hand, with the keys of a two-stage chain (to 1e-12); ideal = 1:
    y = x."""
    from jaxdip.estimators.complementary import ComplementaryFilter
    from jaxdip.sim.twip_sensors import TwipSensors

    dt = 0.01
    new = TwipSensors.table_7_1(dt, **variant)
    raw = LinearSensor(new.C, dt, new.white_std, new.const_bias, new.gm_sigma, new.gm_tau, new.quantum,
                       stationary_start=variant.get("stationary_start", False))
    cf = ComplementaryFilter(0.99, dt, 2, 3, init_from_angle=variant.get("cf_init_from_angle", True))

    def old_init(key, x0):
        k_raw, k_cf = jax.random.split(key, 2)
        return raw.init(k_raw, x0), jnp.zeros(()), cf.init(k_cf, x0)

    def old_step(st, x, key, k):
        bias, p_prev, theta = st
        k_raw, k_cf = jax.random.split(key, 2)
        bias, m, _ = raw.step(bias, x, k_raw, k)
        v = jnp.where(k == 0, 0.0, (m[0] - p_prev) / dt)
        theta, y, _ = cf.step(theta, jnp.stack([m[0], v, m[2], m[3]]), None, k_cf, k)
        return (bias, m[0], theta), y

    key = jax.random.PRNGKey(7)
    xs = jnp.cumsum(0.01 * jax.random.normal(key, (200, 4)), axis=0)
    so, sn = old_init(key, xs[0]), new.init(key, xs[0])
    step_old, step_new = jax.jit(old_step), jax.jit(lambda s, x, kk, k: new.step(s, x, kk, k))
    ideal = eqx_tree_at_ideal(new)
    for k in range(xs.shape[0]):
        kk = jax.random.fold_in(key, k)
        so, yo = step_old(so, xs[k], kk, k)
        sn, yn, _ = step_new(sn, xs[k], kk, k)
        # to rounding: XLA may fuse (37) into a multiply-add, and the filter state carries the last bits on
        np.testing.assert_allclose(np.asarray(yn), np.asarray(yo), rtol=1e-12, atol=1e-15)
        assert np.all(np.asarray(ideal.step(sn, xs[k], kk, k)[1]) == np.asarray(xs[k]))
    assert np.abs(np.asarray(yo) - np.asarray(xs[-1])).max() > 1e-6  # the sensors did add errors


def eqx_tree_at_ideal(s):
    import equinox as eqx

    return eqx.tree_at(lambda m: m.ideal, s, jnp.asarray(1.0))


def backlash_printed_python(u_seq, m, d_minus, d_plus, psi0=0.0, u0=0.0):
    """(161) exactly as printed: direction from u(k+1) - u(k), engaged value m u(k) - m d at the old input."""
    psi, u_prev, out = psi0, u0, []
    for u in u_seq:
        up, down = m * u_prev - m * d_plus, m * u_prev - m * d_minus
        if u - u_prev > 0 and psi <= up:
            psi = up
        elif u - u_prev < 0 and psi >= down:
            psi = down
        out.append(psi)
        u_prev = u
    return np.array(out)


def test_printed_backlash_law_is_161_as_written_and_lags_the_standard_by_one_sample():
    from jaxdip.sim.actuators import OutputBacklash

    m, dm, dp = 1.0, -0.1, 0.1
    u = _triangle(step=0.02)
    sens = OutputBacklash(m, dm, dp, law="printed")
    xs = jnp.zeros((len(u), 4)).at[:, 2].set(jnp.asarray(u))
    state = sens.init(None, None)
    _, (y, psi) = jax.lax.scan(lambda s, x: (lambda r: (r[0], (r[1], r[2])))(sens.step(s, x, None, 0)), state, xs)
    ref = backlash_printed_python(u, m, dm, dp)
    np.testing.assert_allclose(np.asarray(psi), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(y[:, 2]), ref, rtol=0, atol=1e-12)
    # where engaged in both (input moving on the same side), printed = standard one sample later
    std = backlash_python(u, m, dm, dp)
    engaged = np.nonzero((np.abs(np.diff(std)) > 0) & (np.abs(np.diff(ref)) > 0))[0][5:-5]
    assert engaged.size > 50
    np.testing.assert_allclose(ref[engaged + 1], std[engaged], atol=1e-12)
    with pytest.raises(ValueError):
        backlash(0.0, 0.0, 1.0, 1.0, -0.1, 0.1, law="nonsense")
