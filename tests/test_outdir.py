"""Output folders: what jaxdip may replace, what it must keep, and what it cleans up after a killed run.

The hostile cases (refusals) are in ``test_outdir_markers.py`` and ``test_outdir_faults.py``; these are the
cases that must succeed, checked file by file against what the user had before.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest

from jaxdip import cli
from jaxdip.outdir import MARKER, OutputError, check_destination, check_file, prepare, write_file_atomic
from jaxdip.outdir import swap
from outdir_world import marker, sha, whole, write_run


def _listing(path):
    return sorted(os.listdir(path))


def test_new_folder_gets_files_and_a_marker_with_their_hashes(tmp_path):
    dest = tmp_path / "a" / "b" / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "{}", "report.md": "r"})
    assert _listing(dest) == [MARKER, "metrics.json", "report.md"]
    m = marker(dest)
    assert m == {"tool": "jaxdip", "format": 2, "owner": "dip-lqr",
                 "files": {"metrics.json": sha("{}"), "report.md": sha("r")}}
    assert _listing(dest.parent) == ["run"]  # no staging folder left beside it


def test_rerun_replaces_only_what_the_previous_run_wrote(tmp_path):
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "old", "old_figure.png": "x"})
    write_run(dest, "dip-lqr", {"metrics.json": "new", "report.md": "r"})
    assert whole(dest) == {"metrics.json": "new", "report.md": "r"}  # the stale figure went, with the old marker
    assert _listing(tmp_path) == ["run"]


def test_force_replaces_another_experiments_run_and_nothing_else(tmp_path):
    dest = tmp_path / "run"
    write_run(dest, "eki-linear", {"metrics.json": "eki", "eki.png": "x"})
    with pytest.raises(OutputError, match="--force"):
        prepare(str(dest), "dip-lqr")
    assert whole(dest) == {"metrics.json": "eki", "eki.png": "x"}
    write_run(dest, "dip-lqr", {"metrics.json": "lqr"}, force=True)
    assert whole(dest) == {"metrics.json": "lqr"} and marker(dest)["owner"] == "dip-lqr"


def test_existing_empty_folder_keeps_its_permissions(tmp_path):
    dest = tmp_path / "empty"
    dest.mkdir(mode=0o750)
    os.chmod(dest, 0o750)
    write_run(dest, "dip-lqr", {"metrics.json": "{}"})
    assert whole(dest) == {"metrics.json": "{}"} and stat.S_IMODE(os.stat(dest).st_mode) == 0o750


def test_out_dot_keeps_the_working_folder_itself(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    inode = os.stat(tmp_path).st_ino
    write_run(".", "dip-lqr", {"metrics.json": "{}"})
    assert os.getcwd() == str(tmp_path) and whole(tmp_path) == {"metrics.json": "{}"}
    write_run(".", "dip-lqr", {"metrics.json": "2", "report.md": "r"})  # and again, in place
    assert whole(tmp_path) == {"metrics.json": "2", "report.md": "r"}
    assert os.stat(".").st_ino == inode
    assert not [n for n in os.listdir(tmp_path.parent) if n.startswith(f".{tmp_path.name}.")]  # no staging left


def test_without_atomic_exchange_files_move_in_place(tmp_path, monkeypatch):
    monkeypatch.setattr(swap, "exchange", lambda a, b: False)  # a kernel or filesystem without RENAME_EXCHANGE
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "old", "a.png": "a"})
    write_run(dest, "dip-lqr", {"metrics.json": "new", "b.png": "b"})
    assert whole(dest) == {"metrics.json": "new", "b.png": "b"} and _listing(tmp_path) == ["run"]


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_folders_and_files_get_the_users_umask(tmp_path, mask):
    old = os.umask(mask)
    try:
        write_run(tmp_path / "x" / "run", "dip-lqr", {"metrics.json": "{}"})
        write_file_atomic(str(tmp_path / "bench.json"), "{}")
    finally:
        os.umask(old)
    for p, full in ((tmp_path / "x", 0o777), (tmp_path / "x" / "run", 0o777),
                    (tmp_path / "x" / "run" / "metrics.json", 0o666), (tmp_path / "x" / "run" / MARKER, 0o666),
                    (tmp_path / "bench.json", 0o666)):
        assert stat.S_IMODE(os.stat(p).st_mode) == full & ~mask, p


def test_discard_removes_the_staging_folder_and_the_ancestors_it_made(tmp_path):
    st = prepare(str(tmp_path / "x" / "y" / "run"), "dip-lqr")
    assert os.path.isdir(st.tmp)
    st.discard()
    st.discard()
    assert _listing(tmp_path) == []


def _locked_staging_in_another_process(parent, dest_name):
    """A live process holding a staging folder (its owner lock) until its stdin closes."""
    code = ("import sys; from outdir_world import light_import; od = light_import()\n"
            f"st = od.prepare({str(parent / dest_name)!r}, 'dip-lqr'); print(st.container, flush=True)\n"
            "sys.stdin.read()\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                         cwd=os.path.dirname(os.path.dirname(__file__)),
                         env=dict(os.environ, PYTHONPATH=os.path.dirname(os.path.abspath(__file__))))
    return p, p.stdout.readline().strip()


def test_staging_of_a_killed_run_is_removed_and_a_live_ones_is_kept(tmp_path):
    live, live_dir = _locked_staging_in_another_process(tmp_path, "run")
    dead, dead_dir = _locked_staging_in_another_process(tmp_path, "run")
    dead.kill()
    dead.wait()
    with open(os.path.join(dead_dir, "new", "metrics.json"), "w") as fh:
        fh.write("partial")
    lookalike = tmp_path / ".run.jaxdip-nopid"  # no owner lock file: not provably a run's, left alone
    lookalike.mkdir()
    (lookalike / "metrics.json").write_text("x")
    (tmp_path / ".run.jaxdip-empty").mkdir()  # killed between making it and locking it: empty, so removed
    other, other_dir = _locked_staging_in_another_process(tmp_path, "other")  # another destination's
    other.kill()
    other.wait()
    try:
        write_run(tmp_path / "run", "dip-lqr", {"metrics.json": "{}"})
        assert not os.path.exists(dead_dir)
        assert os.path.isdir(live_dir) and lookalike.exists() and os.path.isdir(other_dir)
        assert not (tmp_path / ".run.jaxdip-empty").exists()
    finally:
        live.stdin.close()
        live.wait()


def test_a_half_done_in_place_commit_is_rolled_back_by_the_next_check(tmp_path, monkeypatch):
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "old", "report.md": "old"})
    monkeypatch.setattr(swap, "exchange", lambda a, b: False)
    st = prepare(str(dest), "dip-lqr")
    (open(os.path.join(st.tmp, "metrics.json"), "w")).write("new")
    calls = []
    real = swap.rename_noreplace

    def dies_on_the_fourth_move(src, dst):
        calls.append(dst)
        if len(calls) == 4:
            raise SystemExit  # stands for the process dying here: no roll back runs after it
        real(src, dst)

    monkeypatch.setattr(swap, "rename_noreplace", dies_on_the_fourth_move)
    monkeypatch.setattr(swap, "roll_back", lambda *a: None)
    with pytest.raises(SystemExit):
        st.commit()
    monkeypatch.undo()
    assert whole(dest) is None  # half: the old marker and report are out, the new metrics in
    os.close(st._lock_fd)  # the process "dies": its owner lock goes
    check_destination(str(dest), "dip-lqr")
    assert whole(dest) == {"metrics.json": "old", "report.md": "old"} and _listing(tmp_path) == ["run"]


def test_a_half_done_commit_whose_destination_then_vanished_is_left_alone(tmp_path, monkeypatch):
    import shutil

    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "old"})
    monkeypatch.setattr(swap, "exchange", lambda a, b: False)
    st = prepare(str(dest), "dip-lqr")
    (open(os.path.join(st.tmp, "metrics.json"), "w")).write("new")
    real, calls = swap.rename_noreplace, []

    def dies_on_the_second_move(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise SystemExit
        real(src, dst)

    monkeypatch.setattr(swap, "rename_noreplace", dies_on_the_second_move)
    monkeypatch.setattr(swap, "roll_back", lambda *a: None)
    with pytest.raises(SystemExit):
        st.commit()  # "dies" with the old marker moved out, nothing else
    monkeypatch.undo()
    os.close(st._lock_fd)
    shutil.rmtree(dest)  # the user removed the folder meanwhile
    check_destination(str(dest), "dip-lqr")  # recovery has nowhere to put the old files back: no traceback
    assert os.path.isfile(os.path.join(st.container, "old", MARKER))  # the old marker stays for a person


def test_single_files_replace_only_their_own_kind(tmp_path):
    path = tmp_path / "bench.json"
    write_file_atomic(str(path), json.dumps({"tool": "jaxdip bench"}))
    check_file(str(path), lambda d: b'"tool": "jaxdip bench"' in d)  # ours: may be replaced
    path.write_text('{"my": 1}')
    with pytest.raises(OutputError, match="not written by jaxdip"):
        check_file(str(path), lambda d: b'"tool": "jaxdip bench"' in d)
    assert _listing(tmp_path) == ["bench.json"]  # no temporary file left


def test_cli_run_into_the_working_folder_twice(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    argv = ["run", "dip-lqr", "--quick", "--seeds", "4", "--set", "duration=0.5", "--out", "."]
    assert cli.main(argv) == 0
    first = json.loads((tmp_path / "metrics.json").read_text())["results"]
    files = whole(tmp_path)
    assert files is not None and "report.md" in files and "config.toml" in files
    assert cli.main(argv) == 0
    assert sorted(whole(tmp_path)) == sorted(files)
    assert json.loads((tmp_path / "metrics.json").read_text())["results"] == first


def test_marker_round_trip_and_one_byte_off(tmp_path):
    from jaxdip.outdir.marker import NotOurs, marker_text, parse_marker

    files = {"metrics.json": sha("a"), "fig3_3-controllers.png": sha("b")}
    text = marker_text("dip-lqr", files)
    assert parse_marker(text.encode()) == ("dip-lqr", files)
    assert json.loads(text) == {"tool": "jaxdip", "format": 2, "owner": "dip-lqr", "files": files}
    for bad in (text.replace('"format": 2', '"format": 2.0'), text.replace("dip-lqr", "dip lqr"), text + "x"):
        with pytest.raises(NotOurs):
            parse_marker(bad.encode())
    with pytest.raises(ValueError):
        marker_text("dip-lqr", {"../x": sha("a")})  # jaxdip never records a name it would refuse to read


def test_a_hard_link_the_user_made_to_an_output_keeps_its_content(tmp_path):
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", {"metrics.json": "old"})
    os.link(dest / "metrics.json", tmp_path / "kept_by_me.json")  # a regular file of ours by name and content
    write_run(dest, "dip-lqr", {"metrics.json": "new"})
    assert whole(dest) == {"metrics.json": "new"} and (tmp_path / "kept_by_me.json").read_text() == "old"


OLD_RUN = {"metrics.json": "old", "report.md": "old", "a.png": "old"}
NEW_RUN = {"metrics.json": "new", "report.md": "new", "b.png": "new"}


def _dies(monkeypatch, target, when):
    """Make ``swap.<target>`` end the "process" (SystemExit, no roll back) ``when`` = (call number, before or
    after the real call)."""
    real, calls = getattr(swap, target), []
    n, phase = when

    def f(*a):
        calls.append(a)
        if len(calls) == n and phase == "before":
            raise SystemExit
        out = real(*a)
        if len(calls) == n and phase == "after":
            raise SystemExit
        return out

    monkeypatch.setattr(swap, target, f)
    monkeypatch.setattr(swap, "roll_back", lambda *a: None)


@pytest.mark.parametrize("when", [(n, p) for n in range(1, 9) for p in ("before", "after")])
def test_in_place_commit_killed_at_every_move_is_whole_after_recovery(tmp_path, monkeypatch, when):
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", OLD_RUN)
    monkeypatch.setattr(swap, "exchange", lambda a, b: False)
    st = prepare(str(dest), "dip-lqr")
    for name, text in NEW_RUN.items():
        (open(os.path.join(st.tmp, name), "w")).write(text)
    _dies(monkeypatch, "rename_noreplace", when)  # 4 moves out (marker first), 4 in (marker last)
    with pytest.raises(SystemExit):
        st.commit()
    monkeypatch.undo()
    os.close(st._lock_fd)
    check_destination(str(dest), "dip-lqr")
    assert whole(dest) == (NEW_RUN if when == (8, "after") else OLD_RUN)  # new only once its marker is in
    assert _listing(tmp_path) == ["run"]


@pytest.mark.parametrize("phase", ["before", "after"])
def test_exchange_commit_killed_around_the_exchange_is_always_whole(tmp_path, monkeypatch, phase):
    dest = tmp_path / "run"
    write_run(dest, "dip-lqr", OLD_RUN)
    st = prepare(str(dest), "dip-lqr")
    for name, text in NEW_RUN.items():
        (open(os.path.join(st.tmp, name), "w")).write(text)
    _dies(monkeypatch, "exchange", (1, phase))
    with pytest.raises(SystemExit):
        st.commit()
    monkeypatch.undo()
    expected = OLD_RUN if phase == "before" else NEW_RUN
    assert whole(dest) == expected  # whole without any recovery
    os.close(st._lock_fd)
    check_destination(str(dest), "dip-lqr")  # the next run removes the staging folder (and the replaced run)
    assert whole(dest) == expected and _listing(tmp_path) == ["run"]
