"""Checkpoints: a damaged file is a one-line error naming it, a resume finds only a checkpoint of the very same
run (experiment, config, compile effort, ...), and a finished run removes its own checkpoint and nothing else.

Damaged files are checked against ``checkpoint.load`` directly and through ``jaxdip run --resume`` (which reads
the checkpoint's record before anything compiles, so those cases take a second each).
"""

from __future__ import annotations

import json
import os
import zipfile

import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip import checkpoint, cli, xla_flags
from jaxdip import config as C
from jaxdip.runner import get
from jaxdip.runner.experiment import run_context

TREE = {"a": jnp.arange(6.0).reshape(2, 3), "k": jnp.asarray([1, 2], dtype=jnp.uint32),
        "hist": jnp.zeros((4, 1))}
LIKE = {"a": jnp.zeros((2, 3)), "k": jnp.zeros(2, dtype=jnp.uint32), "hist": jnp.zeros((0, 1))}


def _saved(path, tree=TREE, fp="fp"):
    checkpoint.save(str(path), tree, fp)
    return str(path)


def _rewrite(path, **arrays):
    """The checkpoint at ``path`` with some of its arrays replaced (None: left out)."""
    with np.load(path) as z:
        old = {k: z[k] for k in z.files}
    old.update(arrays)
    np.savez(path, **{k: v for k, v in old.items() if v is not None})


def test_round_trip_and_growing_history(tmp_path):
    tree, meta = checkpoint.load(_saved(tmp_path / "c.npz"), LIKE, "fp")
    np.testing.assert_array_equal(np.asarray(tree["a"]), np.asarray(TREE["a"]))
    assert tree["k"].dtype == jnp.uint32 and tree["hist"].shape == (4, 1) and meta["n"] == 3


