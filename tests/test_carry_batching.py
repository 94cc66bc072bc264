"""``jaxdip.engine.carry_batching``: the carry a vmap batches, read from the loop's program, must be JAX's own
fixed point, so that the program built is the one JAX builds (same jaxpr, text for text) in fewer batching
rounds."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax._src.interpreters import batching

import jaxdip as jd
from jaxdip.engine import carry_batching as cb

KEYS = jax.random.split(jax.random.PRNGKey(0), 3)


def chain(key):
    """A three-link chain (a <- noise, b <- a, c <- b) beside a carry no seed touches (a covariance-like p)."""
    def body(c, e):
        a, b, cc, p = c
        return (a + e, b + 0.5 * a, cc - b, 0.9 * p + 1.0), a * cc
    return jax.lax.scan(body, (0.0, 0.0, 0.0, 1.0), jax.random.normal(key, (20,)))


def nested(key):
    """An outer scan whose body holds a fori_loop (static: a scan), a while_loop, a cond and a linear solve."""
    m = jnp.array([[2.0, 0.3], [0.1, 1.5]])

    def inner(i, c):
        u, v = c
        return u + v, v * 0.5 + u

    def body(c, e):
        x, s, k, n = c
        x = jax.lax.fori_loop(0, 3, inner, (x, s))[0]
        k = jax.lax.while_loop(lambda q: q[0] < 3 + (e > 0), lambda q: (q[0] + 1, q[1] + x.sum()), (0, k))[1]
        s = jax.lax.cond(n > 2, lambda: jnp.linalg.solve(m, x), lambda: s)
        return (x * 0.1, s, k * 0.5, n + 1), k
    x0 = (jnp.zeros(2), jnp.ones(2), 0.0, 0)
    return jax.lax.scan(body, x0, jax.random.normal(key, (6,)) + jnp.zeros((6, 2)).sum(1))


@jax.custom_jvp
def softclip(x):
    return jnp.tanh(x)


softclip.defjvp(lambda p, t: (softclip(p[0]), t[0] * (1 - jnp.tanh(p[0]) ** 2)))


def with_calls(key):
    """Carry passing through a jit, a custom_jvp function and a per-seed branch index."""
    def body(c, e):
        a, b, z = c
        a = jax.jit(lambda q: q + e)(a)
        b = softclip(b + a)
        z = jax.lax.cond(b > 0, lambda: z + 1.0, lambda: z - 1.0)
        return (a, b, z), None
    return jax.lax.scan(body, (0.0, 0.0, 0.0), jax.random.normal(key, (5,)))[0]


def _rounds_and_jaxpr(f, on: bool, monkeypatch):
    calls = [0]
    orig = batching.batch_jaxpr

    def counting(*a, **k):
        calls[0] += 1
        return orig(*a, **k)

    monkeypatch.setattr(batching, "batch_jaxpr", counting)
    if on:
        with cb.active():
            text = str(jax.make_jaxpr(jax.vmap(f))(KEYS))
    else:
        text = str(jax.make_jaxpr(jax.vmap(f))(KEYS))
    monkeypatch.setattr(batching, "batch_jaxpr", orig)
    return calls[0], text


def _checked(f, monkeypatch):
    """Trace vmap(f) with every loop's prediction checked against JAX's own fixed point (raises if one differs);
    the checking pass also binds JAX's loop, so its program is not compared."""
    monkeypatch.setenv("JAXDIP_CHECK_CARRY_BATCHING", "1")
    with cb.active():
        jax.make_jaxpr(jax.vmap(f))(KEYS)
    monkeypatch.delenv("JAXDIP_CHECK_CARRY_BATCHING")


@pytest.mark.parametrize("f", [chain, nested, with_calls], ids=lambda f: f.__name__)
def test_same_program_as_jax_in_fewer_rounds(f, monkeypatch):
    assert cb.install()
    _checked(f, monkeypatch)
    n_jax, jax_text = _rounds_and_jaxpr(f, False, monkeypatch)
    n_ours, ours_text = _rounds_and_jaxpr(f, True, monkeypatch)
    assert ours_text == jax_text
    assert n_ours < n_jax
    # and the numbers: the compiled program agrees bit for bit with JAX's
    with cb.active():
        ours = jax.jit(jax.vmap(f))(KEYS)
    ref = jax.jit(jax.vmap(f))(KEYS)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(ref)):
        np.testing.assert_array_equal(a, b)


def test_reader_finds_the_fixed_point_of_the_chain():
    """The chain's carry (a, b, c, p) with only the noise batched: a, b and c become per-seed, p never does;
    JAX takes three rounds to learn it."""
    e = jnp.zeros(20)
    jaxpr = jax.make_jaxpr(lambda c, xs: jax.lax.scan(
        lambda c, x: ((c[0] + x, c[1] + 0.5 * c[0], c[2] - c[1], 0.9 * c[3] + 1.0), c[0] * c[2]), c, xs))(
        (0.0, 0.0, 0.0, 1.0), e)
    (eqn,) = [q for q in jaxpr.eqns if q.primitive.name == "scan"]
    p = eqn.params
    carry, outs = cb._scan_out(p["jaxpr"], [False] * 4 + [True], p["num_consts"], p["num_carry"])
    assert carry == [True, True, True, False]
    assert outs == [True, True, True, False, True]


def test_named_axis_leaves_the_loop_to_jax():
    """A reduction over the mapped axis is unbatched: the reader does not guess, JAX's rule decides."""
    def f(x):
        def body(c, _):
            return c + jax.lax.psum(x, "seeds"), None
        return jax.lax.scan(body, 0.0, None, length=3)[0]

    jaxpr = jax.make_jaxpr(lambda x: jax.lax.scan(lambda c, _: (c + x, None), 0.0, None, length=2))(1.0)
    assert cb.out_batched(jaxpr.jaxpr, [True]) == [True]
    xs = jnp.arange(3.0)
    with cb.active():
        ours = jax.vmap(f, axis_name="seeds")(xs)
    np.testing.assert_array_equal(ours, jax.vmap(f, axis_name="seeds")(xs))


def test_library_loop_is_checked_against_jax(monkeypatch):
    """The Kalman-filtered pendulum loop of test_simulate under a vmap over seeds: every loop in it (periods,
    sub-steps) predicted as JAX batches it, and the same program."""
    from test_simulate import make_loop

    loop = make_loop()
    x0 = jnp.array([0.1, 0.0])

    def one(key):
        return jd.simulate(loop, x0, key, 30).final

    _checked(one, monkeypatch)
    n_jax, jax_text = _rounds_and_jaxpr(one, False, monkeypatch)
    n_ours, ours_text = _rounds_and_jaxpr(one, True, monkeypatch)
    assert ours_text == jax_text
    assert n_ours < n_jax
