"""lorenz-mhe readings: the EKF's one-step prediction, the noise readings and the score alignments."""

import jaxdip  # noqa: F401  (float64)

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import jaxdip as jd
from jaxdip import config as C
from jaxdip.estimators.kf import ExtendedKalmanFilter
from jaxdip.estimators.wrappers import Prior
import experiments.lorenz_mhe as L
from jaxdip.plants import lorenz
from jaxdip.plants.lorenz import Lorenz

H = 0.001


def _lorenz_f(x):
    s, b, r = 10.0, 8.0 / 3.0, 28.0
    return np.array([s * (x[1] - x[0]), x[0] * (r - x[2]) - x[1], x[0] * x[1] - b * x[2]])


def _numpy_prediction(xbar):
    """x(h) of the model linearised at xbar, x' = f(xbar) + A (x - xbar), from scipy's expm of the augmented
    matrix; A by central differences."""
    eps = 1e-6
    A = np.stack([(_lorenz_f(xbar + eps * e) - _lorenz_f(xbar - eps * e)) / (2 * eps) for e in np.eye(3)], axis=1)
    M = np.zeros((4, 4))
    M[:3, :3], M[:3, 3] = A * H, _lorenz_f(xbar) * H
    return xbar + scipy.linalg.expm(M)[:3, 3]


def test_ekf_prior_is_the_one_step_model_prediction():
    """``Prior`` hands out the propagation of the previous posterior (checked against scipy), and the filter
    itself is the same as without it."""
    Cm = lorenz.output_matrix()
    kw = dict(Q=0.01 * jnp.eye(3), R=25.0 * jnp.eye(2), P0=jnp.eye(3), xhat0=jnp.asarray([-8.0, 7.0, 27.0]), dt=H,
              expm_squarings=3)
    post = ExtendedKalmanFilter(model=Lorenz(), C=Cm, **kw)
    prior = Prior(post)
    rng = np.random.default_rng(0)
    ys = jnp.asarray(np.array([7.0, 27.0]) + 5.0 * rng.standard_normal((30, 2)))
    step_post = jax.jit(lambda s, y, k: post.step(s, y, jnp.zeros(1), None, k))
    step_prior = jax.jit(lambda s, y, k: prior.step(s, y, jnp.zeros(1), None, k))
    sp, sq = post.init(None, None), prior.init(None, None)
    outs_post, outs_prior = [], []
    for k in range(30):
        sp, xp, _ = step_post(sp, ys[k], k)
        sq, xq, _ = step_prior(sq, ys[k], k)
        outs_post.append(np.asarray(xp))
        outs_prior.append(np.asarray(xq))
        np.testing.assert_array_equal(np.asarray(sp.x), np.asarray(sq.x))
    np.testing.assert_array_equal(outs_prior[0], [-8.0, 7.0, 27.0])  # at k = 0: the starting estimate
    for k in range(1, 30):
        np.testing.assert_allclose(outs_prior[k], _numpy_prediction(outs_post[k - 1]), rtol=1e-9, atol=1e-9)
    assert np.abs(np.asarray(outs_prior[1:]) - np.asarray(outs_post[1:])).max() > 1e-3  # not the same stream


def test_noise_readings_reach_the_loop():
    """Each reading's per-sample levels, written out by hand, are what the data and the filters get."""
    cfg = C.load(L.LorenzMheConfig, sets=["eps_reading=variance", "eta_reading=variance", "eta_time=unit_time",
                                          "ekf_eta_time=unit_time"])
    r = L.build(cfg, steps=10)
    assert float(r.loop.process_noise_std) == pytest.approx(math.sqrt(0.1) * math.sqrt(H), rel=1e-15)
    np.testing.assert_allclose(np.asarray(r.loop.sensor.white_std), [math.sqrt(5.0)] * 2, rtol=1e-15)
    ests = r.loop.estimator.estimators
    np.testing.assert_allclose(np.asarray(ests["ekf"].inner.Q), 0.1 * H * np.eye(3), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(ests["ekf"].inner.R), 5.0 * np.eye(2), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(ests["ekf2"].inner.Q), 0.005 * H * np.eye(3), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(ests["ekf2"].inner.R), 10.0 * np.eye(2), rtol=1e-14)
    # the default reading passes the printed values through untouched
    d = L.noise_levels(L.LorenzMheConfig())
    assert d == {"sigma_eps": 5.0, "sigma_eta": 0.1, "ekf_sigma_eps": 5.0, "ekf_sigma_eta": 0.1,
                 "ekf2_sigma_eps": 10.0, "ekf2_sigma_eta": 0.005}


@pytest.mark.slow  # compiles the four-estimator loop twice (~15-35 s)
def test_alignments_score_the_same_estimators():
    """Under "filtered" CPX/SCPX are scored on the current estimates that "mixed" reports as *_current, and the
    EKFs on the same filtered estimates: the estimators do not change with the alignment."""
    base = L.LorenzMheConfig(seeds=2, duration=0.2)
    key = jax.random.PRNGKey(1)
    out = {}
    for a in ("mixed", "filtered"):
        cfg = C.load(L.LorenzMheConfig, sets=["seeds=2", "duration=0.2", f"alignment={a}"])
        assert cfg.alignment == a
        out[a] = jax.tree_util.tree_map(np.asarray, jd.monte_carlo(L.build(cfg), key, base.seeds).metrics["errors"])
    m, f = out["mixed"], out["filtered"]
    np.testing.assert_allclose(f["norm"][:, :2], m["norm_cur"], rtol=1e-12)
    np.testing.assert_allclose(f["xl"][:, :2], m["xl_cur"], rtol=1e-12)
    np.testing.assert_array_equal(f["norm"][:, 2:], m["norm"][:, 2:])
    assert np.abs(f["norm"][:, :2] - m["norm"][:, :2]).max() > 1e-6  # prediction and filtered scores differ
    assert f["norm_cur"].shape == (2, 0)


@pytest.mark.parametrize("item,key", [("alignment=smoothed", "alignment"), ("eps_reading=var", "eps_reading"),
                                      ("eta_time=second", "eta_time"), ("ekf_eta_time=1", "ekf_eta_time")])
def test_bad_reading_keys_are_refused(item, key):
    with pytest.raises(C.ConfigError) as e:
        C.load(L.LorenzMheConfig, sets=[item])
    assert e.value.key == key