def _damage(kind, path):
    if kind == "not_a_zip":
        with open(path, "wb") as fh:
            fh.write(b"this is not a checkpoint\n")
    elif kind == "truncated":
        data = open(path, "rb").read()
        with open(path, "wb") as fh:
            fh.write(data[: len(data) // 2])
    elif kind == "empty":
        open(path, "wb").close()
    elif kind == "meta_not_json":
        _rewrite(path, __meta__=np.frombuffer(b"{not json", dtype=np.uint8))
    elif kind == "meta_wrong_types":
        _rewrite(path, __meta__=np.frombuffer(json.dumps({"fingerprint": 3, "n": "x"}).encode(), dtype=np.uint8))
    elif kind == "meta_missing":
        _rewrite(path, __meta__=None)
    elif kind == "leaf_missing":
        _rewrite(path, leaf_1=None)
    elif kind == "leaf_wrong_shape":
        _rewrite(path, leaf_0=np.zeros((3, 3)))
    elif kind == "leaf_wrong_dtype":
        _rewrite(path, leaf_0=np.zeros((2, 3), dtype=np.float32))
    elif kind == "pickled_leaf":
        _rewrite(path, leaf_0=np.array([{"x": 1}], dtype=object))
    elif kind == "zip_of_text":
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("__meta__.npy", "hello")
    elif kind == "fifo":
        os.remove(path)
        os.mkfifo(path)
    elif kind == "folder":
        os.remove(path)
        os.mkdir(path)
    elif kind == "symlink":
        os.rename(path, path + ".real")
        os.symlink(os.path.basename(path) + ".real", path)


DAMAGE = ["not_a_zip", "truncated", "empty", "meta_not_json", "meta_wrong_types", "meta_missing", "leaf_missing",
          "leaf_wrong_shape", "leaf_wrong_dtype", "pickled_leaf", "zip_of_text", "fifo", "folder", "symlink"]


@pytest.mark.parametrize("kind", DAMAGE)
def test_damaged_checkpoint_is_a_checkpoint_error_naming_the_file(tmp_path, kind):
    path = _saved(tmp_path / "c.npz")
    _damage(kind, path)
    with pytest.raises(checkpoint.CheckpointError) as e:
        checkpoint.load(path, LIKE, "fp")
    assert path in str(e.value) and "\n" not in str(e.value)


def test_another_runs_checkpoint_is_a_mismatch(tmp_path):
    path = _saved(tmp_path / "c.npz")
    with pytest.raises(checkpoint.CheckpointMismatch, match="different config"):
        checkpoint.load(path, LIKE, "other")
    with pytest.raises(checkpoint.CheckpointMismatch, match="structure"):
        checkpoint.load(path, {"a": LIKE["a"]}, "fp")


# ---- through the command line ----------------------------------------------------------------------------

EKI = ["run", "eki-dip", "--quick"]


def _one_line(capsys, argv) -> str:
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --resume: "), err
    return lines[0]


def _checkpoint_of(exp_id, out, effort, sets=(), owner="an interrupted run"):
    """Write a checkpoint exactly where ``jaxdip run <exp_id> --quick --out <out>`` at ``effort`` keeps its own."""
    exp = get(exp_id)
    cfg = C.load(exp.config_cls, quick=exp.quick, sets=list(sets))
    ctx = run_context(exp, cfg, out, compile_effort=effort)
    with checkpoint.owning(owner, ctx.info):
        checkpoint.save(ctx.checkpoint_path, TREE, ctx.fingerprint)
    return ctx.checkpoint_path


def test_resume_at_another_compile_effort_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    other = "full" if xla_flags.effort() != "full" else "fast"  # a level this process does not compile at
    path = _checkpoint_of("eki-dip", "o", other)
    line = _one_line(capsys, [*EKI, "--out", "o", "--resume"])
    assert f"compile_effort '{other}' (this run: '{xla_flags.effort()}')" in line and path in line
    line = _one_line(capsys, [*EKI, "--out", "o", "--resume", "--set", "gamma=11.0"])
    assert "gamma" in line
    assert os.path.exists(path) and not os.path.exists("o")


def test_resume_without_checkpoint_or_for_an_experiment_that_keeps_none(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert "no checkpoint of an interrupted eki-dip run" in _one_line(capsys, [*EKI, "--out", "o", "--resume"])
    _checkpoint_of("tune", "o", xla_flags.effort())  # another experiment's, beside the same folder
    assert "no checkpoint of an interrupted eki-dip run" in _one_line(capsys, [*EKI, "--out", "o", "--resume"])
    line = _one_line(capsys, ["run", "dip-lqr", "--quick", "--out", "o", "--resume"])
    assert "dip-lqr keeps no checkpoint" in line
    assert [p for p in os.listdir() if not p.startswith(".o.tune.")] == []  # nothing written, nothing removed


@pytest.mark.parametrize("kind", ["not_a_zip", "truncated", "meta_not_json", "fifo"])
def test_resume_from_a_damaged_checkpoint_is_one_line(tmp_path, capsys, monkeypatch, kind):
    monkeypatch.chdir(tmp_path)
    path = _checkpoint_of("eki-dip", "o", xla_flags.effort())
    _damage(kind, path)
    line = _one_line(capsys, [*EKI, "--out", "o", "--resume"])
    assert path in line and not os.path.exists("o")


def test_a_finished_run_leaves_other_runs_checkpoints_alone(tmp_path, capsys, monkeypatch):
    """Beside the folder: a checkpoint at dip-lqr's own name that another run wrote (it cannot be this run's),
    and another experiment's. Both survive this run; a checkpoint the run wrote itself does not."""
    monkeypatch.chdir(tmp_path)
    exp = get("dip-lqr")
    same_name = _checkpoint_of("dip-lqr", "o", xla_flags.effort(), owner="a run started later")
    other = _checkpoint_of("eki-dip", "o", "full")
    before = {p: open(p, "rb").read() for p in (same_name, other)}
    assert cli.main(["run", "dip-lqr", "--quick", "--out", "o"]) == 0, capsys.readouterr().err
    assert {p: open(p, "rb").read() for p in (same_name, other)} == before

    cfg = C.load(exp.config_cls, quick=exp.quick)
    ctx = run_context(exp, cfg, "o", compile_effort=xla_flags.effort())
    with checkpoint.owning("this run") as owner:
        checkpoint.save(ctx.checkpoint_path, TREE, ctx.fingerprint)
        assert checkpoint.remove_own(other, owner) is False
        assert checkpoint.remove_own(ctx.checkpoint_path, owner) is True
    assert not os.path.exists(ctx.checkpoint_path) and os.path.exists(other)


def test_resume_from_a_checkpoint_of_other_leaves_is_one_line(tmp_path, capsys, monkeypatch):
    """The leaves are checked where the run loads them, after its programs are built: still one line, and the
    staging folder is gone."""
    monkeypatch.chdir(tmp_path)
    tiny = ["seeds=4", "ensemble=6", "iterations=4", "chunk=2", "T=0.2", "t_star=0.1", "grad_steps=0",
            "eval_states=2", "judge_duration=0.2", "early_stop=false", "min_success=2"]
    path = _checkpoint_of("eki-dip", "o", xla_flags.effort(), sets=tiny)
    line = _one_line(capsys, [*EKI, "--out", "o", "--resume", *[a for s in tiny for a in ("--set", s)]])
    assert path in line and "structure" in line
    assert sorted(os.listdir()) == [os.path.basename(path)]  # no output folder, no staging folder
