"""The CLI's contract: one-line errors with exit 2 and no output on bad config; identical results per key."""

import json
import os
import subprocess
import sys

import pytest

from jaxdip import cli, cli_args
from jaxdip import config as C
import experiments.dip_lqr as dip_lqr
from jaxdip.runner import registry
from test_distributed import compare_results, launch_pair

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def jaxdip(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "jaxdip.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=dict(os.environ, JAXDIP_NO_PROGRESS="1"), timeout=600)


@pytest.mark.parametrize(
    "setting, key",
    [
        ("Qx=[1,2,3,4,5,6]", "Qx"),  # misspelt key
        ("noise_std=[-0.1,0,0,0,0,0]", "noise_std"),  # negative noise level
        ("Q=[[1,0],[0,1]]", "Q"),  # wrong shape
        ("R=-1", "R"),
        ("dt=nan", "dt"),
        ("seeds=many", "seeds"),
    ],
)
def test_bad_config_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, setting, key):
    # in this process: the config is refused before anything runs (the child-process path: the tests below)
    out = tmp_path / "out"
    code = cli.main(["run", "dip-lqr", "--quick", "--out", str(out), "--set", setting])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {key}:"), err
    assert not out.exists()
    assert os.listdir(tmp_path) == []


def test_bad_config_file(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("seeds = 4\nnoise_std = [0.1, 0.1]\n")
    r = jaxdip("run", "dip-lqr", "--config", str(cfg), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and r.stderr.startswith("error: noise_std:")
    assert not (tmp_path / "o").exists()


def test_list_and_unknown_experiment():
    r = jaxdip("list")
    assert r.returncode == 0 and "dip-lqr" in r.stdout.split()
    r = jaxdip("run", "dip-lqq")
    assert r.returncode == 2 and r.stderr.startswith("error: dip-lqq: unknown experiment")


@pytest.fixture(scope="module")
def cached_runs(dip_lqr_uncached):
    """The shared uncached run's command twice more with the compilation cache on, in a so far unmade folder:
    ``b`` (beside the uncached run, which has a cache folder of its own) compiles and fills it, then ``c`` should
    find every loop there. The cache's entries after each."""
    d = dip_lqr_uncached
    cache = d.root / "xla"
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1", JAXDIP_CACHE_DIR=str(cache))
    procs, entries = {}, {}
    for name in ("b", "c"):
        procs[name] = d.Child([*d.args, "--out", str(d.root / name)], env).wait()
        entries[name] = sorted(os.listdir(cache)) if cache.exists() else []
    d.proc.wait()
    return procs, entries


def test_run_writes_contract_and_is_reproducible(dip_lqr_uncached, cached_runs):
    """Two independent runs (each compiles its loops afresh: one with the cache off, one filling an empty cache)
    write the whole folder and the same results."""
    d, (procs, _) = dip_lqr_uncached, cached_runs
    assert d.proc.wait().returncode == 0, d.proc.stderr
    assert procs["b"].returncode == 0, procs["b"].stderr
    a, b = d.out, d.root / "b"
    for out in (a, b):
        for name in ("metrics.json", "report.md", "config.toml", "band_alpha_theta.png"):
            assert (out / name).is_file(), (out, name)
    ma, mb = (json.loads((o / "metrics.json").read_text()) for o in (a, b))
    for k in ("experiment", "seeds", "dtype", "backend", "jax_version", "wall_s", "results"):
        assert k in ma
    assert ma["dtype"] == "float64" and ma["seeds"] == 6
    assert json.dumps(ma["results"], sort_keys=True) == json.dumps(mb["results"], sort_keys=True)
    # the resolved config reproduces the run's settings
    cfg = C.load(dip_lqr.DipLqrConfig, path=str(a / "config.toml"))
    assert cfg.seeds == 6 and cfg.duration == 0.2 and cfg.record_every == 1
    assert not [p for p in os.listdir(d.root) if p.startswith(".")]  # no temporary folders left


@pytest.mark.parametrize("exp_id", sorted(registry()))
def test_config_files_match_defaults(exp_id):
    """configs/<id>.toml is generated from the config's defaults in code, and reads back as those defaults."""
    from jaxdip.cli_config import default_toml

    exp = registry()[exp_id]
    path = os.path.join(ROOT, "configs", f"{exp_id}.toml")
    assert os.path.isfile(path), f"configs/{exp_id}.toml missing: run `jaxdip config --write configs`"
    with open(path, encoding="utf-8") as fh:
        assert fh.read() == default_toml(exp), f"configs/{exp_id}.toml is stale: run `jaxdip config --write configs`"
    assert C.load(exp.config_cls, path=path) == exp.config_cls()


def test_config_write_replaces_only_its_own_files(tmp_path, capsys):
    """`config --write DIR` writes every experiment's file, the same bytes as configs/; it replaces a file it
    wrote (here changed in a value), and refuses, before writing anything, a file of the same name it did not."""
    assert cli.main(["config", "--write", str(tmp_path)]) == 0
    names = sorted(os.listdir(tmp_path))
    assert names == sorted(f"{i}.toml" for i in registry())
    for name in names:
        assert (tmp_path / name).read_bytes() == open(os.path.join(ROOT, "configs", name), "rb").read()
    ours = tmp_path / "dip-lqr.toml"
    ours.write_text(ours.read_text().replace("seeds = 4096", "seeds = 5"))
    assert cli.main(["config", "--write", str(tmp_path)]) == 0
    assert "seeds = 4096" in ours.read_text()
    (tmp_path / "dip-lqr.toml").write_text("seeds = 5\n")
    (tmp_path / "tune.toml").unlink()
    capsys.readouterr()
    assert cli.main(["config", "--write", str(tmp_path)]) == 2
    assert "dip-lqr.toml exists and was not written by jaxdip" in capsys.readouterr().err
    assert (tmp_path / "dip-lqr.toml").read_text() == "seeds = 5\n" and not (tmp_path / "tune.toml").exists()


def _no_nulls(obj, path="results"):
    if isinstance(obj, dict):
        for k, v in obj.items():
            _no_nulls(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _no_nulls(v, f"{path}[{i}]")
    else:
        assert obj is not None, path


def test_all_seeds_diverged_is_reported_not_averaged(tmp_path):
    """Initial states far outside the LQR's basin: every seed leaves the bound, the report says so and how, and
    metrics.json holds no NaN or null in place of statistics over zero seeds."""
    out = tmp_path / "o"
    code = cli.main(["run", "dip-lqr", "--quick", "--seeds", "8", "--set", "init_radius=3", "--set",
                     "duration=0.2", "--set", "record_every=1", "--out", str(out)])
    assert code == 0
    text = (out / "metrics.json").read_text()
    m = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in metrics.json"))
    r = m["results"]
    _no_nulls(r)
    assert r["diverged"] == 8 and r["states"] == {}
    f = r["failures"]
    assert f["out_of_bounds"] + f["nonfinite"] == 8
    assert sum(f["bound_crossed_first"].values()) == f["out_of_bounds"]
    assert 0 < f["time_to_failure_s"]["min"] <= f["time_to_failure_s"]["max"] <= 0.2
    report = (out / "report.md").read_text()
    assert "all 8 seeds diverged" in report and "nan" not in report.lower()


def test_compilation_cache_is_written_and_reused(dip_lqr_uncached, cached_runs):
    """A second run of the same experiment finds its compiled loops on disk (and the results are unchanged);
    --no-compile-cache leaves the folder alone."""
    d, (procs, entries) = dip_lqr_uncached, cached_runs
    assert d.proc.wait().returncode == 0, d.proc.stderr
    assert not d.cache_off.exists()  # the --no-compile-cache run did not make its folder
    for name in ("b", "c"):
        assert procs[name].returncode == 0, procs[name].stderr
    assert entries["b"]
    assert entries["c"] == entries["b"]  # the second run added nothing: every loop came from disk
    res = [json.loads((o / "metrics.json").read_text())["results"] for o in (d.out, d.root / "b", d.root / "c")]
    assert res[0] == res[1] == res[2]


@pytest.mark.slow
def test_parallel_reproduce_equals_sequential(tmp_path):
    """``reproduce --jobs 2`` runs experiments in two worker processes, one of them running two experiments one
    after another: same results and report rows as ``--jobs 1``."""
    import json

    ids = "dip-lqr,eki-linear,twip-extra-control"
    for jobs in ("1", "2"):
        r = jaxdip("reproduce", "--quick", "--only", ids, "--jobs", jobs, "--out", str(tmp_path / f"j{jobs}"))
        assert r.returncode == 0, r.stderr[-2000:]
    for exp_id in ids.split(","):
        a, b = (json.loads((tmp_path / f"j{j}" / exp_id / "metrics.json").read_text())["results"] for j in "12")
        assert a == b
    report = (tmp_path / "j2" / "REPORT.md").read_text()
    assert all(f"[{i}]({i}/report.md)" in report for i in ids.split(","))


@pytest.mark.parametrize("argv, cores, devices", [
    (["run", "dip-lqr"], 2, "2"),
    (["reproduce", "--quick"], 2, "1"),  # two workers side by side: one core each
    (["reproduce", "--jobs", "1"], 2, "2"),
    (["reproduce", "--only", "dip-lqr"], 2, "2"),  # one experiment runs in this process
    (["reproduce", "--only", "dip-lqr,dip-lqr"], 2, "2"),
    (["reproduce"], 8, "4"),
    (["reproduce", "--jobs", "3"], 8, "2"),
    (["run", "dip-lqr"], 1, None),
])
def test_reproduce_workers_share_the_cores(monkeypatch, argv, cores, devices):
    """Each process computing side by side gets its share of the cores as XLA host devices (set before JAX
    starts, inherited by the workers); a user's own device count is kept."""
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    monkeypatch.setattr(os, "cpu_count", lambda: cores)
    args = cli_args.parser().parse_args(argv)
    cli._use_all_cores(cli._reproduce_jobs(args) if args.cmd == "reproduce" else 1)
    flags = os.environ.get("XLA_FLAGS", "")
    assert flags == (f"--xla_force_host_platform_device_count={devices}" if devices else "")
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3")
    cli._use_all_cores(2)
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=3"


@pytest.mark.slow
def test_a_search_where_every_member_fails_ends_with_one_line(tmp_path, capsys):
    # initial states far outside the state bound: every member fails every iteration; with failure "ignore" the
    # search stops after ten skipped iterations with a status, which the CLI prints as one line (status 2)
    code = cli.main(["run", "eki-dip", "--quick", "--out", str(tmp_path / "o"), "--set", "failure=ignore",
                     "--set", "min_success=4", "--set", "iterations=20", "--set", "x0_std=[20.0, 20.0, 20.0, 0, 0, 0]"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("error: search: ensemble search stopped at iteration 10:"), err[-1:]


# ---- the CLI over two processes -------------------------------------------------------------------------------
# Here, not in test_distributed.py, because its one-process reference is the shared uncached run: pytest-xdist
# runs a file in one worker and session fixtures once per worker, so in a file of its own it could start a
# second copy of that run.

def test_cli_run_on_two_processes_equals_one_process(tmp_path, dip_lqr_uncached):
    """The acceptance check: ``jaxdip run dip-lqr --quick --distributed`` on two processes (4 devices, 6 seeds:
    padded to 8) against one process (the conftest's run of the same command without ``--distributed``); most of
    the time goes to compiling the partitioned programs."""
    dist, p1_out, single = tmp_path / "dist", tmp_path / "p1", dip_lqr_uncached.out
    run = [*dip_lqr_uncached.args, "--no-compile-cache"]
    env = {"JAXDIP_NO_PROGRESS": ""}  # progress bars on, to see that only process 0 draws one

    def cmd(i, port):
        # process 1 gets its own --out only to show that it writes nothing
        return [sys.executable, "-m", "jaxdip.cli", *run, "--out", str(dist if i == 0 else p1_out),
                "--distributed", "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                "--process-id", str(i)]

    (rc0, out0, err0), (rc1, out1, err1) = launch_pair(cmd, **env)
    assert rc0 == 0, err0[-3000:]
    assert rc1 == 0, err1[-3000:]
    assert "wrote" in out0 and "wrote" not in out1  # (gloo logs its connections on stdout)
    assert "dip-lqr [" in err0 and "dip-lqr [" not in err1
    assert not p1_out.exists()
    assert dip_lqr_uncached.proc.wait().returncode == 0, dip_lqr_uncached.proc.stderr[-3000:]
    m_dist = json.loads((dist / "metrics.json").read_text())
    m_one = json.loads((single / "metrics.json").read_text())
    assert m_dist["processes"] == 2 and m_dist["devices"] == 4 and "processes" not in m_one
    assert m_dist["seeds"] == m_one["seeds"] == 6
    worst = compare_results(m_dist["results"], m_one["results"])
    print(f"largest relative difference of results: {worst:.3g}")
    assert worst <= 1e-12
    assert sorted(os.listdir(dist)) == sorted(os.listdir(single))
