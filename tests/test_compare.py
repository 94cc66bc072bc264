"""``jaxdip compare A B``: the tests against SciPy, Holm's correction by hand, the classes of findings, and the
command on real runs: the same config is identical, another seeds' key is within the intervals, another gamma is
flagged; exit codes 0, 1 and 2."""

import json
import math
import shutil

import numpy as np
import pytest
import scipy.stats

from jaxdip import cli, stats
from jaxdip.runner import compare as C
from jaxdip.runner import sweep_table


@pytest.mark.parametrize("n1, n2, shift, scale", [(2, 2, 0.5, 1.0), (5, 9, 0.3, 3.0), (60, 40, 0.4, 0.5),
                                                  (3000, 2500, 0.02, 1.0)])
def test_welch_matches_scipy(n1, n2, shift, scale):
    rng = np.random.default_rng(n1)
    a, b = rng.normal(0, 1, n1), rng.normal(shift, scale, n2)
    t, df, p = stats.welch(a, b)
    ref = scipy.stats.ttest_ind(a, b, equal_var=False)
    assert t == pytest.approx(ref.statistic, rel=1e-12)
    assert p == pytest.approx(ref.pvalue, rel=1e-9)
    v1, v2 = a.var(ddof=1) / n1, b.var(ddof=1) / n2
    assert df == pytest.approx((v1 + v2) ** 2 / (v1**2 / (n1 - 1) + v2**2 / (n2 - 1)), rel=1e-12)


@pytest.mark.parametrize("t, df", [(0.0, 1.0), (0.3, 1.5), (2.1, 4.0), (-3.7, 11.2), (8.0, 300.0), (40.0, 2.5)])
def test_t_and_z_pvalues_match_scipy(t, df):
    assert stats.t_pvalue(t, df) == pytest.approx(2 * scipy.stats.t.sf(abs(t), df), rel=1e-10, abs=1e-300)
    assert stats.z_pvalue(t) == pytest.approx(2 * scipy.stats.norm.sf(abs(t)), rel=1e-12, abs=1e-300)


def test_t_pvalue_at_infinite_degrees_of_freedom_is_the_normal():
    assert stats.t_pvalue(1.7, math.inf) == stats.z_pvalue(1.7) == pytest.approx(2 * scipy.stats.norm.sf(1.7))
    with pytest.raises(ValueError, match="df must be > 0"):
        stats.t_pvalue(1.0, 0.0)


def test_welch_refuses_a_single_value():
    with pytest.raises(ValueError, match="at least two"):
        stats.welch([1.0], [1.0, 2.0])


def test_leaves_pair_each_statistic_with_its_interval():
    results = {"cpx": {"v": 1.0, "v_ci95": [0.5, 1.5], "n": 3, "word": "ok"},
               "sweep": {"g": [1, 10], "w": [2.0, 3.0], "w_ci95": [[1.0, 3.0], [2.5, 3.5]]}, "lone_ci95": [0, 1]}
    assert C.leaves(results) == {
        "cpx.v": (1.0, [0.5, 1.5]), "cpx.n": (3, None), "cpx.word": ("ok", None),
        "sweep.g[0]": (1, None), "sweep.g[1]": (10, None),
        "sweep.w[0]": (2.0, [1.0, 3.0]), "sweep.w[1]": (3.0, [2.5, 3.5]),
        "lone_ci95[0]": (0, None), "lone_ci95[1]": (1, None)}


