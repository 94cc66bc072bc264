"""A run's own config.toml repeats it: ``jaxdip run <id> --config <out>/config.toml`` gives bit-identical
``results``, with or without ``--quick``, because the file holds the resolved config (the quick overrides
included) and, in its ``[jaxdip]`` table, the compile effort, whose levels differ in the last bits."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from jaxdip import cli, xla_flags
from jaxdip import config as C
from jaxdip.runner import get, registry
from jaxdip.runner.experiment import config_toml


@pytest.mark.parametrize("exp_id", sorted(registry()))
def test_quick_config_toml_loads_back_to_the_same_config_without_quick(tmp_path, exp_id):
    exp = get(exp_id)
    quick = C.load(exp.config_cls, quick=exp.quick)
    path = tmp_path / "config.toml"
    path.write_text(config_toml(exp, quick, "balanced"))
    again = C.load(exp.config_cls, path=str(path))
    assert C.to_dict(again) == C.to_dict(quick)  # seeds, horizons, every key: the quick overrides are in the file
    assert C.run_table(str(path)) == {"compile_effort": "balanced"}


@pytest.mark.parametrize("table, key", [("[jaxdip]\ncompile_effort = \"fastest\"\n", "jaxdip.compile_effort"),
                                        ("[jaxdip]\ndevices = 3\n", "jaxdip.devices"),
                                        ("jaxdip = 3\n", "jaxdip")])
def test_a_bad_run_table_is_a_config_error(tmp_path, table, key):
    path = tmp_path / "c.toml"
    path.write_text(table)
    with pytest.raises(C.ConfigError) as e:
        C.load(get("dip-lqr").config_cls, path=str(path))
    assert e.value.key == key


def _results(folder) -> str:
    with open(os.path.join(folder, "metrics.json")) as fh:
        return json.dumps(json.load(fh)["results"], sort_keys=True)


def test_dip_lqr_quick_then_its_config_toml_is_bit_identical(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "dip-lqr", "--quick", "--out", "A"]) == 0, capsys.readouterr().err
    assert cli.main(["run", "dip-lqr", "--config", "A/config.toml", "--out", "B"]) == 0, capsys.readouterr().err
    assert _results("A") == _results("B")
    metrics = [json.load(open(f"{d}/metrics.json")) for d in "AB"]
    assert metrics[0]["compile_effort"] == metrics[1]["compile_effort"] == xla_flags.effort()
    # the flag wins over the file: a level this process does not compile at (XLA_FLAGS, conftest) is refused
    # by the flag's name, before anything is written
    other = "full" if xla_flags.effort() != "full" else "fast"
    capsys.readouterr()
    assert cli.main(["run", "dip-lqr", "--config", "A/config.toml", "--compile-effort", other, "--out", "C"]) == 2
    assert "error: --compile-effort: " in capsys.readouterr().err and not os.path.exists("C")
    with open("A/config.toml") as fh:
        text = fh.read().replace(f'compile_effort = "{xla_flags.effort()}"', f'compile_effort = "{other}"')
    with open("D.toml", "w") as fh:
        fh.write(text)
    assert cli.main(["run", "dip-lqr", "--config", "D.toml", "--out", "D"]) == 2
    assert "error: --config: " in capsys.readouterr().err and not os.path.exists("D")


@pytest.mark.slow
def test_every_experiment_quick_then_its_config_toml_is_bit_identical(tmp_path):
    """The loop of the acceptance check, through the console entry point (one process per run)."""
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1")
    differ = []
    for exp_id in sorted(registry()):
        for argv in (["--quick", "--out", f"{exp_id}-A"], ["--config", f"{exp_id}-A/config.toml", "--out", f"{exp_id}-B"]):
            p = subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", exp_id, *argv], cwd=tmp_path, env=env,
                               capture_output=True, text=True, timeout=900)
            assert p.returncode == 0, f"{exp_id}: {p.stderr[-500:]}"
        if _results(tmp_path / f"{exp_id}-A") != _results(tmp_path / f"{exp_id}-B"):
            differ.append(exp_id)
    assert not differ, f"results differ when re-run from their config.toml: {differ}"
