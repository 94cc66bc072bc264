"""The fidelity readings' supporting experiments (twip-transients, twip-allan, rwp-remark3, thesis-theory): each
runs through the CLI at a tiny scale and writes the contract's folder; one number of each is derived again
independently (SciPy's DOP853 for the swing, a NumPy Kalman-filter loop for the overshoot, the white-noise and
random-walk Allan laws, a per-seed paired difference outside the Monte Carlo driver, zeta from SciPy's CARE and a
root finder); and a plain ``reproduce`` leaves ``reproduce=False`` experiments out while ``--only`` runs them."""

import json
import math
from dataclasses import dataclass

import jax
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from jaxdip import cli
from jaxdip import config as C
from jaxdip.runner import Experiment, Outcome, registry

IDS = ("twip-transients", "twip-allan", "rwp-remark3", "thesis-theory")
TINY = {
    "twip-transients": ["duration=3.0", "estimators=[\"kf\"]", "bands=[0.5]", "swing_angles=[10.0, 20.0]",
                        "swing_duration=14.0"],
    "twip-allan": ["records=2", "hours=0.02", "clusters=6", "encoder_duration=5.0"],
    "rwp-remark3": ["seeds=4", "duration=1.0", "tail=0.5", "wheel_biases=[0.5]"],
    "thesis-theory": ["trials=2", "lorenz_steps=20", "dip_steps=20", "rp_trials=2"],
}


def _run(exp_id, tmp_path, sets=()):
    out = tmp_path / exp_id
    argv = ["run", exp_id, "--out", str(out)]
    for s in [*TINY[exp_id], *sets]:
        argv += ["--set", s]
    assert cli.main(argv) == 0
    for name in ("metrics.json", "report.md", "config.toml"):
        assert (out / name).is_file(), name
    m = json.loads((out / "metrics.json").read_text())
    assert m["experiment"] == exp_id and m["dtype"] == "float64"
    return m["results"], (out / "report.md").read_text(), out


def test_marked_out_of_a_plain_reproduce():
    reg = registry()
    for exp_id in IDS:
        assert exp_id in reg and reg[exp_id].reproduce is False


@pytest.fixture(scope="module")
def transients(tmp_path_factory):
    return _run("twip-transients", tmp_path_factory.mktemp("tr"))


def test_twip_transients_contract(transients):
    r, report, out = transients
    assert (out / "swing.png").is_file() and (out / "closed_loop.png").is_file()
    assert [(e["estimator"], e["how"]) for e in r["settling"]] == [("kf", "stays"), ("kf", "first reaches")]
    # "first reaches" can never be later than "stays"
    s, f = r["settling"]
    assert not s["reached"] or (f["reached"] and f["time_s"] <= s["time_s"])
    assert s["holds"] == (s["reached"] and abs(s["time_s"] - 15.0) <= 2.0)
    assert set(r["overshoot"]) == {"kf"} and r["overshoot"]["kf"]["deg"] >= 0
    assert "| kf |" in report and "Fig. 5.5" in report


def test_twip_transients_swing_against_dop853(transients):
    """The swing's readings from SciPy's DOP853 and the plain definitions (period from zero crossings rather
    than peaks, amplitude as the largest |theta| in the windows, the first sample where the cart has moved)."""
    from jaxdip.plants import twip

    r, _, _ = transients
    p = twip.TWIP()
    f = jax.jit(lambda s: twip.f(p, s, jax.numpy.zeros(1)))
    rhs = lambda _t, s: np.asarray(f(s))  # noqa: E731
    for sw in r["swing"]:
        T, dt = sw["end_s"], 0.01
        t = np.arange(int(round(T / dt)) + 1) * dt
        x0 = [0.0, 0.0, math.radians(sw["start_deg"]) - math.pi, 0.0]
        sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", rtol=1e-11, atol=1e-12, t_eval=t)
        th = np.degrees(np.angle(np.exp(1j * (sol.y[2] + math.pi))))
        up = np.nonzero((th[:-1] < 0) & (th[1:] >= 0))[0]
        tc = t[up] - th[up] / (th[up + 1] - th[up]) * dt  # linear interpolation of the crossings
        assert sw["period_s"] == pytest.approx(np.mean(np.diff(tc[:10])), rel=5e-3)
        assert sw["amplitude_10s_deg"] == pytest.approx(np.max(np.abs(th[(t >= 9.0) & (t <= 11.0)])), rel=1e-6)
        assert sw["amplitude_end_deg"] == pytest.approx(np.max(np.abs(th[t >= T - 2.0])), rel=1e-6)
        assert sw["mean_x_last_10s_m"] == pytest.approx(np.mean(sol.y[0][t >= T - 10.0]), rel=1e-4)
        assert sw["first_motion_positive"] == (sol.y[0][np.argmax(np.abs(sol.y[0]) > 1e-6)] > 0)


