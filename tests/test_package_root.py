"""The package root: ``import jaxdip`` turns on float64 and imports no part of the library; each re-exported name
is the object its own module defines, imported on first use; an unknown name is an AttributeError."""

import importlib
import subprocess
import sys

import pytest

import jaxdip


def test_importing_the_root_or_one_module_imports_no_other_part():
    script = ("import sys, jax, jaxdip, jaxdip.xla_flags\n"
              "assert jax.config.jax_enable_x64\n"
              "print(sorted(m for m in sys.modules if m.startswith('jaxdip')))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['jaxdip', 'jaxdip.xla_flags']"


@pytest.mark.parametrize("name", jaxdip.__all__)
def test_each_name_is_its_modules_own(name):
    where = jaxdip._SUBMODULES.get(name) or jaxdip._NAMES[name]
    module = importlib.import_module(where)
    assert getattr(jaxdip, name) is (module if name in jaxdip._SUBMODULES else getattr(module, name))
    assert name in dir(jaxdip)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'simulte'"):
        jaxdip.simulte  # noqa: B018
    assert not hasattr(jaxdip, "simulte")
