"""``jaxdip run <id> --sweep``: the grid, its checks, the table against separate runs, resuming point by point, and
the count of compiled programs (one set, built by the first point, when only an array value changes)."""

import json
import os

import jax
import pytest

from jaxdip import cli
from jaxdip.config import ConfigError
from jaxdip.runner import sweep as S
from jaxdip.runner import sweep_table
from jaxdip.runner.sweep_table import scalars

# the smallest dip-cpx-ldf run that exercises both estimators: 4 seeds, 40 periods, no inner sweep or trial
TINY = ["run", "dip-cpx-ldf", "--quick", "--seeds", "4", "--set", "duration=0.04", "--set", "sweep_points=0",
        "--set", "velocity_trial=false"]
GAMMAS = ["30", "150", "2e4"]


def test_values_split_at_top_level_commas_only():
    assert S.split_values("1,2.5, 3") == ["1", "2.5", "3"]
    assert S.split_values('[1,2],[3, 4],"a,b"') == ["[1,2]", "[3, 4]", '"a,b"']


@pytest.mark.parametrize("items, sets, why", [
    (["cpx_gamma"], [], "expects key=v1,v2"),
    (["=1,2"], [], "expects key=v1,v2"),
    (["cpx_gamma=1,,2"], [], "empty value"),
    (["cpx_gamma=1,2", "cpx_gamma=3"], [], "swept twice"),
    (["cpx_gamma=1,2"], ["cpx_gamma=3"], "also given by --set"),
    (["cpx_gamma=1,2,1"], [], "repeated"),
])
def test_bad_sweeps_are_refused_before_anything_runs(items, sets, why):
    with pytest.raises(ConfigError, match=why) as e:
        S.parse_sweeps(items, sets)
    assert e.value.key == "--sweep"


def test_the_grid_is_the_product_in_the_order_given():
    axes = S.parse_sweeps(["a=1,2", "b=x,[3,4]"])
    seen = []
    points = S.plan(axes, lambda sets: seen.append(sets) or tuple(sets))
    assert [p.name for p in points] == ["a=1,b=x", "a=1,b=[3,4]", "a=2,b=x", "a=2,b=[3,4]"]
    assert seen == [["a=1", "b=x"], ["a=1", "b=[3,4]"], ["a=2", "b=x"], ["a=2", "b=[3,4]"]]
    assert points[1].values == {"a": 1, "b": [3, 4]}  # as --set reads them (TOML values, bare words as text)
    with pytest.raises(ConfigError, match="share one folder"):
        S.plan(S.parse_sweeps(["a=x/y,x?y"]), lambda sets: None)  # both become a=x_y


