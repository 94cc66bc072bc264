"""Command line: ``jaxdip list | run <id> | bench | reproduce``."""

from __future__ import annotations

import argparse
import os
import re
import sys
import time


def _use_all_cores():
    """On CPU, expose one XLA host device per core so Monte Carlo batches shard over all of them.

    XLA reads the flag when the backend starts (first computation), so setting it here, before any array is
    made, is enough. A user's own XLA_FLAGS are left alone.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags and os.environ.get("JAX_PLATFORMS", "cpu") == "cpu":
        n = os.cpu_count() or 1
        if n > 1:
            os.environ["XLA_FLAGS"] = (flags + f" --xla_force_host_platform_device_count={n}").strip()


def _parser():
    p = argparse.ArgumentParser(prog="jaxdip", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="print the experiment ids, one a line")

    r = sub.add_parser("run", help="run one experiment")
    r.add_argument("id")
    r.add_argument("--config", help="TOML file overriding the defaults")
    r.add_argument("--seeds", type=int, help="number of Monte Carlo seeds")
    r.add_argument("--out", help="output folder (default results/<id>)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one config key")
    r.add_argument("--quick", action="store_true", help="reduced run: few seeds, short horizon")
    r.add_argument("--resume", action="store_true", help="continue an interrupted search from its checkpoint")

    c = sub.add_parser("config", help="print an experiment's default config as TOML")
    c.add_argument("id")

    b = sub.add_parser("bench", help="closed-loop throughput against a plain NumPy loop")
    b.add_argument("--quick", action="store_true")
    b.add_argument("--out", default="bench.json")

    rp = sub.add_parser("reproduce", help="run every registered experiment and write one combined report")
    rp.add_argument("--quick", action="store_true")
    rp.add_argument("--out", default="results")
    return p


def _error(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def _resolve(exp_id, args):
    from jaxdip import config as C
    from jaxdip.experiments import get

    exp = get(exp_id)
    if args.seeds is not None and args.seeds < 1:
        raise C.ConfigError("seeds", "must be positive")
    cfg = C.load(exp.config_cls, path=args.config, quick=exp.quick if args.quick else None,
                 seeds=args.seeds, sets=args.set)
    return exp, cfg


def cmd_run(args) -> int:
    from jaxdip.config import ConfigError
    from jaxdip.experiments import run_experiment

    try:
        exp, cfg = _resolve(args.id, args)
    except ConfigError as e:
        return _error(f"{e.key}: {e.why}")
    except KeyError as e:
        return _error(e.args[0])
    out = args.out or os.path.join("results", exp.id)
    from jaxdip.checkpoint import CheckpointMismatch

    try:
        metrics = run_experiment(exp, cfg, out, resume=args.resume)
    except CheckpointMismatch as e:
        return _error(f"--resume: {e}")
    print(f"{exp.id}: wrote {out} ({metrics['wall_s']:.1f} s)")
    return 0


def cmd_reproduce(args) -> int:
    from jaxdip import config as C
    from jaxdip.experiments import registry, run_experiment

    t0 = time.perf_counter()
    rows, sections = [], []
    for exp_id, exp in sorted(registry().items()):
        cfg = C.load(exp.config_cls, quick=exp.quick if args.quick else None)
        out = os.path.join(args.out, exp_id)
        print(f"== {exp_id}", file=sys.stderr)
        m = run_experiment(exp, cfg, out)
        rows.append(f"| [{exp_id}]({exp_id}/report.md) | {exp.title} | {m['seeds']} | {m['wall_s']:.1f} |")
        with open(os.path.join(out, "report.md")) as fh:
            body = fh.read()
        sections.append(re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", rf"![\1]({exp_id}/\2)", body))
    wall = time.perf_counter() - t0
    text = (
        f"# jaxdip reproduction{' (quick)' if args.quick else ''}\n\n"
        f"Total wall time {wall:.1f} s.\n\n| experiment | what | seeds | wall (s) |\n|---|---|---|---|\n"
        + "\n".join(rows) + "\n\n" + "\n\n---\n\n".join(sections)
    )
    path = os.path.join(args.out, "REPORT.md")
    tmp = path + ".tmp"
    os.makedirs(args.out, exist_ok=True)
    with open(tmp, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)
    print(f"reproduce: wrote {path} ({wall:.1f} s)")
    return 0


def cmd_bench(args) -> int:
    from jaxdip.bench import run_bench

    run_bench(quick=args.quick, out=args.out)
    return 0


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.cmd in ("run", "reproduce", "bench"):
        _use_all_cores()
    if args.cmd == "list":
        from jaxdip.experiments import registry

        for exp_id in sorted(registry()):
            print(exp_id)
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
    return {"run": cmd_run, "reproduce": cmd_reproduce, "bench": cmd_bench}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
