"""Faults around a run's commit and bench's files: each case gives its exit code and exactly one line on stderr,
and leaves the output folder and a victim folder beside it as they were, except for the run's own outputs (a
refused run's output goes to the ``dest.kept-*`` folder its error line names, itself one whole run).

The experiment is dip-lqr with its computation replaced by a stub (``fake``): configuration, checks, writing
and commit are the real ones, and nothing compiles. A stub can act in the middle of the run, as a user or a
second run would.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import os
import signal
import stat
import subprocess
import sys

import pytest

import jaxdip.runner as runner
from jaxdip.outdir import MARKER, swap
import outdir_world as W
from outdir_world import ROOT, fake_run, old_run, refused, run, whole, write_run
from snapshots import snapshot

world, fake = W.world, W.fake  # the shared fixtures


def _tests_on_path() -> dict:
    """The environment of a child that imports outdir_world: this folder on its PYTHONPATH."""
    return dict(os.environ, PYTHONPATH=os.path.dirname(os.path.abspath(__file__)))


# ---- a file of the user's in the way, found before the run -------------------------------------------------


def test_report_edited_after_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    with open(world / "dest" / "report.md", "a") as fh:
        fh.write("my own note\n")
    assert "report.md" in refused(world, capsys, run)
    assert fake.calls == 1  # refused before the stub ran again


def test_figure_edited_after_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    (world / "dest" / "fig.png").write_bytes(b"\x89PNG cropped by the user")
    assert "fig.png" in refused(world, capsys, run)


def test_file_removed_and_replaced_by_a_folder_before_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    os.remove(world / "dest" / "metrics.json")
    os.mkdir(world / "dest" / "metrics.json")
    assert "metrics.json" in refused(world, capsys, run)


def test_destination_is_an_ancestor_of_the_working_folder(world, fake, capsys, monkeypatch):
    old_run(world, fake, capsys)
    os.mkdir(world / "dest" / "analysis")
    monkeypatch.chdir(world / "dest" / "analysis")
    refused(world, capsys, lambda: run(out=str(world / "dest")))
    assert os.getcwd() == str(world / "dest" / "analysis")


# ---- the destination changes while the run computes --------------------------------------------------------


def test_user_adds_a_file_during_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    fake.during = lambda: (world / "dest" / "notes.txt").write_text("mine\n")
    refused(world, capsys, run, kept=True, fake=fake)
    assert (world / "dest" / "notes.txt").read_text() == "mine\n"


def test_user_edits_a_file_during_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    fake.during = lambda: (world / "dest" / "report.md").write_text("rewritten\n")
    refused(world, capsys, run, kept=True, fake=fake)


def test_a_name_turns_into_a_folder_during_the_run(world, fake, capsys):
    old_run(world, fake, capsys)

    def during():
        os.remove(world / "dest" / "report.md")
        os.mkdir(world / "dest" / "report.md")
        (world / "dest" / "report.md" / "draft.md").write_text("mine\n")

    fake.during = during
    refused(world, capsys, run, kept=True, fake=fake)


def test_destination_becomes_a_link_to_the_victim_during_the_run(world, fake, capsys):
    fake.during = lambda: os.symlink(world / "victim", world / "dest")
    refused(world, capsys, run, kept=True, fake=fake)
    assert sorted(os.listdir(world / "victim")) == ["thesis.tex"]


def test_destination_deleted_during_the_run(world, fake, capsys):
    import shutil

    old_run(world, fake, capsys)
    fake.during = lambda: shutil.rmtree(world / "dest")
    refused(world, capsys, run, kept=True, fake=fake)


def test_another_experiment_commits_first(world, fake, capsys):
    fake.during = lambda: write_run(world / "dest", "eki-linear", {"metrics.json": "eki"})
    line = refused(world, capsys, run, kept=True, fake=fake)
    assert "eki-linear" in line and whole(world / "dest") == {"metrics.json": "eki"}


def test_another_experiment_commits_first_even_with_force(world, fake, capsys):
    # --force given at the start covers what was there at the start (nothing), not a folder that appeared
    fake.during = lambda: write_run(world / "dest", "eki-linear", {"metrics.json": "eki"})
    refused(world, capsys, lambda: run("--force"), kept=True, fake=fake)
    assert whole(world / "dest") == {"metrics.json": "eki"}


def test_the_same_experiment_commits_first(world, fake, capsys):
    old_run(world, fake, capsys)
    fake.during = lambda: write_run(world / "dest", "dip-lqr", {"metrics.json": "other run"})
    refused(world, capsys, run, kept=True, fake=fake)
    assert whole(world / "dest") == {"metrics.json": "other run"}


# ---- the commit itself fails ---------------------------------------------------------------------------------


def _raise(code):
    def f(*a):
        raise OSError(code, os.strerror(code))
    return f


@pytest.mark.parametrize("code", [errno.EACCES, errno.EROFS, errno.EBUSY, errno.ENOSPC])
def test_exchange_fails(world, fake, capsys, monkeypatch, code):
    old_run(world, fake, capsys)
    monkeypatch.setattr(swap, "exchange", _raise(code))
    assert os.strerror(code) in refused(world, capsys, run, kept=True, fake=fake) or code == errno.ENOSPC


def test_rename_into_a_new_destination_denied(world, fake, capsys, monkeypatch):
    real = swap.rename_noreplace

    def deny_dest(src, dst):
        if dst == str(world / "dest"):
            raise PermissionError(errno.EACCES, "Permission denied")
        real(src, dst)

    monkeypatch.setattr(swap, "rename_noreplace", deny_dest)
    assert "Permission denied" in refused(world, capsys, run, kept=True, fake=fake)


def test_disk_full_writing_the_marker(world, fake, capsys, monkeypatch):
    import builtins

    import jaxdip.outdir.staging as staging

    def full(path, *a, **k):
        if str(path).endswith(MARKER):
            raise OSError(errno.ENOSPC, "No space left on device")
        return builtins.open(path, *a, **k)

    monkeypatch.setattr(staging, "open", full, raising=False)
    assert "disk is full" in refused(world, capsys, run)


def test_disk_full_writing_the_results(world, fake, capsys, monkeypatch):
    import builtins

    import jaxdip.runner.experiment as base

    old_run(world, fake, capsys)

    def full(path, *a, **k):
        if str(path).endswith("metrics.json"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return builtins.open(path, *a, **k)

    monkeypatch.setattr(base, "open", full, raising=False)
    assert "No space left" in refused(world, capsys, run)


def test_disk_full_half_way_through_an_in_place_commit(world, fake, capsys, monkeypatch):
    monkeypatch.chdir(world / "victim")  # --out . : the working folder, committed file by file
    os.remove("thesis.tex")
    assert run(out=".") == 0 and whole(world / "victim") is not None
    capsys.readouterr()
    real, calls = swap.rename_noreplace, []

    def fills_up(src, dst):
        calls.append(dst)
        if len(calls) == 6:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(src, dst)

    monkeypatch.setattr(swap, "rename_noreplace", fills_up)
    before = whole(world / "victim")
    refused(world, capsys, lambda: run(out="."), kept=True)
    assert whole(world / "victim") == before and len(calls) >= 6


def test_the_old_folder_changes_between_the_check_and_the_exchange(world, fake, capsys, monkeypatch):
    old_run(world, fake, capsys)
    real = swap.exchange

    def user_first(a, b):
        (world / "dest" / "late.txt").write_text("mine\n")
        return real(a, b)

    monkeypatch.setattr(swap, "exchange", user_first)
    before = snapshot(world)
    assert run() == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "kept" in err[0]
    assert (world / "dest" / "late.txt").read_text() == "mine\n"
    kept = [n for n in os.listdir(world) if ".kept-" in n]
    after = {p: v for p, v in snapshot(world).items() if not p.startswith(kept[0]) and p != "dest/late.txt"}
    assert after == before  # swapped back: the old run and the late file are where they were


def test_sigterm_during_the_run(world, fake, capsys):
    old_run(world, fake, capsys)
    fake.during = lambda: os.kill(os.getpid(), signal.SIGTERM)
    refused(world, capsys, run, code=130, starts="interrupted: ")


# ---- what a run leaves: modes, staging of killed runs, reproduce's logs --------------------------------------


@pytest.mark.parametrize("mask", [0o002, 0o027])
def test_cli_run_gets_the_umask(world, fake, capsys, mask):
    old = os.umask(mask)
    try:
        assert run(out="a/dest") == 0
    finally:
        os.umask(old)
    for p in ("a", "a/dest"):
        assert stat.S_IMODE(os.stat(world / p).st_mode) == 0o777 & ~mask
    for name in os.listdir(world / "a" / "dest"):
        assert stat.S_IMODE(os.stat(world / "a" / "dest" / name).st_mode) == 0o666 & ~mask, name


def test_staging_of_a_killed_cli_run_is_cleaned_by_the_next(world, fake, capsys):
    code = ("import os; from outdir_world import light_import; od = light_import()\n"
            f"st = od.prepare({str(world / 'dest')!r}, 'dip-lqr')\n"
            "open(os.path.join(st.tmp, 'metrics.json'), 'w').write('half'); os.kill(os.getpid(), 9)\n")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_tests_on_path())
    assert [n for n in os.listdir(world) if ".jaxdip-" in n]
    assert run() == 0
    assert sorted(os.listdir(world)) == ["dest", "victim"] and whole(world / "dest") is not None


@pytest.mark.parametrize("forked", [False, True] if sys.platform.startswith("linux") else [False])
def test_reproduce_leaves_no_temporary_folder(world, forked):
    from test_cli_reliability import _parallel_with_fake_workers

    tmp = world / "tmpdir"
    tmp.mkdir()
    r = _parallel_with_fake_workers(world, ("dip-lqr", "twip-dmso"), 2, forked, tmpdir=tmp)
    assert r.returncode == 0 and os.listdir(tmp) == [], r.stderr
    # a failure: its log is named, and kept
    r = _parallel_with_fake_workers(world, ("eki-linear", "dip-lqr"), 1, forked, tmpdir=tmp)
    logs = os.listdir(tmp)
    assert r.returncode == 1 and len(logs) == 1 and os.path.join(str(tmp), logs[0]) in r.stderr, r.stderr


def test_light_import_does_not_import_jax():
    r = subprocess.run([sys.executable, "-c", "import sys; from outdir_world import "
                        "light_import; light_import(); print('jax' in sys.modules)"], cwd=ROOT, env=_tests_on_path(), capture_output=True,
                       text=True)
    assert r.stdout.strip() == "False", r.stderr


def _planted_staging(world, journal=None, link=False):
    """A folder shaped like a dead run's staging folder, as an archive or a prankster could leave it."""
    c = world / ".dest.jaxdip-planted"
    (c / "new").mkdir(parents=True)
    (c / "old").mkdir()
    (c / "victim").mkdir()  # where a traversing name would land the victim's file
    (c / "owner.pid").write_text("1\n")  # nobody holds its lock: "dead"
    (c / "new" / "metrics.json").write_text("x")
    if link:
        os.symlink(world / "victim", c / "new" / "figs")
    if journal is not None:
        (c / "journal.json").write_text(json.dumps(journal))
    return c


