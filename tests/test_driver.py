"""``jaxdip.monte_carlo``: a seed's numbers do not depend on batching, chunking or sharding; sweeps compile once."""

import os
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from conftest import host_devices_flags

STEPS = 200


def save_x(s):
    return s.x


def dip_rollout(steps=STEPS, save_every=1, save=save_x, **loop_kw):
    """The dip-lqr loop (printed DIP, LQR, white noise) with the library's components."""
    plant = jd.plants.DIP()
    K, _, _ = jd.control.lqr(*jd.linearize(plant), np.diag([30.0, 350, 100, 0, 0, 0]), 0.1)
    loop = jd.Loop(plant=plant, sensor=jd.sensors.WhiteNoise(jnp.array([1e-3] * 3 + [1e-2] * 3)),
                   estimator=jd.Passthrough(), controller=jd.control.StateFeedback(K), dt=0.001,
                   state_bound=jnp.array([1.0, 1.5708, 1.5708, np.inf, np.inf, np.inf]), **loop_kw)
    metrics = {"x": jd.metrics.Moments("x"), "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=steps - 50)}
    return jd.Rollout(loop, jd.Ball(jnp.zeros(6), 0.05), steps, save=save, save_every=save_every,
                      metrics=metrics)


def assert_same(a, b, rtol=1e-12):
    """Equal up to rounding: different batch shapes vectorise the same arithmetic differently (last-bit
    differences), so "the same trajectory" is checked to 1e-12 of each array's largest entry."""
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for u, v in zip(la, lb):
        u, v = np.asarray(u), np.asarray(v)
        assert u.shape == v.shape and u.dtype == v.dtype
        if u.dtype.kind in "biu":
            np.testing.assert_array_equal(u, v)
        else:
            assert np.max(np.abs(u - v), initial=0.0) <= rtol * np.max(np.abs(v), initial=0.0), (u, v)


def take(tree, i):
    return jax.tree_util.tree_map(lambda a: a[i:i + 1], tree)


def test_seed_alone_in_a_batch_and_chunked_over_seeds_and_time():
    r = dip_rollout()
    key = jax.random.PRNGKey(7)
    batch = jd.monte_carlo(r, key, 1024)
    assert batch.saved.shape == (1024, STEPS, 6) and batch.result.shape == (1024,)
    assert np.all(np.asarray(batch.result) == jd.RESULTS.ok)
    for i in (0, 517, 1023):
        assert_same(jd.monte_carlo(r, key, 1, offset=i), take(batch, i))
    chunked = jd.monte_carlo(r, key, 1024, chunk=300, time_chunk=30, progress=True)  # 4 calls, the last padded
    assert_same(chunked, batch)
    # a different base key gives different trajectories, and seeds differ from each other
    other = jd.monte_carlo(r, jax.random.PRNGKey(8), 1)  # one seed: the single-seed program above, no new compile
    assert not np.allclose(np.asarray(other.final.x), np.asarray(batch.final.x[:1]))
    assert len({tuple(np.round(x, 12)) for x in np.asarray(batch.final.x[:64])}) == 64


def test_seed_key_and_initial_state_convention():
    r = dip_rollout(steps=10)
    key = jax.random.PRNGKey(3)
    sol = jd.monte_carlo(r, key, 5)
    for i in range(5):
        sk = jax.random.fold_in(key, i)
        x0 = jd.Ball(jnp.zeros(6), 0.05)(jax.random.fold_in(sk, 0))
        np.testing.assert_allclose(np.asarray(sol.saved[i, 0]), np.asarray(x0), rtol=1e-14)
        one = eqx.filter_jit(jd.simulate)(r.loop, x0, sk, 10, save=save_x, metrics=r.metrics)
        assert_same(take(sol, i), jax.tree_util.tree_map(lambda a: a[None], one))


def test_generic_function_of_a_key():
    key = jax.random.PRNGKey(0)
    out = jd.monte_carlo(lambda k: {"z": jax.random.normal(k, (3,))}, key, 10, chunk=4)
    ref = np.stack([np.asarray(jax.random.normal(jax.random.fold_in(key, i), (3,))) for i in range(10)])
    np.testing.assert_array_equal(np.asarray(out["z"]), ref)
    # an int seed is PRNGKey(seed)
    np.testing.assert_array_equal(np.asarray(jd.monte_carlo(lambda k: jax.random.normal(k, (3,)), 0, 10)), ref)


class Gaussian(eqx.Module):
    """A toy Monte Carlo target with one hyperparameter; counts how often it is traced."""

    mean: jax.Array = jd.param(0.0)
    scale: jax.Array = jd.param(1.0)
    traces = [0]

    def __call__(self, key):
        Gaussian.traces[0] += 1
        return self.mean + self.scale * jax.random.normal(key, (2,))


def test_sweep_compiles_once_and_equals_separate_runs():
    Gaussian.traces[0] = 0
    key = jax.random.PRNGKey(1)
    means = jnp.array([0.0, 1.0, -2.0, 5.0])
    swept = jd.monte_carlo(Gaussian(), key, 9, chunk=4, sweep=(lambda g: g.mean, means))  # 3 calls
    assert swept.shape == (4, 9, 2)
    assert Gaussian.traces[0] == 1
    for j, m in enumerate(means):
        np.testing.assert_allclose(np.asarray(swept[j]), np.asarray(jd.monte_carlo(Gaussian(m), key, 9, chunk=4)),
                                   rtol=1e-14)
    # the unswept program, traced once for all four values
    assert Gaussian.traces[0] == 2
    # several leaves at once
    both = jd.monte_carlo(Gaussian(), key, 9, sweep=(lambda g: (g.mean, g.scale), (means, jnp.zeros(4))))
    np.testing.assert_array_equal(np.asarray(both), np.broadcast_to(np.asarray(means)[:, None, None], (4, 9, 2)))


class Indexed(eqx.Module):
    """A trial of (key, seed index): a per-seed value and a 'trajectory' (the detail)."""

    scale: jax.Array = jd.param(2.0)

    def __call__(self, key, i):
        traj = self.scale * jnp.arange(5.0) + jax.random.normal(key, (5,))
        return {"i": i, "last": traj[-1]}, traj


def detail(out):
    return out[0], out[1]


def test_index_and_detail_equal_the_plain_runs():
    """``index=True`` hands the seed index; ``detail`` keeps the first seed's part only. Against the plain
    per-seed outputs of the same function (no index, no detail), chunked, padded and swept."""
    key = jax.random.PRNGKey(3)
    f = Indexed()
    per, traj0 = jd.monte_carlo(f, key, 7, chunk=3, index=True, detail=detail)  # 3 calls, the last padded
    np.testing.assert_array_equal(np.asarray(per["i"]), np.arange(7))
    full = jd.monte_carlo(lambda k: f(k, 0), key, 7)  # the same keys, every trajectory kept
    np.testing.assert_allclose(np.asarray(per["last"]), np.asarray(full[1][:, -1]), rtol=1e-15)
    np.testing.assert_allclose(np.asarray(traj0), np.asarray(full[1][0]), rtol=1e-15)
    # with an offset the detail is that of the run's first seed
    _, traj3 = jd.monte_carlo(f, key, 2, offset=3, index=True, detail=detail)
    np.testing.assert_allclose(np.asarray(traj3), np.asarray(full[1][3]), rtol=1e-15)
    # swept: one detail per sweep entry
    scales = jnp.array([1.0, -4.0])
    per_s, traj_s = jd.monte_carlo(f, key, 4, index=True, detail=detail, sweep=(lambda g: g.scale, scales))
    assert traj_s.shape == (2, 5) and per_s["last"].shape == (2, 4)
    for j, c in enumerate(scales):
        np.testing.assert_allclose(np.asarray(traj_s[j]), np.asarray(Indexed(c)(jax.random.fold_in(key, 0), 0)[1]),
                                   rtol=1e-15)
    with pytest.raises(ValueError, match="Rollout"):
        jd.monte_carlo(dip_rollout(steps=10), key, 2, index=True)


def test_rollout_sweep_over_a_hyperparameter_compiles_once():
    traces = [0]

    def save(s):
        traces[0] += 1
        return s.x[1:3]

    r = dip_rollout(steps=100, save=save)
    where = lambda r: r.loop.sensor.std  # noqa: E731
    stds = jnp.stack([s * r.loop.sensor.std for s in (0.0, 1.0, 5.0)])
    swept = jd.monte_carlo(r, jax.random.PRNGKey(2), 6, chunk=3, sweep=(where, stds))
    assert traces[0] == 1
    assert swept.saved.shape == (3, 6, 100, 2)
    for j in range(3):
        alone = jd.monte_carlo(eqx.tree_at(where, r, stds[j]), jax.random.PRNGKey(2), 6, chunk=3)
        assert_same(jax.tree_util.tree_map(lambda a: a[j], swept), alone)
    assert traces[0] == 2
    # the noise level mattered
    assert float(jnp.max(jnp.abs(swept.saved[0] - swept.saved[2]))) > 1e-4


def test_grad_through_monte_carlo_matches_central_differences():
    r = dip_rollout(steps=30, substeps=1)  # one RK4 step per period: a smaller program to differentiate
    key = jax.random.PRNGKey(4)

    def cost(scale):
        rr = eqx.tree_at(lambda r: r.loop.controller.K, r, scale * r.loop.controller.K)
        sol = jd.monte_carlo(rr, key, 16, chunk=8)
        return jnp.mean(sol.metrics["x"]["mean_sq"][:, 1])

    g = jax.grad(cost)(1.0)
    h = 1e-5
    fd = (cost(1.0 + h) - cost(1.0 - h)) / (2 * h)
    assert abs(float(g)) > 1e-9
    np.testing.assert_allclose(float(g), float(fd), rtol=1e-5)


def test_bad_arguments():
    r = dip_rollout(steps=10)
    with pytest.raises(ValueError, match="n must be"):
        jd.monte_carlo(r, 0, 0)
    with pytest.raises(ValueError, match="multiple of save_every"):
        dip_rollout(steps=10, save_every=3)


def lorenz_rollout(steps=50):
    """A cheap closed loop (Lorenz, 3 states, one RK4 step a period) that compiles in about a second: how seeds are
    split over devices and calls does not depend on the plant."""
    loop = jd.Loop(plant=jd.plants.Lorenz(), sensor=jd.sensors.WhiteNoise(jnp.array(0.5)),
                   estimator=jd.Passthrough(), controller=jd.control.ConstantInput(jnp.zeros(1)), dt=0.01,
                   substeps=1, process_noise_std=0.01)
    metrics = {"x": jd.metrics.Moments("x"), "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=steps - 10)}
    return jd.Rollout(loop, jd.Ball(jnp.array([1.0, 1.0, 20.0]), 0.5), steps, save=save_x, metrics=metrics)


SHARD_SCRIPT = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp, numpy as np
    import jaxdip as jd
    from test_driver import assert_same, dip_rollout, lorenz_rollout
    assert jax.device_count() == 8, jax.devices()
    r = dip_rollout(steps=100) if sys.argv[1] == "dip" else lorenz_rollout(steps=100)
    key = jax.random.PRNGKey(3)
    compiled = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda ev, d, **kw: compiled.append(kw.get("fun_name")) if ev.endswith("backend_compile_duration") else None)
    one = jd.monte_carlo(r, key, 20, shard=False)
    compiled.clear()
    many = jd.monte_carlo(r, key, 20, shard=True, chunk=16, time_chunk=25)  # 2 calls of 16, padded
    assert len(many.saved.sharding.device_set) == 8, many.saved.sharding
    assert_same(one, many)
    # one program each for the start, a chunk of periods and the metrics: the second chunk and the second call
    # find the first's program (the carry is laid out the same way each time)
    assert compiled.count("jit(_batch)") == 3, compiled
    where = lambda r: r.loop.sensor.std
    stds = jnp.stack([0.5 * r.loop.sensor.std, 2.0 * r.loop.sensor.std])
    sw1 = jd.monte_carlo(r, key, 20, shard=False, sweep=(where, stds))
    sw8 = jd.monte_carlo(r, key, 20, shard=True, sweep=(where, stds))
    assert_same(sw1, sw8)
    compiled.clear()
    sw8t = jd.monte_carlo(r, key, 20, shard=True, sweep=(where, stds), time_chunk=25)  # seeds on axis 1
    assert_same(sw1, sw8t)
    assert compiled.count("jit(_batch)") == 3, compiled
    print("max_abs_diff", float(np.max(np.abs(np.asarray(one.saved) - np.asarray(many.saved)))))
    """
)


def run_sharded(rollout):
    # the script imports this module: the tests folder on the child's PYTHONPATH
    env = dict(os.environ, XLA_FLAGS=host_devices_flags(8), JAX_PLATFORMS="cpu", PYTHONPATH=os.path.dirname(__file__))
    out = subprocess.run([sys.executable, "-c", SHARD_SCRIPT, rollout], env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "max_abs_diff" in out.stdout


def test_sharded_over_8_host_devices_equals_single_device():
    """Seeds split over 8 devices, over calls (padded) and over time chunks, and a sweep over 8 devices, give the
    one-device numbers; on a cheap loop (the DIP version below is the same check at about 2.5x the time)."""
    run_sharded("lorenz")


@pytest.mark.slow
def test_sharded_dip_lqr_loop_over_8_host_devices_equals_single_device():
    run_sharded("dip")