def test_twip_transients_overshoot_from_a_numpy_loop(transients):
    """The 5 deg reading again from a plain loop: the Kalman filter of (176)-(178) written out in NumPy (prior
    handed out, estimate from zero), u = -K xhat clipped at +-11.1 V, the Table 8.2 TWIP integrated by SciPy's
    DOP853 over each held period."""
    from jaxdip.plants import twip
    from jaxdip.scenarios import twip_dmso as S
    from jaxdip.theory import twip_transients as TT

    r, _, _ = transients
    dt, n = 0.01, 300
    d = S.design(dt)
    F, G, K = (np.asarray(a) for a in (d.F, d.G, d.K))
    Q, R = np.diag([1e-4, 1e-2, 1e-4, 1e-2]), np.diag([1e-6, 1e-5, 4e-6, 2e-5])
    p = twip.TWIP.table("8.2")
    f = jax.jit(lambda s, u: twip.f(p, s, u))
    x = np.array([1.0, 0.3, math.radians(10.0), math.radians(1.0)])
    xp, P, u_prev, phi = np.zeros(4), 0.01 * np.eye(4), np.zeros(1), []
    for k in range(n):
        phi.append(x[2])
        if k > 0:  # predict with the voltage applied over the last period
            xp, P = F @ xp + G @ u_prev, F @ P @ F.T + Q
        prior = xp.copy()
        L = P @ np.linalg.inv(P + R)  # y = x
        xp, P = xp + L @ (x - xp), (np.eye(4) - L) @ P
        u = np.clip(-K @ prior, -11.1, 11.1)
        sol = solve_ivp(lambda _t, s: np.asarray(f(s, u)), (0.0, dt), x, method="DOP853", rtol=1e-11, atol=1e-13)
        x, u_prev = sol.y[:, -1], u
    assert r["overshoot"]["kf"]["deg"] == pytest.approx(math.degrees(TT.overshoot(np.array(phi))), abs=1e-8)


def test_twip_allan_against_the_white_and_random_walk_laws(tmp_path):
    """tau << tau_r: the Gauss-Markov bias is nearly a random walk, so AVAR = sigma_r^2 / m (the white-noise law
    sigma^2 / tau) + sigma_br^2 tau / 3 (the random-walk law) with its first corrections: the bias's decay,
    factor 1 - 3 tau / (4 tau_r) (the expansion of the continuous Gauss-Markov law), and the sampling of the walk,
    + sigma_br^2 dt / (6 m) (the discrete walk's law). At m = 1 the simulated records' ADEV is the white std to
    within their sampling error."""
    from jaxdip.sim.twip_sensors import DEG, table_7_1

    r, report, out = _run("twip-allan", tmp_path)
    assert (out / "allan_deviation.png").is_file()
    tab = table_7_1()
    tau, m = np.asarray(r["tau_s"]), np.asarray(r["cluster_samples"])
    assert m[0] == 1 and np.allclose(tau, m * 0.01)
    for s in ("tilt", "gyro"):
        white, q, T = tab[f"{s}_white_std"] ** 2, tab[f"{s}_gm_sigma"] ** 2, tab[f"{s}_gm_tau"]
        law = np.asarray(r[s]["law_adev"]) * DEG
        short = tau <= 10.0
        approx = white / m + q * tau / 3 * (1 - 0.75 * tau / T) + q * 0.01 / (6 * m)
        np.testing.assert_allclose(law[short], np.sqrt(approx)[short], rtol=1e-4)
        n = 2 * 0.02 * 3600 / 0.01  # samples in both records
        assert r[s]["adev"][0] * DEG == pytest.approx(math.sqrt(white), rel=5 / math.sqrt(n))
        lo, hi = r[s]["adev_ci95"][0]
        assert lo <= r[s]["adev"][0] <= hi
    enc = r["encoder"]
    assert enc["max_position_error_m"] <= enc["quantum_m"] / 2 + 1e-12 and enc["holds"]
    assert "tilt" in report and "cluster times hold" in report


