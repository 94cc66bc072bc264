"""A closed loop whose sensor drops samples: the engine's Kalman filter with nan_missing equals the offline
masked filter over the recorded readings; the loss rate and pattern are as stated."""

import numpy as np
import pytest

import jax
import jax.numpy as jnp

import jaxdip as jd
from jaxdip.engine.checks import ArgumentError
from jaxdip.estimators.recorded import kalman_filter
from jaxdip.sim.sensors import Dropout
from tests.test_simulate import make_loop

STEPS = 150


def _run(sensor, key=3, nan_missing=True):
    loop = make_loop()
    est = loop.estimator
    kf = jd.estimators.KalmanFilter(est.Phi, est.W, est.C, est.Q, est.R, est.P0, est.xhat0, nan_missing=nan_missing)
    loop = jd.Loop(plant=loop.plant, sensor=sensor, estimator=kf, controller=loop.controller, actuator=loop.actuator,
                   dt=loop.dt, substeps=loop.substeps, process_noise_std=loop.process_noise_std,
                   state_bound=loop.state_bound)
    sol = jd.simulate(loop, jnp.array([0.1, 0.0]), jax.random.PRNGKey(key), STEPS,
                      save=lambda s: (s.y, s.xhat, s.u, s.aux.sensor[1]))
    return kf, sol


def test_closed_loop_with_dropped_packets_equals_the_offline_masked_filter():
    kf, sol = _run(Dropout(jd.sensors.WhiteNoise(jnp.array([0.01, 0.05])), 0.3, per_component=True))
    ys, xhat, us, delivered = (np.asarray(a) for a in sol.saved)
    assert np.array_equal(np.isnan(ys), ~delivered)
    assert 0 < np.mean(~delivered) < 1 and np.all(np.isfinite(xhat))
    off = kalman_filter(kf, ys, us, nan_missing=True)
    np.testing.assert_allclose(xhat, off.mean, rtol=0, atol=1e-12)
    # the same readings with the NaNs replaced and the losses given as a mask
    off2 = kalman_filter(kf, np.where(delivered, ys, 0.0), us, mask=delivered)
    np.testing.assert_allclose(xhat, off2.mean, rtol=0, atol=1e-12)
    # without nan_missing the first lost sample poisons the estimate from then on
    _, sol_bad = _run(Dropout(jd.sensors.WhiteNoise(jnp.array([0.01, 0.05])), 0.3, per_component=True),
                      nan_missing=False)
    first = int(np.argmax(~delivered.all(axis=1)))
    assert np.all(np.isnan(np.asarray(sol_bad.saved[1])[first:]))


def test_dropout_keeps_the_wrapped_readings_and_loses_at_rate_p():
    inner = jd.sensors.WhiteNoise(jnp.array([0.01, 0.05]))
    x = jnp.array([0.3, -0.2])
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    step = jax.vmap(lambda k: Dropout(inner, 0.2).step((), x, k, 0)[1])
    ys = np.asarray(step(keys))
    lost = np.isnan(ys).all(axis=1)
    assert np.array_equal(np.isnan(ys).any(axis=1), lost)  # whole samples are lost
    assert abs(lost.mean() - 0.2) < 4 * np.sqrt(0.2 * 0.8 / ys.shape[0])
    ref = np.asarray(jax.vmap(lambda k: inner.step((), x, k, 0)[1])(keys))
    np.testing.assert_array_equal(ys[~lost], ref[~lost])


def test_dropout_pattern_is_deterministic_and_bad_arguments_are_refused():
    pattern = np.array([[True, True], [False, True], [False, False]])
    sens = Dropout(jd.sensors.WhiteNoise(0.0), pattern=pattern)
    ys = np.stack([np.asarray(sens.step((), jnp.ones(2), jax.random.PRNGKey(k), k)[1]) for k in range(6)])
    np.testing.assert_array_equal(~np.isnan(ys), np.concatenate([pattern, pattern]))
    with pytest.raises(ArgumentError, match="probability"):
        Dropout(jd.sensors.WhiteNoise(0.0), 1.5)
    with pytest.raises(ArgumentError, match="pattern"):
        Dropout(jd.sensors.WhiteNoise(0.0), pattern=np.ones(3))
