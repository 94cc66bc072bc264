"""``jaxdip.plants.trig.sincos`` against NumPy's (the C library's) sin and cos, its derivative against the
cosine, and its special values."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.plants.trig import sincos


def _angles() -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.concatenate([
        np.linspace(-20.0, 20.0, 400_001),  # every quadrant, many times
        rng.normal(0.0, 3.0, 200_000),
        rng.uniform(-1e6, 1e6, 20_000),
        np.linspace(-1e-8, 1e-8, 1001),  # the smallest angles, where sin x = x to rounding
        np.arange(-1000, 1001) * (np.pi / 2),  # the floating-point neighbours of the zeros
        np.array([0.0, -0.0, 5e-324, np.pi / 4, -np.pi / 4, 3 * np.pi / 4]),
    ])


def test_sincos_matches_the_c_library():
    x = _angles()
    s, c = (np.asarray(v) for v in jax.jit(sincos)(jnp.asarray(x)))
    for got, ref in ((s, np.sin(x)), (c, np.cos(x))):
        # absolute: within one ulp of 1 everywhere
        assert np.max(np.abs(got - ref)) <= np.spacing(1.0)
        # relative: a few ulp, except within 1e-12 |x| of a zero, where the three-part reduction by pi/2 (not the
        # C library's exact one) leaves an absolute error of ~1e-28 |x|
        away = np.abs(ref) > 1e-12 * np.maximum(np.abs(x), 1.0)
        assert np.sum(~away) < 2500
        ulps = np.abs(got - ref)[away] / np.spacing(np.abs(ref[away]))
        assert np.max(ulps) <= 3.0


def test_sincos_of_inf_and_nan_is_nan():
    s, c = sincos(jnp.array([np.inf, -np.inf, np.nan]))
    assert np.all(np.isnan(np.asarray(s))) and np.all(np.isnan(np.asarray(c)))


def test_derivatives_are_the_cosine_and_minus_the_sine():
    x = jnp.asarray(np.linspace(-10.0, 10.0, 2001))
    ds = jax.vmap(jax.grad(lambda v: sincos(v)[0]))(x)
    dc = jax.vmap(jax.grad(lambda v: sincos(v)[1]))(x)
    np.testing.assert_allclose(np.asarray(ds), np.cos(np.asarray(x)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.asarray(dc), -np.sin(np.asarray(x)), rtol=0, atol=1e-15)


def test_float32_input_gets_xlas_float32_sin_and_cos():
    x = jnp.asarray(np.linspace(-10.0, 10.0, 10001, dtype=np.float32))
    s, c = sincos(x)
    assert s.dtype == jnp.float32 and c.dtype == jnp.float32
    assert np.array_equal(np.asarray(s), np.asarray(jnp.sin(x))) and np.array_equal(np.asarray(c), np.asarray(jnp.cos(x)))


def test_dip_vectorised_trig_agrees_with_the_library_trig_and_numpy():
    import dataclasses as dc

    from jaxdip.bench.scoreboard import numpy_dip_f, numpy_dip_params
    from jaxdip.plants.dip import DIP

    rng = np.random.default_rng(1)
    xs = rng.uniform(-1.0, 1.0, (200, 6)) * np.array([0.5, 3.0, 3.0, 2.0, 10.0, 10.0])
    us = rng.uniform(-6.0, 6.0, 200)
    lib, vec = DIP(), DIP(trig="vectorised")
    assert [f.name for f in dc.fields(vec)] == [f.name for f in dc.fields(lib)]
    f_lib = jax.jit(jax.vmap(lambda x, u: lib.vector_field(x, u)))(jnp.asarray(xs), jnp.asarray(us))
    f_vec = jax.jit(jax.vmap(lambda x, u: vec.vector_field(x, u)))(jnp.asarray(xs), jnp.asarray(us))
    f_np = np.array([numpy_dip_f(numpy_dip_params(), x, u) for x, u in zip(xs, us)])
    scale = np.max(np.abs(f_np), axis=0)
    assert np.max(np.abs(np.asarray(f_vec) - f_np) / scale) < 1e-13
    assert np.max(np.abs(np.asarray(f_vec) - np.asarray(f_lib)) / scale) < 1e-13
    assert not np.array_equal(np.asarray(f_vec), np.asarray(f_lib))  # a different evaluation, not the same call


def test_dip_lqr_loop_with_vectorised_trig_stays_with_the_library_loop():
    """The LQR loop has no quantiser: the two trig evaluations keep the same trajectory to rounding."""
    import equinox as eqx

    import jaxdip as jd
    from jaxdip.plants.dip import DIP
    from jaxdip.scenarios.dip_lqr import dip_lqr

    r = dip_lqr(substeps=1, duration=1.0, record_every=None)
    rv = eqx.tree_at(lambda r: r.loop.plant, r, DIP(trig="vectorised"))
    key = jax.random.PRNGKey(3)
    a = np.asarray(jd.monte_carlo(r, key, 64).final.x)
    b = np.asarray(jd.monte_carlo(rv, key, 64).final.x)
    assert np.max(np.abs(a - b)) < 1e-11 and np.max(np.abs(a)) > 1e-4


def test_dip_rejects_an_unknown_trig():
    import pytest

    from jaxdip.engine.checks import ArgumentError
    from jaxdip.plants.dip import DIP

    with pytest.raises(ArgumentError, match="trig"):
        DIP(trig="fast")


def test_higher_derivatives_at_zero_and_elsewhere_are_the_sines_and_cosines():
    """The power-series control design takes Taylor coefficients of the DIP at upright (angles 0): the third
    derivative of sin there must be -1, not the 0 a special case at x = 0 would give."""
    d1 = jax.grad(lambda v: sincos(v)[0])
    d2 = jax.grad(d1)
    d3 = jax.grad(d2)
    for x0 in (0.0, -0.0, 0.3, -2.0, 7.5):
        np.testing.assert_allclose([float(d1(x0)), float(d2(x0)), float(d3(x0))],
                                   [np.cos(x0), -np.sin(x0), -np.cos(x0)], rtol=0, atol=1e-13)
    c3 = jax.grad(jax.grad(jax.grad(lambda v: sincos(v)[1])))
    np.testing.assert_allclose([float(c3(x0)) for x0 in (0.0, 0.3, -2.0)], [np.sin(x0) for x0 in (0.0, 0.3, -2.0)],
                               rtol=0, atol=1e-13)


def test_the_derivative_is_the_defined_rule_on_the_computed_values():
    """d sin = cos dx and d cos = -sin dx from the values sincos returns, to the bit: the rule, not the formula
    traced (whose tangents XLA copied into every consumer; a dip-cpx-ldf run, whose power-series control takes
    three derivatives of the model every period, ran 12.7x slower)."""
    x = jnp.asarray(np.linspace(-10.0, 10.0, 1001))
    (s, c), (ds, dc) = jax.jvp(sincos, (x,), (jnp.ones_like(x),))
    assert np.array_equal(np.asarray(ds), np.asarray(c)) and np.array_equal(np.asarray(dc), np.asarray(-s))


def test_sin_and_cos_each_come_out_of_a_division():
    """XLA copies a cheap value into every fused kernel that reads it, but not a division's: the quadrant's swaps
    and signs act on the numerators, so sin and cos each leave the formula as a division's output (with the selects
    after the divisions, the power-series control's third derivative of the vectorised DIP took 3x as long)."""
    jaxpr = jax.make_jaxpr(sincos)(jnp.zeros(3)).jaxpr
    (call,) = [e for e in jaxpr.eqns if e.primitive.name == "custom_jvp_call"]
    inner = call.params["call_jaxpr"].jaxpr
    made_by = {v: e.primitive.name for e in inner.eqns for v in e.outvars}
    assert [made_by[v] for v in inner.outvars] == ["div", "div"]


def test_the_vectorised_dip_takes_one_sincos_for_both_angles():
    """One formula for the stacked angles: with one per angle, two copies of its reduction steps went into the
    kernel of the power-series control's third derivative, and dip-cpx-ldf's LDF loop ran 2.5x slower than with
    the C library's trig (docs/performance.md)."""
    from jaxdip.plants.dip import DIP

    jaxpr = jax.make_jaxpr(lambda x: DIP(trig="vectorised").vector_field(x, jnp.zeros(1)))(jnp.full(6, 0.1)).jaxpr
    calls = [e for e in jaxpr.eqns if e.primitive.name == "custom_jvp_call"]
    assert len(calls) == 1 and calls[0].invars[0].aval.shape == (2,)
