"""Hostile inputs to the CLI: each gives exit 2, one line ``error: <key or flag>: <why>``, no output folder, and
leaves every file it did not write exactly as it was (a snapshot of the working folder before and after).

The cases run in-process through ``jaxdip.cli.main`` (every one fails before anything compiles, so the whole
table takes seconds); ``test_console_script_one_line`` checks the same contract through a real process.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import pytest

from jaxdip import cli
from jaxdip.outdir import MARKER
from snapshots import snapshot

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIG = "1" + "0" * 22  # beyond int64


def _marker(folder, owner, files):
    """A folder as jaxdip writes it: the files and a marker with each one's hash (so a refusal is for the reason
    the case names, not for a malformed marker)."""
    os.makedirs(folder, exist_ok=True)
    for f in files:
        with open(os.path.join(folder, f), "w") as fh:
            fh.write("old result\n")
    digest = hashlib.sha256(b"old result\n").hexdigest()
    with open(os.path.join(folder, MARKER), "w") as fh:
        json.dump({"tool": "jaxdip", "format": 2, "owner": owner, "files": {f: digest for f in files}}, fh)


# ---- the world each case starts from (all inside a fresh temporary working folder) --------------------------


def setup_world(tmp):
    os.makedirs("userdir")
    with open("userdir/thesis.tex", "w") as fh:
        fh.write("my thesis\n")
    with open("notes.txt", "w") as fh:
        fh.write("my notes\n")
    os.symlink("userdir", "link_to_userdir")
    _marker("other_run", "eki-linear", ["metrics.json", "report.md"])
    _marker("lqr_run_plus_mine", "dip-lqr", ["metrics.json", "report.md"])
    with open("lqr_run_plus_mine/my_plot.py", "w") as fh:
        fh.write("print('mine')\n")
    os.makedirs("bad_marker")
    with open("bad_marker/" + MARKER, "w") as fh:
        fh.write("{not json")
    with open("bad_marker/x.txt", "w") as fh:
        fh.write("x\n")
    os.makedirs("foreign_marker")
    with open("foreign_marker/" + MARKER, "w") as fh:
        json.dump({"tool": "other", "owner": "dip-lqr", "files": ["x.txt"]}, fh)
    with open("foreign_marker/x.txt", "w") as fh:
        fh.write("x\n")
    os.makedirs("repro/dip-lqr")
    with open("repro/dip-lqr/mine.txt", "w") as fh:
        fh.write("mine\n")
    os.makedirs("repro_report")
    with open("repro_report/REPORT.md", "w") as fh:
        fh.write("my own report\n")
    with open("bench_mine.json", "w") as fh:
        json.dump({"my": "data"}, fh)
    files = {
        "binary.toml": b"\xff\xfe\x00\x01binary",
        "latin1.toml": "seeds = 4 # caf\xe9".encode("latin-1"),
        "nul.toml": b"seeds = 4\n\x00\n",
        "bad_syntax.toml": b"seeds = = 4\n",
        "dup.toml": b"seeds = 4\nseeds = 5\n",
        "unknown_key.toml": b"seedz = 4\n",
        "wrong_type.toml": b'seeds = "many"\n',
        "negative.toml": b"seeds = -3\n",
        "table_for_value.toml": b"[seeds]\na = 1\n",
        "unknown_table.toml": b"[foo]\na = 1\n",
        "ragged.toml": b"Q = [[1, 0, 0, 0, 0, 0], [1.0]]\n",
        "deep.toml": b"Q = [[[[1.0]]]]\n",
        "huge.toml": b"# padding\n" * 120_000,
    }
    for name, data in files.items():
        with open(name, "wb") as fh:
            fh.write(data)


RUN = ["run", "dip-lqr", "--quick"]

CASES = [
    # -- output destinations
    ("out_user_folder", [*RUN, "--out", "userdir"], "--out"),
    ("out_cwd", [*RUN, "--out", "."], "--out"),
    ("out_empty_string", [*RUN, "--out", ""], "--out"),
    ("out_is_file", [*RUN, "--out", "notes.txt"], "--out"),
    ("out_under_file", [*RUN, "--out", "notes.txt/sub"], "--out"),
    ("out_deep_under_file", [*RUN, "--out", "notes.txt/a/b/c"], "--out"),
    ("out_unwritable_fs", [*RUN, "--out", "/proc/jaxdip-out"], "--out"),
    ("out_symlink", [*RUN, "--out", "link_to_userdir"], "--out"),
    ("out_other_experiment", [*RUN, "--out", "other_run"], "--out"),
    ("out_own_run_plus_user_file", [*RUN, "--out", "lqr_run_plus_mine"], "--out"),
    ("out_own_run_plus_user_file_force", [*RUN, "--force", "--out", "lqr_run_plus_mine"], "--out"),
    ("out_bad_marker", [*RUN, "--out", "bad_marker"], "--out"),
    ("out_foreign_marker", [*RUN, "--out", "foreign_marker"], "--out"),
    ("reproduce_out_file", ["reproduce", "--quick", "--out", "notes.txt"], "--out"),
    ("reproduce_user_subfolder", ["reproduce", "--quick", "--out", "repro"], "--out"),
    ("reproduce_user_report", ["reproduce", "--quick", "--out", "repro_report"], "--out"),
    ("reproduce_unwritable", ["reproduce", "--quick", "--out", "/proc/jaxdip-repro"], "--out"),
    ("reproduce_only_unknown", ["reproduce", "--quick", "--only", "dip-lqr,nope", "--out", "o"], "--only"),
    ("reproduce_only_empty", ["reproduce", "--quick", "--only", ",", "--out", "o"], "--only"),
    ("reproduce_jobs_zero", ["reproduce", "--quick", "--jobs", "0", "--out", "o"], "--jobs"),
    ("bench_user_file", ["bench", "--quick", "--out", "bench_mine.json"], "--out"),
    ("bench_folder", ["bench", "--quick", "--out", "userdir"], "--out"),
    ("bench_unwritable", ["bench", "--quick", "--out", "/proc/bench.json"], "--out"),
    ("bench_under_file", ["bench", "--quick", "--out", "notes.txt/bench.json"], "--out"),
    ("resume_without_checkpoint", ["run", "eki-dip", "--quick", "--resume", "--out", "fresh"], "--resume"),
    # -- config files
    ("config_missing", [*RUN, "--config", "nope.toml", "--out", "o"], "--config"),
    ("config_folder", [*RUN, "--config", "userdir", "--out", "o"], "--config"),
    ("config_binary", [*RUN, "--config", "binary.toml", "--out", "o"], "--config"),
    ("config_latin1", [*RUN, "--config", "latin1.toml", "--out", "o"], "--config"),
    ("config_nul", [*RUN, "--config", "nul.toml", "--out", "o"], "--config"),
    ("config_syntax", [*RUN, "--config", "bad_syntax.toml", "--out", "o"], "--config"),
    ("config_duplicate_key", [*RUN, "--config", "dup.toml", "--out", "o"], "--config"),
    ("config_huge", [*RUN, "--config", "huge.toml", "--out", "o"], "--config"),
    ("config_unknown_key", [*RUN, "--config", "unknown_key.toml", "--out", "o"], "seedz"),
    ("config_wrong_type", [*RUN, "--config", "wrong_type.toml", "--out", "o"], "seeds"),
    ("config_negative_with_quick", [*RUN, "--config", "negative.toml", "--out", "o"], "seeds"),
    ("config_table_for_value", [*RUN, "--config", "table_for_value.toml", "--out", "o"], "seeds"),
    ("config_unknown_table", [*RUN, "--config", "unknown_table.toml", "--out", "o"], "foo"),
    ("config_ragged", [*RUN, "--config", "ragged.toml", "--out", "o"], "Q"),
    ("config_deep", [*RUN, "--config", "deep.toml", "--out", "o"], "Q"),
    # -- --set
    ("set_no_equals", [*RUN, "--set", "seeds", "--out", "o"], "--set"),
    ("set_empty_key", [*RUN, "--set", "=5", "--out", "o"], "--set"),
    ("set_unknown_key", [*RUN, "--set", "Qx=[1,2,3,4,5,6]", "--out", "o"], "Qx"),
    ("set_seeds_word", [*RUN, "--set", "seeds=many", "--out", "o"], "seeds"),
    ("set_seeds_zero", [*RUN, "--set", "seeds=0", "--out", "o"], "seeds"),
    ("set_seeds_negative", [*RUN, "--set", "seeds=-1", "--out", "o"], "seeds"),
    ("set_seeds_fraction", [*RUN, "--set", "seeds=1.5", "--out", "o"], "seeds"),
    ("set_seeds_bool", [*RUN, "--set", "seeds=true", "--out", "o"], "seeds"),
    ("set_seeds_table", [*RUN, "--set", "seeds.x=1", "--out", "o"], "seeds.x"),
    ("set_smuggled_lines", [*RUN, "--set", "seeds=1\nseeds=2", "--out", "o"], "seeds"),
    ("set_dt_nan", [*RUN, "--set", "dt=nan", "--out", "o"], "dt"),
    ("set_dt_inf", [*RUN, "--set", "dt=inf", "--out", "o"], "dt"),
    ("set_dt_negative", [*RUN, "--set", "dt=-0.001", "--out", "o"], "dt"),
    ("set_R_negative", [*RUN, "--set", "R=-1", "--out", "o"], "R"),
    ("set_noise_negative", [*RUN, "--set", "noise_std=[-0.1,0,0,0,0,0]", "--out", "o"], "noise_std"),
    ("set_Q_wrong_shape", [*RUN, "--set", "Q=[[1,0],[0,1]]", "--out", "o"], "Q"),
    ("set_Q_ragged", [*RUN, "--set", "Q=[[1,0,0,0,0,0],[1.0]]", "--out", "o"], "Q"),
    ("set_Q_mixed", [*RUN, "--set", "Q=[1,[2]]", "--out", "o"], "Q"),
    ("set_Q_not_psd", [*RUN, "--set", "Q=[-1,0,0,0,0,0]", "--out", "o"], "Q"),
    # PSD but leaves the cart position unseen: no stabilising CARE solution
    ("set_Q_not_detectable", [*RUN, "--set", "Q=[0,350,100,0,0,0]", "--out", "o"], "Q, R"),
    ("set_seed_expression", [*RUN, "--set", "seed=2**70", "--out", "o"], "seed"),
    ("set_seed_huge", [*RUN, "--set", f"seed={BIG}", "--out", "o"], "seed"),
    ("set_seed_negative", [*RUN, "--set", "seed=-1", "--out", "o"], "seed"),
    ("set_duration_huge", [*RUN, "--set", "duration=1e9", "--out", "o"], "duration"),
    ("set_duration_overflow", [*RUN, "--set", "duration=1e400", "--out", "o"], "duration"),
    ("set_variant_unknown", [*RUN, "--set", "variant=upside_down", "--out", "o"], "variant"),
    ("set_record_every_not_dividing", [*RUN, "--set", "record_every=7", "--out", "o"], "record_every"),
    ("set_init_radius_negative", [*RUN, "--set", "init_radius=-1", "--out", "o"], "init_radius"),
    ("set_state_bound_zero", [*RUN, "--set", "state_bound=[0,1,1,1,1,1]", "--out", "o"], "state_bound"),
    # -- --seeds
    ("seeds_zero", [*RUN, "--seeds", "0", "--out", "o"], "--seeds"),
    ("seeds_negative", [*RUN, "--seeds", "-5", "--out", "o"], "--seeds"),
    ("seeds_word", [*RUN, "--seeds", "abc", "--out", "o"], "--seeds"),
    ("seeds_too_many_for_memory", ["run", "dip-lqr", "--seeds", "1000000000000", "--out", "o"], "--seeds"),
    ("seeds_beyond_int64", [*RUN, "--seeds", BIG, "--out", "o"], "--seeds"),
    # -- the command line itself
    ("run_without_id", ["run"], "id"),
    ("unknown_flag", [*RUN, "--bogus", "--out", "o"], "--bogus"),
    ("unknown_command", ["bogus"], "command"),
    ("unknown_experiment", ["run", "dip-lqq", "--out", "o"], "dip-lqq"),
    ("config_unknown_experiment", ["config", "dip-lqq"], "dip-lqq"),
    # -- other experiments' own checks
    ("eki_ensemble_memory", ["run", "eki-dip", "--set", "ensemble=1000000000000", "--out", "o"], "ensemble"),
    ("lorenz_duration", ["run", "lorenz-mhe", "--set", "duration=1e12", "--out", "o"], "duration"),
    ("twip_seeds_memory", ["run", "twip-dmso", "--seeds", "100000000000", "--out", "o"], "--seeds"),
    ("tune_target_unknown", ["run", "tune", "--quick", "--set", "target=bogus", "--out", "o"], "target"),
    ("rwp_bias_zero", ["run", "rwp-bias", "--quick", "--set", "bias=0", "--out", "o"], "bias"),
    ("rwp_luenberger_omega_length", ["run", "rwp-bias", "--quick", "--set", "luenberger_omega=[1.0]", "--out", "o"],
     "luenberger_omega"),
    ("rwp_observer_current_unknown", ["run", "rwp-bias", "--quick", "--set", "observer_current=both", "--out", "o"],
     "observer_current"),
    ("eki_nonlinear_final_unknown", ["run", "eki-nonlinear", "--quick", "--set", "final=best", "--out", "o"],
     "final"),
    ("eki_nonlinear_x0_draw_unknown", ["run", "eki-nonlinear", "--quick", "--set", "x0_draw=each", "--out", "o"],
     "x0_draw"),
    ("dip_cpx_ldf_gamma_negative", ["run", "dip-cpx-ldf", "--quick", "--set", "cpx_gamma=-1", "--out", "o"],
     "cpx_gamma"),
]


def test_there_are_at_least_sixty_cases():
    assert len(CASES) >= 60 and len({c[0] for c in CASES}) == len(CASES)


@pytest.fixture
def world(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # restored after the test
    setup_world(tmp_path)
    return tmp_path


@pytest.mark.parametrize("name, argv, key", CASES, ids=[c[0] for c in CASES])
def test_hostile_input(world, capsys, name, argv, key):
    before = snapshot(world)
    code = cli.main(list(argv))
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"error: {key}: "), lines[0]
    assert snapshot(world) == before  # nothing written, nothing of the user's touched


def test_console_script_one_line(tmp_path):
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1")
    (tmp_path / "mine.txt").write_text("mine\n")
    r = subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", "dip-lqr", "--quick", "--out", str(tmp_path)],
                       capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("error: --out: "), r.stderr
    assert os.listdir(tmp_path) == ["mine.txt"]


FAKE_WORKER = """
import json, os, sys

