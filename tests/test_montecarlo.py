"""Reproducibility of the original Monte Carlo loop (``jaxdip.sim.montecarlo``, kept until every experiment runs
on ``jaxdip.monte_carlo``): same key, same numbers, however the seeds are batched."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np

from jaxdip import config as C
from jaxdip.control import feedback_params, lqr, state_feedback
from jaxdip.estimators import passthrough
from jaxdip.experiments import dip_lqr
from jaxdip.experiments.common import ball_sampler, weight_matrix
from jaxdip.plants import dip
from jaxdip.sim import Loop, LoopParams, linearize, montecarlo, sensors


def _cfg(**kw):
    base = {"seeds": 8, "duration": 0.3, "record_every": 1}
    base.update(kw)
    return C.load(dip_lqr.DipLqrConfig, quick=base)


def legacy_build(cfg):
    """dip-lqr's loop in the original Loop/LoopParams form: (loop, params, x0 sampler, periods)."""
    import jax.numpy as jnp

    plant = dip.make(cfg.variant)
    p = plant.default_params()
    A, B = linearize(plant.f, p, jnp.zeros(6), 0.0)
    K, _, _ = lqr(A, B, weight_matrix("Q", cfg.Q, 6), cfg.R)
    n_steps = int(round(cfg.duration / cfg.dt))
    loop = Loop(plant=plant, dt=cfg.dt, sensor=sensors.linear_sensor(cfg.dt), estimator=passthrough,
                controller=state_feedback(), substeps=cfg.substeps, tail_steps=min(n_steps, int(round(1.0 / cfg.dt))))
    params = LoopParams(plant=p, sensor=sensors.full_state_params(6, white_std=jnp.asarray(cfg.noise_std)),
                        estimator=(), controller=feedback_params(K), state_bound=jnp.asarray(cfg.state_bound))
    return loop, params, ball_sampler(jnp.zeros(6), cfg.init_radius), n_steps


def test_seed_alone_equals_seed_in_batch_of_1024():
    cfg = _cfg(seeds=1024)
    loop, params, x0_fn, n = legacy_build(cfg)
    key = jax.random.PRNGKey(7)
    batch = montecarlo.run(loop, params, x0_fn, key, 1024, n, record_every=1, record_fn=lambda r: r.x,
                           progress=False)
    for i in (0, 517, 1023):
        alone = montecarlo.run(loop, params, x0_fn, key, 1, n, record_every=1, record_fn=lambda r: r.x,
                               seed_offset=i, progress=False)
        np.testing.assert_allclose(alone.records[0], batch.records[i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(alone.carry.x[0], batch.carry.x[i], rtol=0, atol=1e-12)


def test_chunking_does_not_change_results():
    cfg = _cfg()
    loop, params, x0_fn, n = legacy_build(cfg)
    key = jax.random.PRNGKey(1)
    a = montecarlo.run(loop, params, x0_fn, key, 8, n, chunk_steps=n, progress=False)
    b = montecarlo.run(loop, params, x0_fn, key, 8, n, chunk_steps=70, progress=False)
    np.testing.assert_array_equal(np.asarray(a.carry.x), np.asarray(b.carry.x))
    np.testing.assert_array_equal(np.asarray(a.carry.stats.sum_x2), np.asarray(b.carry.stats.sum_x2))


def test_different_seeds_differ_and_keys_matter():
    cfg = _cfg()
    loop, params, x0_fn, n = legacy_build(cfg)
    a = montecarlo.run(loop, params, x0_fn, jax.random.PRNGKey(0), 8, n, progress=False)
    b = montecarlo.run(loop, params, x0_fn, jax.random.PRNGKey(1), 8, n, progress=False)
    xa = np.asarray(a.carry.x)
    assert not np.allclose(xa, np.asarray(b.carry.x))
    assert len({tuple(np.round(r, 12)) for r in xa}) == 8


def test_divergence_is_marked_and_frozen():
    # a destabilising gain: the pendulum falls, the trajectory is frozen at the last in-bound state
    cfg = _cfg(seeds=4, duration=2.0)
    loop, params, x0_fn, n = legacy_build(cfg)
    params = params._replace(controller=params.controller._replace(K=-params.controller.K))
    res = montecarlo.run(loop, params, x0_fn, jax.random.PRNGKey(0), 4, n, record_every=1,
                         record_fn=lambda r: r.x, progress=False)
    assert np.all(np.asarray(res.carry.diverged))
    at = np.asarray(res.carry.diverged_at)
    rec = np.asarray(res.records)
    for i in range(4):
        assert 0 < at[i] < n
        frozen = rec[i, at[i]:]
        assert np.all(np.isfinite(frozen))
        np.testing.assert_array_equal(frozen, np.broadcast_to(frozen[0], frozen.shape))
        assert np.all(np.abs(frozen[0]) <= np.asarray(cfg.state_bound))
    # x_{at} left the bound, so period at-1 (which produced it) is the first one left out of the statistics
    assert np.all(np.asarray(res.carry.stats.count) == at - 1)


SHARD_SCRIPT = textwrap.dedent(
    """
    import sys
    import jax, numpy as np
    sys.path.insert(0, sys.argv[1])
    import jaxdip
    from jaxdip import config as C
    from jaxdip.experiments import dip_lqr
    from jaxdip.sim import montecarlo
    from test_montecarlo import legacy_build
    assert jax.device_count() == 8, jax.devices()
    cfg = C.load(dip_lqr.DipLqrConfig, quick={"seeds": 20, "duration": 0.3, "record_every": 1})
    loop, params, x0_fn, n = legacy_build(cfg)
    key = jax.random.PRNGKey(3)
    kw = dict(record_every=1, record_fn=lambda r: r.x, progress=False)
    one = montecarlo.run(loop, params, x0_fn, key, 20, n, shard=False, **kw)
    many = montecarlo.run(loop, params, x0_fn, key, 20, n, shard=True, **kw)
    assert len(many.carry.x.sharding.device_set) == 8 or many.carry.x.shape[0] == 20
    err = float(np.max(np.abs(np.asarray(one.records) - np.asarray(many.records))))
    print("max_abs_diff", err)
    assert err <= 1e-12, err
    """
)


def test_sharded_over_8_host_devices_equals_single_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=8", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", SHARD_SCRIPT, os.path.dirname(__file__)], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "max_abs_diff" in out.stdout