def test_each_class_of_finding():
    a = {"same": 1.0, "close": 1.0, "near": 1.0, "near_ci95": [0.0, 2.0], "far": 1.0, "far_ci95": [0.9, 1.1],
         "count": 3, "only_a": 1}
    b = {"same": 1.0, "close": 1.0 + 1e-12, "near": 1.2, "near_ci95": [0.2, 2.2], "far": 5.0, "far_ci95": [4.9, 5.1],
         "count": 4, "only_b": 1}
    kinds = {f.path: f.kind for f in C.compare(a, b)}
    assert kinds == {"same": C.IDENTICAL, "close": C.EQUAL, "near": C.WITHIN, "far": C.SIGNIFICANT,
                     "count": C.DIFFERS, "only_a": C.MISSING, "only_b": C.MISSING}
    near = next(f for f in C.compare(a, b) if f.path == "near")
    se = 2.0 / (2 * stats.Z95)  # each interval's half-width over 1.96
    assert near.p == pytest.approx(2 * scipy.stats.norm.sf(0.2 / math.hypot(se, se)), rel=1e-12)
    assert C.compare(a, b, rtol=0)[1].kind == C.DIFFERS  # no tolerance: 1e-12 apart is a difference
    assert C.status(C.compare(a, a)) == 0 and C.status(C.compare(a, b)) == 1


def test_holm_step_down():
    # p sorted: 0.005 <= 0.05/4, 0.01 <= 0.05/3, 0.03 > 0.05/2: the first two are rejected, the rest are not
    fs = [C.Finding(str(i), C.WITHIN, p=p) for i, p in enumerate([0.01, 0.04, 0.03, 0.005])]
    C.holm(fs, 0.05)
    assert [f.kind for f in fs] == [C.SIGNIFICANT, C.WITHIN, C.WITHIN, C.SIGNIFICANT]
    # uncorrected, 0.03 and 0.04 would count: with many statistics a few would be flagged by chance
    fs = [C.Finding(str(i), C.WITHIN, p=p) for i, p in enumerate([0.04, 0.03])]
    C.holm(fs, 0.05)
    assert [f.kind for f in fs] == [C.WITHIN, C.WITHIN]


