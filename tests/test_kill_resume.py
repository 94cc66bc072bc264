"""Long searches killed mid-run (SIGKILL: no chance to clean up; SIGINT: Ctrl-C) and continued with ``--resume``
give ``results`` identical to an uninterrupted run, and nothing half-written in between."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# small enough to run in seconds, long enough (20 checkpoints; the judging after the search takes seconds more)
# that a kill at the first checkpoint lands inside the search
EKI = ["run", "eki-dip", "--quick", "--seeds", "4", "--set", "ensemble=8", "--set", "iterations=40",
       "--set", "chunk=2", "--set", "T=0.4", "--set", "t_star=0.1", "--set", "grad_steps=0",
       "--set", "eval_states=2", "--set", "judge_duration=0.2", "--set", "early_stop=false",
       "--set", "min_success=2"]
TUNE = ["run", "tune", "--quick", "--set", "steps=40", "--set", "patience=0", "--set", "heldout_seeds=8",
        "--set", "landscape_points=3"]


def _env():
    return dict(os.environ, JAXDIP_NO_PROGRESS="1")


def _run(argv, cwd):
    return subprocess.run([sys.executable, "-m", "jaxdip.cli", *argv], capture_output=True, text=True,
                          env=_env(), cwd=cwd, timeout=600)


def _results(folder):
    with open(os.path.join(folder, "metrics.json")) as fh:
        return json.load(fh)["results"]


def kill_and_resume(tmp_path, argv, sig):
    _kill_and_resume(tmp_path, argv, sig)
    # the uninterrupted reference runs last (its own folder and checkpoint file): by then the runs before it have
    # compiled its programs into the shared compilation cache, so the test costs about one cold run, not two
    ref = _run([*argv, "--out", "ref"], tmp_path)
    assert ref.returncode == 0, ref.stderr
    assert json.dumps(_results(tmp_path / "run"), sort_keys=True) == json.dumps(_results(tmp_path / "ref"),
                                                                              sort_keys=True)


def _checkpoint(tmp_path):
    """The run's checkpoint: beside its folder, named after the folder, the experiment and the run's fingerprint."""
    found = [p for p in tmp_path.glob(".run.*.ckpt.npz") if ".tmp." not in p.name]
    return found[0] if found else None


def _kill_and_resume(tmp_path, argv, sig):
    p = subprocess.Popen([sys.executable, "-m", "jaxdip.cli", *argv, "--out", "run"], cwd=tmp_path, env=_env(),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while _checkpoint(tmp_path) is None and p.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    ckpt = _checkpoint(tmp_path)
    assert ckpt is not None, "no checkpoint appeared"
    assert ckpt.name.startswith(f".run.{argv[1]}.")
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    assert p.returncode != 0, "the run finished before the signal: make the test's search longer"
    assert not (tmp_path / "run").exists()  # nothing half-written
    assert ckpt.exists()  # the last checkpoint survives
    if sig == signal.SIGINT:
        assert p.returncode == 130
        last = err.strip().splitlines()[-1]
        assert last.startswith("interrupted: progress kept in ") and "--resume" in last, err
    res = _run([*argv, "--out", "run", "--resume"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert not ckpt.exists()  # removed once the folder is complete


def test_eki_dip_sigkill_then_resume(tmp_path):
    kill_and_resume(tmp_path, EKI, signal.SIGKILL)


@pytest.mark.slow
def test_eki_dip_sigint_then_resume(tmp_path):
    kill_and_resume(tmp_path, EKI, signal.SIGINT)


@pytest.mark.slow
def test_tune_sigkill_then_resume(tmp_path):
    kill_and_resume(tmp_path, TUNE, signal.SIGKILL)


@pytest.mark.slow
def test_tune_sigint_then_resume(tmp_path):
    kill_and_resume(tmp_path, TUNE, signal.SIGINT)
