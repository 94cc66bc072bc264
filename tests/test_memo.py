"""``jaxdip.engine.memo``: a result is reused only for arguments equal in every value, never under a trace; and
the TWIP's LQR design, which the experiments rebuild for every case, is served from it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control.twip_lqr import twip_dlqr
from jaxdip.engine.memo import memoised, value_key
from jaxdip.plants import twip


def test_value_key_tells_apart_what_a_function_could_tell_apart():
    a = (jnp.arange(3.0), {"q": 1.0, "n": 2})
    assert value_key(a) == value_key((jnp.arange(3.0), {"n": 2, "q": 1.0}))
    assert value_key(a) != value_key((jnp.arange(3.0), {"q": 1.0, "n": 2.0}))  # an int is not a float
    assert value_key(a) != value_key((jnp.arange(3.0).astype(jnp.float32), {"q": 1.0, "n": 2}))
    assert value_key(a) != value_key((jnp.arange(3.0), {"q": float(np.nextafter(1.0, 2.0)), "n": 2}))
    assert value_key(a) != value_key((jnp.arange(3.0).reshape(1, 3), {"q": 1.0, "n": 2}))
    assert value_key((object(),)) is None  # not an array or a number: no value to key on
    seen = []
    jax.jit(lambda x: seen.append(value_key((x,))) or x)(1.0)
    assert seen == [None]  # a tracer


def test_memoised_returns_the_stored_result_only_for_equal_values_and_keeps_the_last_ones():
    calls = []

    @memoised(2)
    def f(x, scale=1.0):
        calls.append(x)
        return x * scale

    a = f(jnp.asarray(2.0))
    assert f(jnp.asarray(2.0)) is a and len(calls) == 1
    assert f(jnp.asarray(2.0), scale=3.0) is not a and len(calls) == 2
    f(jnp.asarray(5.0))  # a third result pushes out the oldest
    assert f(jnp.asarray(2.0)) is not a and len(calls) == 4
    g = jax.grad(lambda x: f(x, scale=3.0))(jnp.asarray(2.0))  # traced: computed, never served from the memo
    assert float(g) == 3.0 and len(calls) == 5


def test_twip_dlqr_serves_a_repeat_and_recomputes_any_other_value():
    d = twip_dlqr(twip.TWIP(), (1.0, 1.0, 0.1, 0.1), 1.0, 0.01)
    assert twip_dlqr(twip.TWIP(), (1.0, 1.0, 0.1, 0.1), 1.0, 0.01) is d  # a new but equal plant and weights
    near = (1.0, 1.0, 0.1, float(np.nextafter(0.1, 1.0)))
    e = twip_dlqr(twip.TWIP(), near, 1.0, 0.01)
    raw = twip_dlqr.__wrapped__(twip.TWIP(), near, 1.0, 0.01)
    assert e is not d
    for got, want in zip(e, raw):
        assert np.array_equal(np.asarray(got), np.asarray(want))
    heavier = twip_dlqr(twip.TWIP(Mp=twip.TWIP().Mp * 1.01), (1.0, 1.0, 0.1, 0.1), 1.0, 0.01)
    assert not np.array_equal(np.asarray(heavier.K), np.asarray(d.K))
    # a gradient through the design (the plant's mass traced) is computed, not served
    dk = jax.grad(lambda m: twip_dlqr(twip.TWIP(Mp=m), (1.0, 1.0, 0.1, 0.1), 1.0, 0.01).K[0, 0])(twip.TWIP().Mp)
    assert np.isfinite(float(dk)) and float(dk) != 0.0