TINY = ["run", "dip-cpx-ldf", "--quick", "--seeds", "4", "--set", "duration=0.04", "--set", "sweep_points=0",
        "--set", "velocity_trial=false"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The default config run alone, and a sweep of gamma x the seeds' key."""
    root = tmp_path_factory.mktemp("compare")
    assert cli.main([*TINY, "--out", str(root / "base")]) == 0
    with pytest.MonkeyPatch.context() as mp:  # the sweep's figures are not compared (and slow to render)
        mp.setattr(sweep_table, "varies", lambda row: False)
        assert cli.main([*TINY, "--out", str(root / "sw"), "--sweep", "cpx_gamma=150,1e5", "--sweep", "seed=0,1"]) == 0
    return root, root / "sw" / "points"


def _compare(capsys, a, b):
    code = cli.main(["compare", str(a), str(b)])
    return code, capsys.readouterr().out.strip().splitlines()


def test_the_same_config_is_identical(runs, capsys):
    root, points = runs
    code, out = _compare(capsys, root / "base", points / "cpx_gamma=150,seed=0")
    assert code == 0
    assert len(out) == 1 and out[0].startswith("compare: ") and "identical, 0 equal, 0 within" in out[0]


def test_another_seeds_key_is_within_the_intervals(runs, capsys):
    _, points = runs
    code, out = _compare(capsys, points / "cpx_gamma=150,seed=0", points / "cpx_gamma=150,seed=1")
    assert code == 0
    assert out[0] == "note: config seed: 0 vs 1"
    lines = out[1:-1]
    assert lines and all(": within interval: " in ln for ln in lines)
    assert any(ln.startswith("cpx.theta_var: ") for ln in lines)  # a statistic over seeds did change
    assert "0 significantly different, 0 differs, 0 missing" in out[-1]


def test_another_gamma_is_flagged(runs, capsys):
    _, points = runs
    code, out = _compare(capsys, points / "cpx_gamma=150,seed=0", points / "cpx_gamma=1e5,seed=0")
    assert code == 1
    flagged = {ln.split(":")[0] for ln in out if ": significantly different: " in ln}
    assert {"cpx.theta_dot_rms_err", "cpx.u_var"} <= flagged
    assert not any(ln.startswith("ldf.") for ln in out)  # the LDF runs do not see gamma: identical
    assert out[-1].endswith("-> differences (exit 1)")


def test_a_statistic_on_one_side_only(runs, capsys, tmp_path):
    root, _ = runs
    other = tmp_path / "other"
    shutil.copytree(root / "base", other)
    m = json.loads((other / "metrics.json").read_text())
    del m["results"]["cpx"]["u_var"]
    (other / "metrics.json").write_text(json.dumps(m))
    code, out = _compare(capsys, root / "base", other)
    assert code == 1 and "cpx.u_var: missing in B" in out


def test_folders_that_cannot_be_compared(runs, capsys, tmp_path):
    root, _ = runs
    assert cli.main(["compare", str(root / "base"), str(tmp_path / "nowhere")]) == 2
    assert capsys.readouterr().err.strip().endswith("nowhere: no such folder")
    assert cli.main(["compare", str(root / "base"), str(tmp_path)]) == 2
    assert "not a jaxdip result folder" in capsys.readouterr().err
    assert cli.main(["compare", str(root / "sw"), str(root / "base")]) == 2
    assert "is a sweep: compare its points" in capsys.readouterr().err
    other = tmp_path / "other"
    shutil.copytree(root / "base", other)
    m = json.loads((other / "metrics.json").read_text())
    (other / "metrics.json").write_text(json.dumps({**m, "experiment": "dip-lqr"}))
    assert cli.main(["compare", str(root / "base"), str(other)]) == 2
    assert "not comparable" in capsys.readouterr().err
    assert cli.main(["compare", str(root / "base"), str(other), "--alpha", "1.5"]) == 2
    assert "--alpha: must be between 0 and 1" in capsys.readouterr().err


@pytest.mark.parametrize("k1, n1, k2, n2", [(3, 10, 7, 12), (0, 16, 5, 16), (40, 100, 45, 90)])
def test_the_proportion_test_is_the_chi_square_test_of_the_two_by_two_table(k1, n1, k2, n2):
    table = [[k1, n1 - k1], [k2, n2 - k2]]
    ref = scipy.stats.chi2_contingency(table, correction=False).pvalue
    assert C.proportion_pvalue(k1, n1, k2, n2) == pytest.approx(ref, rel=1e-10)
    assert C.proportion_pvalue(0, 5, 0, 9) == 1.0 and C.proportion_pvalue(5, 5, 9, 9) == 1.0


LOW, HIGH = "[0.001,0.001,0.001,0.01,0.01,0.01]", "[0.01,0.01,0.01,0.1,0.1,0.1]"  # the default, and 10 times it


@pytest.fixture(scope="module")
def lqr_runs(tmp_path_factory):
    """dip-lqr with per-seed data: two seeds' keys x two levels of measurement noise."""
    pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    pytest.importorskip("h5py")
    from conftest import TINY_DIP_LQR

    root = tmp_path_factory.mktemp("lqr")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep_table, "varies", lambda row: False)
        assert cli.main([*TINY_DIP_LQR, "--per-seed", "--out", str(root), "--sweep", "seed=0,1",
                         "--sweep", f"noise_std={LOW},{HIGH}"]) == 0
    return root / "points"


def test_per_seed_data_are_tested_by_welch(lqr_runs, capsys):
    a, b = lqr_runs / f"seed=0,noise_std={LOW}", lqr_runs / f"seed=1,noise_std={LOW}"
    code, out = _compare(capsys, a, b)
    assert code == 0
    assert out[1].startswith("note: per-seed data in both folders: ")
    tested = [ln for ln in out if ": within interval: " in ln]
    assert tested and all("(Welch t-test on the per-seed values, p = " in ln for ln in tested)
    # the p-value from the files, read here with xarray and tested by SciPy
    import xarray as xr

    def alpha_mean_abs(folder):
        ds = xr.open_dataset(folder / "per_seed.nc", engine="h5netcdf").load()
        return ds["x.mean_abs"].sel(state="alpha").values[ds["ok"].values.astype(bool)]

    sa, sb = (C.per_seed_samples(str(f), json.loads((f / "metrics.json").read_text())["results"]) for f in (a, b))
    ref = scipy.stats.ttest_ind(alpha_mean_abs(a), alpha_mean_abs(b), equal_var=False).pvalue
    assert C.sample_test(sa["states.alpha.mean_abs"], sb["states.alpha.mean_abs"]) == ("welch", pytest.approx(ref))


