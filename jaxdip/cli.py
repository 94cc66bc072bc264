"""Command line: ``jaxdip list | run <id> | bench | reproduce``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import shlex
import signal
import sys
import time


def _use_all_cores(processes: int = 1):
    """On CPU, expose one XLA host device per core so Monte Carlo batches shard over all of them; with
    ``processes`` processes computing side by side (the workers of a parallel ``reproduce``), each gets its share
    of the cores: sharding one worker's batches over cores the other workers keep busy only adds compilation
    (the partitioned programs) and synchronisation, cold ``reproduce --quick`` 92 s against 79 s on 2 cores.

    XLA reads the flag when the backend starts (first computation), so setting it here, before any array is
    made, is enough. A user's own XLA_FLAGS are left alone; worker processes inherit this one.
    """
    from jaxdip import xla_flags

    cores = os.cpu_count() or 1
    n = max(1, cores // max(1, processes))
    # set even when it is 1: the workers' own `run` would otherwise take every core
    if cores > 1 and os.environ.get("JAX_PLATFORMS", "cpu") == "cpu":
        xla_flags.append(xla_flags.pending({"xla_force_host_platform_device_count": n}))


def _jobs(args) -> int:
    """``reproduce --jobs``, or its default: one per core, at most 2."""
    return args.jobs if args.jobs is not None else max(1, min(2, os.cpu_count() or 1))


def _reproduce_jobs(args) -> int:
    """How many worker processes a ``reproduce`` runs side by side (1: the experiments run in this process)."""
    several = args.only is None or len({w.strip() for w in args.only.split(",") if w.strip()}) > 1
    return max(1, _jobs(args)) if several and not args.distributed else 1


def _compile_cache(enabled: bool) -> None:
    """Keep XLA's compiled code on disk so a second run of the same loops skips compilation.

    The folder is ``$JAXDIP_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxdip/xla`` (``~/.cache/jaxdip/xla``). JAX keys
    each entry by the computation, the jaxlib version and the XLA flags (so the host device count), so a stale
    entry is never used; it only saves time. ``--no-compile-cache`` turns it off for one run.
    """
    if not enabled:
        return
    folder = os.environ.get("JAXDIP_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "jaxdip", "xla")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        print(f"warning: compilation cache off: cannot create {folder}: {e.strerror or e}", file=sys.stderr)
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # a threshold would make the cache depend on load
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors: ``error: <flag>: <why>`` and exit 2, no usage block."""

    def error(self, message: str):
        message = " ".join(message.split())
        if m := re.match(r"argument ([^:]+): (.*)", message):
            message = f"{m.group(1).split('/')[0]}: {m.group(2)}"
        elif m := re.match(r"the following arguments are required: (.*)", message):
            message = f"{m.group(1)}: required"
        elif m := re.match(r"unrecognized arguments: (.*)", message):
            message = f"{m.group(1)}: unrecognized argument (see jaxdip {self.prog.split()[-1]} --help)"
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _parser():
    p = _Parser(prog="jaxdip", description=__doc__)
    sub = p.add_subparsers(dest="cmd", metavar="command", required=True, parser_class=_Parser)
    sub.add_parser("list", help="print the experiment ids, one a line")

    r = sub.add_parser("run", help="run one experiment")
    r.add_argument("id")
    r.add_argument("--config", help="TOML file overriding the defaults")
    r.add_argument("--seeds", type=int, help="number of Monte Carlo seeds")
    r.add_argument("--out", help="output folder (default results/<id>)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one config key")
    r.add_argument("--quick", action="store_true", help="reduced run: few seeds, short horizon")
    r.add_argument("--resume", action="store_true", help="continue an interrupted search from its checkpoint")
    r.add_argument("--force", action="store_true",
                   help="replace a jaxdip result folder of another experiment (a user's files are never replaced)")

    c = sub.add_parser("config", help="print an experiment's default config as TOML")
    c.add_argument("id")

    b = sub.add_parser("bench", help="closed-loop throughput against a plain NumPy loop")
    b.add_argument("--quick", action="store_true")
    b.add_argument("--out", default="bench.json")

    rp = sub.add_parser("reproduce", help="run every registered experiment and write one combined report")
    rp.add_argument("--quick", action="store_true")
    rp.add_argument("--out", default="results")
    rp.add_argument("--force", action="store_true", help="replace jaxdip result folders of other experiments")
    rp.add_argument("--jobs", type=int, default=None,
                    help="experiments run side by side in worker processes (default: one per CPU core, "
                         "at most 2; compilation is single-threaded, so a second job uses the idle core)")
    rp.add_argument("--only", default=None, metavar="ID,ID", help="run these experiments only (default: every "
                    "experiment but the fidelity readings' supporting runs, which `jaxdip list` marks)")
    for q in (r, rp):
        q.add_argument("--compile-effort", choices=("fast", "balanced", "full"), default=None,
                       help="how hard XLA optimises the compiled programs: fast compiles in about half the time "
                            "and runs slower, full is XLA's default (default: full; with --quick, the level "
                            "measured best for each experiment's quick run); results agree to the last bits")
    for q in (r, b, rp):
        q.add_argument("--no-compile-cache", action="store_true",
                       help="do not read or write the on-disk cache of compiled code (see JAXDIP_CACHE_DIR)")
    for q in (r, rp):
        d = q.add_argument_group("several processes (jax.distributed)")
        d.add_argument("--distributed", action="store_true",
                       help="run as one of several processes: Monte Carlo seeds are split over the devices of all "
                            "of them and only process 0 writes; the values below, else JAXDIP_COORDINATOR, "
                            "JAXDIP_NUM_PROCESSES, JAXDIP_PROCESS_ID, else the cluster's (SLURM, Open MPI)")
        d.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0's coordinator service")
        d.add_argument("--num-processes", metavar="N", help="number of processes")
        d.add_argument("--process-id", metavar="I", help="this process's index, 0 .. N-1")
    return p


