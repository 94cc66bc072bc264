"""``jaxdip.program_cache``: a stored program gives the ordinary call's results bit for bit; its key moves with
everything the trace depends on, and not with the process (string hashing) or with array values; what it cannot
key goes the ordinary way."""

import dataclasses
import os
import pickle
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip import program_cache, program_key
from jaxdip.engine import driver
from jaxdip.scenarios.dip_lqr import dip_lqr


@pytest.fixture
def folder(tmp_path):
    """The cache on, in a folder of this test's own; the suite's setting restored after."""
    before = program_cache.enabled_folder()
    program_cache.enable(str(tmp_path / "programs"))
    yield tmp_path / "programs"
    program_cache.enable(before)


def rollout(**kw):
    return dip_lqr(dt=1e-3, substeps=1, duration=0.1, record_every=5, **kw)


def leaves(tree):
    return [np.asarray(a) for a in jax.tree_util.tree_leaves(tree)]


def assert_bitwise(a, b):
    la, lb = leaves(a), leaves(b)
    assert len(la) == len(lb)
    for u, v in zip(la, lb):
        assert u.dtype == v.dtype and u.shape == v.shape
        np.testing.assert_array_equal(u, v)


def test_stored_program_gives_the_ordinary_results_bit_for_bit(folder):
    r, key = rollout(), jax.random.PRNGKey(7)
    program_cache.enable(None)
    plain = jd.monte_carlo(r, key, 12)
    program_cache.enable(str(folder))
    first = jd.monte_carlo(r, key, 12)  # traced, exported, written
    written = sorted(os.listdir(folder))
    assert written and all(name.endswith(".jaxexport") for name in written)
    program_cache.enable(str(folder))  # a new process: nothing in memory, the files on disk
    again = jd.monte_carlo(r, key, 12)
    assert sorted(os.listdir(folder)) == written  # served from the files, nothing exported again
    assert_bitwise(plain, first)
    assert_bitwise(plain, again)
    # chunked over time (start, chunks, metrics: three programs) and a sweep: the same
    chunked = jd.monte_carlo(r, key, 12, time_chunk=20)
    program_cache.enable(None)
    assert_bitwise(chunked, jd.monte_carlo(r, key, 12, time_chunk=20))


def test_a_damaged_entry_is_exported_again(folder):
    r, key = rollout(), jax.random.PRNGKey(1)
    want = jd.monte_carlo(r, key, 4)
    for name in os.listdir(folder):
        (folder / name).write_bytes(b"not a program")
    program_cache.enable(str(folder))
    assert_bitwise(want, jd.monte_carlo(r, key, 4))


def test_the_key_follows_the_trace_not_the_values():
    fp = lambda r, n=4: program_key.fingerprint(driver._batch_body, (
        driver._m_call, r, None, None, jax.random.PRNGKey(0), jnp.arange(n, dtype=jnp.uint32), None, 0, None))
    r = rollout()
    base = fp(r)
    assert fp(rollout()) == base  # built again: the same key
    # new numbers in the traced leaves (a gain): the same program
    scaled = dataclasses.replace(r, loop=dataclasses.replace(r.loop, controller=dataclasses.replace(
        r.loop.controller, K=2.0 * r.loop.controller.K)))
    assert fp(scaled) == base
    # what shapes the trace: a static field, the horizon, a leaf's shape, a function in a field
    assert fp(dataclasses.replace(r, loop=dataclasses.replace(r.loop, plant=dataclasses.replace(
        r.loop.plant, trig="library")))) != base
    assert fp(dataclasses.replace(r, steps=r.steps + 5)) != base
    assert fp(r, n=5) != base  # an input's shape
    from jaxdip.scenarios.dip_cpx_ldf import estimation_error

    assert fp(dataclasses.replace(r, save=estimation_error)) != base  # another function in a field


def test_functions_count_by_code_defaults_and_closure():
    import functools

    from jaxdip.control.designs import lqr
    from jaxdip.engine.integrate import rk4_step, rk4_zoh

    fp = lambda f: program_key.fingerprint(f, ())
    with pytest.raises(program_key.Unkeyable):  # this test module is not in the project's packages
        fp(lambda x: x)
    # the project's functions count by what they are, not by which object they are
    assert fp(rk4_step) == fp(rk4_step) and fp(rk4_step) != fp(rk4_zoh)
    # a partial's arguments, a closure's captured values, a bound method's object are part of the key
    assert fp(functools.partial(lqr, rtol=1e-9)) != fp(functools.partial(lqr, rtol=1e-8))
    assert fp(functools.partial(lqr, rtol=1e-9)) == fp(functools.partial(lqr, rtol=1e-9))
    r = rollout()
    assert fp(r.loop.plant.vector_field) != fp(dataclasses.replace(r.loop.plant, trig="library").vector_field)


