"""The command line's arguments: the parser, and the checks on them that need no experiment loaded.

argparse's usage block is replaced by the one-line error format (``Parser.error``), and every flag with a
range (``--jobs``, ``--connect-timeout``) is checked by its type, so a bad value stops the command before it
starts anything.
"""

from __future__ import annotations

import argparse
import math
import os
import re

from jaxdip.cli_errors import error
from jaxdip.distributed import DEFAULT_TIMEOUT_S, MAX_TIMEOUT_S
from jaxdip.messages import shown, suggestion
from jaxdip.reproduce_pool import MAX_JOBS


PATH_MAX, NAME_MAX = 4096, 255  # Linux's limits, the strictest of the common systems


class Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors: ``error: <flag>: <why>`` and exit 2, no usage block; a
    misspelt command, choice or flag gets the closest one suggested (``messages.suggestion``)."""

    commands: dict[str, argparse.ArgumentParser] | None = None  # the top-level parser's subcommands

    def _check_value(self, action, value):
        # argparse's own wording ("invalid choice: 'x' (choose from ...)") differs between Python versions and
        # suggests nothing before 3.14; this is the one place it checks a value against a choice list
        if action.choices is not None and value not in action.choices:
            raise argparse.ArgumentError(action, f"invalid choice {shown(value)}{suggestion(value, action.choices)}")

    def parse_args(self, args=None, namespace=None):
        # a subcommand's parser hands the arguments it does not know up to this one: it is the subcommand's
        # flags that a misspelt one is closest to
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(ns, "cmd", None)
            sub = (self.commands or {}).get(command, self)
            flags = [f for f in sub._option_string_actions if f.startswith("--")]  # argparse has no public list
            first = next((e for e in extras if e.startswith("-")), None)
            hint = suggestion(first.split("=", 1)[0], flags, known=None) if first else ""
            see = f"jaxdip {command} --help" if sub is not self else "jaxdip --help"
            raise SystemExit(error(" ".join(extras), f"unrecognized argument{hint or f' (see {see})'}"))
        return ns

    def error(self, message: str):
        message = " ".join(message.split())
        key, why = "jaxdip", message
        if m := re.match(r"argument ([^:]+): (.*)", message):
            key, why = m.group(1).split("/")[0], m.group(2)
        elif m := re.match(r"the following arguments are required: (.*)", message):
            key, why = m.group(1), "required"
        elif m := re.match(r"unrecognized arguments: (.*)", message):  # parse_args reports them first
            key, why = m.group(1), "unrecognized argument (see jaxdip --help)"
        raise SystemExit(error(key, why))


def _whole(text: str) -> int:
    """An integer in ASCII digits only: ``int`` also takes "1_000" and other scripts' digits ("٢", "２")."""
    if not re.fullmatch(r"[+-]?[0-9]+", text.strip()):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {shown(text)}")
    return int(text)


def _jobs(text: str) -> int:
    n = _whole(text)
    if not 1 <= n <= MAX_JOBS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_JOBS}, got {shown(text, 24)}")
    return n


def _seconds(text: str) -> float:
    try:
        s = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {shown(text)}") from None
    if not (math.isfinite(s) and 0 < s <= MAX_TIMEOUT_S):
        raise argparse.ArgumentTypeError(f"must be above 0 and at most {MAX_TIMEOUT_S:g} s, got {shown(text, 24)}")
    return s


