"""What the command line says: help in plain text naming every command, one "did you mean" wherever a name is
taken, and a quick run's report and metrics.json stating its scale (and that its numbers differ for it)."""

from __future__ import annotations

import json
import re

import pytest

from jaxdip import cli
from jaxdip import config as C
from jaxdip.cli_args import parser
from jaxdip.messages import suggestion
from jaxdip.runner import get, registry
from jaxdip.runner.scale import CUSTOM, FULL, QUICK, quick_changes, scale, scale_line

COMMANDS = ["list", "run", "config", "compare", "bench", "reproduce"]  # written out: a command missing from the parser fails
MARKUP = re.compile(r"``|`|:func:|:class:|\*\*|\\\\")  # reStructuredText and Markdown a terminal shows as written
HINT = re.compile(r" \(did you mean '[^']+'\?\)")


def _help(capsys, *argv) -> str:
    assert cli.main([*argv, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: jaxdip"), out[:200]
    return out


def test_top_help_is_plain_text_and_its_usage_names_every_command(capsys):
    out = _help(capsys)
    usage = out.split("\n\n")[0]
    assert usage == "usage: jaxdip [-h] {" + ",".join(COMMANDS) + "} ...", usage
    assert not MARKUP.search(out), MARKUP.search(out).group(0)
    assert sorted(parser().commands) == sorted(COMMANDS)
    for c in COMMANDS:  # and every command has its one-line summary in the list
        assert re.search(rf"^    {c}\b", out, re.M), c


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_help_is_plain_text_and_describes_it(capsys, command):
    out = _help(capsys, command)
    assert not MARKUP.search(out), (command, MARKUP.search(out).group(0))
    description = out.split("\n\n")[1]
    assert description[0].isupper() and description.rstrip().endswith("."), description
    # every flag says what it does: an option's line has its text after it, or the next line does
    lines = out.split("options:\n", 1)[1].splitlines() + [""]
    bare = [ln for ln, nxt in zip(lines, lines[1:])
            if ln.startswith("  -") and not re.search(r"\S  +\S", ln) and not nxt.startswith(" " * 8)]
    assert not bare, bare


# ---- "did you mean" --------------------------------------------------------------------------------------


def test_suggestion_wording():
    assert suggestion("dip-lqq", ["dip-lqr", "eki-dip"]) == " (did you mean 'dip-lqr'?)"
    assert suggestion("zzz", ["dip-lqr", "eki-dip"]) == " (known: dip-lqr, eki-dip)"
    assert suggestion("zzz", ["seeds"], "known keys") == " (known keys: seeds)"
    assert suggestion("zzz", ["fast", "full"], known=None) == ""
    assert suggestion(3, ["fast"], known=None) == ""  # a value of the wrong type: nothing to compare


@pytest.mark.parametrize("argv, key, near", [
    (["rnu"], "command", "run"),
    (["run", "dip-lqq"], "dip-lqq", "dip-lqr"),
    (["config", "eki-linaer"], "eki-linaer", "eki-linear"),
    (["reproduce", "--only", "dip-lqr,dip-lqq", "--out", "o"], "--only", "dip-lqr"),
    (["run", "dip-lqr", "--set", "sedes=3", "--out", "o"], "sedes", "seeds"),
    (["run", "dip-lqr", "--set", "variant=printd", "--out", "o"], "variant", "printed"),
    (["run", "dip-lqr", "--compile-effort", "fats", "--out", "o"], "--compile-effort", "fast"),
    (["run", "dip-lqr", "--qiuck", "--out", "o"], "--qiuck", "--quick"),
    (["reproduce", "--quick", "--onyl", "dip-lqr"], "--onyl dip-lqr", "--only"),
    (["bench", "--qick"], "--qick", "--quick"),
    (["run", "dip-lqr", "--config", "c.toml", "--out", "o"], "jaxdip.compile_efort", "compile_effort"),
])
def test_a_misspelt_name_gets_the_closest_one(tmp_path, monkeypatch, capsys, argv, key, near):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.toml").write_text('[jaxdip]\ncompile_efort = "fast"\n')
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {key}: "), err
    hints = HINT.findall(err)
    assert hints == [f" (did you mean '{near}'?)"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]  # refused before anything was written


def test_only_names_each_unknown_id_and_lists_the_ids_when_one_is_far_from_all(capsys):
    assert cli.main(["reproduce", "--only", "dip-lqq,zzzz", "--out", "o"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --only: unknown experiment 'dip-lqq' (did you mean 'dip-lqr'?), 'zzzz' (known: ")
    assert "twip-allan" in err or err.endswith("...)") or " ... " in err  # the list, cut to one line at worst


def test_an_unknown_flag_far_from_all_points_at_its_command_help(capsys):
    assert cli.main(["run", "dip-lqr", "--zzzzzz"]) == 2
    assert capsys.readouterr().err.strip() == "error: --zzzzzz: unrecognized argument (see jaxdip run --help)"


@pytest.mark.parametrize("module, given, near", [
    ("dip", "contollers", "controllers"),
    ("twip", "transient", "transients"),
    ("lorenz_published_p", "lorenzz", "lorenz"),
    ("integration_choice", "dip-controlers", "dip-controllers"),
])
def test_the_fidelity_scripts_only_suggests_too(capsys, module, given, near):
    import importlib

    main = importlib.import_module(f"experiments.fidelity.{module}").main
    with pytest.raises(SystemExit) as e:
        main(["--only", given])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(f"error: --only: unknown {'experiment' if module == 'integration_choice' else 'part'} "
                        f"'{given}' (did you mean '{near}'?)"), err


# ---- the scale of a quick run ----------------------------------------------------------------------------


def test_dip_lqr_quick_line_names_the_readme_scale():
    exp = get("dip-lqr")
    cfg = C.load(exp.config_cls, quick=exp.quick)
    assert scale(exp, cfg, quick=True) == QUICK
    assert scale_line(exp, cfg, QUICK) == (
        "**Quick scale** (the `--quick` overrides): seeds 64 (full run: 4096), duration 2 s (full run: 6.5 s). "
        "Its numbers differ from the full run's (`jaxdip run dip-lqr`) because of the smaller scale.")


@pytest.mark.parametrize("exp_id", sorted(registry()))
def test_every_quick_line_names_what_its_overrides_change(exp_id):
    exp = get(exp_id)
    cfg = C.load(exp.config_cls, quick=exp.quick)
    default = exp.config_cls()
    changed = [k for k, v in exp.quick.items() if getattr(default, k) != v]
    assert changed, f"{exp_id}: its quick overrides change nothing"
    assert [k for k, _, _ in quick_changes(exp, cfg)] == changed
    line = scale_line(exp, cfg, scale(exp, cfg, quick=True))
    assert "\n" not in line and line.endswith("because of the smaller scale.")
    for k in changed:
        assert re.search(rf"\b{re.escape(k)} \S.* \(full run: ", line), (k, line)
    # a quick run's own config.toml, run again without --quick, is at the quick scale too
    assert scale(exp, cfg, quick=False) == QUICK


def test_full_and_custom_scales():
    exp = get("twip-allan")
    full = C.load(exp.config_cls)
    assert scale(exp, full) == FULL and scale_line(exp, full, FULL) == ""
    fewer = C.load(exp.config_cls, sets=["records=3"])
    assert scale(exp, fewer) == CUSTOM
    assert scale_line(exp, fewer, CUSTOM) == (
        "**Changed scale**: records 3 (full run: 8). Its numbers differ from the full run's (`jaxdip run "
        "twip-allan`) because of the different scale.")
    quick = C.load(exp.config_cls, quick=exp.quick)
    assert "hours 0.25 h (full run: 4 h)" in scale_line(exp, quick, QUICK)


def test_a_quick_run_states_its_scale_outside_its_results(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "dip-lqr", "--quick", "--out", "q"]) == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "q" / "metrics.json").read_text())
    assert metrics["scale"] == "quick" and "scale" not in metrics["results"]
    report = (tmp_path / "q" / "report.md").read_text().split("\n\n")
    assert report[0].startswith("# dip-lqr: ")
    assert report[1].startswith("**Quick scale** (the `--quick` overrides): seeds 64 (full run: 4096)")
    assert report[2].startswith("Reproduces: ")
