"""jd.summary and jaxdip.stats.t_interval against a plain NumPy/SciPy computation: a real Monte Carlo of the DIP
(Kalman filter and LQR) started far enough from upright that most seeds leave the state bound, so the masking of
diverged seeds decides the numbers."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats as sps

import jaxdip as jd
from jaxdip.stats import t_interval, t_quantile


def scipy_interval(values):
    """The reference: SciPy's t interval of the selected per-seed values."""
    v = np.asarray(values, dtype=np.float64)
    return v.mean(axis=0), *sps.t.interval(0.95, v.shape[0] - 1, loc=v.mean(axis=0), scale=sps.sem(v, axis=0))


@pytest.fixture(scope="module")
def run():
    plant, dt, I = jd.plants.DIP(), 0.001, jnp.eye(6)
    A, B = jd.linearize(plant)
    m = jd.zoh(A, B, dt)
    K, _, _ = jd.control.lqr(A, B, jnp.diag(jnp.array([30.0, 350, 100, 0, 0, 0])), 0.1)
    std = jnp.array([1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2])
    kf = jd.estimators.KalmanFilter(m.Phi, m.W, C=I, Q=1e-9 * I, R=jnp.diag(std**2), P0=1e-3 * I)
    loop = jd.Loop(plant, sensor=jd.sensors.WhiteNoise(std), estimator=kf, controller=jd.control.StateFeedback(K),
                   dt=dt, state_bound=1.0)
    metrics = {"theta": jd.metrics.RMS(lambda s: s.x[2]), "error": jd.metrics.RMS(lambda s: s.xhat - s.x),
               "x": jd.metrics.Moments("x")}
    sol = jd.monte_carlo(jd.Rollout(loop, x0=jd.Ball(jnp.zeros(6), 0.1), steps=300, metrics=metrics), 0, 64)
    return plant, sol


def test_summary_masks_diverged_seeds_and_matches_scipy(run):
    plant, sol = run
    codes = np.asarray(sol.result)
    ok = codes == jd.RESULTS.ok
    assert 5 < ok.sum() < 60  # both live and diverged seeds, so the mask matters
    s = jd.summary(sol, plant)
    assert s.seeds == 64 and s.failed == int((~ok).sum())
    assert s.codes == {r.name: int((codes == r).sum()) for r in jd.RESULTS}
    assert set(s) == {"theta", "error", "x.count", "x.mean", "x.var", "x.mean_abs", "x.var_abs", "x.mean_sq"}
    for path, metric in s.items():
        leaf = sol.metrics
        for part in path.split("."):
            leaf = leaf[part]
        if path == "x.count":  # every live seed ran all 300 periods: no spread, the interval is the point
            np.testing.assert_array_equal([metric.mean, metric.lo, metric.hi], [300, 300, 300])
            continue
        mean, lo, hi = scipy_interval(np.asarray(leaf)[ok])
        np.testing.assert_allclose(metric.mean, mean, rtol=1e-12, err_msg=path)
        np.testing.assert_allclose(metric.lo, lo, rtol=1e-10, err_msg=path)
        np.testing.assert_allclose(metric.hi, hi, rtol=1e-10, err_msg=path)
        assert np.all(metric.n == ok.sum())
    # the diverged seeds would move the mean: the mask is not a no-op
    assert not np.isclose(s["theta"].mean, np.mean(np.asarray(sol.metrics["theta"])))


def test_summary_is_indexed_by_state_name(run):
    plant, sol = run
    s = jd.summary(sol, plant)
    i = plant.index("theta")
    err = s["error"]["theta"]
    assert err.mean == s["error"].mean[i] and (err.lo, err.hi) == (s["error"].lo[i], s["error"].hi[i])
    assert jd.summary(sol, plant.state_names)["x.var"]["alpha_dot"].mean == s["x.var"].mean[plant.index("alpha_dot")]
    with pytest.raises(KeyError, match="states are"):
        s["error"]["phi"]
    with pytest.raises(KeyError, match="no state axis"):
        s["theta"]["theta"]  # a scalar metric
    with pytest.raises(KeyError, match="metrics are"):
        s["rms"]
    text = repr(s)
    assert "failed" in text and "error[theta_dot]" in text and text.count("\n") + 1 == 2 + 2 + 6 * 6  # head, theta, x.count, 6 vectors


def test_summary_of_a_metrics_pytree_with_result_codes_and_a_sweep_axis():
    # synthetic per-seed values in a (sweep, seed) layout, as monte_carlo's sweep= returns them
    rng = np.random.default_rng(1)
    values = rng.normal(size=(3, 40, 2))
    codes = rng.choice([0, 0, 0, 1, 2], size=(3, 40))
    s = jd.summary({"v": values}, ("a", "b"), result=codes, axis=1)
    for j in range(3):
        mean, lo, hi = scipy_interval(values[j][codes[j] == 0])
        np.testing.assert_allclose([s["v"].mean[j], s["v"].lo[j], s["v"].hi[j]], [mean, lo, hi], rtol=1e-12)
        assert s.failed[j] == (codes[j] != 0).sum()
    np.testing.assert_array_equal(s["v"]["b"].mean, s["v"].mean[:, 1])
    # no result: nothing masked; one live seed: a mean, no interval; none: NaN
    np.testing.assert_allclose(jd.summary(values[0])["metric"].mean, values[0].mean(axis=0), rtol=1e-12)
    m, lo, hi, n = t_interval([1.0, 2.0, 3.0], [False, True, False])
    assert (m, n) == (2.0, 1) and np.isnan(lo) and np.isnan(hi)
    assert np.isnan(t_interval([1.0, 2.0], [False, False])[0])
    with pytest.raises(ValueError, match="result must have 40 seeds along axis 1"):
        jd.summary({"v": values}, result=codes[:, :5], axis=1)


@pytest.mark.parametrize("df", [1, 2, 3, 4, 7, 30, 63, 255, 999, 1001, 4095, 10**6])
@pytest.mark.parametrize("level", [0.9, 0.95, 0.99])
def test_t_quantile_matches_scipy(df, level):
    assert t_quantile(level, df) == pytest.approx(sps.t.ppf(0.5 + level / 2, df), rel=1e-13)


def test_stats_is_public():
    import jaxdip.stats

    assert jd.stats is jaxdip.stats and "stats" in dir(jd) and "summary" in dir(jd)