def serve(tasks):
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    for line in tasks:
        task = json.loads(line)
        with open(task["log"], "w") as log:
            print("started " + task["id"], file=log)
            if task["id"] == "eki-linear":
                print("error: boom", file=log, flush=True)  # as the real worker: the log is written before the answer
                answers.write(json.dumps({"id": task["id"], "rc": 1}) + "\\n")
                continue
        if task["id"] == "lorenz-mhe":
            os._exit(9)  # the worker dies without answering
        answers.write(json.dumps({"id": task["id"], "rc": 0}) + "\\n")
    return 0
"""


def _parallel_with_fake_workers(tmp_path, ids, jobs, forked=False, tmpdir=None):
    """``run_parallel`` with workers that answer the protocol without running anything: started as new
    interpreters (the parent's ``sys.executable`` is a script running FAKE_WORKER), or, with ``forked``, forked
    from a process that has not started JAX (``reproduce_worker.main`` replaced before the fork). ``tmpdir``: the
    run's temporary folder (default ``tmp_path``)."""
    import subprocess
    import sys

    worker = tmp_path / "fake_worker.py"
    worker.write_text(FAKE_WORKER + "serve(sys.stdin)\n")
    fake = tmp_path / "fake-python"
    fake.write_text(f"#!/bin/sh\nexec {sys.executable} {worker}\n")
    fake.chmod(0o755)
    if forked:
        start = ("from jaxdip import reproduce_worker\n"
                 f"exec({FAKE_WORKER!r})\n"
                 "reproduce_worker.main = serve\n"
                 "assert reproduce_pool.can_fork()\n")
    else:
        start = f"sys.executable = {str(fake)!r}\nreproduce_pool.can_fork = lambda: False\n"
    code = (
        "import sys, types\n"
        "from jaxdip import reproduce_pool\n"
        + start +
        f"args = types.SimpleNamespace(out={str(tmp_path / 'o')!r}, quick=False, force=False, no_compile_cache=False, compile_effort=None)\n"
        f"reg = [(i, None) for i in {tuple(ids)!r}]\n"
        f"sys.exit(reproduce_pool.run_parallel(args, reg, {jobs}, 'interrupted'))\n"
    )
    # a cache folder of its own: the order of the experiments follows the durations the last reproduction with
    # that folder recorded (reproduce-times.json), which another test's fake run would have written; and the
    # test's folder as the temporary one: a failed reproduction keeps its failing experiment's log there
    env = dict(os.environ, JAXDIP_CACHE_DIR=str(tmp_path / "cache"), TMPDIR=str(tmpdir or tmp_path))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)


