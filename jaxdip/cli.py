"""Command line: ``jaxdip list | run <id> | config [<id>] | bench | reproduce`` (the parser: ``cli_args``)."""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import sys
import threading
import time

import numpy as np

from jaxdip import gc_policy, xla_flags
from jaxdip.cli_args import check_paths, parser, special_kind
from jaxdip.cli_errors import (Signals, component_refusal, emit, end_process, error, guarded, interrupt_seen, note,
                               numerical, remember_sigint, riccati_keys, run_refusal, warn)
from jaxdip.messages import listing, unknown
from jaxdip.reproduce_pool import run_argv, run_parallel


def _use_all_cores(processes: int = 1):
    """On CPU, expose one XLA host device per core so Monte Carlo batches shard over all of them; with
    ``processes`` processes computing side by side (the workers of a parallel ``reproduce``), each gets its share
    of the cores: sharding one worker's batches over cores the other workers keep busy only adds compilation
    (the partitioned programs) and synchronisation, cold ``reproduce --quick`` 92 s against 79 s on 2 cores.

    XLA reads the flag when the backend starts (first computation), so setting it here, before any array is
    made, is enough. A user's own XLA_FLAGS are left alone; worker processes inherit this one."""
    cores = os.cpu_count() or 1
    n = max(1, cores // max(1, processes))
    # set even when it is 1: the workers' own `run` would otherwise take every core
    if cores > 1 and os.environ.get("JAX_PLATFORMS", "cpu") == "cpu":
        xla_flags.append(xla_flags.pending({"xla_force_host_platform_device_count": n}))


def _jobs(args) -> int:
    """``reproduce --jobs`` (the parser checks 1 to ``reproduce_pool.MAX_JOBS``), or one per core, at most 2."""
    return args.jobs if args.jobs is not None else max(1, min(2, os.cpu_count() or 1))


def _reproduce_jobs(args) -> int:
    """How many worker processes a ``reproduce`` runs side by side (1: the experiments run in this process)."""
    several = args.only is None or len({w.strip() for w in args.only.split(",") if w.strip()}) > 1
    return _jobs(args) if several and not args.distributed else 1


def _compile_cache(enabled: bool) -> None:
    """XLA's compiled code kept on disk (``xla_flags.use_compile_cache``); a folder it cannot create: a warning."""
    if enabled and (why := xla_flags.use_compile_cache()):
        warn(why)


def _distributed(args) -> int:
    """``--distributed``: join the other processes (before any JAX computation, so before the experiments are
    imported). 0, or the exit code. A connection attempt that is interrupted or times out ends the process here:
    JAX's call cannot be cancelled, and would abort the process later with a C++ stack trace."""
    from jaxdip import distributed

    given = [f for f, v in (("--coordinator", args.coordinator), ("--num-processes", args.num_processes),
                            ("--process-id", args.process_id), ("--connect-timeout", args.connect_timeout))
             if v is not None]
    if not args.distributed:
        return error(given[0], "only with --distributed") if given else 0
    if getattr(args, "sweep", None):
        return error("--sweep", "not with --distributed: a sweep runs its points one after another in one process")
    if args.cmd == "reproduce":
        if args.jobs is not None and args.jobs != 1:
            return error("--jobs", "--distributed runs the experiments one after another in this process; "
                                   "leave --jobs out")
        args.jobs = 1
    timeout = args.connect_timeout or distributed.DEFAULT_TIMEOUT_S
    try:
        pid, _ = distributed.initialize(args.coordinator, args.num_processes, args.process_id, timeout_s=timeout,
                                        stop=interrupt_seen)
    except distributed.DistributedError as e:
        code = error("--distributed", str(e))
        if e.stuck:
            os._exit(code)
        return code
    except KeyboardInterrupt:
        note("interrupted: nothing was written")
        os._exit(130)
    if pid != 0:
        os.environ["JAXDIP_NO_PROGRESS"] = "1"  # one progress bar, process 0's
    return 0


def _flag_keys(args) -> dict:
    keys = {}
    if getattr(args, "seeds", None) is not None:
        keys["seeds"] = "--seeds"
    return keys


def _resolve(exp_id, args):
    from jaxdip import config as C
    from jaxdip.runner import get

    exp = get(exp_id)
    cfg = C.load(exp.config_cls, path=args.config, quick=exp.quick if args.quick else None,
                 seeds=args.seeds, sets=args.set)
    return exp, cfg


def _unknown(exp_id: str, e: KeyError) -> int:
    """``jaxdip.runner.get``'s refusal, ``<id>: unknown experiment (...)``, with the id as the line's key."""
    message = str(e.args[0])
    return error(exp_id, message[len(exp_id) + 2:] if message.startswith(f"{exp_id}: ") else message)


def _interrupted(checkpoint: str | None, argv: list[str] | None) -> int:
    if checkpoint and os.path.exists(checkpoint):
        again = list(argv or sys.argv[1:])
        if "--resume" not in again:
            again.append("--resume")
        note(f"interrupted: progress kept in {checkpoint}; continue with: jaxdip {shlex.join(again)}")
    else:
        note("interrupted: nothing was written")
    return 130


def _set_effort(args) -> int:
    """Make the run's compile effort the process's, before JAX starts (``jaxdip.xla_flags``): ``--compile-effort``,
    else the config file's ``[jaxdip]`` table (a run's own config.toml records it), else balanced with --quick
    (cold and cached, the cheapest single level for the quick runs; docs/performance.md) and full without. A
    level ``XLA_FLAGS`` already sets (the user's, a ``reproduce``'s parent's) stays; one asked for must agree.
    0, or the exit code."""
    from jaxdip.config import ConfigError, run_table

    try:
        asked = args.compile_effort or run_table(getattr(args, "config", None)).get("compile_effort")
    except ConfigError:
        asked = None  # the run reports the config's error, after the checks that come before it
    xla_flags.set_effort(asked or ("balanced" if args.quick else "full"))
    try:
        level = xla_flags.effort()
    except ValueError as e:
        return error("XLA_FLAGS", str(e))
    if asked and level != asked:
        return error("--compile-effort" if args.compile_effort else "--config",
                     f"compile effort {asked!r} asked, but XLA_FLAGS already sets {level!r} for this process")
    return 0


def cmd_run(args, argv=None) -> int:
    from jaxdip.config import ConfigError
    from jaxdip.runner import run_experiment
    from jaxdip.runner.experiment import run_context

    flags = _flag_keys(args)
    try:
        exp, cfg = _resolve(args.id, args)
    except ConfigError as e:
        return error(e.key, e.why)
    except KeyError as e:
        return _unknown(args.id, e)
    out = args.out or os.path.join("results", exp.id)
    if args.per_seed:
        from jaxdip import dataset

        if not exp.per_seed:
            return error("--per-seed", f"{exp.id} keeps no per-seed data (docs/data.md)")
        try:
            dataset.require()
        except dataset.MissingExtra as e:
            return error("--per-seed", str(e))
    if args.sweep:
        from jaxdip.cli_sweep import cmd_sweep

        return cmd_sweep(args, exp, shlex.join(["jaxdip", *(sys.argv[1:] if argv is None else argv)]))
    ckpt = None
    with Signals() as sig:
        try:
            level = xla_flags.effort()
            ckpt = run_context(exp, cfg, out, compile_effort=level).checkpoint_path
            metrics = run_experiment(exp, cfg, out, resume=args.resume, force=args.force,
                                     flag_keys=flags, stop_requested=sig.requested, compile_effort=level,
                                     quick=args.quick, per_seed=args.per_seed,
                                     command=shlex.join(["jaxdip", *(sys.argv[1:] if argv is None else argv)]))
        except KeyboardInterrupt:
            return _interrupted(ckpt, argv)
        except Exception as e:
            if (code := run_refusal(e, cfg, exp.id)) is None:
                raise
            return code
    from jaxdip.distributed import is_main

    if is_main():
        emit(f"{exp.id}: wrote {out} ({metrics['wall_s']:.1f} s)")
    return 0


def cmd_reproduce(args, argv=None) -> int:
    """Every experiment (or ``--only``'s), then one combined REPORT.md. Every argument, config and destination
    is checked before the first experiment starts, and before any worker process does."""
    from jaxdip import config as C
    from jaxdip import distributed, outdir
    from jaxdip.config import ConfigError
    from jaxdip.control.riccati import RiccatiError
    from jaxdip.engine.checks import ArgumentError
    from jaxdip.search.failures import SearchStopped
    from jaxdip.runner import registry, run_experiment
    from jaxdip.outdir import OutputError

    jobs = _reproduce_jobs(args)
    reg = sorted(registry().items())
    if args.only is None:
        reg = [(i, e) for i, e in reg if e.reproduce]
    else:
        want = [w.strip() for w in args.only.split(",") if w.strip()]
        ids = [i for i, _ in reg]
        if not want:
            return error("--only", f"no experiment given{listing(ids)}")
        if missing := [w for w in want if w not in ids]:
            return error("--only", unknown("experiment", missing, ids))
        reg = [(i, e) for i, e in reg if i in want]
    report_path = os.path.join(args.out, "REPORT.md")
    # every destination is checked before anything compiles (--distributed: by process 0, whose verdict all follow)
    main = not args.distributed or distributed.is_main()
    refused = None
    try:
        cfgs = {exp_id: C.load(exp.config_cls, quick=exp.quick if args.quick else None) for exp_id, exp in reg}
        if main:
            if os.path.exists(args.out) and not os.path.isdir(args.out):
                raise OutputError("--out", f"{args.out} exists and is a file, not a folder")
            for exp_id, _ in reg:
                outdir.check_destination(os.path.join(args.out, exp_id), exp_id, force=args.force)
            if kind := special_kind(report_path):  # never opened: reading a FIFO would block
                raise OutputError("--out", f"{report_path} is {kind}, not a report jaxdip wrote")
            outdir.check_file(report_path, lambda data: data.startswith(b"# jaxdip reproduction"))
    except ConfigError as e:
        return error(e.key, e.why)
    except OutputError as e:
        refused = e
    if args.distributed and not distributed.agree(refused is None):
        refused = refused or OutputError("--out", f"process 0 cannot write {args.out} (see its error)")
    if refused is not None:
        return error(refused.key, refused.why)
    kept = set()
    if args.resume:
        from jaxdip.runner.experiment import is_complete

        kept = {exp_id for exp_id, exp in reg
                if is_complete(exp, cfgs[exp_id], os.path.join(args.out, exp_id), xla_flags.effort())}
        for exp_id, _ in reg:
            if exp_id in kept:
                print(f"== {exp_id}: complete, kept", file=sys.stderr)

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

    todo = [(exp_id, exp) for exp_id, exp in reg if exp_id not in kept]
    stopped = (f"interrupted: the experiments finished before it are in {args.out}; "
               f"add --resume to the same command to continue")
    if jobs > 1 and len(todo) > 1:
        with Signals():
            code = run_parallel(args, todo, jobs, stopped)
        if code:
            return code
    else:
        with Signals() as sig:
            try:
                for exp_id, exp in todo:
                    out = os.path.join(args.out, exp_id)
                    if main:
                        print(f"== {exp_id}", file=sys.stderr)
                    run_experiment(exp, cfgs[exp_id], out, force=args.force, stop_requested=sig.requested,
                                   compile_effort=xla_flags.effort(), quick=args.quick,
                                   command=shlex.join(["jaxdip", *run_argv(args, exp_id)]))
            except (ConfigError, OutputError) as e:
                return error(e.key, e.why)
            except RiccatiError as e:
                return error(exp_id, f"{riccati_keys(cfgs[exp_id])}: {e}")
            except SearchStopped as e:
                return error(exp_id, e.why)
            except ArgumentError as e:
                return component_refusal(cfgs[exp_id], e, exp_id, f"{exp_id}: ")
            except (np.linalg.LinAlgError, ArithmeticError, ValueError) as e:
                return numerical(cfgs[exp_id], e, f"{exp_id}: ")
            except KeyboardInterrupt:
                note(stopped)
                return 130
    wall = time.perf_counter() - t0
    if not main:
        return 0
    for exp_id, exp in reg:  # in the registry's order, the kept ones with the rest
        collect(exp_id, exp)
    text = (
        f"# jaxdip reproduction{' (quick)' if args.quick else ''}\n\n"
        f"Total wall time {wall:.1f} s"
        + (f" ({len(kept)} of {len(reg)} experiments kept from an earlier run)" if kept else "")
        + ".\n\n| experiment | what | seeds | wall (s) |\n|---|---|---|---|\n"
        + "\n".join(rows) + "\n\n" + "\n\n---\n\n".join(sections)
    )
    try:  # again: the user had the whole reproduction to put a REPORT.md of their own there
        outdir.check_file(report_path, lambda data: data.startswith(b"# jaxdip reproduction"))
    except OutputError as e:
        return error(e.key, f"{e.why} (the experiments' folders are written)")
    outdir.write_file_atomic(report_path, text)
    emit(f"reproduce: wrote {report_path} ({wall:.1f} s)")
    return 0


def cmd_bench(args, argv=None) -> int:
    from jaxdip import outdir
    from jaxdip.bench.scoreboard import check_outputs, run_bench

    try:
        check_outputs(args.out)
    except outdir.OutputError as e:
        return error(e.key, e.why)
    with Signals():
        try:
            run_bench(quick=args.quick, out=args.out)
        except outdir.OutputError as e:
            return error(e.key, e.why)
        except KeyboardInterrupt:
            return _interrupted(None, argv)
    return 0


def _command(args, argv) -> int:
    if code := check_paths(args):
        return code
    if args.cmd in ("run", "reproduce", "bench"):
        _use_all_cores(_reproduce_jobs(args) if args.cmd == "reproduce" else 1)
        if args.cmd != "bench" and (code := _set_effort(args)):
            return code
        _compile_cache(not args.no_compile_cache)
        if args.cmd == "bench":
            # the bench times the loops as a library user calls them: no program-cache lookup inside its timings
            from jaxdip import program_cache

            program_cache.enable(None)
    if args.cmd == "reproduce" and args.resume and args.distributed:
        # each process would judge the folders on its own disk, and they must agree on the experiments that run
        return error("--resume", "not with --distributed: resume a single-process reproduction")
    if args.cmd in ("run", "reproduce") and (code := _distributed(args)):
        return code
    if args.cmd == "list":
        from jaxdip.runner import registry

        for exp_id, exp in sorted(registry().items()):
            # the readings' supporting runs are marked: a plain `reproduce` leaves them out
            emit(exp_id if exp.reproduce else f"{exp_id}  (fidelity readings; reproduce --only {exp_id})")
        return 0
    if args.cmd == "config":
        from jaxdip.cli_config import cmd_config

        return cmd_config(args, _unknown)
    if args.cmd == "compare":
        from jaxdip.cli_compare import cmd_compare

        return cmd_compare(args)
    return {"run": cmd_run, "reproduce": cmd_reproduce, "bench": cmd_bench}[args.cmd](args, argv)


def main(argv=None) -> int:
    """``jaxdip``'s entry point: the exit status (0, 2 for a refusal, 130 for an interrupt)."""

    def command() -> int:
        try:
            args = parser().parse_args(argv)
        except SystemExit as e:
            return int(e.code or 0)
        return _command(args, argv)

    if threading.current_thread() is not threading.main_thread():  # signal handlers are the main thread's to set
        return guarded(command)
    old = remember_sigint()
    try:
        return guarded(command)
    finally:
        if old is not None:  # None: a handler set outside Python, which cannot be put back from here
            signal.signal(signal.SIGINT, old)


def entry() -> None:
    """The ``jaxdip`` command: ``main`` with its status as the exit code."""
    gc_policy.for_a_command()
    end_process(main())


if __name__ == "__main__":
    entry()