def test_per_seed_data_flag_more_measurement_noise(lqr_runs, capsys):
    code, out = _compare(capsys, lqr_runs / f"seed=0,noise_std={LOW}", lqr_runs / f"seed=0,noise_std={HIGH}")
    assert code == 1
    flagged = [ln for ln in out if ": significantly different: " in ln]
    assert {"u.var", "u.mean_abs"} <= {ln.split(":")[0] for ln in flagged}  # the input follows the noise
    assert all("Welch t-test on the per-seed values" in ln or "two-proportion" in ln for ln in flagged)


def test_a_sweep_asked_for_per_seed_data_reruns_the_points_without_it(lqr_runs, tmp_path, capsys):
    from conftest import TINY_DIP_LQR

    argv = [*TINY_DIP_LQR, "--out", str(tmp_path), "--sweep", "seed=0,1"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep_table, "varies", lambda row: False)
        for extra, said in (([], "(2 run, 0 kept"), (["--per-seed"], "(2 run, 0 kept"), (["--per-seed"], "(0 run, 2 kept"),
                            ([], "(0 run, 2 kept")):
            assert cli.main([*argv, *extra]) == 0
            assert said in capsys.readouterr().out
    assert (tmp_path / "points" / "seed=1" / "per_seed.nc").exists()


def test_per_seed_paths_follow_the_results_lists_dotted_labels_and_masks(tmp_path):
    """A hand-made per_seed.nc (docs/data.md's layout): list entries by index, a label holding a dot, the seeds
    a mean is over, a fraction, and a dimension the path does not name (not one statistic: left out)."""
    pytest.importorskip("xarray")
    pytest.importorskip("h5py")
    from jaxdip import dataset

    rng = np.random.default_rng(0)
    v, w, ok = rng.normal(size=(5, 2)), rng.normal(size=(5, 2)), np.array([True, True, False, True, True])
    variables = {
        "ok": (("seed",), ok, {"units": "1"}),
        "sweep.v": (("sweep_seed", "gamma_index"), v, {"units": "1", "summarised_as": "sweep.v.{gamma_index}",
                                                        "statistic": C.MEAN}),
        "gain.w": (("seed", "gain"), w, {"units": "1", "summarised_as": "gains.{gain}.w", "statistic": C.MEAN,
                                         "over": "ok"}),
        "stab": (("seed",), ok, {"units": "1", "summarised_as": "stabilized", "statistic": C.FRACTION}),
        "both": (("seed", "gain"), w, {"units": "1", "summarised_as": "both", "statistic": C.MEAN}),
    }
    dataset.write(dataset.build(variables, {"gain": ["0.5", "2"], "gamma_index": [0, 1]}),
                  str(tmp_path / "per_seed.nc"))
    results = {"sweep": {"v": [0.1, 0.2]}, "gains": {"0.5": {"w": 1.0}, "2": {"w": 2.0}}, "stabilized": 0.8,
               "both": 3.0}
    got = C.per_seed_samples(str(tmp_path), results)
    assert sorted(got) == ["gains.0.5.w", "gains.2.w", "stabilized", "sweep.v[0]", "sweep.v[1]"]
    assert set(got) <= set(C.leaves(results))  # the names compare gives the statistics
    np.testing.assert_array_equal(got["sweep.v[1]"][1], v[:, 1])
    np.testing.assert_array_equal(got["gains.0.5.w"][1], w[ok, 0])
    assert got["stabilized"][0] == C.FRACTION and got["stabilized"][1].sum() == 4