forked_or_started = pytest.mark.parametrize("forked", [
    False, pytest.param(True, marks=pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux only"))])


@forked_or_started
def test_parallel_reproduce_stops_after_a_failing_child(tmp_path, forked):
    """A failing experiment stops the parallel reproduce with its error line (it used to wait forever for the
    experiments it would no longer start)."""
    r = _parallel_with_fake_workers(tmp_path, ("eki-linear", "dip-lqr", "twip-dmso"), 1, forked)
    assert r.returncode == 1, r.stderr
    assert "error: eki-linear: boom" in r.stderr
    assert "dip-lqr done" not in r.stderr  # would have been next: never given to the worker


@forked_or_started
def test_parallel_reproduce_survives_a_dying_worker(tmp_path, forked):
    """A worker that dies mid-experiment (killed, out of memory) fails that experiment instead of hanging; the
    other worker finishes the one it is running, and one worker runs experiments one after another."""
    r = _parallel_with_fake_workers(tmp_path, ("dip-lqr", "twip-dmso", "lorenz-mhe", "rwp-bias"), 2, forked)
    assert r.returncode == 1, r.stderr
    assert "error: lorenz-mhe: started lorenz-mhe" in r.stderr, r.stderr
    assert "dip-lqr done" in r.stderr and "twip-dmso done" in r.stderr  # three experiments on two workers