def _tolerance(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {shown(text)}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be finite and >= 0, got {shown(text, 24)}")
    return v


def _level(text: str) -> float:
    v = _tolerance(text)
    if not 0 < v < 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {shown(text, 24)}")
    return v


DESCRIPTION = ("Run the experiments of jaxdip (differentiable estimation and control of pendulums in JAX): list "
               "them, run one or sweep its config, print their configs, compare two result folders, time the closed loop, "
               "or reproduce them all into one report. "
               "'jaxdip COMMAND --help' describes a command.")


def _command(sub, name: str, what: str) -> Parser:
    """A subcommand whose one-line summary is also its own --help's description."""
    return sub.add_parser(name, help=what, description=what[0].upper() + what[1:] + ".")


def parser(description: str = DESCRIPTION) -> Parser:
    """The command line's parser. Every help text is plain text (no markup: a terminal shows it as written) and
    the usage line names every command."""
    p = Parser(prog="jaxdip", description=description)
    sub = p.add_subparsers(dest="cmd", metavar="command", required=True, parser_class=Parser)
    _command(sub, "list", "print the experiment ids, one a line")

    r = _command(sub, "run", "run one experiment")
    r.add_argument("id", help="the experiment (jaxdip list prints the ids)")
    r.add_argument("--config", help="TOML file overriding the defaults")
    r.add_argument("--seeds", type=_whole, help="number of Monte Carlo seeds")
    r.add_argument("--out", help="output folder (default results/<id>)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one config key")
    r.add_argument("--sweep", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="run every value (repeat for a grid: the product) into <out>/points/<key=value,...>/ and "
                        "write <out>/sweep.md, sweep.json and a figure per headline result; points already "
                        "complete are kept, so an interrupted sweep continues (default out results/<id>-sweep)")
    r.add_argument("--quick", action="store_true", help="reduced run: few seeds, short horizon")
    r.add_argument("--resume", action="store_true", help="continue an interrupted search from its checkpoint")
    r.add_argument("--force", action="store_true",
                   help="replace a jaxdip result folder of another experiment (a user's files are never replaced)")
    r.add_argument("--per-seed", nargs="?", const="final", choices=("final", "trajectories"), default=None,
                   help="also write per_seed.nc, every seed's final values, metrics and failures as a labelled "
                        "netCDF dataset (trajectories: with the saved trajectories); needs pip install -e '.[data]'")

    c = _command(sub, "config", "print an experiment's default config as TOML, or write every one's")
    c.add_argument("id", nargs="?", help="the experiment (jaxdip list prints the ids)")
    c.add_argument("--write", metavar="DIR",
                   help="write DIR/<id>.toml for every experiment (the repository's configs/), replacing only files "
                        "this command wrote")

    cmp = _command(sub, "compare", "compare two result folders statistic by statistic (exit 0: no significant "
                                   "difference, 1: differences, 2: not comparable)")
    cmp.add_argument("a", metavar="A", help="a result folder (jaxdip run --out)")
    cmp.add_argument("b", metavar="B", help="the result folder to compare it with")
    cmp.add_argument("--rtol", type=_tolerance, default=1e-9, help="relative tolerance of 'equal' (default 1e-9)")
    cmp.add_argument("--atol", type=_tolerance, default=0.0, help="absolute tolerance of 'equal' (default 0)")
    cmp.add_argument("--alpha", type=_level, default=0.05,
                     help="family-wise significance level of the two-sample tests, Holm-corrected over the "
                          "statistics (default 0.05)")

    b = _command(sub, "bench", "closed-loop throughput against a plain NumPy loop")
    b.add_argument("--quick", action="store_true", help="fewer seeds and steps")
    b.add_argument("--out", default="bench.json", help="the JSON file written (default bench.json)")

    rp = _command(sub, "reproduce", "run every registered experiment and write one combined report")
    rp.add_argument("--quick", action="store_true",
                    help="every experiment's reduced run: few seeds, short horizon (each report says what changed)")
    rp.add_argument("--out", default="results", help="output folder: <out>/<id>/ and <out>/REPORT.md "
                                                      "(default results)")
    rp.add_argument("--force", action="store_true", help="replace jaxdip result folders of other experiments")
    rp.add_argument("--resume", action="store_true",
                    help="keep every experiment whose folder under --out is a complete, unchanged jaxdip result of "
                         "the same config and run settings, run the rest, and write REPORT.md from all of them")
    rp.add_argument("--jobs", type=_jobs, default=None,
                    help="experiments run side by side in worker processes (default: one per CPU core, "
                         f"at most 2; at most {MAX_JOBS}; compilation is single-threaded, so a second job uses the "
                         "idle core)")
    rp.add_argument("--only", default=None, metavar="ID,ID", help="run these experiments only (default: every "
                    "experiment but the fidelity readings' supporting runs, which jaxdip list marks)")
    for q in (r, rp):
        q.add_argument("--compile-effort", choices=("fast", "balanced", "full"), default=None,
                       help="how hard XLA optimises every program the process compiles: fast compiles in about "
                            "half the time and runs slower, full is XLA's default (default: full; with --quick, "
                            "balanced); results agree to the last bits")
    for q in (r, b, rp):
        q.add_argument("--no-compile-cache", action="store_true",
                       help="do not read or write the on-disk caches of compiled code and traced programs (see "
                            "JAXDIP_CACHE_DIR)")
    for q in (r, rp):
        d = q.add_argument_group("several processes (jax.distributed)")
        d.add_argument("--distributed", action="store_true",
                       help="run as one of several processes: Monte Carlo seeds are split over the devices of all "
                            "of them and only process 0 writes; the values below, else JAXDIP_COORDINATOR, "
                            "JAXDIP_NUM_PROCESSES, JAXDIP_PROCESS_ID, else the cluster's (SLURM, Open MPI)")
        d.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0's coordinator service")
        d.add_argument("--num-processes", metavar="N", help="number of processes")
        d.add_argument("--process-id", metavar="I", help="this process's index, 0 .. N-1")
        d.add_argument("--connect-timeout", metavar="SECONDS", type=_seconds, default=None,
                       help=f"how long to wait for the coordinator and the other processes (default "
                            f"{DEFAULT_TIMEOUT_S:g}); Ctrl-C stops the wait")
    # argparse's usage shows the metavar "command"; the names themselves say what there is to run
    p.usage = "%(prog)s [-h] {" + ",".join(sub.choices) + "} ..."
    p.commands = dict(sub.choices)
    return p


def special_kind(path: str) -> str | None:
    """"a FIFO", "a socket" or "a device" when ``path`` (followed through links) is one, else None."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"),
                       (stat.S_ISBLK, "a device")):
        if test(mode):
            return name
    return None


def check_paths(args) -> int:
    """0, or the error status for a path argument that cannot name anything: empty, or relative to a working
    folder that no longer exists (``os.getcwd`` fails once it has been deleted)."""
    paths = {flag: getattr(args, flag, None) for flag in ("out", "config", "write")}
    for flag, v in paths.items():
        if v is None:
            continue
        if not v.strip():
            return error(f"--{flag}", "empty path")
        # the system refuses these anyway, some of its calls only after deep recursion (os.makedirs)
        raw = os.fsencode(v)
        if len(raw) >= PATH_MAX:
            return error(f"--{flag}", f"{shown(v)} is {len(raw)} bytes long; paths stop at {PATH_MAX - 1}")
        if any(len(part) > NAME_MAX for part in raw.split(b"/")):
            return error(f"--{flag}", f"{shown(v)} has a name longer than {NAME_MAX} bytes")
        if flag == "out" and (kind := special_kind(v)):
            # a FIFO would block the first read of it (the check that a file there is jaxdip's own)
            return error("--out", f"{shown(v)} is {kind}; give a folder or a file name")
    try:
        os.getcwd()
    except OSError as e:
        relative = [f for f, v in paths.items() if v is not None and not os.path.isabs(v)]
        if args.cmd == "run" and paths["out"] is None:
            relative.append("out")  # the default, results/<id>
        if relative:
            return error(f"--{relative[0]}", f"a relative path, and the working folder is gone ({e.strerror}); "
                                             "give an absolute path or change to an existing folder")
    return 0
