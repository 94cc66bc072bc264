"""The README's Library example, extracted from README.md and run as written."""

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def library_example() -> str:
    text = README.read_text()
    section = text[text.index("\n## Library\n"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_library_example_runs_and_its_gradient_is_right(capsys):
    code = library_example()
    assert len([line for line in code.splitlines() if line.strip()]) <= 16
    ns = {"__name__": "readme_example"}
    exec(compile(code, str(README), "exec"), ns)
    printed = capsys.readouterr().out
    value, grad = (float(v) for v in re.search(r"mean phi\^2: (\S+)\s+d/dr: (\S+)", printed).groups())
    # the LQR + KF loop keeps every one of the 1024 seeds up
    import jaxdip as jd

    sol = jd.monte_carlo(ns["run"], 0, 1024)
    assert np.all(np.asarray(sol.result) == jd.RESULTS.ok)
    np.testing.assert_allclose(value, float(np.mean(np.asarray(sol.metrics["mean_sq"])[:, 1])), rtol=1e-12)
    # the printed gradient against central differences of the same Monte Carlo cost
    r, h = 1e-4, 1e-7
    fd = (float(ns["cost"](r + h)) - float(ns["cost"](r - h))) / (2 * h)
    assert abs(grad) > 0
    np.testing.assert_allclose(grad, fd, rtol=1e-5)