def test_rwp_remark3_paired_difference_seed_by_seed(tmp_path):
    """The paired difference re-derived outside ``jd.monte_carlo``: each seed's rollout on its own key
    (fold_in(key, i)), its tail mean in NumPy, the 95% normal interval by hand."""
    import equinox as eqx
    import jax.numpy as jnp

    from jaxdip.estimators import homd
    from jaxdip.plants import rwp as P
    from jaxdip.scenarios import rwp as S

    r, report, _ = _run("rwp-remark3", tmp_path)
    assert "(contrast)" in report and len(r["wheel"]) == 1
    steps, idx = int(round(1.0 / P.DT)), int(round(0.5 / P.DT))
    est = homd.HOMDObserver.build(P.DT, substeps=10)
    base = S.rollout(est, steps=steps, theta0=0.1, save_every=1)

    def tail_errors(d_r):
        ro = eqx.tree_at(lambda x: x.loop.sensor.const_bias, base, jnp.array([0.0, d_r]))
        one = jax.jit(lambda k: ro(k).saved)
        out = []
        for i in range(4):
            rec = np.asarray(one(jax.random.fold_in(jax.random.PRNGKey(0), i)))
            out.append(np.mean(rec[idx:, S.REC["xr2"]] - rec[idx:, S.REC["thetar_dot"]]))
        return np.array(out)

    d = tail_errors(0.5) - tail_errors(0.0)
    half = 1.959963984540054 * d.std(ddof=1) / math.sqrt(d.size)
    c = r["wheel"][0]
    assert c["d_r"] == 0.5 and c["kept"] == 4
    assert c["paired_mean"] == pytest.approx(d.mean(), abs=1e-12)
    np.testing.assert_allclose(c["paired_ci95"], [d.mean() - half, d.mean() + half], atol=1e-12)
    assert c["holds"] == bool(c["paired_ci95"][0] <= 0 <= c["paired_ci95"][1]
                              or max(map(abs, c["paired_ci95"])) <= 1e-3)


def test_thesis_theory_zeta_from_scipy(tmp_path):
    """zeta of Prop. 2.4.2 again: P from SciPy's CARE, and the weight where the largest eigenvalue of
    sym(P A_cl(gamma)) (linear in gamma) crosses 0, by Brent's method."""
    from scipy.linalg import solve_continuous_are
    from scipy.optimize import brentq

    import jaxdip as jd
    from jaxdip.plants import dip

    r, report, _ = _run("thesis-theory", tmp_path)
    assert "Prop. 2.4.2" in report
    A, B = (np.asarray(a) for a in jd.linearize(dip.DIP()))
    B = B.reshape(6, -1)
    P = solve_continuous_are(A, B, np.diag([30.0, 350.0, 100.0, 1.0, 1.0, 1.0]), np.array([[0.1]]))
    L = B @ np.linalg.solve(B.T @ P @ B, B.T @ P)

    def top(g):
        Acl = A - L @ (g * np.eye(6) + A)
        return np.linalg.eigvalsh(0.5 * (P @ Acl + Acl.T @ P)).max()

    zeta = brentq(top, 1.0, 1e6, xtol=1e-12, rtol=1e-12)
    rp = r["prop_2_4_2"]
    assert rp["zeta"] == pytest.approx(zeta, rel=1e-6)
    assert rp["rate_max"] < 0 and rp["trials"] == 2
    assert r["thm_1_3_2"]["trials"] == 2 and r["prop_1_4_1"]["steps"] == 20


@pytest.mark.parametrize("exp_id, setting, key", [
    ("twip-transients", "estimators=[\"ukf\"]", "estimators"),
    ("twip-transients", "swing_duration=5", "swing_duration"),
    ("twip-transients", "settling_truth=\"8.3\"", "settling_truth"),
    ("twip-allan", "records=1", "records"),
    ("twip-allan", "hours=0", "hours"),
    ("rwp-remark3", "tail=30", "tail"),
    ("rwp-remark3", "wheel_biases=[]", "wheel_biases"),
    ("thesis-theory", "Q=[1,2]", "Q"),
])
def test_bad_keys_are_one_line_errors(tmp_path, capsys, exp_id, setting, key):
    out = tmp_path / "o"
    assert cli.main(["run", exp_id, "--quick", "--set", setting, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {key}:"), err
    assert not out.exists()


@dataclass
class _Cfg:
    seeds: int = C.field(1, C.positive, doc="seeds")


def _fake(exp_id: str, reproduce: bool) -> Experiment:
    return Experiment(id=exp_id, title=exp_id, config_cls=_Cfg, reproduce=reproduce,
                      run=lambda cfg, ctx=None: Outcome(results={"id": exp_id}, report=f"ran {exp_id}"))


def test_plain_reproduce_leaves_readings_out_and_only_runs_them(tmp_path, monkeypatch):
    import jaxdip.runner as E

    fakes = {"headline": _fake("headline", True), "readings": _fake("readings", False)}
    monkeypatch.setattr(E, "registry", lambda: dict(fakes))
    assert cli.main(["reproduce", "--jobs", "1", "--out", str(tmp_path / "a")]) == 0
    assert (tmp_path / "a" / "headline" / "metrics.json").is_file()
    assert not (tmp_path / "a" / "readings").exists()
    assert "readings" not in (tmp_path / "a" / "REPORT.md").read_text()
    assert cli.main(["reproduce", "--jobs", "1", "--only", "readings", "--out", str(tmp_path / "b")]) == 0
    m = json.loads((tmp_path / "b" / "readings" / "metrics.json").read_text())
    assert m["results"] == {"id": "readings"}
    assert not (tmp_path / "b" / "headline").exists()


def test_list_marks_the_readings(capsys):
    assert cli.main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for exp_id in IDS:
        assert any(line.startswith(exp_id) and "fidelity readings" in line for line in lines)