def test_what_it_cannot_key_goes_the_ordinary_way(folder):
    class Unknown:
        pass

    assert program_cache.call(driver._batch_body, (Unknown(),), "_batch") is program_cache.MISS
    # a gradient through the Monte Carlo: tracers are not keyed; the result is the ordinary one
    r, key = rollout(), jax.random.PRNGKey(2)

    def cost(scale):
        rr = dataclasses.replace(r, loop=dataclasses.replace(r.loop, controller=dataclasses.replace(
            r.loop.controller, K=scale * r.loop.controller.K)))
        return jnp.mean(jd.monte_carlo(rr, key, 4).final.x ** 2)

    with_cache = jax.grad(cost)(1.0)
    program_cache.enable(None)
    assert float(with_cache) == float(jax.grad(cost)(1.0))


def test_the_key_does_not_depend_on_string_hashing():
    # a frozenset constant (``x in {"a", "b"}``) is stored in the order of the process's string hashes
    script = textwrap.dedent("""
        from jaxdip import program_cache, program_key

        code = compile("def f(x):\\n    return x in {'alpha', 'beta', 'gamma', 'delta'}\\n", "m", "exec")
        key = program_key._Key()
        program_key._code(key, code)
        program_key._static(key, ({"b": 1, "a": (2.0, "c")}, frozenset({"x", "y", "z"})))
        print(key.h.hexdigest())
    """)
    keys = set()
    for seed in ("1", "2", "3", "4"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        keys.add(out.stdout.strip())
    assert len(keys) == 1, keys


def test_the_key_follows_the_source_tree(tmp_path, monkeypatch):
    tree = tmp_path / "pkg"
    tree.mkdir()
    (tree / "a.py").write_text("X = 1\n")
    monkeypatch.setattr(program_key, "_project_trees", lambda: (str(tree),))
    from jaxdip.control.designs import lqr

    before = program_key.fingerprint(lqr, ())
    (tree / "a.py").write_text("X = 2\n")
    program_key._tree_hash.cache_clear()
    assert program_key.fingerprint(lqr, ()) != before


def test_project_objects_modules_and_closures_are_keyed():
    import types as pytypes

    from jaxdip.tune import objective as objective_module

    fp = lambda obj: program_key.fingerprint(program_cache.call, (obj,))
    # a module object: by its name (its code is the tree's or a version's)
    assert fp(jnp) == fp(jnp) and fp(jnp) != fp(np)
    assert isinstance(objective_module, pytypes.ModuleType) and fp(objective_module) != fp(jnp)
    # a plain object of the project's: its attributes count
    obj = objective_module.Objective.__new__(objective_module.Objective)
    obj.__dict__.update(per_seed=None, diverged=None, seeds=np.arange(3), on_seeds=None)
    other = objective_module.Objective.__new__(objective_module.Objective)
    other.__dict__.update(per_seed=None, diverged=None, seeds=np.arange(4), on_seeds=None)
    assert fp(obj) != fp(other)


def test_jit_stores_once_and_serves_the_next_process(folder):
    from jaxdip.control.designs import lqr

    a = jnp.array([[0.0, 1.0], [2.0, -0.5]])
    b = jnp.array([[0.0], [1.0]])
    run = program_cache.jit(lqr)
    want = lqr(a, b, jnp.eye(2), jnp.eye(1))
    got = run(a, b, jnp.eye(2), jnp.eye(1))
    assert len(os.listdir(folder)) == 1
    assert_bitwise(jax.jit(lqr)(a, b, jnp.eye(2), jnp.eye(1)), got)
    np.testing.assert_allclose(np.asarray(got[0]), np.asarray(want[0]), rtol=1e-12)
    program_cache.enable(str(folder))
    again = program_cache.jit(lqr)(2.0 * a, b, jnp.eye(2), jnp.eye(1))  # new values, the same program
    assert len(os.listdir(folder)) == 1
    assert_bitwise(jax.jit(lqr)(2.0 * a, b, jnp.eye(2), jnp.eye(1)), again)


def test_a_loop_feeding_a_stored_program_its_own_outputs_compiles_it_once(folder):
    # a stored program's outputs are committed to their device; its next call must find the program the first
    # call compiled (tune's steps: value and gradient, update, value and gradient again)
    import functools

    from jaxdip.control.designs import lqr

    compiled = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda ev, d, **kw: compiled.append(kw.get("fun_name")) if ev.endswith("backend_compile_duration") else None)
    a, b, r = jnp.array([[0.0, 1.0], [2.0, -0.5]]), jnp.array([[0.0], [1.0]]), jnp.eye(1)
    design = functools.partial(lqr, a, b)
    step = program_cache.jit(design, "riccati_step")
    q = jnp.eye(2)  # uncommitted
    p1 = step(q, r)[1]
    assert len(os.listdir(folder)) == 1
    p2 = step(p1, r)[1]  # committed: the program's own output
    p3 = step(p2, r)[1]
    assert compiled.count("jit(riccati_step)") == 1, compiled
    program_cache.enable(None)
    direct = jax.jit(design)
    assert_bitwise(p3, direct(direct(direct(q, r)[1], r)[1], r)[1])