def _distributed(args) -> int:
    """``--distributed``: join the other processes (before any JAX computation). 0, or the exit code."""
    from jaxdip import distributed

    given = [f for f, v in (("--coordinator", args.coordinator), ("--num-processes", args.num_processes),
                            ("--process-id", args.process_id)) if v is not None]
    if not args.distributed:
        return _error(f"{given[0]}: only with --distributed") if given else 0
    if args.cmd == "reproduce":
        if args.jobs is not None and args.jobs != 1:
            return _error("--jobs: --distributed runs the experiments one after another in this process; "
                          "leave --jobs out")
        args.jobs = 1
    try:
        pid, n = distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    except distributed.DistributedError as e:
        return _error(f"--distributed: {e}")
    if pid != 0:
        os.environ["JAXDIP_NO_PROGRESS"] = "1"  # one progress bar, process 0's
    return 0


def _error(msg: str) -> int:
    print(f"error: {' '.join(str(msg).split())}", file=sys.stderr)
    return 2


class _Signals:
    """SIGINT and SIGTERM stop a run: the first raises KeyboardInterrupt and is remembered, so a run whose
    library code swallowed it still refuses to write its folder (``run_experiment``'s ``stop_requested``)."""

    def __init__(self):
        self.hit = None
        self._old = {}

    def _handler(self, signum, frame):
        self.hit = signum
        raise KeyboardInterrupt

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, h in self._old.items():
            signal.signal(sig, h)
        return False

    def requested(self) -> bool:
        return self.hit is not None


def _flag_keys(args) -> dict:
    keys = {}
    if getattr(args, "seeds", None) is not None:
        keys["seeds"] = "--seeds"
    return keys


def _resolve(exp_id, args):
    from jaxdip import config as C
    from jaxdip.experiments import get

    exp = get(exp_id)
    cfg = C.load(exp.config_cls, path=args.config, quick=exp.quick if args.quick else None,
                 seeds=args.seeds, sets=args.set)
    return exp, cfg


def _interrupted(checkpoint: str | None, argv: list[str] | None) -> int:
    if checkpoint and os.path.exists(checkpoint):
        again = list(argv or sys.argv[1:])
        if "--resume" not in again:
            again.append("--resume")
        print(f"interrupted: progress kept in {checkpoint}; continue with: jaxdip {shlex.join(again)}",
              file=sys.stderr)
    else:
        print("interrupted: nothing was written", file=sys.stderr)
    return 130


def _out_of_memory(e: BaseException) -> bool:
    return isinstance(e, MemoryError) or "RESOURCE_EXHAUSTED" in str(e) or "Out of memory" in str(e)


def _riccati_keys(cfg) -> str:
    """The config keys that shape a Riccati design, to point the user at what to change."""
    names = [f.name for f in dataclasses.fields(cfg)] if dataclasses.is_dataclass(cfg) else []
    keys = [n for n in names if n in ("Q", "R", "Q_lqr", "R_lqr", "Qk", "Rk", "W", "V")
            or n.startswith(("Q_", "R_", "lqr_"))]
    return ", ".join(keys) if keys else "the weights"


