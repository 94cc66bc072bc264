"""docs/tutorial.md runs as written: its python blocks, in order, in one namespace (as a reader pastes them into
one session). The tutorial's own ``assert`` lines are the checks of each step (a gradient against a finite
difference, the MHE against the Kalman filter, the sweep's minimum at the LQR gain, offline filtering against the
loop's); this test adds that every step ran and left the names the next one uses."""

import pathlib
import re

TUTORIAL = pathlib.Path(__file__).resolve().parents[1] / "docs" / "tutorial.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


def test_tutorial_blocks_are_found():
    blocks = python_blocks(TUTORIAL.read_text())
    assert len(blocks) == 10
    # every step asserts something of its own
    assert all("assert" in b for b in blocks)


def test_tutorial_runs_in_order(capsys):
    ns = {"__name__": "tutorial"}
    for i, code in enumerate(python_blocks(TUTORIAL.read_text())):
        exec(compile(code, f"{TUTORIAL}:block{i}", "exec"), ns)
    printed = capsys.readouterr().out
    # step 2: optax moved gamma and lowered the cost; step 4: the sweep holds every scale and seed
    assert float(ns["tuned"]) < float(ns["value"]) and float(ns["params"]) < 0  # log gamma below log 1
    assert ns["J"].shape == (5, 64)
    for line in ("KF: RMS velocity error", "CPX: RMS velocity error", "d cost / d log gamma", "cart-pole",
                 "mean LQR cost by gain scale", "smoother", "CPX over the recording"):
        assert line in printed

