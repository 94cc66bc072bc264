"""The scoring readings of twip-dmso (Stumfoll §8.1.1-§8.1.2): the per-seed metrics and the three readings of f
(153) against a plain NumPy version, the ratio summaries against direct arithmetic, the ``dt_fine_gamma`` key,
and fidelity_twip's merge of a partial run into the committed page and rows."""

import os

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import gmean

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
import experiments.twip_dmso as E
import experiments.twip_dmso.report as ER
from jaxdip.scenarios import twip_dmso as S

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _record(T=140, seed=0):
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(size=(T, 4)) * 0.01, axis=0) + np.array([1.0, 0.3, 0.17, 0.02])
    xhat = x + rng.normal(size=(T, 4)) * np.geomspace(1e-1, 1e-5, T)[:, None]
    u = rng.normal(size=T)
    fhat = rng.normal(size=(T, 2)) * 1e-3
    return {"x": x, "xhat": xhat, "u": u, "y": x, "fhat": fhat}


def _model(seed=1):
    rng = np.random.default_rng(seed)
    F = np.eye(4) + 0.01 * rng.normal(size=(4, 4))
    G = 0.01 * rng.normal(size=(4, 1))
    return F, G


def _numpy_f(rec, F, G):
    """The three readings of f (153), written out sample by sample (rows x_dot, phi_dot)."""
    x, xh, u = rec["x"], rec["xhat"], rec["u"]
    T = len(u)
    one, est, ol = np.zeros((T - 1, 4)), np.zeros((T - 1, 4)), np.zeros((T - 1, 4))
    z = x[0].copy()
    for k in range(T - 1):
        one[k] = x[k + 1] - (F @ x[k] + G[:, 0] * u[k])
        est[k] = x[k + 1] - (F @ xh[k] + G[:, 0] * u[k])
        z = F @ z + G[:, 0] * u[k]
        ol[k] = x[k + 1] - z
    rows = [1, 3]
    return np.stack([one[:, rows], est[:, rows], ol[:, rows]])


