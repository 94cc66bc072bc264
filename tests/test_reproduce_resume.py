"""``jaxdip reproduce --resume``: an interrupted reproduction continues with the experiments it has not finished.

The default-suite tests run dip-lqr at --quick twice under two ids (the real experiment, its copy registered as
``dip-lqr-b``): real configs, computations and result folders, and the second compiles nothing new. The slow test
kills a real two-experiment reproduction in a child process and resumes it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

import jaxdip.runner as runner
from jaxdip import cli

IDS = ("dip-lqr", "dip-lqr-b")


@pytest.fixture
def two(monkeypatch):
    """A registry of dip-lqr and its copy ``dip-lqr-b``; ``two.stop`` (an id) makes that experiment's run send
    this process a SIGINT, as a user's Ctrl-C in the middle of it would."""
    real = runner.registry()["dip-lqr"]
    state = type("Two", (), {"stop": None, "ran": []})()

    def wrap(exp_id):
        def run(cfg, ctx=None):
            state.ran.append(exp_id)
            out = real.run(cfg, ctx)
            if state.stop == exp_id:
                os.kill(os.getpid(), signal.SIGINT)  # caught by the CLI's handler: the run stops before its commit
            return out
        return dataclasses.replace(real, id=exp_id, run=run)

    monkeypatch.setattr(runner, "registry", lambda: {i: wrap(i) for i in IDS})
    return state


def _reproduce(out, *extra):
    return cli.main(["reproduce", "--quick", "--jobs", "1", "--only", ",".join(IDS), "--out", str(out), *extra])


def _results(folder):
    return json.loads((folder / "metrics.json").read_text())["results"]


def _report(out):
    """REPORT.md without its wall times (this run's, and each experiment's own), the line on kept runs and the
    folder's own path (in each report's regenerate command)."""
    text = (out / "REPORT.md").read_text().replace(str(out), "OUT")
    text = re.sub(r"Total wall time [0-9.]+ s[^.]*\.", "Total wall time", text)
    text = re.sub(r"wall time [0-9.]+ s", "wall time", text)
    return re.sub(r"\| [0-9.]+ \|\n", "| |\n", text)


def test_interrupted_reproduction_resumes_to_the_uninterrupted_one(tmp_path, two, capsys):
    assert _reproduce(tmp_path / "whole") == 0
    capsys.readouterr()

    two.stop, two.ran[:] = "dip-lqr-b", []
    assert _reproduce(tmp_path / "cut") == 130
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == (f"interrupted: the experiments finished before it are in "
                                            f"{tmp_path / 'cut'}; add --resume to the same command to continue")
    assert (tmp_path / "cut" / "dip-lqr" / "metrics.json").exists()
    assert not (tmp_path / "cut" / "dip-lqr-b").exists() and not (tmp_path / "cut" / "REPORT.md").exists()

    two.stop, two.ran[:] = None, []
    assert _reproduce(tmp_path / "cut", "--resume") == 0
    err = capsys.readouterr().err
    assert two.ran == ["dip-lqr-b"]  # the finished one is not run again
    assert "== dip-lqr: complete, kept" in err.splitlines() and "== dip-lqr-b" in err.splitlines()
    for exp_id in IDS:
        assert _results(tmp_path / "cut" / exp_id) == _results(tmp_path / "whole" / exp_id)
    assert "(1 of 2 experiments kept from an earlier run)" in (tmp_path / "cut" / "REPORT.md").read_text()
    assert _report(tmp_path / "cut") == _report(tmp_path / "whole")

    # everything complete: nothing runs, the report is written again from the folders
    two.ran[:] = []
    assert _reproduce(tmp_path / "cut", "--resume") == 0
    assert two.ran == [] and _report(tmp_path / "cut") == _report(tmp_path / "whole")
    # without --resume a reproduction runs everything again, as before
    assert _reproduce(tmp_path / "cut") == 0 and two.ran == list(IDS)


def test_a_changed_config_or_changed_file_is_not_kept(tmp_path, two, capsys):
    out = tmp_path / "o"
    # dip-lqr's folder from a run with another config: a jaxdip result of the experiment, but not this run's
    assert cli.main(["run", "dip-lqr", "--quick", "--set", "R=0.2", "--out", str(out / "dip-lqr")]) == 0
    other = _results(out / "dip-lqr")
    capsys.readouterr()
    assert _reproduce(out, "--resume") == 0
    assert two.ran == list(IDS) and "complete, kept" not in capsys.readouterr().err
    assert _results(out / "dip-lqr") != other
    assert 'R = 0.1' in (out / "dip-lqr" / "config.toml").read_text()

    # a metrics.json edited by hand: the folder is no longer an unchanged jaxdip result, so resume refuses to
    # replace it (as a plain reproduce does) rather than keep or overwrite the user's edit
    with open(out / "dip-lqr-b" / "metrics.json", "a") as fh:
        fh.write("\n")
    two.ran[:] = []
    assert _reproduce(out, "--resume") == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("error: --out") and "metrics.json" in line, line
    assert two.ran == []


