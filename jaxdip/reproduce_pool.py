"""The worker processes of a parallel ``jaxdip reproduce``.

Each worker (``jaxdip.reproduce_worker``) starts JAX once and runs the ``jaxdip run`` commands it is given one
after another, keeping its compiled programs in memory. ``run_parallel`` hands the experiments out, longest
first, each worker taking the next when it finishes one; each experiment's output goes to a log, shown only when
it fails.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

from jaxdip import xla_flags
from jaxdip.cli_errors import error, flush_output, note
from jaxdip.outdir.files import write_file_atomic

TIMES = "reproduce-times.json"  # in the cache folder: {"quick": {id: seconds}, "full": {...}}, the last durations
MAX_JOBS = 64  # far beyond the experiments there are; a larger --jobs is a typo, not a plan


def cpu_blocks(n: int) -> list[list[int]]:
    """The CPUs this process may use, split into ``n`` near-equal blocks, one per worker (empty: fewer CPUs than
    workers, or no affinity support). Each worker keeps to its block: XLA's CPU runtime sizes its thread pool from
    the CPUs a process may use and splits each loop's kernels over it, and two processes whose pools share the
    same cores wait on each other's descheduled threads at every kernel. Measured on 2 cores (tune's held-out
    evaluation, 256 seeds x 2000 periods, one device): 3.3 s alone with both cores, 1.6 s alone on one core,
    35-50 s each for two unpinned processes side by side, 1.6 s each for two processes on a core each."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []
    if n < 2 or len(cpus) < n:
        return []
    q, r = divmod(len(cpus), n)
    starts = [i * q + min(i, r) for i in range(n + 1)]
    return [cpus[starts[i]:starts[i + 1]] for i in range(n)]


def _threads() -> int | None:
    try:
        return len(os.listdir("/proc/self/task"))  # Linux: this process's threads, Python's and native ones
    except OSError:
        return None


_THREADS_AT_IMPORT = _threads()  # jax and numpy are imported by now (the command line imports this module)


def can_fork() -> bool:
    """Whether the workers may be forked from this process rather than started as new interpreters: on Linux,
    while no thread has started here since this module was imported. JAX's CPU backend starts a dozen when it
    starts (the first computation), and a fork after that would copy its state without its threads; so the
    ``jaxdip`` command, which computes nothing before it starts its workers, forks them, and a process that
    has used JAX (a test, a script calling ``cli.main``) starts them the slower way."""
    return sys.platform.startswith("linux") and hasattr(os, "fork") and _threads() == _THREADS_AT_IMPORT


