"""float32 closed loops (``jd.Loop(precision="float32")``): the whole period runs in float32, and a float32 loop
follows its float64 twin to float32 accuracy; float64 loops are unchanged."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.scenarios import eki_dip
from jaxdip.control.feedback import StateFeedback
from jaxdip.search import p_search

from float32_jaxpr import float64_equations, float64_equations_of


def _search_cfg(precision="float64", **kw):
    return eki_dip.search_setup(T=0.2, t_star=0.1, **kw)._replace(precision=precision)


def _member_P():
    # a stabilising weight: the LQR direction's P, as the eki-dip search starts from
    p = eki_dip.plant()
    A, B = jd.linearize(p)
    v = eki_dip.lqr_direction(A, B)
    from jaxdip.control.spd import P_v
    return P_v(v, 1e3)


def test_the_walker_finds_float64_inside_a_scan():
    """The checker itself: a float64 constant made inside a scan body of a float32 program is found."""

    def leaky(x):
        return jax.lax.scan(lambda c, _: (c + jnp.zeros(3).astype(jnp.float32), None), x, None, length=2)[0]

    def clean(x):
        return jax.lax.scan(lambda c, _: (c + jnp.zeros(3, c.dtype), None), x, None, length=2)[0]

    x = jnp.ones(3, jnp.float32)
    assert any("scan" in p for p in float64_equations_of(leaky, x))
    assert float64_equations_of(clean, x) == []


@pytest.mark.parametrize("noise_ahead", [False, True])
def test_performance_loop_runs_in_float32(noise_ahead):
    """The eki-dip search's evaluation (DIP, relaxed projection, process noise, quadratic reducer) with
    precision="float32": no float64 equation anywhere in the program, and a float32 performance."""
    cfg = _search_cfg(precision="float32")
    p, P = eki_dip.plant(), _member_P()

    def perf(key):
        return p_search.rp_performance(p, P, cfg, key, noise_ahead=noise_ahead)

    jaxpr = jax.make_jaxpr(perf)(jax.random.key(0))
    assert float64_equations(jaxpr.jaxpr) == []
    assert jaxpr.out_avals[0].dtype == jnp.float32


def test_float32_follows_float64_over_a_short_horizon():
    """Deterministic loop (no noise): the float32 trajectory agrees with the float64 one (the reference) to a
    float32-sized tolerance, and the float64 loop is the one of today (explicit precision == default)."""
    cfg = _search_cfg(noise_std=0.0)
    p, P = eki_dip.plant(), _member_P()
    loop64 = p_search.performance_loop(p, P, cfg)
    loop32 = dataclasses.replace(loop64, precision="float32")
    x0 = jnp.array([0.02, 0.05, -0.03, 0.0, 0.1, -0.1])
    save = lambda s: (s.x, s.u)
    sol64 = jax.jit(lambda: jd.simulate(loop64, x0, jax.random.key(1), 200, save=save))()
    sol32 = jax.jit(lambda: jd.simulate(loop32, x0, jax.random.key(1), 200, save=save))()
    (x64, u64), (x32, u32) = sol64.saved, sol32.saved
    assert x32.dtype == u32.dtype == sol32.final.x.dtype == jnp.float32
    assert x64.dtype == jnp.float64
    assert int(sol32.result) == int(sol64.result) == 0
    scale = np.max(np.abs(np.asarray(x64)), axis=0) + 1e-12
    err = np.max(np.abs(np.asarray(x32, np.float64) - np.asarray(x64)), axis=0) / scale
    assert np.all(err < 1e-4), err  # float32 eps 1.2e-7, grown over 200 periods of an unstable plant
    assert np.all(err > 0)  # it did run in float32 (a float64 run would match exactly)
    uscale = np.max(np.abs(np.asarray(u64)))
    assert np.max(np.abs(np.asarray(u32, np.float64) - np.asarray(u64))) / uscale < 1e-4


def test_white_noise_draws_in_the_loop_dtype():
    """A float32 loop's WhiteNoise draws float32 normals: the measurement is x + std * normal(float32) from
    the sensor's key, as drawn here with jax.random directly."""
    p = eki_dip.plant()
    K = jnp.zeros((1, 6))
    loop = jd.Loop(plant=p, sensor=jd.sensors.WhiteNoise(0.1), estimator=jd.Passthrough(),
                   controller=StateFeedback(K), dt=0.001,
                   precision="float32")
    x0 = jnp.zeros(6)
    key = jax.random.key(3)
    sol = jd.simulate(loop, x0, key, 1, save=lambda s: s.y)
    k_sens = loop.keys.period(loop.keys.base(key), 0)[0]
    xi = jax.random.normal(jd.split_lanes(k_sens, 2)[0], (6,), jnp.float32)
    assert sol.saved.dtype == jnp.float32
    # to a float32 ulp or two (XLA may fuse the product differently); a float64 draw is another stream
    np.testing.assert_allclose(np.asarray(sol.saved[0]), np.float32(0.1) * np.asarray(xi), rtol=2.5e-7)


def test_monte_carlo_of_a_float32_rollout():
    """Through ``jd.Rollout`` and ``jd.monte_carlo``: float32 metrics, the same first-order statistics as the
    float64 run within their 95% intervals."""
    cfg = _search_cfg()
    p, P = eki_dip.plant(), _member_P()
    out = {}
    for prec in ("float64", "float32"):
        loop = dataclasses.replace(p_search.performance_loop(p, P, cfg), precision=prec)
        r = jd.Rollout(loop, jd.Ball(jnp.zeros(6), 0.02), 100, metrics=jd.metrics.RMS("x"))
        out[prec] = jd.monte_carlo(r, jax.random.key(0), 64).metrics
    assert out["float32"].dtype == jnp.float32
    a, b = np.asarray(out["float64"]), np.asarray(out["float32"], np.float64)
    half = 1.96 * a.std(axis=0, ddof=1) / np.sqrt(a.shape[0])
    assert np.all(np.abs(b.mean(axis=0) - a.mean(axis=0)) <= 2 * half + 1e-12)


@pytest.mark.parametrize("bad", ["float16", "f32", 32, None])
def test_bad_precision_is_refused(bad):
    p = eki_dip.plant()
    with pytest.raises(jd.ArgumentError, match="precision must be one of"):
        jd.Loop(plant=p, sensor=jd.Identity(), estimator=jd.Passthrough(), controller=jd.Identity(), dt=0.001,
                precision=bad)
    with pytest.raises(jd.ArgumentError, match="precision must be one of"):
        p_search.performance_loop(p, jnp.eye(6), _search_cfg(precision=bad))
