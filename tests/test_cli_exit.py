"""``jaxdip.cli_errors.end_process``: a finished command exits with its status and what it printed, without the
interpreter's teardown (atexit handlers, JAX clearing its backends), unless the process is traced or profiled,
whose tools write their data at exit."""

from __future__ import annotations

import subprocess
import sys

import pytest

CHILD = """
import atexit, sys
from jaxdip.cli_errors import end_process
atexit.register(lambda: print("teardown", flush=True))
{setup}
print("printed", end="")  # left in the buffer: end_process must flush it
sys.stderr.write("said")
end_process(3)
"""


@pytest.mark.parametrize("setup, teardown", [("", False), ("sys.settrace(lambda *a: None)", True),
                                             ("sys.setprofile(lambda *a: None)", True)])
def test_end_process_skips_the_teardown_unless_traced(setup, teardown):
    child = subprocess.run([sys.executable, "-c", CHILD.format(setup=setup)], capture_output=True, text=True,
                           timeout=120)
    assert child.returncode == 3
    assert child.stdout == ("printed" + ("teardown\n" if teardown else ""))
    assert child.stderr == "said"


def test_the_command_ends_through_it():
    # the console script and ``python -m jaxdip.cli`` both go through ``entry``
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["jaxdip"] == "jaxdip.cli:entry"
    child = subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", "no-such-experiment"], capture_output=True,
                           text=True, timeout=120)
    assert child.returncode == 2 and child.stderr.startswith("error: ")
