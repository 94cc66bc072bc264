"""The documentation's examples, extracted from README.md and docs/engine.md and run as written; the README's
length and the relative links of README.md and docs/ resolving to files of the repository."""

import pathlib
import re

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
ENGINE = ROOT / "docs" / "engine.md"
README_MARKER = "<!-- readme-example: run by tests/test_readme_example.py -->"


def python_block(text: str, start: str) -> str:
    """The first ```python block after ``start`` in ``text``."""
    return re.search(r"```python\n(.*?)```", text[text.index(start):], re.S).group(1)


def run_block(code: str, origin: pathlib.Path) -> dict:
    ns = {"__name__": "readme_example"}
    exec(compile(code, str(origin), "exec"), ns)
    return ns


def test_readme_example_runs_and_its_interval_is_right(capsys):
    code = python_block(README.read_text(), README_MARKER)
    assert len(code.splitlines()) <= 15
    ns = run_block(code, README)
    printed = capsys.readouterr().out
    m = re.search(r"RMS theta (\S+) rad, 95% \[(\S+), (\S+)\], failed (\d+)", printed)
    mean, lo, hi, failed = float(m.group(1)), float(m.group(2)), float(m.group(3)), int(m.group(4))
    assert failed == 0 and np.all(np.asarray(ns["sol"].result) == 0)  # the LQR + KF loop keeps every seed up
    # the interval again, from the per-seed values with the t quantile (independent of the example's 1.96)
    from scipy import stats

    rms = np.asarray(ns["sol"].metrics["theta"])
    assert rms.shape == (256,) and np.all(np.isfinite(rms))
    sem = stats.sem(rms)
    np.testing.assert_allclose([lo, hi], stats.t.interval(0.95, rms.size - 1, loc=rms.mean(), scale=sem), rtol=2e-3)
    assert lo < mean < hi and mean == float(f"{rms.mean():.3e}")
    # stabilised: the tilt's RMS over 2 s is below the initial ball's radius, and the filter's velocity error
    # is below the raw velocity measurement's noise (what a Kalman filter is for)
    assert 0 < mean < 0.05
    kf_error = float(re.search(r"theta_dot (\S+) rad/s", printed).group(1))
    assert 0 < kf_error < 1e-2


def test_engine_md_plant_example_runs_and_its_gradient_is_right(capsys):
    code = python_block(ENGINE.read_text(), "\n## A plant of your own (example)\n")
    assert len([line for line in code.splitlines() if line.strip()]) <= 16
    ns = run_block(code, ENGINE)
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


def test_readme_is_at_most_250_lines():
    assert len(README.read_text().splitlines()) <= 250


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def relative_links(page: pathlib.Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)  # code is not a link
    # a path has a dot or a slash: E[I](r) in a formula is not a link
    return [t for t in LINK.findall(text)
            if not re.match(r"[a-z]+:", t) and not t.startswith("#") and re.search(r"[./]", t)]


def test_every_relative_link_of_the_readme_and_docs_names_a_file_of_the_repository():
    pages = [README, *sorted((ROOT / "docs").rglob("*.md"))]
    broken = []
    for page in pages:
        for target in relative_links(page):
            path = (page.parent / target.split("#")[0]).resolve()
            if not path.is_relative_to(ROOT) or not path.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken
    assert len(relative_links(README)) >= 16


def test_every_experiment_page_is_in_the_readme_table():
    linked = set(re.findall(r"\]\(docs/experiments/([\w-]+)\.md\)", README.read_text()))
    pages = {p.stem for p in (ROOT / "docs" / "experiments").glob("*.md")}
    from jaxdip.runner.discovery import registry

    assert pages == set(registry()) and linked == pages  # one page per registered experiment, each in the table


def test_ci_runs_the_readme_test_command():
    block = re.search(r"```bash\n(.*?)```", README.read_text(), re.S).group(1)
    command = block.split("# 2.")[1].splitlines()[1]
    ci = (ROOT / ".ci" / "run").read_text()
    assert "pytest" in command and all(part in ci for part in command.split(" && "))