def test_a_planted_entry_cannot_run_code(folder, tmp_path):
    # an entry's output tree is a pickle: one naming a function (here one that would write a file) is refused,
    # and the call exports its program again
    r, key = rollout(), jax.random.PRNGKey(3)
    want = jd.monte_carlo(r, key, 4)
    marker = tmp_path / "planted"

    class Plant:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    for name in os.listdir(folder):
        program = (folder / name).read_bytes().split(b"\n", 1)[1]
        (folder / name).write_bytes(pickle.dumps(Plant()).hex().encode() + b"\n" + program)
    program_cache.enable(str(folder))
    assert_bitwise(want, jd.monte_carlo(r, key, 4))
    assert not marker.exists()


def test_counts_say_how_the_calls_went(folder):
    r, key = rollout(), jax.random.PRNGKey(4)
    before = program_cache.counts()
    jd.monte_carlo(r, key, 4)  # one program, exported
    program_cache.enable(str(folder))
    jd.monte_carlo(r, key, 4)  # read back
    assert program_cache.call(driver._batch_body, (object(),), "_batch") is program_cache.MISS
    after = program_cache.counts()
    assert {k: after[k] - before[k] for k in after} == {"read": 1, "exported": 1, "ordinary": 1}


SHARDED = textwrap.dedent("""
    import jax, numpy as np
    import jaxdip as jd
    from jaxdip import program_cache, program_key
    from jaxdip.scenarios.dip_lqr import dip_lqr

    assert len(jax.devices()) == 2
    r, key, folder = dip_lqr(dt=1e-3, substeps=1, duration=0.1, record_every=5), jax.random.PRNGKey(3), {folder!r}
    compiled = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda ev, d, **kw: compiled.append(kw.get("fun_name")) if ev.endswith("backend_compile_duration") else None)

    def run():
        # whole horizon, and over time in chunks (the carry laid out over the devices by the first call)
        return jd.monte_carlo(r, key, 16, shard=True), jd.monte_carlo(r, key, 16, shard=True, time_chunk=25)

    program_cache.enable(None)
    plain = run()
    program_cache.enable(folder)
    first = run()
    stored = program_cache.counts()
    program_cache.enable(folder)  # a new process: the files on disk only
    compiled.clear()
    again = run()
    served = program_cache.counts()
    for out in (first, again):
        for u, v in zip(jax.tree_util.tree_leaves(plain), jax.tree_util.tree_leaves(out)):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))
    x = jax.numpy.arange(16.0)
    mesh = jd.engine.driver.device_mesh()
    split = jax.device_put(x, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seeds")))
    try:
        keys = {{program_key.fingerprint(jd.engine.driver._batch_body, (a,)) for a in (x, split)}}
    except program_key.Unkeyable:
        keys = ()
    print(stored["exported"], stored["ordinary"], served["read"] - stored["read"],
          served["exported"] - stored["exported"], served["ordinary"] - stored["ordinary"],
          compiled.count("jit(_batch)"), len(keys))
""")


def test_sharded_batches_are_stored_and_give_the_ordinary_results_bit_for_bit(tmp_path):
    from conftest import host_devices_flags

    env = dict(os.environ, XLA_FLAGS=host_devices_flags(2), JAX_PLATFORMS="cpu")
    script = SHARDED.format(folder=str(tmp_path / "programs"))
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    exported, ordinary, read, again, ordinary_again, compiles, keys = map(int, out.stdout.split()[-7:])
    assert exported >= 3 and ordinary == 0  # every sharded batch went through the cache
    assert read == exported and again == 0 and ordinary_again == 0  # and the next process read them all
    assert compiles == exported  # each stored program compiles once, the loop over time chunks included
    assert keys == 2  # the same array on one device and over two is another program
