"""The registry finds experiments by walking a package (jaxdip.runner.discovery, docs/registry.md): checked on
synthetic packages written here, so it never depends on which experiments the repository holds."""

from __future__ import annotations

import sys
import textwrap

import pytest

from jaxdip.runner import discovery as R

HEAD = "from jaxdip.runner import Experiment, Outcome\n"


def _one(exp_id: str) -> str:
    return (f"Experiment(id={exp_id!r}, title={exp_id!r}, config_cls=dict, "
            f"run=lambda cfg, ctx=None: Outcome(results={{}}, report=''))")


def _package(tmp_path, monkeypatch, name: str, files: dict[str, str]) -> str:
    """A package ``name`` in ``tmp_path`` holding ``files`` (path -> source), importable for this test only."""
    root = tmp_path / name
    root.mkdir()
    (root / "__init__.py").write_text("")
    for path, src in files.items():
        f = root / path
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(textwrap.dedent(src))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, name, raising=False)
    return name


def test_modules_and_sub_packages_are_found_and_the_rest_skipped(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_found", {
        "alpha.py": HEAD + f"EXPERIMENT = {_one('alpha')}\n",
        "pair.py": HEAD + f"EXPERIMENTS = ({_one('pair-a')}, {_one('pair-b')})\n",
        "gamma/__init__.py": HEAD + "from exps_found.gamma.config import N\n" + f"EXPERIMENT = {_one('gamma')}\n",
        "gamma/config.py": "N = 3\n",
        "_helpers.py": "raise AssertionError('a private module is never imported')\n",
        "fidelity/__init__.py": "raise AssertionError('the fidelity studies are not experiments')\n",
    })
    assert R.homes(pkg) == ["exps_found.alpha", "exps_found.gamma", "exps_found.pair"]
    reg = R.registry(pkg)
    assert sorted(reg) == ["alpha", "gamma", "pair-a", "pair-b"]
    assert R.get("pair-b", pkg) is reg["pair-b"]


def test_a_home_without_an_experiment_is_an_error_naming_it(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_missing", {"alpha.py": HEAD + f"EXPERIMENT = {_one('alpha')}\n",
                                                          "beta.py": HEAD + f"EXPERIMNT = {_one('beta')}\n"})
    with pytest.raises(TypeError, match="exps_missing.beta defines neither EXPERIMENT nor EXPERIMENTS"):
        R.registry(pkg)


def test_something_else_than_an_experiment_is_an_error(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_wrong", {"alpha.py": "EXPERIMENT = 'alpha'\n"})
    with pytest.raises(TypeError, match="exps_wrong.alpha: 'alpha' is not an Experiment"):
        R.registry(pkg)


def test_an_id_defined_twice_is_an_error(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_twice", {"a.py": HEAD + f"EXPERIMENT = {_one('same')}\n",
                                                        "b.py": HEAD + f"EXPERIMENT = {_one('same')}\n"})
    with pytest.raises(ValueError, match="'same' defined twice"):
        R.registry(pkg)


def test_an_unknown_id_names_the_closest(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_close", {"alpha.py": HEAD + f"EXPERIMENT = {_one('alpha-one')}\n"})
    with pytest.raises(KeyError, match="alpah-one: unknown experiment \\(did you mean 'alpha-one'\\?\\)"):
        R.get("alpah-one", pkg)
    with pytest.raises(KeyError, match="known: alpha-one"):
        R.get("zzz", pkg)


def test_get_imports_only_the_home_named_after_the_id(tmp_path, monkeypatch):
    pkg = _package(tmp_path, monkeypatch, "exps_lazy", {
        "alpha_one.py": HEAD + f"EXPERIMENT = {_one('alpha-one')}\n",
        "pair.py": HEAD + f"EXPERIMENTS = ({_one('pair-a')}, {_one('pair-b')})\n",
        "zeta.py": "import sys\nsys.modules['exps_lazy'].ZETA_IMPORTED = True\n" + HEAD + f"EXPERIMENT = {_one('zeta')}\n",
    })
    assert R.get("alpha-one", pkg).id == "alpha-one"
    assert not hasattr(sys.modules[pkg], "ZETA_IMPORTED")  # no other home was imported
    assert R.get("pair-b", pkg) is R.registry(pkg)["pair-b"]  # an id whose home has another name: the whole walk
    assert sys.modules[pkg].ZETA_IMPORTED
