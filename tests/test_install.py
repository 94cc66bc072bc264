"""The import trap: ``git clone`` makes a folder named ``jaxdip``, and a script run from the folder that contains
the clone must import the installed package, not that folder as an empty namespace package.

setuptools' default editable install puts an import hook after Python's path search, which finds the clone's
folder first (through the script's own directory on sys.path); with ``package-dir = {"" = "."}`` in
pyproject.toml the install is a .pth path entry to the repository root instead, and the path search itself finds
the real package there. The fast tests check that mechanism in this environment; the slow one clones, installs
with the README's command and imports from the parent folder, as a new user would.
"""

import importlib.machinery
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "jaxdip" / "__init__.py"
IMPORT = "import jaxdip; jaxdip.plants; print(jaxdip.__file__)"


def test_jaxdip_is_found_by_the_path_search_not_a_finder_hook():
    # PathFinder searches sys.path only: it finds the package when the install is a path entry (.pth) or the
    # tests run from the root; with the editable hook it would find nothing here (or the clone's empty folder)
    spec = importlib.machinery.PathFinder.find_spec("jaxdip")
    assert spec is not None and spec.origin is not None, "jaxdip is not on sys.path: reinstall with pip install -e ."
    assert pathlib.Path(spec.origin).resolve() == PACKAGE
    hooks = [f for f in sys.meta_path if "editable" in repr(f).lower() and "jaxdip" in repr(f).lower()]
    assert not hooks, f"an editable finder hook for jaxdip is installed: {hooks}; reinstall with pip install -e ."


def test_pyproject_declares_the_root_as_package_dir():
    import tomllib

    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setuptools["package-dir"] == {"": "."}


def test_import_from_a_folder_holding_an_empty_jaxdip_folder(tmp_path):
    # the clone's parent folder as Python sees it: a directory named jaxdip without __init__.py next to the script
    (tmp_path / "jaxdip").mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", IMPORT], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert pathlib.Path(out.stdout.strip()).resolve() == PACKAGE


def readme_install_command() -> str:
    """The README's test command up to the test run: the venv and ``pip install -e ".[test]"``."""
    line = next(s for s in (ROOT / "README.md").read_text().splitlines() if "-m pytest" in s and "pip install" in s)
    install = line[: line.index(" && .venv/bin/python -m")]
    assert re.fullmatch(r'python3 -m venv \.venv && \.venv/bin/pip install -q -e "\.\[test\]"', install), install
    return install


@pytest.mark.slow
def test_fresh_clone_installed_with_the_readme_command_imports_from_its_parent(tmp_path):
    clone = tmp_path / "jaxdip"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    # python3 of the README is this interpreter, so the test runs under the Python it was started with
    install = readme_install_command().replace("python3 ", f"{sys.executable} ", 1)
    subprocess.run(install, shell=True, cwd=clone, check=True, timeout=1800)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([str(clone / ".venv" / "bin" / "python"), "-c", IMPORT], cwd=tmp_path, env=env,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert pathlib.Path(out.stdout.strip()) == clone / "jaxdip" / "__init__.py"
