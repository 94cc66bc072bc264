"""eki-dip at toy scale: an interrupted search resumed from its checkpoint ends at the same P."""

import json

import pytest

from jaxdip import checkpoint
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

TINY = {"seeds": 4, "ensemble": 6, "iterations": 6, "chunk": 2, "T": 0.3, "t_star": 0.1, "grad_steps": 0,
        "eval_states": 2, "judge_duration": 0.3, "early_stop": False, "min_success": 2}


def test_interrupted_search_resumes_to_the_same_P(tmp_path, monkeypatch):
    exp = get("eki-dip")
    cfg = C.load(exp.config_cls, quick=TINY)
    full = run_experiment(exp, cfg, str(tmp_path / "full"))["results"]

    real_save = checkpoint.save
    calls = {"n": 0}

    def save_then_die(*a, **k):
        real_save(*a, **k)
        calls["n"] += 1
        if calls["n"] == 2:  # killed right after the second checkpoint (iteration 4 of 6)
            raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, cfg, str(tmp_path / "resumed"))
    assert not (tmp_path / "resumed").exists()  # nothing half-written
    assert (tmp_path / ".resumed.ckpt.npz").exists()
    monkeypatch.setattr(checkpoint, "save", real_save)
    resumed = run_experiment(exp, cfg, str(tmp_path / "resumed"), resume=True)["results"]
    assert resumed["iterations"] == full["iterations"] == 6
    assert json.dumps(resumed["P_basis"]) == json.dumps(full["P_basis"])
    assert json.dumps(resumed["P_singular_values"]) == json.dumps(full["P_singular_values"])
    assert resumed["history_mean_performance"] == full["history_mean_performance"]
    assert not (tmp_path / ".resumed.ckpt.npz").exists()  # removed once the folder is complete


def test_resume_refuses_a_checkpoint_of_another_config(tmp_path, monkeypatch):
    exp = get("eki-dip")
    cfg = C.load(exp.config_cls, quick=TINY)
    real_save = checkpoint.save

    def save_then_die(*a, **k):
        real_save(*a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, cfg, str(tmp_path / "o"))
    monkeypatch.setattr(checkpoint, "save", real_save)
    other = C.load(exp.config_cls, quick={**TINY, "gamma": 11.0})
    with pytest.raises(ValueError, match="different config"):
        run_experiment(exp, other, str(tmp_path / "o"), resume=True)