def _effort(args, exp) -> str:
    """The compile effort of a run: the flag's, else the config file's (a run's own config.toml records it),
    else the experiment's quick-run level with --quick, else full."""
    from jaxdip.config import run_table

    if args.compile_effort:
        return args.compile_effort
    return run_table(getattr(args, "config", None)).get("compile_effort") or (
        exp.quick_effort if args.quick else "full")


def cmd_run(args, argv=None) -> int:
    from jaxdip.checkpoint import CheckpointError
    from jaxdip.config import ConfigError
    from jaxdip.control.riccati import RiccatiError
    from jaxdip.experiments import run_experiment
    from jaxdip.experiments.base import run_context
    from jaxdip.experiments.common import ResultError
    from jaxdip.outdir import OutputError

    flags = _flag_keys(args)
    try:
        exp, cfg = _resolve(args.id, args)
    except ConfigError as e:
        return _error(f"{flags.get(e.key, e.key)}: {e.why}")
    except KeyError as e:
        return _error(e.args[0])
    out = args.out or os.path.join("results", exp.id)
    ckpt = None
    with _Signals() as sig:
        try:
            level = _effort(args, exp)
            ckpt = run_context(exp, cfg, out, compile_effort=level).checkpoint_path
            metrics = run_experiment(exp, cfg, out, resume=args.resume, force=args.force,
                                     flag_keys=flags, stop_requested=sig.requested, compile_effort=level)
        except ConfigError as e:
            return _error(f"{e.key}: {e.why}")
        except OutputError as e:
            return _error(f"{e.key}: {e.why}")
        except CheckpointError as e:
            return _error(f"--resume: {e}")
        except ResultError as e:
            return _error(f"{e.key}: {e.why}")
        except RiccatiError as e:
            return _error(f"{_riccati_keys(cfg)}: {e}")
        except KeyboardInterrupt:
            return _interrupted(ckpt, argv)
        except Exception as e:
            if _out_of_memory(e):
                return _error("--seeds: the run ran out of memory; lower --seeds, shorten the run or save less")
            raise
    from jaxdip.distributed import is_main

    if is_main():
        print(f"{exp.id}: wrote {out} ({metrics['wall_s']:.1f} s)")
    return 0


def cmd_reproduce(args, argv=None) -> int:
    jobs = _jobs(args)
    # the workers start importing JAX while this process loads and checks the experiments' configurations
    pool = _Workers(jobs) if _reproduce_jobs(args) > 1 else None
    try:
        return _reproduce(args, jobs, pool)
    finally:
        if pool is not None:
            pool.close()


