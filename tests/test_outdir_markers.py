"""Hostile and damaged markers: a run into a folder whose ``.jaxdip.json`` is not exactly what jaxdip writes
stops with one line (exit 2) and leaves the folder, and a victim folder beside it, exactly as they were.

Each case builds ``dest`` (holding ``metrics.json``, an old result) with some marker, next to ``victim`` (the
user's files that a marker tries to reach). The run goes through ``jaxdip.cli.main`` in-process; every case is
refused before anything compiles.
"""

from __future__ import annotations

import json
import os

import pytest

from jaxdip import cli
from jaxdip.outdir import MARKER
from outdir_world import sha
from snapshots import snapshot

OLD = "old result\n"
SECRET = "my thesis\n"


def _valid(**over):
    m = {"tool": "jaxdip", "format": 2, "owner": "dip-lqr", "files": {"metrics.json": sha(OLD)}}
    m.update(over)
    return json.dumps(m).encode()


def _files(files):
    return _valid(files=files)


# name -> marker bytes, or a function(world) that builds the marker itself (special files, links)
def _symlinked_marker(w):
    (w / "elsewhere.json").write_bytes(_valid())
    os.symlink(w / "elsewhere.json", w / "dest" / MARKER)


def _marker_dir(w):
    os.mkdir(w / "dest" / MARKER)


def _marker_fifo(w):
    os.mkfifo(w / "dest" / MARKER)  # reading it would block forever


def _marker_dev_zero(w):
    os.symlink("/dev/zero", w / "dest" / MARKER)


def _marker_other_user(w):
    (w / "dest" / MARKER).write_bytes(_valid())
    os.chown(w / "dest" / MARKER, 65534, 65534)


def _listed_symlink_to_victim(w):
    # an entry named like an output, a link to the user's file, listed with that file's own hash
    os.remove(w / "dest" / "metrics.json")
    os.symlink(w / "victim" / "thesis.tex", w / "dest" / "metrics.json")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(SECRET)}))


def _listed_symlinked_folder(w):
    os.symlink(w / "victim", w / "dest" / "figs")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(OLD), "figs": sha(SECRET)}))


def _listed_name_is_a_folder(w):
    os.mkdir(w / "dest" / "report.md")
    (w / "dest" / "report.md" / "keep.txt").write_text("mine\n")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(OLD), "report.md": sha("")}))


def _edited_file(w):
    (w / "dest" / MARKER).write_bytes(_valid())
    (w / "dest" / "metrics.json").write_text(OLD + "my note\n")


def _control_characters(w):
    name = "evil\x1b[31mred"
    (w / "dest" / name).write_text("x")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(OLD), name: sha("x")}))


def _dest_is_symlink(w):
    os.rename(w / "dest", w / "real_dest")
    (w / "real_dest" / MARKER).write_bytes(_valid())
    os.symlink(w / "real_dest", w / "dest")


def _fifo_entry(w):
    os.mkfifo(w / "dest" / "report.md")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(OLD), "report.md": sha("")}))


def _hardlink_to_victim(w):
    # a hard link is a regular file with the victim's content: listed with that hash it would be "ours" by
    # content; replacing it unlinks only this name, the victim keeps its data (checked by the snapshot)
    os.remove(w / "dest" / "metrics.json")
    os.link(w / "victim" / "thesis.tex", w / "dest" / "metrics.json")
    (w / "dest" / MARKER).write_bytes(_files({"metrics.json": sha(SECRET)}))
    (w / "dest" / "extra.txt").write_text("unlisted\n")  # and an unlisted file, so the run must refuse


def _non_utf8_name(w):
    (w / "dest" / MARKER).write_bytes(_valid())
    with open(os.path.join(os.fsencode(w / "dest"), b"caf\xe9\x1b.txt"), "w") as fh:  # not UTF-8, with ESC
        fh.write("mine\n")


