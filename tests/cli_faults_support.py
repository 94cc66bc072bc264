"""What the command line's fault tests share: the one-line check of a refusal, the ``world`` of folders a run must
leave as they were, and a child ``jaxdip`` process with a clean environment."""

from __future__ import annotations

import os
import subprocess
import sys

RUN = ["run", "dip-lqr", "--quick", "--out", "o"]


def one_line(err: str) -> str:
    """The single line of ``err``, after checking the contract's form."""
    assert err.endswith("\n") and err.count("\n") == 1, repr(err[:2000])
    line = err[:-1]
    assert len(line) <= 300, len(line)
    assert not any(ord(c) < 32 or 0x7F <= ord(c) < 0xA0 for c in line), repr(line)
    return line


def make_world(tmp_path, monkeypatch):
    """``work`` (the working folder, with a user's file and folder) and ``victim`` beside it: each test file's
    ``world`` fixture."""
    work, victim = tmp_path / "work", tmp_path / "victim"
    for d in (work, victim):
        (d / "sub").mkdir(parents=True)
        (d / "notes.txt").write_text("mine\n")
        (d / "sub" / "data.csv").write_text("1,2\n")
    (work / "bad_seeds.toml").write_text("seeds = -3\n")
    (work / "bad_dt.toml").write_text('dt = "fast"\n')
    os.mkfifo(work / "fifo.toml")
    monkeypatch.chdir(work)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # restored after the test
    return work, victim


def child_env(**extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SLURM_", "OMPI_", "PMI_", "JAX_COORD"))}
    env.update(JAXDIP_NO_PROGRESS="1", **extra)
    return env


def run_child(args, cwd, timeout=60, **popen):
    popen.setdefault("stdout", subprocess.PIPE)
    return subprocess.run([sys.executable, "-m", "jaxdip.cli", *args], cwd=cwd, env=popen.pop("env", child_env()),
                          stderr=subprocess.PIPE, text=True, timeout=timeout, **popen)
