"""Output folders: what jaxdip may replace, what it must keep, and what it cleans up after a killed run.

The hostile cases (refusals) are in ``test_cli_reliability.py``; these are the cases that must succeed, checked
file by file against what the user had before.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from jaxdip import cli
from jaxdip.outdir import MARKER, PIDFILE, OutputError, check_file, prepare, read_marker, write_file_atomic


def _write_run(path, owner, files, *, force=False):
    st = prepare(path, owner, force=force)
    try:
        for name, text in files.items():
            with open(os.path.join(st.tmp, name), "w") as fh:
                fh.write(text)
        st.commit()
    finally:
        st.discard()


def _listing(path):
    return sorted(os.listdir(path))


def test_new_folder_gets_files_and_marker(tmp_path):
    dest = tmp_path / "a" / "b" / "run"
    _write_run(str(dest), "dip-lqr", {"metrics.json": "{}", "report.md": "r"})
    assert _listing(dest) == [MARKER, "metrics.json", "report.md"]
    m = read_marker(str(dest))
    assert m["owner"] == "dip-lqr" and m["files"] == ["metrics.json", "report.md"]
    assert _listing(dest.parent) == ["run"]  # no temporary folder left beside it


def test_rerun_replaces_only_what_the_previous_run_wrote(tmp_path):
    dest = tmp_path / "run"
    _write_run(str(dest), "dip-lqr", {"metrics.json": "old", "old_figure.png": "x"})
    _write_run(str(dest), "dip-lqr", {"metrics.json": "new", "report.md": "r"})
    assert _listing(dest) == [MARKER, "metrics.json", "report.md"]  # the stale figure went, with the old marker
    assert (dest / "metrics.json").read_text() == "new"


def test_force_replaces_another_experiments_run_and_nothing_else(tmp_path):
    dest = tmp_path / "run"
    _write_run(str(dest), "eki-linear", {"metrics.json": "eki", "eki.png": "x"})
    with pytest.raises(OutputError, match="--force"):
        prepare(str(dest), "dip-lqr")
    assert (dest / "metrics.json").read_text() == "eki"
    _write_run(str(dest), "dip-lqr", {"metrics.json": "lqr"}, force=True)
    assert _listing(dest) == [MARKER, "metrics.json"] and read_marker(str(dest))["owner"] == "dip-lqr"


def test_existing_empty_folder_is_used_in_place(tmp_path):
    dest = tmp_path / "empty"
    dest.mkdir()
    inode = os.stat(dest).st_ino
    _write_run(str(dest), "dip-lqr", {"metrics.json": "{}"})
    assert os.stat(dest).st_ino == inode and _listing(dest) == [MARKER, "metrics.json"]


def test_out_dot_in_an_empty_working_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _write_run(".", "dip-lqr", {"metrics.json": "{}"})
    assert os.getcwd() == str(tmp_path) and _listing(tmp_path) == [MARKER, "metrics.json"]
    _write_run(".", "dip-lqr", {"metrics.json": "{}", "report.md": "r"})  # and again, in place
    assert _listing(tmp_path) == [MARKER, "metrics.json", "report.md"]


def test_a_file_the_user_adds_during_the_run_stops_the_commit(tmp_path):
    dest = tmp_path / "run"
    _write_run(str(dest), "dip-lqr", {"metrics.json": "old"})
    st = prepare(str(dest), "dip-lqr")
    with open(os.path.join(st.tmp, "metrics.json"), "w") as fh:
        fh.write("new")
    (dest / "analysis.py").write_text("mine")
    with pytest.raises(OutputError, match="analysis.py"):
        st.commit()
    st.discard()
    assert (dest / "analysis.py").read_text() == "mine" and (dest / "metrics.json").read_text() == "old"
    assert _listing(tmp_path) == ["run"]


def test_discard_removes_the_temporary_folder_and_the_ancestors_it_made(tmp_path):
    st = prepare(str(tmp_path / "x" / "y" / "run"), "dip-lqr")
    assert os.path.isdir(st.tmp)
    st.discard()
    assert _listing(tmp_path) == []


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_staging_of_a_killed_run_is_removed_and_a_live_ones_is_kept(tmp_path):
    def staging(name, pid):
        d = tmp_path / name
        d.mkdir()
        (d / "metrics.json").write_text("partial")
        if pid is not None:
            (d / PIDFILE).write_text(str(pid))
        return d

    dead = staging(".run.tmp-dead", _dead_pid())
    live = staging(".run.tmp-live", os.getpid())
    unmarked = staging(".run.tmp-nopid", None)  # not provably ours: left alone
    other = staging(".other.tmp-dead", _dead_pid())  # another destination's: left alone
    _write_run(str(tmp_path / "run"), "dip-lqr", {"metrics.json": "{}"})
    assert not dead.exists()
    assert live.exists() and unmarked.exists() and other.exists()


def test_single_files_replace_only_their_own_kind(tmp_path):
    path = tmp_path / "bench.json"
    write_file_atomic(str(path), json.dumps({"tool": "jaxdip bench"}))
    check_file(str(path), lambda t: '"tool": "jaxdip bench"' in t)  # ours: may be replaced
    path.write_text('{"my": 1}')
    with pytest.raises(OutputError, match="not written by jaxdip"):
        check_file(str(path), lambda t: '"tool": "jaxdip bench"' in t)
    assert _listing(tmp_path) == ["bench.json"]  # no temporary file left


def test_cli_run_into_the_working_folder_twice(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    argv = ["run", "dip-lqr", "--quick", "--seeds", "4", "--set", "duration=0.5", "--out", "."]
    assert cli.main(argv) == 0
    first = json.loads((tmp_path / "metrics.json").read_text())["results"]
    files = _listing(tmp_path)
    assert MARKER in files and "report.md" in files
    assert cli.main(argv) == 0
    assert _listing(tmp_path) == files
    assert json.loads((tmp_path / "metrics.json").read_text())["results"] == first
