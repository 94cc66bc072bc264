"""Real processes at the commit: two runs racing for one destination, and SIGKILL at random instants of a
commit. The drivers (``outdir_driver.py``) use the staging API without JAX, so each repetition costs a process
start (~0.1 s); ``test_two_cli_runs_race`` is the same race through the real command line."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import pytest

from outdir_driver import FILES
from outdir_world import ROOT, whole, write_run

TESTS = os.path.join(ROOT, "tests")


def _start(dest, owner, tag, go, *extra):
    return subprocess.Popen([sys.executable, os.path.join(TESTS, "outdir_driver.py"), str(dest), owner, tag, str(go),
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=TESTS)


def _tags(folder) -> set[str] | None:
    """The tags of a whole run's files ({tag}), or None where the folder is not one whole run."""
    files = whole(folder)
    if files is None:
        return None
    return {text.split(":", 1)[0] for text in files.values()}


def _staging_left(parent) -> list[str]:
    return [n for n in os.listdir(parent) if ".jaxdip-" in n]


FULL = pytest.param(20, marks=pytest.mark.slow, id="20")  # the acceptance figure; the default suite runs 4


@pytest.mark.parametrize("reps", [4, FULL])
@pytest.mark.parametrize("owners", [("dip-lqr", "dip-lqr"), ("dip-lqr", "eki-linear")], ids=["same", "different"])
def test_two_processes_race_for_one_destination(tmp_path, owners, reps):
    outcomes = {"new": 0, "old": 0}
    for rep in range(reps):
        d = tmp_path / f"r{rep}"
        d.mkdir()
        dest = d / "out"
        start = "old" if rep % 2 else "new"
        if start == "old":  # a previous run of the first owner's experiment: both may replace it
            write_run(dest, owners[0], {n: f"old:{n}\n" for n in FILES[:3]})
        go = d / "go"
        # the other experiment's run replaces the old folder only with --force (given at its start)
        procs = [_start(dest, owner, f"p{i}", go, *["--force"] * (owner != owners[0])) for i, owner in enumerate(owners)]
        for p in procs:
            assert p.stdout.readline().strip() == "ready", p.stderr.read()
        go.touch()
        res = [(p.wait(timeout=60), p.stdout.read(), p.stderr.read()) for p in procs]
        codes = sorted(r[0] for r in res)
        assert codes == [0, 2], res  # one commits, the other stops
        winner = next(i for i, r in enumerate(res) if r[0] == 0)
        loser_err = res[1 - winner][2].strip().splitlines()
        assert len(loser_err) == 1 and "nothing was replaced" in loser_err[0], res
        assert _tags(dest) == {f"p{winner}"}  # the winner's run, whole: never mixed, never lost
        kept = [n for n in os.listdir(d) if ".kept-" in n]
        assert len(kept) == 1 and kept[0] in loser_err[0] and _tags(d / kept[0]) == {f"p{1 - winner}"}
        assert _staging_left(d) == []
        outcomes[start] += 1
    assert outcomes == {"new": reps // 2, "old": reps // 2}


def _kill_loop(tmp_path, reps, in_place):
    from jaxdip.outdir import check_destination

    dest = tmp_path / "out"
    write_run(dest, "dip-lqr", {n: f"t0:{n}\n" for n in FILES})
    # three commits untouched, to scale the kill instants to how long a commit takes here (the median)
    took = []
    for k in range(3):
        go = tmp_path / f"warm{k}"
        p = _start(dest, "dip-lqr", "t1", go, *["--in-place"] * in_place)
        assert p.stdout.readline().strip() == "ready"
        go.touch()
        out, err = p.communicate(timeout=60)
        took.append(float(out.split()[-1]))
    commit_s = sorted(took)[1]
    current, seen = "t1", {"old": 0, "new": 0}
    rng = random.Random(0)
    for rep in range(2, reps + 2):
        tag, go = f"t{rep}", tmp_path / f"go{rep}"
        p = _start(dest, "dip-lqr", tag, go, *["--in-place"] * in_place)
        assert p.stdout.readline().strip() == "ready", p.stderr.read()
        go.touch()
        time.sleep(rng.uniform(0, 1.5 * commit_s))
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
        if not in_place:
            assert _tags(dest) in ({current}, {tag}), rep  # whole at every instant: no recovery needed
        elif _tags(dest) is None:
            seen["half"] = seen.get("half", 0) + 1  # killed mid-way: the journal lets the next run undo it
        check_destination(str(dest), "dip-lqr")  # what the next run does first: finishes or undoes a half commit
        got = _tags(dest)
        assert got in ({current}, {tag}), (rep, got)
        seen["new" if got == {tag} else "old"] += 1
        current = got.pop()
        assert _staging_left(tmp_path) == [], rep  # the killed run's staging folder is gone
    return seen, commit_s


@pytest.mark.parametrize("reps", [8, pytest.param(50, marks=pytest.mark.slow, id="50")])
@pytest.mark.parametrize("in_place", [False, True], ids=["exchange", "in-place"])
def test_sigkill_at_random_instants_of_the_commit(tmp_path, in_place, reps):
    seen, commit_s = _kill_loop(tmp_path, reps, in_place=in_place)
    print(f"{'in-place' if in_place else 'exchange'} commit {commit_s * 1e3:.2f} ms; after {reps} kills the "
          f"folder was old {seen['old']}, new {seen['new']} times ({seen.get('half', 0)} half-done, recovered)")


@pytest.mark.slow
def test_two_cli_runs_race(tmp_path):
    """Two real ``jaxdip run`` processes into one new --out: one writes it, the other keeps its output aside."""
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1")
    argv = [sys.executable, "-m", "jaxdip.cli", "run", "dip-lqr", "--quick", "--seeds", "2", "--set",
            "duration=0.2", "--out", str(tmp_path / "out")]
    procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
             for _ in range(2)]
    res = [(p.wait(timeout=600), p.stderr.read()) for p in procs]
    codes = sorted(r[0] for r in res)
    print(f"two CLI runs: exit codes {codes}")
    assert whole(tmp_path / "out") is not None
    kept = [n for n in os.listdir(tmp_path) if ".kept-" in n]
    if codes == [0, 2]:  # they overlapped (the usual case): the second to finish stops with one line
        err = next(r[1] for r in res if r[0] == 2).strip().splitlines()
        assert len(err) == 1 and len(kept) == 1 and kept[0] in err[0] and whole(tmp_path / kept[0]) is not None
    else:  # one finished before the other started: it replaced its own experiment's folder
        assert codes == [0, 0] and kept == [], res
    assert _staging_left(tmp_path) == []
