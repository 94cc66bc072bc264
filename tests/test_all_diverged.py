"""The all-diverged rule: a run in which every seed diverges writes a ``failures`` block and no ``null``, ``NaN``,
``nan``, ``nan%`` or ``inf`` anywhere in metrics.json or report.md (a statistic over no seed is left out, and the
report says n/a).

Every experiment of the registry is classified here (``test_every_experiment_is_classified``):
- ``ALL_DIVERGE``: a tiny config that makes every seed diverge at once (a state bound of 1e-9, an initial
  state past the bound) and a count in the results that shows it did;
- ``NO_SURVIVOR_STATISTICS``: experiments whose seeds can fail but whose statistics are not averages over the
  surviving seeds; the run with the most hostile config we have must still write no NaN:
  eki-linear / eki-nonlinear (the seeds are independent searches; a failed evaluation scores the thesis's
  finite penalty, and the result is the fraction of searches that end stabilising), tune (a diverged seed adds
  ``divergence_penalty`` to its loss, so every loss is finite, and held-out divergences are counted; no config
  key makes every seed diverge: the closed loop's initial states and bounds are the scenario's),
  twip-transients (no seeds: a few deterministic trajectories; a fall shows in their settling entries);
- ``NO_SEEDS``: nothing that can diverge (theory checks, sensor noise statistics, an immune model).

Each case runs in-process at a few seeds and a fraction of a second of simulated time; the default suite runs
two of them, the rest are marked slow.
"""

from __future__ import annotations

import json
import re

import pytest

from jaxdip import config as C
from jaxdip import xla_flags
from jaxdip.runner import get, registry, run_experiment

TINY_BOUND = "[1e-9, 1e-9, 1e-9, 1e-9, 1e-9, 1e-9]"

# id -> (--set pairs, a path in results, the count it must hold: every seed of that part diverged)
ALL_DIVERGE = {
    "dip-lqr": (["seeds=4", "duration=0.1", f"state_bound={TINY_BOUND}"], ["failures", "out_of_bounds"], 4),
    "dip-controllers": (["seeds=4", "duration=0.1", f"state_bound={TINY_BOUND}"], ["lqr", "diverged"], 4),
    "dip-cpx-ldf": (["seeds=4", "duration=0.1", f"state_bound={TINY_BOUND}"], ["cpx", "diverged"], 4),
    "lorenz-mhe": (["seeds=4", "duration=0.1", "divergence_bound=1e-9"], ["failures", "diverged", "scpx"], 4),
    "twip-dmso": (["seeds=4", "det_seeds=2", "duration=1.0", "duration_fine=0.5", "tail_s=0.5",
                   "tilt_bound_deg=1e-6", "chunk_seeds=4"], ["failures", "diverged", "noise/dmso"], 4),
    "twip-extra-control": (["seeds=4", "chunk_seeds=4", "duration=1.0", "tilt_bound_deg=1e-6"],
                           ["failures", "diverged", "param/extra"], 4),
    "rwp-bias": (["seeds=4", "bias_seeds=2", "no_bias_duration=1.0", "bias_duration=1.0", "lowpass_duration=1.0",
                  "reduced_duration=1.0", "gamma_check_duration=12.0", "steady_window=0.5", "theta0=[2.0, 2.5]",
                  "bias_theta0=2.0"], ["bias", "diverged"], 2),
    "rwp-remark3": (["seeds=4", "duration=1.0", "tail=0.5", "theta0=3.0"], ["reference", "diverged"], 4),
    "eki-dip": (["seeds=4", "ensemble=6", "iterations=2", "chunk=2", "T=0.3", "t_star=0.1", "grad_steps=0",
                 "eval_states=2", "judge_duration=0.3", "early_stop=false", "min_success=2", "judge_radius=50.0"],
                ["judge", "diverged"], 4),
    # every initial state past the bound (std 10 rad on the links against 1.57 rad)
    "dip-mpc": (["seeds=4", "duration=0.1", "x0_scales=[1000.0]", "tune_steps=1", "tune_seeds=2",
                 "tune_duration=0.1"], ["table", "x1000", "mpc", "diverged"], 4),
}
NO_SURVIVOR_STATISTICS = {
    "eki-linear": ["seeds=4", "iterations=2", "fail_norm=1e-9", "judge_states=8"],
    "eki-nonlinear": ["seeds=4", "iterations=2", "fail_norm=1e-9", "judge_states=8", "restarts=1"],
    "tune": ["steps=2", "heldout_seeds=4", "landscape_points=3"],
    "twip-transients": ["x0=[1.0, 2.0, 10.0, 1.0]", "swing_duration=12.0", "duration=2.0"],
}
NO_SEEDS = {
    "thesis-theory": "checks of theorems on random matrices and states: no closed loop runs long enough to fail",
    "twip-allan": "Allan deviations of simulated sensor noise: nothing is controlled",
    "ifn-protection": "an immune-response model integrated by quadrature and lineage sampling: no bound to leave",
}
FAST = ("dip-lqr", "rwp-remark3")