def _reproduce(args, jobs: int, pool) -> int:
    from jaxdip import config as C
    from jaxdip import distributed, outdir
    from jaxdip.config import ConfigError
    from jaxdip.control.riccati import RiccatiError
    from jaxdip.experiments import registry, run_experiment
    from jaxdip.outdir import OutputError

    reg = sorted(registry().items())
    if args.only is None:
        reg = [(i, e) for i, e in reg if e.reproduce]
    else:
        want = [w.strip() for w in args.only.split(",") if w.strip()]
        unknown = [w for w in want if w not in dict(reg)]
        if unknown or not want:
            return _error(f"--only: unknown experiment {', '.join(unknown) or '(none given)'}; "
                          f"choose from {', '.join(i for i, _ in reg)}")
        reg = [(i, e) for i, e in reg if i in want]
    if jobs < 1:
        return _error(f"--jobs: must be >= 1, got {jobs}")
    report_path = os.path.join(args.out, "REPORT.md")
    # every destination is checked before the first experiment compiles (with --distributed by process 0, the
    # only one that writes; the others follow its verdict)
    main = not args.distributed or distributed.is_main()
    refused = None
    try:
        cfgs = {exp_id: C.load(exp.config_cls, quick=exp.quick if args.quick else None) for exp_id, exp in reg}
        if main:
            if os.path.exists(args.out) and not os.path.isdir(args.out):
                raise OutputError("--out", f"{args.out} exists and is a file, not a folder")
            for exp_id, _ in reg:
                outdir.check_destination(os.path.join(args.out, exp_id), exp_id, force=args.force)
            outdir.check_file(report_path, lambda data: data.startswith(b"# jaxdip reproduction"))
    except ConfigError as e:
        return _error(f"{e.key}: {e.why}")
    except OutputError as e:
        refused = e
    if args.distributed and not distributed.agree(refused is None):
        refused = refused or OutputError("--out", f"process 0 cannot write {args.out} (see its error)")
    if refused is not None:
        return _error(f"{refused.key}: {refused.why}")

    t0 = time.perf_counter()
    rows, sections = [], []

    def collect(exp_id, exp):
        if not main:
            return
        out = os.path.join(args.out, exp_id)
        with open(os.path.join(out, "metrics.json")) as fh:
            m = json.load(fh)
        rows.append(f"| [{exp_id}]({exp_id}/report.md) | {exp.title} | {m['seeds']} | {m['wall_s']:.1f} |")
        with open(os.path.join(out, "report.md")) as fh:
            body = fh.read()
        sections.append(re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", rf"![\1]({exp_id}/\2)", body))

    if jobs > 1 and len(reg) > 1:
        with _Signals():
            code = _reproduce_parallel(args, reg, jobs, pool)
        if code:
            return code
        for exp_id, exp in reg:
            collect(exp_id, exp)
    else:
        with _Signals() as sig:
            try:
                for exp_id, exp in reg:
                    out = os.path.join(args.out, exp_id)
                    if main:
                        print(f"== {exp_id}", file=sys.stderr)
                    run_experiment(exp, cfgs[exp_id], out, force=args.force, stop_requested=sig.requested,
                                   compile_effort=_effort(args, exp))
                    collect(exp_id, exp)
            except (ConfigError, OutputError) as e:
                return _error(f"{e.key}: {e.why}")
            except RiccatiError as e:
                return _error(f"{exp_id}: {_riccati_keys(cfgs[exp_id])}: {e}")
            except KeyboardInterrupt:
                print(f"interrupted: the experiments finished before it are in {args.out}", file=sys.stderr)
                return 130
    wall = time.perf_counter() - t0
    if not main:
        return 0
    text = (
        f"# jaxdip reproduction{' (quick)' if args.quick else ''}\n\n"
        f"Total wall time {wall:.1f} s.\n\n| experiment | what | seeds | wall (s) |\n|---|---|---|---|\n"
        + "\n".join(rows) + "\n\n" + "\n\n---\n\n".join(sections)
    )
    try:  # again: the user had the whole reproduction to put a REPORT.md of their own there
        outdir.check_file(report_path, lambda data: data.startswith(b"# jaxdip reproduction"))
    except OutputError as e:
        return _error(f"{e.key}: {e.why} (the experiments' folders are written)")
    outdir.write_file_atomic(report_path, text)
    print(f"reproduce: wrote {report_path} ({wall:.1f} s)")
    return 0


def _reproduce_parallel(args, reg, jobs: int, pool: "_Workers | None" = None) -> int:
    """``_reproduce_parallel_in`` with its logs in a temporary folder, removed on every way out unless the error
    line names a log in it."""
    import shutil
    import tempfile

    logs, named = tempfile.mkdtemp(prefix="jaxdip-reproduce-"), []
    try:
        return _reproduce_parallel_in(args, reg, jobs, pool, logs, named)
    finally:
        if not named:
            shutil.rmtree(logs, ignore_errors=True)


def _reproduce_parallel_in(args, reg, jobs: int, pool: "_Workers | None", logs: str, named: list) -> int:
    """Run the experiments in ``jobs`` worker processes (``jaxdip.reproduce_worker``), longest first, each worker
    taking the next experiment when it finishes one: a worker starts JAX once and keeps its compiled programs in
    memory for the experiments after the first. Each experiment's output goes to a log, shown only when it
    fails. 0 or the exit code."""
    import queue

    order = sorted(reg, key=lambda r: -_QUICK_COST.get(r[0], 10.0)) if args.quick else list(reg)
    pending = [exp_id for exp_id, _ in order]
    failed: list = []
    n, done = len(order), 0
    pool = pool or _Workers(jobs)
    answers, workers = pool.answers, pool.workers[:n]
    for w in pool.workers[n:]:
        _close(w)

    def give(w):
        exp_id = pending.pop(0)
        argv = ["run", exp_id, "--out", os.path.join(args.out, exp_id)]
        argv += ["--quick"] * bool(args.quick) + ["--force"] * bool(args.force)
        argv += ["--no-compile-cache"] * bool(args.no_compile_cache)
        argv += ["--compile-effort", args.compile_effort] if args.compile_effort else []
        w["task"], w["t"] = exp_id, time.perf_counter()
        w["given"] = True
        try:
            w["proc"].stdin.write(json.dumps({"id": exp_id, "argv": argv, "log": _log(exp_id)}) + "\n")
            w["proc"].stdin.flush()
        except OSError:
            pass  # the worker has died: its reader reports the end, and the experiment counts as failed

    def _log(exp_id):
        return os.path.join(logs, f"{exp_id}.log")

    def tail(exp_id):
        try:
            with open(_log(exp_id)) as fh:
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
                print(f"== {exp_id} done ({time.perf_counter() - w['t']:.1f} s) [{done}/{n}]", file=sys.stderr)
            else:
                failed.append((exp_id, rc, tail(exp_id)))
            if pending and not failed and ans is not None:
                give(w)
            else:
                _close(w)
    except KeyboardInterrupt:
        for w in workers:
            if w["task"] is not None and w["proc"].poll() is None:
                w["proc"].send_signal(signal.SIGINT)  # once: the workers are in their own sessions
        pool.close()
        print(f"interrupted: the experiments finished before it are in {args.out}", file=sys.stderr)
        return 130
    pool.close()
    if failed:
        exp_id, code, line = failed[0]
        named.append(_log(exp_id))
        line = line[len("error: "):] if line.startswith("error: ") else line
        print(f"error: {exp_id}: {line} (log: {_log(exp_id)})", file=sys.stderr)
        return 130 if code == 130 else (code if code == 2 else 1)
    return 0


class _Workers:
    """``n`` started ``jaxdip.reproduce_worker`` processes (started early: each spends its first seconds importing
    JAX) and one queue of their answers, ``(worker, answer or None when the worker has ended)``."""

    def __init__(self, n: int):
        import queue
        import subprocess
        import threading

        self.answers: queue.Queue = queue.Queue()
        self.workers = []
        env = dict(os.environ, JAXDIP_NO_PROGRESS="1")
        for _ in range(n):
            proc = subprocess.Popen([sys.executable, "-m", "jaxdip.reproduce_worker"], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True,
                                    bufsize=1, start_new_session=True)
            w = {"proc": proc, "task": None, "t": 0.0, "given": False}
            threading.Thread(target=self._read, args=(w,), daemon=True).start()
            self.workers.append(w)

    def _read(self, w):
        for line in w["proc"].stdout:
            self.answers.put((w, json.loads(line)))
        self.answers.put((w, None))

    def close(self):
        for w in self.workers:
            _close(w)
            if not w["given"] and w["proc"].poll() is None:
                w["proc"].kill()  # never given an experiment (the run was refused): do not wait for its start-up
            w["proc"].wait()


def _close(w):
    """End of input: the worker exits once its current experiment is done."""
    if w["proc"].stdin and not w["proc"].stdin.closed:
        try:
            w["proc"].stdin.close()
        except OSError:
            pass


# cold --quick wall times (s) of each experiment in the parallel reproduce on a 2-core CPU, at the quick compile
# efforts (rwp-bias estimated at balanced from its run alone): the parallel reproduce starts the long ones first
_QUICK_COST = {"ifn-protection": 37, "eki-dip": 25, "tune": 18, "rwp-bias": 18, "dip-cpx-ldf": 15,
               "lorenz-mhe": 14, "dip-controllers": 13, "twip-dmso": 10, "eki-linear": 9, "eki-nonlinear": 7,
               "twip-extra-control": 6, "dip-lqr": 2}


def cmd_bench(args, argv=None) -> int:
    from jaxdip import outdir
    from jaxdip.bench import check_outputs, run_bench

    try:
        check_outputs(args.out)
    except outdir.OutputError as e:
        return _error(f"{e.key}: {e.why}")
    with _Signals():
        try:
            run_bench(quick=args.quick, out=args.out)
        except outdir.OutputError as e:
            return _error(f"{e.key}: {e.why}")
        except KeyboardInterrupt:
            return _interrupted(None, argv)
    return 0


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0)
    for flag in ("out", "config"):
        v = getattr(args, flag, None)
        if v is not None and not v.strip():
            return _error(f"--{flag}: empty path")
    if args.cmd in ("run", "reproduce", "bench"):
        _use_all_cores(_reproduce_jobs(args) if args.cmd == "reproduce" else 1)
        _compile_cache(not args.no_compile_cache)
    if args.cmd in ("run", "reproduce") and (code := _distributed(args)):
        return code
    if args.cmd == "list":
        from jaxdip.experiments import registry

        for exp_id, exp in sorted(registry().items()):
            # the readings' supporting runs are marked: a plain `reproduce` leaves them out
            print(exp_id if exp.reproduce else f"{exp_id}  (fidelity readings; reproduce --only {exp_id})")
        return 0
    if args.cmd == "config":
        from jaxdip import config as C
        from jaxdip.experiments import get

        try:
            exp = get(args.id)
        except KeyError as e:
            return _error(e.args[0])
        print(C.documented_toml(exp.config_cls(), f"{exp.id}: {exp.title}", exp.source), end="")
        return 0
    return {"run": cmd_run, "reproduce": cmd_reproduce, "bench": cmd_bench}[args.cmd](args, argv)


if __name__ == "__main__":
    sys.exit(main())
