"""Helpers shared by the output-folder tests: write a run through the staging API, read a marker back, check
that a folder is one whole jaxdip run, load ``jaxdip.outdir`` without importing JAX (for driver processes), and
the fault tests' world (a working folder with a victim folder beside the output), stub experiment and refusal check."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import types

import pytest

from snapshots import snapshot

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def light_import():
    """``jaxdip.outdir`` without ``jaxdip/__init__`` (which imports JAX): a driver process starts in ~50 ms."""
    if "jaxdip" not in sys.modules:
        pkg = types.ModuleType("jaxdip")
        pkg.__path__ = [os.path.join(ROOT, "jaxdip")]
        sys.modules["jaxdip"] = pkg
    import jaxdip.outdir

    return jaxdip.outdir


def write_run(path, owner, files, *, force=False):
    from jaxdip.outdir import prepare

    st = prepare(str(path), owner, force=force)
    try:
        for name, text in files.items():
            with open(os.path.join(st.tmp, name), "w") as fh:
                fh.write(text)
        st.commit()
    finally:
        st.discard()
    return st


def marker(folder) -> dict:
    with open(os.path.join(folder, ".jaxdip.json"), encoding="utf-8") as fh:
        return json.load(fh)


def sha(data) -> str:
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()


def whole(folder) -> dict[str, str] | None:
    """The files of ``folder`` ({name: text}) if it is exactly one jaxdip run (every file listed in its marker
    with the recorded hash, nothing else), else None."""
    try:
        m = marker(folder)
        names = sorted(os.listdir(folder))
    except (OSError, ValueError):
        return None
    if names != sorted([".jaxdip.json", *m["files"]]):
        return None
    out = {}
    for name, digest in m["files"].items():
        with open(os.path.join(folder, name), "rb") as fh:
            data = fh.read()
        if sha(data) != digest:
            return None
        out[name] = data.decode("utf-8", "replace")
    return out


# ---- the fault tests' world, stub experiment and refusal check --------------------------------------------


@pytest.fixture
def world(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    (tmp_path / "victim").mkdir()
    (tmp_path / "victim" / "thesis.tex").write_text("my thesis\n")
    return tmp_path


@pytest.fixture
def fake(monkeypatch, world):
    """``fake.during`` (if set) runs inside the stub experiment, between the start checks and the commit; what
    it changes is the user's (or another run's) doing, so the folder is snapshot again after it."""
    import jaxdip.runner as runner  # here, not at the top: the driver processes must not import JAX

    real_get = runner.get
    state = type("Fake", (), {"during": None, "calls": 0, "seen": None, "world": world})()
    monkeypatch.setattr(runner, "get", lambda exp_id: dataclasses.replace(real_get(exp_id), run=fake_run(state)))
    return state


def fake_run(state):
    """The stub experiment's run function."""
    from matplotlib.figure import Figure

    from jaxdip.runner import Outcome

    world = state.world

    def run(cfg, ctx):
        state.calls += 1
        if state.during is not None:
            state.during()
            state.seen = {p: v for p, v in snapshot(world).items()
                          if not any(".jaxdip-" in part for part in p.split(os.sep))}  # the run's staging
        fig = Figure(figsize=(1, 1))
        fig.add_subplot().plot([0, state.calls])
        return Outcome(results={"calls": state.calls}, report="stub report", figures={"fig": fig})

    return run


def run(*extra, out="dest", exp="dip-lqr"):
    from jaxdip import cli

    return cli.main(["run", exp, "--quick", "--out", out, *extra])


def refused(world, capsys, argv_or_fn, *, code=2, kept=False, starts="error: --out: ", fake=None, extra=()):
    """Run it, check exit code, one line, and that nothing changed but the kept folder (and the run's own
    outputs under ``extra``); returns the line."""
    from jaxdip import cli

    before = snapshot(world)
    got = argv_or_fn() if callable(argv_or_fn) else cli.main(argv_or_fn)
    if fake is not None and fake.seen is not None:
        before = fake.seen
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("== ")]  # reproduce's progress lines
    assert got == code, err
    assert len(lines) == 1 and lines[0].startswith(starts), err
    assert len(lines[0]) <= 300 and lines[0].isprintable(), lines[0]
    after = snapshot(world)
    kept_dirs = sorted({p.split(os.sep)[0] for p in after if ".kept-" in p.split(os.sep)[0]})
    assert len(kept_dirs) == int(kept), (kept_dirs, err)
    if kept:
        assert kept_dirs[0] in lines[0] and whole(world / kept_dirs[0]) is not None
        after = {p: v for p, v in after.items() if not p.startswith(kept_dirs[0])}
    after = {p: v for p, v in after.items() if not p.startswith(tuple(extra))}
    assert after == before
    assert not [n for n in os.listdir(world) if ".jaxdip-" in n]  # no staging folder left
    return lines[0]


def old_run(world, fake, capsys, out="dest", exp="dip-lqr"):
    assert run(out=out, exp=exp) == 0
    capsys.readouterr()
    assert whole(world / out) is not None