@pytest.mark.parametrize("kind", ["journal_traversal", "journal_absolute", "journal_other_dest", "link_inside"])
def test_a_planted_staging_folder_is_left_alone(world, fake, capsys, kind):
    old_run(world, fake, capsys)
    digest = hashlib.sha256(b"my thesis\n").hexdigest()
    journal = {"journal_traversal": {"mode": "in-place", "dest": str(world / "dest"),
                                     "old": {}, "new": {"metrics.json": digest, "../victim/thesis.tex": digest}},
               "journal_absolute": {"mode": "exchange", "dest": str(world / "dest"), "old": {},
                                    "new": {str(world / "victim" / "thesis.tex"): digest}},
               "journal_other_dest": {"mode": "in-place", "dest": str(world / "victim"),
                                      "old": {"thesis.tex": digest}, "new": {}},
               "link_inside": None}[kind]
    c = _planted_staging(world, journal, link=kind == "link_inside")
    before = snapshot(world)
    assert run() == 0  # the run itself goes ahead
    capsys.readouterr()
    after = snapshot(world)
    for p, v in before.items():
        if p.startswith(("victim", c.name)):
            assert after.get(p) == v, p  # the victim and the planted folder exactly as they were
    assert whole(world / "dest") is not None


def test_reproduce_keeps_a_report_the_user_wrote_during_it(world, fake, capsys, monkeypatch):
    real = runner.registry()["dip-lqr"]
    monkeypatch.setattr(runner, "registry", lambda: {"dip-lqr": dataclasses.replace(real, run=fake_run(fake))})
    os.mkdir(world / "repro")
    fake.during = lambda: (world / "repro" / "REPORT.md").write_text("my own report\n")
    line = refused(world, capsys, ["reproduce", "--quick", "--jobs", "1", "--only", "dip-lqr", "--out", "repro"],
                   fake=fake, extra=("repro/dip-lqr",))
    assert "REPORT.md" in line and (world / "repro" / "REPORT.md").read_text() == "my own report\n"
    assert whole(world / "repro" / "dip-lqr") is not None