@pytest.mark.parametrize("sweep, key, why", [
    ("cpx_gamm=1,2", "cpx_gamm", "did you mean 'cpx_gamma'"),
    ("cpx_gamma=150,-1", "cpx_gamma", "must be"),
])
def test_a_bad_key_or_value_is_the_same_one_line_error_as_with_set(tmp_path, capsys, sweep, key, why):
    out = tmp_path / "sw"
    assert cli.main([*TINY, "--out", str(out), "--sweep", sweep]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {key}: ") and why in err[0]
    single = sweep.split("=")[0] + "=" + sweep.split(",")[-1]
    assert cli.main([*TINY, "--out", str(tmp_path / "one"), "--set", single]) == 2
    assert capsys.readouterr().err.strip() == err[0]
    assert not out.exists()


def test_a_folder_that_is_not_a_sweep_is_refused(tmp_path, capsys):
    out = tmp_path / "sw"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert cli.main([*TINY, "--out", str(out), "--sweep", "cpx_gamma=1,2"]) == 2
    assert "not a jaxdip sweep folder" in capsys.readouterr().err
    assert os.listdir(out) == ["notes.txt"]


class Blank:
    def savefig(self, buf, **kw):
        buf.write(b"png")


def _results(folder):
    with open(os.path.join(folder, "metrics.json")) as fh:
        return json.load(fh)["results"]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """One uninterrupted sweep of CPX's gamma, and the same points run separately."""
    root = tmp_path_factory.mktemp("sweep")
    # an earlier test in this process may have built the same programs: start from an empty in-memory cache, so
    # the first point's count does not depend on which tests ran before
    jax.clear_caches()
    assert cli.main([*TINY, "--out", str(root / "sw"), "--sweep", "cpx_gamma=" + ",".join(GAMMAS)]) == 0
    for g in GAMMAS:
        assert cli.main([*TINY, "--out", str(root / f"one-{g}"), "--set", f"cpx_gamma={g}"]) == 0
    with open(root / "sw" / "sweep.json") as fh:
        return root, json.load(fh)


def test_the_table_equals_separate_runs(swept):
    root, doc = swept
    assert [p["name"] for p in doc["points"]] == [f"cpx_gamma={g}" for g in GAMMAS]
    assert [p["values"]["cpx_gamma"] for p in doc["points"]] == [30, 150, 2e4]
    for i, g in enumerate(GAMMAS):
        alone = _results(root / f"one-{g}")
        assert _results(root / "sw" / "points" / f"cpx_gamma={g}") == alone
        for stat, (v, ci) in scalars(alone).items():
            assert doc["table"][stat]["value"][i] == v and doc["table"][stat]["ci95"][i] == ci
    table = doc["table"]
    assert table["cpx.theta_var"]["headline"] and not table["cpx.diverged"]["headline"]
    # gamma changes CPX's statistics and leaves the LDF's alone (same seeds, same program)
    assert len(set(table["cpx.theta_dot_rms_err"]["value"])) == 3
    assert len(set(table["ldf.theta_dot_rms_err"]["value"])) == 1
    md = (root / "sw" / "sweep.md").read_text()
    assert "| cpx.theta_var |" in md and "cpx_gamma=2e4" in md
    assert (root / "sw" / "sweep-cpx.theta_var.png").read_bytes()[:4] == b"\x89PNG"
    assert not (root / "sw" / "sweep-ldf.theta_var.png").exists()  # the same at every point: a row, no figure
    assert "ldf.theta_var" in md.split("without a figure:")[1]


def test_gamma_points_after_the_first_compile_nothing(swept):
    _, doc = swept
    per_point = doc["compilations"]["per_point"]
    assert per_point[0] > 0 and per_point[1:] == [0, 0]  # gamma is an array leaf: the jit cache serves it
    assert doc["compilations"]["total"] == per_point[0]


def test_an_interrupted_sweep_resumes_point_by_point(swept, tmp_path, monkeypatch, capsys):
    root, doc = swept
    out = tmp_path / "sw"
    argv = [*TINY, "--out", str(out), "--sweep", "cpx_gamma=" + ",".join(GAMMAS)]
    real, calls = S.run_experiment, []

    def killed_at_second(*a, **k):  # the interrupt arrives while the second point runs
        calls.append(a[2])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(S, "run_experiment", killed_at_second)
    monkeypatch.setattr(sweep_table, "figure", lambda *a: Blank())  # rendering is tested above; it is slow
    assert cli.main(argv) == 130
    assert "1 of 3 points are complete" in capsys.readouterr().err
    assert sorted(os.listdir(out / "points")) == [f"cpx_gamma={GAMMAS[0]}"]
    assert not (out / "sweep.json").exists()
    first = (out / "points" / f"cpx_gamma={GAMMAS[0]}" / "metrics.json").stat()

    monkeypatch.setattr(S, "run_experiment", real)
    assert cli.main(argv) == 0
    assert "(2 run, 1 kept" in capsys.readouterr().out
    again = (out / "points" / f"cpx_gamma={GAMMAS[0]}" / "metrics.json").stat()
    assert (again.st_ino, again.st_mtime_ns) == (first.st_ino, first.st_mtime_ns)  # kept, not rerun
    with open(out / "sweep.json") as fh:
        resumed = json.load(fh)
    assert resumed["table"] == doc["table"] and resumed["points"] == doc["points"]
    assert resumed["compilations"]["per_point"][0] is None
    for g in GAMMAS:
        assert _results(out / "points" / f"cpx_gamma={g}") == _results(root / "sw" / "points" / f"cpx_gamma={g}")

    # a point whose config changed is run again; one a user edited is refused, not replaced
    (out / "points" / f"cpx_gamma={GAMMAS[1]}" / "report.md").write_text("edited")
    assert cli.main(argv) == 2
    assert "changed since jaxdip wrote them" in capsys.readouterr().err


KILLER = """
import dataclasses, os, signal, sys
from jaxdip import cli
from jaxdip.runner import sweep as S

real, calls = S.run_experiment, []

def run_experiment(exp, *a, **k):
    calls.append(1)
    if len(calls) < 2:
        return real(exp, *a, **k)
    def killed(cfg, ctx):  # SIGKILL in the middle of the second point, its staging folder half-written
        os.kill(os.getpid(), signal.SIGKILL)
    return real(dataclasses.replace(exp, run=killed), *a, **k)

S.run_experiment = run_experiment
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_a_sigkilled_sweep_resumes_to_the_uninterrupted_table(swept, tmp_path):
    import signal
    import subprocess
    import sys

    root, doc = swept
    argv = [*TINY, "--out", str(tmp_path / "sw"), "--sweep", "cpx_gamma=" + ",".join(GAMMAS)]
    child = subprocess.run([sys.executable, "-c", KILLER, *argv], capture_output=True, text=True, timeout=600)
    assert child.returncode == -signal.SIGKILL
    assert os.listdir(tmp_path / "sw" / "points") != sorted(os.listdir(root / "sw" / "points"))
    again = subprocess.run([sys.executable, "-m", "jaxdip.cli", *argv], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert "(2 run, 1 kept" in again.stdout
    with open(tmp_path / "sw" / "sweep.json") as fh:
        resumed = json.load(fh)
    assert resumed["table"] == doc["table"]
    assert sorted(os.listdir(tmp_path / "sw" / "points")) == sorted(os.listdir(root / "sw" / "points"))
