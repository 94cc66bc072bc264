"""The ``jaxdip`` command's process collects garbage less often and leaves what it loaded out of its collections
(``jaxdip.gc_policy``); a script or a test calling ``cli.main`` keeps its own collector as it set it."""

import gc
import os
import subprocess
import sys

from jaxdip import cli, gc_policy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# ``entry`` as the ``jaxdip`` command runs it, with its last step (which ends the process without a teardown)
# replaced by a report of the collector's settings at that moment
_COMMAND = """
import gc, sys
from jaxdip import cli
def report(code):
    print(code, *gc.get_threshold(), gc.get_freeze_count())
cli.end_process = report
sys.argv = ["jaxdip", "list"]
cli.entry()
"""


def test_the_command_collects_less_often_and_leaves_what_it_loaded_out():
    out = subprocess.run([sys.executable, "-c", _COMMAND], capture_output=True, text=True, cwd=ROOT, timeout=120,
                         env=dict(os.environ, JAXDIP_NO_PROGRESS="1"))
    assert out.returncode == 0, out.stderr
    code, young, middle, old, frozen = map(int, out.stdout.split()[-5:])
    assert code == 0
    assert (young, middle, old) == (gc_policy.YOUNG, gc_policy.MIDDLE, gc_policy.OLD)
    assert young > 700  # Python's default, which a cold run paid 0.6-0.9 s of collections for
    # the interpreter, the CLI and what they import: tens of thousands of objects, never scanned again
    assert frozen > 10_000


def test_a_library_call_keeps_the_callers_collector():
    before, frozen = gc.get_threshold(), gc.get_freeze_count()
    assert cli.main(["list"]) == 0
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == frozen