CASES = {
    # names that would be paths
    "traversal": _files({"../victim/thesis.tex": sha(SECRET)}),
    "traversal_nested": _files({"a/../../victim/thesis.tex": sha(SECRET)}),
    "traversal_only_dotdot": _files({"..": sha(SECRET)}),
    "dot": _files({".": sha(SECRET)}),
    "absolute": "ABS",  # filled in with the victim's absolute path
    "backslash": _files({"..\\victim\\thesis.tex": sha(SECRET)}),
    "nul_in_name": _files({"metrics.json\x00../victim": sha(OLD)}),
    "empty_name": _files({"": sha(OLD)}),
    "slash_in_name": _files({"sub/metrics.json": sha(OLD)}),
    "hidden_marker_listed": _files({MARKER: sha(OLD), "metrics.json": sha(OLD)}),
    # wrong types and shapes
    "old_format_list": json.dumps({"tool": "jaxdip", "owner": "dip-lqr", "files": ["metrics.json"]}).encode(),
    "files_non_string_list": _files([1, 2]),
    "files_nested_list": _files([["metrics.json"]]),
    "files_string": _files("metrics.json"),
    "files_null": _files(None),
    "digest_not_string": _files({"metrics.json": 5}),
    "digest_uppercase": _files({"metrics.json": sha(OLD).upper()}),
    "digest_short": _files({"metrics.json": sha(OLD)[:40]}),
    "digest_nested": _files({"metrics.json": [sha(OLD)]}),
    "too_many_files": _files({f"f{i}.png": sha(OLD) for i in range(600)}),
    "huge": _valid()[:-1] + b"," + b" " * 70_000 + b'"pad": 1}',
    "deeply_nested": b'{"tool": "jaxdip", "files": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
    "duplicate_file_key": ('{"tool": "jaxdip", "format": 2, "owner": "dip-lqr", "files": {"metrics.json": "%s", '
                           '"metrics.json": "%s"}}' % (sha(OLD), sha(OLD))).encode(),
    "duplicate_owner_key": ('{"tool": "jaxdip", "format": 2, "owner": "eki-dip", "owner": "dip-lqr", '
                            '"files": {"metrics.json": "%s"}}' % sha(OLD)).encode(),
    "unknown_key": _valid(extra=1),
    "missing_format": json.dumps({"tool": "jaxdip", "owner": "dip-lqr", "files": {"metrics.json": sha(OLD)}}).encode(),
    "format_string": _valid(format="2"),
    "format_bool": _valid(format=True),
    "format_future": _valid(format=3),
    "format_nan": _valid()[:-1] + b', "format": NaN}',
    # wrong tool or owner
    "tool_other": _valid(tool="other"),
    "tool_missing": json.dumps({"format": 2, "owner": "dip-lqr", "files": {"metrics.json": sha(OLD)}}).encode(),
    "tool_case": _valid(tool="JAXDIP"),
    "owner_number": _valid(owner=5),
    "owner_traversal": _valid(owner="../dip-lqr"),
    "owner_other_experiment": _valid(owner="eki-linear"),
    "owner_empty": _valid(owner=""),
    # not JSON, not an object
    "not_json": b"{not json",
    "empty_file": b"",
    "not_utf8": b'{"tool": "jaxdip\xff"}',
    "utf8_bom": b"\xef\xbb\xbf" + _valid(),
    "array": b"[]",
    "trailing_garbage": _valid() + b" {}",
    # the marker is not a regular file of this user, or the folder holds something else
    "marker_symlink": _symlinked_marker,
    "marker_directory": _marker_dir,
    "marker_fifo": _marker_fifo,
    "marker_dev_zero": _marker_dev_zero,
    "marker_other_user": _marker_other_user,
    "listed_symlink_to_victim": _listed_symlink_to_victim,
    "listed_symlinked_folder": _listed_symlinked_folder,
    "listed_name_is_a_folder": _listed_name_is_a_folder,
    "listed_fifo": _fifo_entry,
    "edited_since_written": _edited_file,
    "control_characters_in_a_name": _control_characters,
    "destination_is_a_symlink": _dest_is_symlink,
    "hardlink_to_victim_plus_unlisted": _hardlink_to_victim,
    "non_utf8_file_name_beside_a_valid_marker": _non_utf8_name,
}


def test_there_are_at_least_thirty_markers():
    assert len(CASES) >= 30


@pytest.fixture
def world(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    (tmp_path / "victim").mkdir()
    (tmp_path / "victim" / "thesis.tex").write_text(SECRET)
    (tmp_path / "victim" / "data").mkdir()
    (tmp_path / "victim" / "data" / "raw.csv").write_text("1,2\n")
    (tmp_path / "dest").mkdir()
    (tmp_path / "dest" / "metrics.json").write_text(OLD)
    return tmp_path


# with --force another experiment's valid folder is replaced (tests/test_outdir.py): not a hostile case
_RUNS = [(name, force) for name in CASES for force in (False, True)
         if not (name == "owner_other_experiment" and force)]


@pytest.mark.parametrize("name, force", _RUNS, ids=[f"{n}-{'force' if f else 'plain'}" for n, f in _RUNS])
def test_hostile_marker(world, capsys, name, force):
    if name == "marker_other_user" and os.geteuid() != 0:
        pytest.skip("making a file of another user needs root")
    case = CASES[name]
    if case == "ABS":
        case = _files({str(world / "victim" / "thesis.tex"): sha(SECRET)})
    if callable(case):
        case(world)
    else:
        (world / "dest" / MARKER).write_bytes(case)
    before = snapshot(world)
    code = cli.main(["run", "dip-lqr", "--quick", "--out", "dest"] + ["--force"] * force)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: --out: "), err
    assert len(lines[0]) <= 400 and lines[0].isprintable(), repr(lines[0])
    assert snapshot(world) == before  # the folder, the victim beside it and everything else as they were