# a number that is not one, as JSON, Python, NumPy or a format string writes it
NOT_A_NUMBER = re.compile(r"(?<![\w.])(?:(?i:nan%?|[-+]?inf(?:inity)?)|null|None)(?!\w)")


def _run(tmp_path, exp_id, sets):
    exp = get(exp_id)
    cfg = C.load(exp.config_cls, quick=exp.quick, sets=sets)
    run_experiment(exp, cfg, str(tmp_path / "out"), compile_effort=xla_flags.effort())
    metrics = (tmp_path / "out" / "metrics.json").read_text()
    report = (tmp_path / "out" / "report.md").read_text()
    for name, text in (("metrics.json", metrics), ("report.md", report)):
        bad = [line.strip()[:120] for line in text.splitlines() if NOT_A_NUMBER.search(line)]
        assert not bad, f"{exp_id}: {name} writes a non-number: {bad[:3]}"
    return json.loads(metrics)["results"], report


def _has_failures(obj) -> bool:
    if isinstance(obj, dict):
        return bool(obj.get("failures")) or any(_has_failures(v) for v in obj.values())
    return False


def _case(exp_id):
    return pytest.param(exp_id, marks=() if exp_id in FAST else pytest.mark.slow)


@pytest.mark.parametrize("exp_id", [_case(e) for e in ALL_DIVERGE])
def test_every_seed_diverged(tmp_path, exp_id):
    sets, path, count = ALL_DIVERGE[exp_id]
    results, report = _run(tmp_path, exp_id, sets)
    v = results
    for k in path:
        v = v[k]
    assert v == count, f"{exp_id}: {'.'.join(path)} = {v}, so not every seed diverged"
    assert _has_failures(results), f"{exp_id}: no failures block"
    assert "iverged" in report


@pytest.mark.slow
@pytest.mark.parametrize("exp_id", list(NO_SURVIVOR_STATISTICS))
def test_hostile_config_writes_no_nan(tmp_path, exp_id):
    _run(tmp_path, exp_id, NO_SURVIVOR_STATISTICS[exp_id])


def test_every_experiment_is_classified():
    classified = set(ALL_DIVERGE) | set(NO_SURVIVOR_STATISTICS) | set(NO_SEEDS)
    assert classified == set(registry()), "classify every experiment under the all-diverged rule"
    assert not set(ALL_DIVERGE) & set(NO_SURVIVOR_STATISTICS) and not set(NO_SEEDS) & set(ALL_DIVERGE)


def test_unwritable_results_are_kept_not_lost(tmp_path, monkeypatch, capsys):
    """An experiment that leaves a NaN where the final check finds it (a defect, found only after the whole run)
    is refused in one line, replaces nothing, and its results and report are kept in the one file the line
    names, so a long run's computation is not lost."""
    import dataclasses
    import os

    import jaxdip.runner as runner
    from jaxdip import cli
    from jaxdip.runner import Outcome
    from snapshots import snapshot

    real = runner.get("dip-lqr")
    nan_run = lambda cfg, ctx: Outcome(results={"fine": 1.0, "ci": [float("nan"), 2.0]}, report="a report")
    monkeypatch.setattr(runner, "get", lambda exp_id: dataclasses.replace(real, run=nan_run))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "victim").mkdir()
    (tmp_path / "victim" / "notes.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    assert cli.main(["run", "dip-lqr", "--quick", "--out", "dest"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: results.ci[0]: "), lines
    kept = [n for n in os.listdir(tmp_path) if n.startswith("dest.unwritable-")]
    assert len(kept) == 1 and kept[0] in lines[0]
    saved = json.loads((tmp_path / kept[0]).read_text())
    assert saved["results"] == {"fine": 1.0, "ci": [None, 2.0]} and saved["report"] == "a report"
    after = snapshot(tmp_path)
    assert {p: v for p, v in after.items() if p != kept[0]} == before  # no dest, no staging, the victim as it was