def test_parallel_reproduce_hands_out_only_the_unfinished(tmp_path, two, capsys, monkeypatch):
    """The parallel path gets the same list: the kept experiments never reach a worker."""
    import shutil

    out = tmp_path / "o"
    assert _reproduce(out) == 0
    given = []

    def fake_parallel(args, reg, jobs, stopped):
        given.append([i for i, _ in reg])
        return 1  # as a failed experiment would: cmd_reproduce stops there, before the report

    monkeypatch.setattr(cli, "run_parallel", fake_parallel)
    argv = ["reproduce", "--quick", "--jobs", "2", "--only", ",".join(IDS), "--out", str(out), "--resume"]
    shutil.rmtree(out / "dip-lqr-b")
    two.ran[:] = []
    # one experiment left: it runs in this process, as a single experiment always has
    assert cli.main(argv) == 0 and given == [] and two.ran == ["dip-lqr-b"]
    for d in IDS:
        shutil.rmtree(out / d)
    assert cli.main(argv) == 1 and given == [list(IDS)]


def test_resume_refuses_distributed(tmp_path, capsys):
    assert cli.main(["reproduce", "--quick", "--only", "dip-lqr", "--out", str(tmp_path), "--resume",
                     "--distributed"]) == 2
    assert "--resume" in capsys.readouterr().err


@pytest.mark.slow
def test_killed_reproduction_resumes(tmp_path):
    """A real reproduction of two experiments, killed (SIGKILL) once the first is written, resumes to the
    results of an uninterrupted one."""
    ids = "dip-lqr,twip-extra-control"
    cmd = [sys.executable, "-m", "jaxdip.cli", "reproduce", "--quick", "--jobs", "1", "--only", ids, "--out"]
    assert subprocess.run([*cmd, str(tmp_path / "whole")], capture_output=True).returncode == 0
    p = subprocess.Popen([*cmd, str(tmp_path / "cut")], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL)
    while not (tmp_path / "cut" / "dip-lqr" / "metrics.json").exists() and p.poll() is None:
        time.sleep(0.05)
    p.kill()
    p.wait()
    r = subprocess.run([*cmd, str(tmp_path / "cut"), "--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "== dip-lqr: complete, kept" in r.stderr
    for exp_id in ids.split(","):
        assert _results(tmp_path / "cut" / exp_id) == _results(tmp_path / "whole" / exp_id)
    assert _report(tmp_path / "cut") == _report(tmp_path / "whole")


@pytest.mark.slow
def test_terminated_parallel_reproduction_resumes(tmp_path):
    """The parallel path: SIGTERM once one experiment is written stops the workers (exit 130, the --resume
    line); the same command with --resume keeps what was finished and runs the rest in workers."""
    ids = "dip-lqr,eki-linear,twip-extra-control"
    cmd = [sys.executable, "-m", "jaxdip.cli", "reproduce", "--quick", "--jobs", "2", "--only", ids, "--out",
           str(tmp_path / "cut")]
    p = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    while p.poll() is None and not any((tmp_path / "cut" / i / "metrics.json").exists() for i in ids.split(",")):
        time.sleep(0.05)
    p.send_signal(signal.SIGTERM)
    err = p.communicate()[1]
    finished = [i for i in ids.split(",") if (tmp_path / "cut" / i / "metrics.json").exists()]
    if p.returncode == 130:
        assert err.strip().splitlines()[-1].endswith("add --resume to the same command to continue"), err
    r = subprocess.run([*cmd, "--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert all(f"== {i}: complete, kept" in r.stderr for i in finished) and finished
    w = subprocess.run([*cmd[:-1], str(tmp_path / "whole")], capture_output=True)  # uninterrupted, 2 workers
    assert w.returncode == 0
    for exp_id in ids.split(","):
        assert _results(tmp_path / "cut" / exp_id) == _results(tmp_path / "whole" / exp_id)
    assert _report(tmp_path / "cut") == _report(tmp_path / "whole")
