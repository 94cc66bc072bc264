"""A second, independent set of hostile inputs for the command line's refusals: digits from other scripts,
control and bidirectional characters, damaged or look-alike markers, config files that are folders, links,
binary or deeply nested, output paths that are not a place for results. Each must stop with exit 2, exactly
one short line on standard error with no raw control character, and leave the working folder and a victim
folder beside it exactly as they were. Nothing here compiles: every case stops before the work starts."""

from __future__ import annotations

import json
import os

import pytest

from cli_faults_support import RUN, one_line
from jaxdip import cli
from snapshots import snapshot

ESC = "\x1b[2J"


def _marker(text: str):
    def make(work, victim):
        (work / "o").mkdir()
        (work / "o" / ".jaxdip.json").write_text(text)
    return make


def _write(name: str, data: bytes):
    return lambda work, victim: (work / name).write_bytes(data)


CASES = [
    # -- integers: int() takes other scripts' digits and underscores; a count is ASCII digits only
    ("seeds_arabic_indic_digit", [*RUN, "--seeds", "\u0662"], None, "--seeds"),
    ("seeds_fullwidth_digit", [*RUN, "--seeds", "\uff12"], None, "--seeds"),
    ("seeds_underscore", [*RUN, "--seeds", "1_0"], None, "--seeds"),
    ("seeds_float_text", [*RUN, "--seeds", "2.0"], None, "--seeds"),
    ("seeds_negative_zero", [*RUN, "--seeds", "-0"], None, "--seeds"),
    ("seeds_beyond_int64", [*RUN, "--seeds", str(10**30)], None, "--seeds"),
    ("jobs_fullwidth_digit", ["reproduce", "--quick", "--jobs", "\uff12", "--out", "r"], None, "--jobs"),
    # -- --set values with line breaks, NUL, C1 and bidirectional controls
    ("set_newline", [*RUN, "--set", "seeds=1\n2"], None, "seeds"),
    ("set_nul", [*RUN, "--set", "seeds=1\x00"], None, "seeds"),
    ("set_c1_csi", [*RUN, "--set", "seeds=\x9b2J"], None, "seeds"),
    ("set_bidi_override", [*RUN, "--set", "seeds=\u202e1"], None, "seeds"),
    ("set_negative_zero_dt", [*RUN, "--set", "dt=-0.0"], None, "dt"),
    ("set_1e309", [*RUN, "--set", "dt=1e309"], None, "dt"),
    ("set_bells", [*RUN, "--set", "dt=" + "\x07" * 500], None, "dt"),
    ("set_unknown_key_escape", [*RUN, "--set", f"zz{ESC}=1"], None, "zz"),
    ("set_empty_key", [*RUN, "--set", "=3"], None, "--set"),
    # -- config files that are not a TOML file, or hostile TOML
    ("config_folder", [*RUN, "--config", "sub"], None, "--config"),
    ("config_link_to_folder", [*RUN, "--config", "ln"],
     lambda w, v: os.symlink(v / "sub", w / "ln"), "--config"),
    ("config_dangling_link", [*RUN, "--config", "dang"],
     lambda w, v: os.symlink(w / "nowhere", w / "dang"), "--config"),
    ("config_proc_file", [*RUN, "--config", "/proc/self/status"], None, "--config"),
    ("config_binary", [*RUN, "--config", "c.toml"], _write("c.toml", b"\xff\xfe\x00seeds=1"), "--config"),
    ("config_nested_bomb", [*RUN, "--config", "c.toml"],
     _write("c.toml", b"x = " + b"[" * 5000 + b"]" * 5000 + b"\n"), "--config"),
    ("config_duplicate_key", [*RUN, "--config", "c.toml"], _write("c.toml", b"seeds=1\nseeds=2\n"), "--config"),
    ("config_huge_int", [*RUN, "--config", "c.toml"], _write("c.toml", b"seeds = " + b"9" * 30 + b"\n"),
     "seeds"),
    ("config_inf", [*RUN, "--config", "c.toml"], _write("c.toml", b"dt = inf\n"), "dt"),
    ("config_jaxdip_table_wrong_types", [*RUN, "--config", "c.toml"],
     _write("c.toml", b'[jaxdip]\ncompile_effort = "x"\n'), "jaxdip.compile_effort"),
    # -- output paths that are no place for results
    ("out_dot", ["run", "dip-lqr", "--quick", "--out", "."], None, "--out"),
    ("out_dotdot", ["run", "dip-lqr", "--quick", "--out", ".."], None, "--out"),
    ("out_root", ["run", "dip-lqr", "--quick", "--out", "/"], None, "--out"),
    ("out_under_proc", ["run", "dip-lqr", "--quick", "--out", "/proc/self/x"], None, "--out"),
    ("out_link_to_victim", ["run", "dip-lqr", "--quick", "--out", "ln"],
     lambda w, v: os.symlink(v, w / "ln"), "--out"),
    ("out_user_folder_with_force", ["run", "dip-lqr", "--quick", "--out", "sub", "--force"],
     lambda w, v: (w / "sub" / "data.csv").write_text("1,2\n"), "--out"),
    # -- markers that are not what jaxdip writes
    ("marker_fullwidth_dotdot", [*RUN, "--force"], _marker(json.dumps({"files": ["\uff0e\uff0e/notes.txt"]})),
     "--out"),
    ("marker_list", [*RUN, "--force"], _marker("[]"), "--out"),
    ("marker_nul_name", [*RUN, "--force"], _marker('{"files": ["metrics.json\\u0000"]}'), "--out"),
    ("marker_link_to_user_file", [*RUN, "--force"],
     lambda w, v: ((w / "o").mkdir(), os.symlink(v / "notes.txt", w / "o" / ".jaxdip.json")), "--out"),
    ("marker_is_folder", [*RUN, "--force"], lambda w, v: (w / "o" / ".jaxdip.json").mkdir(parents=True), "--out"),
    ("marker_case_folded_name", [*RUN, "--force"],
     lambda w, v: ((w / "o").mkdir(), (w / "o" / ".JAXDIP.json").write_text("{}")), "--out"),
    # -- the rest of the command line
    ("resume_with_link_named_like_a_checkpoint", [*RUN, "--resume"],
     lambda w, v: os.symlink(v / "notes.txt", w / "o.ckpt"), "--resume"),
    ("bench_out_png", ["bench", "--quick", "--out", "x.png"], None, "--out"),
    ("bench_out_missing_parent", ["bench", "--quick", "--out", "nope/x.json"], None, "--out"),
    ("reproduce_only_escape", ["reproduce", "--quick", "--only", ESC, "--out", "r"], None, "--only"),
    ("command_escape", [ESC], None, "command"),
]


def test_enough_cases():
    assert len(CASES) >= 40 and len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize("name, argv, setup, key", CASES, ids=[c[0] for c in CASES])
def test_probe_refusal(tmp_path, monkeypatch, capsys, name, argv, setup, key):
    work, victim = tmp_path / "work", tmp_path / "victim"
    for d in (work, victim):
        (d / "sub").mkdir(parents=True)
        (d / "notes.txt").write_text("mine\n")
    monkeypatch.chdir(work)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    if setup:
        setup(work, victim)
    before = snapshot(work), snapshot(victim)
    code = cli.main(list(argv))
    line = one_line(capsys.readouterr().err)
    assert code == 2, line
    assert line.startswith(f"error: {key}"), line
    assert (snapshot(work), snapshot(victim)) == before


def test_unknown_flag_names_the_right_help(capsys):
    """The top-level parser reports a subcommand's unknown flag; its hint used to read "jaxdip jaxdip --help",
    and names the subcommand's help now."""
    assert cli.main(["run", "dip-lqr", "--" + "z" * 100_000]) == 2
    line = one_line(capsys.readouterr().err)
    assert "jaxdip jaxdip" not in line and line.endswith("(see jaxdip run --help)"), line