def test_f_readings_match_numpy():
    rec, (F, G) = _record(), _model()
    tr = S.trace({k: jnp.asarray(v) for k, v in rec.items()}, jnp.asarray(F), jnp.asarray(G))
    ref = _numpy_f(rec, F, G)
    np.testing.assert_allclose(np.asarray(tr["f_readings"]), ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(np.asarray(tr["f"]), np.asarray(tr["f_readings"][0]))
    assert S.F_READINGS == ("one_step", "estimated", "open_loop")


def test_seed_metrics_match_numpy():
    rec, (F, G) = _record(), _model()
    dt, tail_s, settle_s = 0.01, 0.3, 0.25
    band = np.array([1e-3, 1e-3, 1e-4, 1e-3])
    tr = S.trace({k: jnp.asarray(v) for k, v in rec.items()}, jnp.asarray(F), jnp.asarray(G))
    m = {k: np.asarray(v) for k, v in S.seed_metrics(tr, jnp.asarray(band), dt, tail_s, settle_s).items()}
    err = rec["xhat"] - rec["x"]
    T = err.shape[0]
    n1, nt, ns = 101, 30, 25
    np.testing.assert_allclose(m["peak_1s"], np.abs(err[1:n1]).max(0), rtol=1e-14)
    np.testing.assert_allclose(m["logmean_tail"], np.log10(np.abs(err[T - nt:])).mean(0), rtol=1e-12)
    fr = _numpy_f(rec, F, G)
    d = rec["fhat"][1:][None] - fr
    rms = lambda a: np.sqrt((a**2).mean(1))  # noqa: E731
    expect = {"u_rms_err": rms(d), "u_rms": rms(fr), "u_rms_err_settled": rms(d[:, ns:]),
              "u_rms_settled": rms(fr[:, ns:]), "u_peak_err": np.abs(d).max(1),
              "u_peak_err_settled": np.abs(d[:, ns:]).max(1), "u_peak": np.abs(fr).max(1),
              "u_mae_settled": np.abs(d[:, ns:]).mean(1), "u_ma_settled": np.abs(fr[:, ns:]).mean(1),
              "u_median_pointwise_settled": np.median(np.abs(d[:, ns:]) / np.abs(fr[:, ns:]), axis=1)}
    for k, v in expect.items():
        assert m[k].shape == (3, 2)
        np.testing.assert_allclose(m[k], v, rtol=1e-9, err_msg=k)
    # the one-step reading is the one the existing metrics use
    np.testing.assert_allclose(m["u_rms_err"][0], m["unc_rms_err"], rtol=1e-14)
    # convergence of fhat to f (Fig. 8.9): the first sample after which |fhat - f| stays inside p% of max |f|,
    # by a plain loop over samples (fhat - f at index i belongs to sample i + 1)
    dev = np.abs(rec["fhat"][1:] - fr[0])
    for p in (10, 25):
        want = []
        for j in range(2):
            inside = dev[:, j] <= p / 100 * np.abs(fr[0][:, j]).max()
            k = len(inside)
            while k > 0 and inside[k - 1]:
                k -= 1
            want.append((k + 1) * dt)
        np.testing.assert_allclose(m[f"unc_conv_{p}"], want, rtol=1e-12, err_msg=p)


def test_uncertainty_readings_are_per_seed_ratios():
    rng = np.random.default_rng(3)
    n = 6
    m = {k: rng.uniform(0.1, 2.0, size=(n, 3, 2)) for k in ("u_rms_err", "u_rms", "u_rms_err_settled",
                                                              "u_rms_settled", "u_peak_err", "u_peak_err_settled",
                                                              "u_peak", "u_mae_settled", "u_ma_settled",
                                                              "u_median_pointwise_settled")}
    ok = np.array([True, True, False, True, True, True])
    r = E.uncertainty_readings(m, ok)
    assert set(r) == set(S.F_READINGS)
    want = (m["u_peak_err_settled"] / m["u_peak"])[ok, 1, 0].mean()  # estimated f, x_dot row
    assert r["estimated"]["peak_over_peak_settled"]["x_dot"] == pytest.approx(want, rel=1e-14)
    want = (m["u_rms_err"] / m["u_rms"])[ok, 2, 1].mean()  # open-loop f, phi_dot row
    assert r["open_loop"]["rel_rms"]["phi_dot"] == pytest.approx(want, rel=1e-14)


def _est(vals):
    return dict(zip(E.STATES, vals))


def test_comparison_readings():
    dm = {"rms_error_first_1s": _est([1.0, 2.0, 4.0, 8.0]), "peak_error_first_1s": _est([1.0, 1.0, 1.0, 1.0]),
          "rms_error": _est([1.0, 1.0, 1.0, 1.0]), "logmean_error_tail": _est([-5.0, -5.0, -5.0, -5.0])}
    kf = {"rms_error_first_1s": _est([10.0, 1.0, 40.0, 16.0]), "peak_error_first_1s": _est([2.0, 3.0, 4.0, 5.0]),
          "rms_error": _est([0.5, 1.0, 2.0, 3.0]), "logmean_error_tail": _est([-4.0, -4.0, -4.0, -6.0])}
    c = ER.comparison_readings(dm, kf)
    ratio = [10.0, 0.5, 10.0, 2.0]
    assert list(c["first_1s_rms_ratio_kf_over_dmso"].values()) == ratio
    assert c["first_1s_rms_ratio_means"]["all"]["geometric"] == pytest.approx(gmean(ratio), rel=1e-14)
    assert c["first_1s_rms_ratio_means"]["all"]["arithmetic"] == pytest.approx(np.mean(ratio), rel=1e-14)
    assert c["first_1s_rms_ratio_means"]["uncertain"]["geometric"] == pytest.approx(1.0, rel=1e-14)
    assert c["dmso_smaller_first_1s_rms"] == _est([True, False, True, True])
    assert c["dmso_smaller_first_1s_peak"] == _est([True] * 4)
    assert c["dmso_smaller_run_rms"] == _est([False, False, True, True])
    assert c["kf_lower_log_tail_tilt_rate"] is True


def test_uncertainty_ratio_readings():
    def case(dt, gamma, rms):
        one = {k: {"x_dot": rms, "phi_dot": 2 * rms} for k in ("rms_error", "rms_error_settled",
                                                               "peak_error_settled", "rel_rms", "rel_rms_settled")}
        return {"dt": dt, "gamma": gamma, "dmso": {"uncertainty_readings": {"one_step": one}}}

    r = ER.uncertainty_ratio_readings(case(0.01, 0.1, 3.0), case(0.001, 0.5, 0.05))
    assert r["gamma"] == {"coarse": 0.1, "fine": 0.5}
    assert r["rms_error"]["x_dot"] == pytest.approx(60.0) and r["rms_error"]["geometric"] == pytest.approx(60.0)
    assert r["rms_error_per_unit_time"]["phi_dot"] == pytest.approx(6.0)
    assert "rel_rms_per_unit_time" not in r


def test_dt_fine_gamma_key():
    cfg = C.load(E.TwipDmsoConfig, sets=["cases=[\"param\"]", "dt_fine_gamma=variant", "dmso_gamma_variant=0.7"])
    fine = {s.name: s for s in E.case_specs(cfg)}["param_dt_fine"]
    assert fine.gamma == 0.7
    cfg = C.load(E.TwipDmsoConfig, sets=["cases=[\"param\"]"])
    assert {s.name: s for s in E.case_specs(cfg)}["param_dt_fine"].gamma == cfg.dmso_gamma
    with pytest.raises(C.ConfigError, match="dt_fine_gamma"):
        C.load(E.TwipDmsoConfig, sets=["dt_fine_gamma=fine"])


def test_loads_count_only_the_cases_that_run():
    nominal = C.load(E.TwipDmsoConfig, sets=["cases=[\"nominal\"]"]).loads()
    assert nominal[0].trajectories == 0 and nominal[1].steps == 2000
    full = C.load(E.TwipDmsoConfig).loads()
    assert full[0].trajectories == 1000 and full[0].steps == 2000 and full[1].steps == 20000

