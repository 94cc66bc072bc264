"""The sensor-noise candidates of ``jaxdip.bench.noise`` against the checks today's stream passes: moments,
normality (scipy.stats), independence across seeds, periods and components. Every stream is drawn from fixed
seeds, so each check is deterministic; the bounds are ~4.5 standard errors, which a correct N(0, 1) stream of this
size passes (today's does) and a stream with a real defect of that size fails (the broken streams below)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jaxdip as jd
from jaxdip.bench import noise as N

SEEDS, STEPS = 256, 200  # 307,200 numbers per stream


@pytest.fixture(scope="module")
def streams():
    return {name: N.noise(name, SEEDS, STEPS, chunk=100) for name in N.CANDIDATES}


def check_stream(z: np.ndarray) -> list[str]:
    """What is wrong with ``z`` (seeds, steps, 6) as independent standard normals: an empty list when nothing."""
    bad = []
    flat = z.ravel()
    n = flat.size
    se = 1.0 / np.sqrt(n)
    if not np.all(np.isfinite(flat)):
        bad.append("non-finite")
    if abs(flat.mean()) > 4.5 * se:
        bad.append(f"mean {flat.mean():.2e}")
    if abs(flat.var() - 1.0) > 4.5 * np.sqrt(2.0) * se:
        bad.append(f"variance {flat.var():.5f}")
    if abs(stats.skew(flat)) > 4.5 * np.sqrt(6.0) * se:
        bad.append(f"skewness {stats.skew(flat):.2e}")
    if abs(stats.kurtosis(flat)) > 4.5 * np.sqrt(24.0) * se:
        bad.append(f"excess kurtosis {stats.kurtosis(flat):.2e}")
    # the tails: the share beyond 3 sigma (a float32 or a truncated generator thins them)
    tail, p3 = np.mean(np.abs(flat) > 3.0), 2 * stats.norm.sf(3.0)
    if abs(tail - p3) > 4.5 * np.sqrt(p3 * (1 - p3) / n):
        bad.append(f"share beyond 3 sigma {tail:.2e} (normal {p3:.2e})")
    for test, p in (("Kolmogorov-Smirnov", stats.kstest(flat, "norm").pvalue),
                    ("D'Agostino-Pearson", stats.normaltest(flat).pvalue)):
        if p < 1e-4:
            bad.append(f"{test} p = {p:.1e}")
    # independence: correlations between neighbouring periods, neighbouring seeds, and the six components
    pairs = {"periods": (z[:, 1:], z[:, :-1]), "seeds": (z[1:], z[:-1])}
    pairs.update({f"components {i},{j}": (z[..., i], z[..., j]) for i in range(6) for j in range(i + 1, 6)})
    for what, (a, b) in pairs.items():
        r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
        if abs(r) > 4.5 / np.sqrt(a.size):
            bad.append(f"correlation across {what} {r:.2e}")
    # whole rows: no two seeds' sequences may coincide or be strongly related
    rows = z.reshape(SEEDS, -1)
    c = np.corrcoef(rows)
    np.fill_diagonal(c, 0.0)
    if np.max(np.abs(c)) > 5.5 / np.sqrt(rows.shape[1]):
        bad.append(f"largest correlation between two seeds' sequences {np.max(np.abs(c)):.3f}")
    return bad


@pytest.mark.parametrize("name", list(N.CANDIDATES))
def test_candidate_passes_todays_checks(streams, name):
    assert check_stream(streams[name]) == []


def test_the_checks_catch_broken_streams(streams):
    """Each kind of defect a faster generator could bring is caught: the checks can fail."""
    z = streams["threefry"]
    rng = np.random.default_rng(0)
    # every other seed repeats its neighbour (a key derivation that collides for pairs of seeds)
    assert any("correlation across seeds" in b for b in check_stream(np.repeat(z[::2], 2, axis=0)))
    assert any("periods" in b for b in check_stream(0.95 * z + 0.31 * np.roll(z, 1, axis=1)))
    uniform = (rng.uniform(size=z.shape) - 0.5) * np.sqrt(12.0)  # right mean and variance, wrong law
    assert any("kurtosis" in b or "Kolmogorov" in b for b in check_stream(uniform))
    assert any("beyond 3 sigma" in b for b in check_stream(np.clip(z, -3.0, 3.0)))
    assert any("variance" in b for b in check_stream(1.01 * z))
    same_seed = z.copy()
    same_seed[7] = same_seed[3]
    assert any("two seeds" in b for b in check_stream(same_seed))


@pytest.mark.parametrize("name, draw_dtype", [("threefry", "float64"), ("float32", "float32")])
def test_the_stream_is_the_loops(name, draw_dtype):
    """``noise(name)`` is what the library's loop draws with ``WhiteNoise(draw_dtype=...)``: the measurement
    minus the state, seed by seed, in a dip-lqr loop (today's stream for the default)."""
    plant = jd.plants.dip.DIP()
    K, _, _ = jd.control.lqr(*jd.linearize(plant), np.diag(N.TABLE_3_1_Q), 0.1)
    sensor = jd.sensors.WhiteNoise(N.NOISE_STD, draw_dtype=draw_dtype)
    loop = jd.Loop(plant=plant, sensor=sensor, estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(K), dt=N.DT, substeps=1)
    keys = N.seed_keys(name, 4)
    x0 = jnp.array([0.0, 0.03, -0.02, 0.0, 0.0, 0.0])
    sol = jax.vmap(lambda key: jd.simulate(loop, x0, key, 50, save=lambda s: (s.y - s.x) / N.NOISE_STD))(keys)
    # float32: the loop's program fuses the float32 inverse error function differently from the standalone
    # draw, and ~4% of the numbers differ by one float32 rounding (1.2e-7 relative); float64 agrees to ~1e-15
    rtol = 1e-9 if draw_dtype == "float64" else 2.5e-7
    np.testing.assert_allclose(np.asarray(sol.saved), N.noise(name, 4, 50), rtol=rtol, atol=1e-12)
    assert sol.saved.dtype == jnp.float64


def test_white_noise_default_is_todays_draw_and_bad_dtype_refused():
    key = jax.random.PRNGKey(5)
    x = jnp.zeros(6)
    _, y, _ = jd.sensors.WhiteNoise(1.0).step(None, x, key, 0)
    want = jax.random.normal(jax.random.split(key)[0], (6,))  # split(key)[0], as the docstring says
    np.testing.assert_array_equal(np.asarray(y), np.asarray(want))
    with pytest.raises(jd.ArgumentError, match="draw_dtype must be one of"):
        jd.sensors.WhiteNoise(1.0, draw_dtype="float16")


def test_box_muller_against_numpy():
    """Box-Muller on known uniforms equals the textbook transform written in NumPy."""
    key = jax.random.PRNGKey(3)
    u = np.asarray(jax.random.uniform(key, (2, 4)))
    r = np.sqrt(-2.0 * np.log(1.0 - u[0]))
    want = np.concatenate([r * np.cos(2 * np.pi * u[1]), r * np.sin(2 * np.pi * u[1])])[:7]
    np.testing.assert_allclose(np.asarray(N.box_muller(key, (7,))), want, rtol=1e-14)


def test_no_draw_bound_is_the_loop_with_zero_noise():
    """``NoDraw`` (the bench's bound: the loop less its noise draw) runs the same loop as a zero-std
    ``WhiteNoise``, whose y = x + 0 xi is x exactly: the same final states to the bit, and not those of the noisy
    loop."""
    import equinox as eqx
    from jaxdip.scenarios.dip_lqr import dip_lqr

    r = dip_lqr(duration=0.05, substeps=1, record_every=None)
    key = jax.random.PRNGKey(3)

    def final(sensor):
        return np.asarray(jd.monte_carlo(eqx.tree_at(lambda r: r.loop.sensor, r, sensor), key, 8).final.x)

    zero = final(jd.sensors.WhiteNoise(jnp.zeros(6)))
    np.testing.assert_array_equal(final(N.NoDraw()), zero)
    assert not np.array_equal(final(r.loop.sensor), zero)