class Forked:
    """A worker forked from this process, for ``Workers`` in place of a ``subprocess.Popen``: it inherits the
    modules imported here (JAX, equinox, optax, the experiments), which a new interpreter takes about 0.8 s to
    import before its first experiment, on the reproduction's critical path. ``extra``: environment variables
    to set in it. It keeps none of this process's open files but its own two pipes, as a started worker: not
    the pipes of the workers forked before it (holding another's input open would keep that one from ever
    seeing the end of its input), nor a lock this process holds."""

    def __init__(self, extra: dict[str, str]):
        task_r, task_w = os.pipe()
        answer_r, answer_w = os.pipe()
        flush_output()  # what is buffered here must not be written a second time by the worker
        pid = os.fork()
        if pid == 0:  # the worker: never returns into the code that forked it
            code = 1
            try:
                os.setsid()  # its own session, as start_new_session: a Ctrl-C reaches the parent only
                for name in os.listdir("/proc/self/fd"):
                    if int(name) > 2 and int(name) not in (task_r, answer_w):
                        try:
                            os.close(int(name))
                        except OSError:  # the listing's own descriptor, closed by now
                            pass
                null = os.open(os.devnull, os.O_RDWR)  # nothing of the terminal: no input, no messages
                os.dup2(null, 0)
                os.dup2(answer_w, 1)
                os.dup2(null, 2)
                os.environ.update(extra)
                from jaxdip import reproduce_worker

                code = reproduce_worker.main(os.fdopen(task_r, "r"))
                flush_output()
            finally:
                os._exit(code)
        os.close(task_r)
        os.close(answer_w)
        self.pid, self.returncode = pid, None
        self.stdin = os.fdopen(task_w, "w", buffering=1)
        self.stdout = os.fdopen(answer_r, "r")

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self) -> int:
        if self.returncode is None:
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class Workers:
    """``n`` worker processes (forked, ``Forked``, where ``can_fork``; else started as ``python -m
    jaxdip.reproduce_worker``) and one queue of their answers, ``(worker, answer or None when the worker has
    ended)``. Only ever made after every argument has been checked."""

    def __init__(self, n: int):
        if not 1 <= n <= MAX_JOBS:
            raise ValueError(f"{n} workers")
        self.answers: queue.Queue = queue.Queue()
        self.workers = []
        blocks = cpu_blocks(n)
        fork = can_fork()
        for i in range(n):
            extra = {"JAXDIP_NO_PROGRESS": "1"}
            if blocks:
                extra["JAXDIP_WORKER_CPUS"] = ",".join(map(str, blocks[i]))
            if fork:
                proc = Forked(extra)
            else:
                proc = subprocess.Popen([sys.executable, "-m", "jaxdip.reproduce_worker"], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                        env=dict(os.environ, **extra), text=True, bufsize=1, start_new_session=True)
            self.workers.append({"proc": proc, "task": None, "t": 0.0, "given": False})
        for w in self.workers:  # after every fork: a thread of this process must not be running while it forks
            threading.Thread(target=self._read, args=(w,), daemon=True).start()

    def _read(self, w):
        for line in w["proc"].stdout:
            self.answers.put((w, json.loads(line)))
        self.answers.put((w, None))

    def close(self):
        for w in self.workers:
            close(w)
            if not w["given"] and w["proc"].poll() is None:
                w["proc"].kill()  # never given an experiment: do not wait for its start-up
            w["proc"].wait()


def work_order(reg, cost: str, learned: dict[str, float]) -> list:
    """``reg`` (``[(id, Experiment)]``) longest first: by ``learned`` seconds where given, else by the estimate
    named ``cost``; stable, so an entry without either stays in its place among equals."""
    return sorted(reg, key=lambda r: -learned.get(r[0], getattr(r[1], cost, 0.0)))


def last_times(path: str | None, scale: str) -> dict[str, float]:
    """{experiment: seconds} of the last reproduction at ``scale`` recorded in ``path``; {} if none (or unreadable:
    it only orders the work)."""
    if path is None:
        return {}
    try:
        with open(path, encoding="utf-8") as fh:
            got = json.load(fh)[scale]
        return {str(k): float(v) for k, v in got.items()
                if isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 1e7}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def record_times(path: str | None, scale: str, took: dict[str, float]) -> None:
    """Add this reproduction's durations to ``path`` (the others' kept); a folder that cannot take it is no error."""
    if path is None or not took:
        return
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        if not isinstance(data, dict):
            data = {}
    except (OSError, ValueError):
        data = {}
    if not isinstance(data.get(scale), dict):
        data[scale] = {}
    data[scale].update({k: round(v, 3) for k, v in took.items()})
    try:
        write_file_atomic(path, json.dumps(data, indent=1, sort_keys=True) + "\n")
    except OSError:
        pass


def close(w):
    """End of input: the worker exits once its current experiment is done."""
    if w["proc"].stdin and not w["proc"].stdin.closed:
        try:
            w["proc"].stdin.close()
        except OSError:
            pass


def run_argv(args, exp_id: str) -> list[str]:
    """The ``jaxdip run`` arguments that make ``exp_id``'s folder of a reproduction (a worker runs them; an
    experiment run in the reproduction's own process records them as its command, so a folder's report reads
    the same whichever way it was made)."""
    argv = ["run", exp_id, "--out", os.path.join(args.out, exp_id)]
    argv += ["--quick"] * bool(args.quick) + ["--force"] * bool(args.force)
    argv += ["--no-compile-cache"] * bool(args.no_compile_cache)
    return argv + (["--compile-effort", args.compile_effort] if args.compile_effort else [])


def run_parallel(args, reg, jobs: int, stopped: str) -> int:
    """Run the experiments ``reg`` (``[(id, Experiment)]``) in ``jobs`` workers; 0 or the exit code (on an
    interrupt after the one-line note ``stopped``)."""
    cost = "quick_cost_s" if args.quick else "full_cost_s"
    times = None if args.no_compile_cache else os.path.join(xla_flags.cache_folder(), TIMES)
    scale = "quick" if args.quick else "full"
    # longest first: by the time each took in the last reproduction with this cache (a warm run's durations are
    # not a cold one's: compiling dominates the first, computing and figures the others), else by its estimate
    order = work_order(reg, cost, last_times(times, scale))
    pending = [exp_id for exp_id, _ in order]
    failed: list = []
    logs = tempfile.mkdtemp(prefix="jaxdip-reproduce-")
    n, done = len(order), 0
    took: dict[str, float] = {}
    pool = Workers(min(jobs, n))
    answers, workers = pool.answers, pool.workers

    def log(exp_id):
        return os.path.join(logs, f"{exp_id}.log")

    def give(w):
        exp_id = pending.pop(0)
        argv = run_argv(args, exp_id)
        w["task"], w["t"] = exp_id, time.perf_counter()
        w["given"] = True
        try:
            w["proc"].stdin.write(json.dumps({"id": exp_id, "argv": argv, "log": log(exp_id)}) + "\n")
            w["proc"].stdin.flush()
        except OSError:
            pass  # the worker has died: its reader reports the end, and the experiment counts as failed

    def tail(exp_id):
        try:
            with open(log(exp_id), errors="replace") as fh:
                lines = [ln for ln in fh.read().splitlines() if ln.strip()]
        except OSError:
            lines = []
        return (lines[-1:] or ["(no output)"])[0]

    try:
        for w in workers:
            give(w)
        # after a failure nothing new starts, and the loop ends once the running ones have finished
        while any(w["task"] is not None for w in workers):
            try:
                w, ans = answers.get(timeout=0.2)
            except queue.Empty:
                continue
            exp_id, w["task"] = w["task"], None
            if exp_id is None:
                continue
            done += 1
            rc = ans["rc"] if ans is not None else (w["proc"].wait() or 1)
            if rc == 0:
                took[exp_id] = time.perf_counter() - w["t"]
                print(f"== {exp_id} done ({took[exp_id]:.1f} s) [{done}/{n}]", file=sys.stderr)
            else:
                failed.append((exp_id, rc, tail(exp_id)))
            if pending and not failed and ans is not None:
                give(w)
            else:
                close(w)
    except KeyboardInterrupt:
        for w in workers:
            if w["task"] is not None and w["proc"].poll() is None:
                w["proc"].send_signal(signal.SIGINT)  # once: the workers are in their own sessions
        pool.close()
        shutil.rmtree(logs, ignore_errors=True)
        note(stopped)
        return 130
    pool.close()
    record_times(times, scale, took)
    if not failed:
        shutil.rmtree(logs, ignore_errors=True)
        return 0
    # the failing experiment's log is kept (the line names it); the others' are not worth a folder each
    for name in os.listdir(logs):
        if name != f"{failed[0][0]}.log":
            os.remove(os.path.join(logs, name))
    exp_id, code, line = failed[0]
    line = line[len("error: "):] if line.startswith("error: ") else line
    error(exp_id, f"{line} (log: {log(exp_id)})")
    return 130 if code == 130 else (code if code == 2 else 1)
