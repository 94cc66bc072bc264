"""Sweeps: one experiment run over the product of config values, point by point, in one process.

``jaxdip run <id> --sweep key=v1,v2 [--sweep key2=...]`` runs every point of the grid as an ordinary run into
``<out>/points/<key=value,...>/`` (a complete result folder each, written atomically by ``run_experiment``), then
writes the table and figures of ``jaxdip.runner.sweep_table``. A point whose folder is already complete (a
jaxdip folder of the experiment, unchanged, whose config.toml is the one this point would write) is not run
again, so a sweep that was interrupted continues point by point when the same command is given again.

All points run in one process: the engine's compiled programs are cached by structure, so a point whose config
changes only array values (CPX's gamma, a gain, a noise level) reuses the programs the first point compiled.
``CompileCounter`` counts the programs built per point (``jax.monitoring``'s backend-compile event, which fires
for every program the process builds, whether XLA compiles it or it is read from the on-disk cache); a config
key that changes a program's structure (a horizon, a number of seeds, a variant) recompiles at every point.

The sweep's own folder holds a marker (``.jaxdip-sweep.json``) naming the experiment and the summary files with
their SHA-256, so a later sweep replaces only what a sweep wrote and a user's files are never touched.
"""

from __future__ import annotations

import collections
import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass, field
from typing import Any, Callable

from jaxdip import config as cfgmod
from jaxdip import outdir
from jaxdip.config import ConfigError
from jaxdip.messages import shown
from jaxdip.runner.experiment import Experiment, is_complete, run_experiment

SWEEP_MARKER = ".jaxdip-sweep.json"
POINTS = "points"
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
NAME_MAX = 255
_UNSAFE = re.compile(r"[^A-Za-z0-9._+\-=,\[\]]")
# write_file_atomic's temporary names for the sweep's own files
_LEFT_OVER = re.compile(r"^\.(\.jaxdip-sweep\.json|sweep\.md|sweep\.json|sweep-[^/]*\.png)\.tmp-[A-Za-z0-9_]+$")


def split_values(text: str) -> list[str]:
    """``v1,v2,...`` split at the commas outside brackets and quotes (``[1,2],[3,4]`` is two list values)."""
    parts, depth, quote, cur = [], 0, None, ""
    for c in text:
        if quote:
            quote = None if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c == "[":
            depth += 1
        elif c == "]":
            depth -= 1
        elif c == "," and depth == 0:
            parts.append(cur.strip())
            cur = ""
            continue
        cur += c
    parts.append(cur.strip())
    return parts


def parse_sweeps(items: list[str], sets: list[str] = ()) -> list[tuple[str, list[str]]]:
    """The swept keys with their values' texts, in the order given; a ``ConfigError`` keyed ``--sweep`` for an
    item that is not ``key=v1,v2,...``, a key swept twice or also given by ``--set``, or a repeated value."""
    axes: list[tuple[str, list[str]]] = []
    set_keys = {item.split("=", 1)[0].strip() for item in sets if "=" in item}
    for item in items:
        if "=" not in item or not item.split("=", 1)[0].strip():
            raise ConfigError("--sweep", f"expects key=v1,v2,..., got {shown(item)}")
        key, raw = (s.strip() for s in item.split("=", 1))
        values = split_values(raw)
        if any(not v for v in values):
            raise ConfigError("--sweep", f"{key}: empty value in {shown(raw)}")
        if key in (k for k, _ in axes):
            raise ConfigError("--sweep", f"{key} is swept twice; give all its values in one --sweep")
        if key in set_keys:
            raise ConfigError("--sweep", f"{key} is also given by --set; sweep it or set it")
        if len(set(values)) != len(values):
            raise ConfigError("--sweep", f"{key}: a value is repeated in {shown(raw)}")
        axes.append((key, values))
    return axes


def point_name(point: list[tuple[str, str]]) -> str:
    """The point's folder name, ``key=value,key2=value2``, with characters a path should not hold as ``_``."""
    return _UNSAFE.sub("_", ",".join(f"{k}={v}" for k, v in point))


@dataclass
class Point:
    name: str
    texts: dict[str, str]  # key -> the value as given on the command line
    values: dict[str, Any]  # key -> the value as the config reads it
    cfg: Any


def plan(axes: list[tuple[str, list[str]]], load: Callable[[list[str]], Any]) -> list[Point]:
    """Every point of the grid with its validated config: ``load(sets)`` is the config of a run given the extra
    ``--set`` items ``sets`` (the same checks and one-line errors as ``--set``), called for every point before
    anything runs."""
    points, names = [], {}
    for combo in itertools.product(*[[(k, v) for v in vs] for k, vs in axes]):
        name = point_name(list(combo))
        if name in names:
            raise ConfigError("--sweep", f"points {shown(names[name])} and {shown(','.join(f'{k}={v}' for k, v in combo))} "
                                         "would share one folder name; write the values differently")
        if len(name.encode()) > NAME_MAX:
            raise ConfigError("--sweep", f"the point {shown(name)} makes a folder name over {NAME_MAX} bytes")
        names[name] = ",".join(f"{k}={v}" for k, v in combo)
        cfg = load([f"{k}={v}" for k, v in combo])
        values = {k: cfgmod.parse_set(f"{k}={v}")[1] for k, v in combo}
        points.append(Point(name, dict(combo), values, cfg))
    return points


class CompileCounter:
    """Counts the programs the process builds while it is entered (``count``, and ``names`` by function)."""

    def __init__(self):
        self.names: collections.Counter = collections.Counter()

    def _listen(self, event: str, duration: float, **kwargs) -> None:
        if event == COMPILE_EVENT:
            self.names[kwargs.get("fun_name", "?")] += 1

    def __enter__(self) -> "CompileCounter":
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(self._listen)
        return self

    def __exit__(self, *exc) -> bool:
        import jax.monitoring

        jax.monitoring.unregister_event_duration_listener(self._listen)
        return False

    @property
    def count(self) -> int:
        return sum(self.names.values())


def _digest(path: str) -> str | None:
    try:
        with open(path, "rb") as fh:
            return hashlib.sha256(fh.read()).hexdigest()
    except OSError:
        return None


class SweepFolder:
    """The sweep's output folder: made, or checked to be a sweep of the same experiment holding only what a sweep
    writes (its marker, ``points/``, and the summary files the marker lists, unchanged)."""

    def __init__(self, path: str, exp_id: str):
        self.path, self.exp_id = path, exp_id
        self.marker = os.path.join(path, SWEEP_MARKER)
        self.files: dict[str, str] = {}

    def check(self) -> None:
        """An ``OutputError`` where the folder could hold a user's files."""
        label = outdir.shown(self.path)
        if os.path.islink(self.path) or (os.path.lexists(self.path) and not os.path.isdir(self.path)):
            raise outdir.OutputError("--out", f"{label} exists and is not a folder")
        if not os.path.isdir(self.path):
            return
        entries = os.listdir(self.path)
        if not entries:
            return
        try:
            with open(self.marker) as fh:
                data = json.load(fh)
            owner, files = data["sweep"], dict(data["files"])
        except (OSError, ValueError, KeyError, TypeError):
            raise outdir.OutputError("--out", f"{label} exists and is not a jaxdip sweep folder; choose a new or "
                                              "empty folder") from None
        if owner != self.exp_id:
            raise outdir.OutputError("--out", f"{label} holds a sweep of {owner!r}, not {self.exp_id!r}; choose "
                                              "another folder")
        for e in [e for e in entries if _LEFT_OVER.match(e)]:  # a summary file's write that a kill cut short
            os.remove(os.path.join(self.path, e))
            entries.remove(e)
        foreign = [e for e in entries if e not in (SWEEP_MARKER, POINTS) and e not in files]
        changed = [n for n, d in files.items() if os.path.lexists(os.path.join(self.path, n))
                   and _digest(os.path.join(self.path, n)) != d]
        if foreign or changed or (os.path.lexists(p := os.path.join(self.path, POINTS)) and not os.path.isdir(p)):
            raise outdir.OutputError("--out", f"{label} holds files a sweep did not write or that changed since "
                                              f"({', '.join((foreign + changed)[:3]) or POINTS}); move them or "
                                              "choose another folder")
        self.files = files

    def open(self) -> None:
        os.makedirs(os.path.join(self.path, POINTS), exist_ok=True)
        self._write_marker()

    def _write_marker(self) -> None:
        outdir.write_file_atomic(self.marker, json.dumps({"sweep": self.exp_id, "files": self.files}, indent=1))

    def write(self, files: dict[str, str | bytes]) -> None:
        """Replace the summary files by ``files`` (name -> content): the old ones a sweep wrote are removed."""
        for name in set(self.files) - set(files):
            path = os.path.join(self.path, name)
            if _digest(path) == self.files[name]:
                os.remove(path)
        self.files = {}
        for name, data in files.items():
            path = os.path.join(self.path, name)
            outdir.write_file_atomic(path, data)
            self.files[name] = _digest(path)
        self._write_marker()

    def point(self, p: Point) -> str:
        return os.path.join(self.path, POINTS, p.name)


@dataclass
class SweepRun:
    """What ``run_sweep`` did: per point, whether it was run (else reused) and the programs it built."""

    ran: list[bool] = field(default_factory=list)
    compilations: list[int | None] = field(default_factory=list)
    programs: list[dict] = field(default_factory=list)


def run_sweep(exp: Experiment, points: list[Point], folder: SweepFolder, done: SweepRun, *,
              compile_effort: str = "full", quick: bool = False, stop_requested: Callable[[], bool] | None = None,
              say: Callable[[str], None] = lambda s: None, **run_options) -> SweepRun:
    """Run the points not already complete, in order, each into its folder, recording in ``done`` (so a caller
    that catches an exception knows the point that raised it: ``points[len(done.ran)]``). Every destination is
    checked before the first point runs. An interrupt leaves the finished points in place (and nothing of the
    one it stopped). ``run_options`` go to every point's ``run_experiment`` (``per_seed``, ``command``)."""
    folder.check()
    for p in points:
        outdir.check_destination(folder.point(p), exp.id, key="--out")
    folder.open()
    for i, p in enumerate(points[len(done.ran):], len(done.ran) + 1):
        dest = folder.point(p)
        if is_complete(exp, p.cfg, dest, compile_effort, run_options.get("per_seed")):
            say(f"== point {i}/{len(points)} {p.name}: complete, kept")
            done.ran.append(False)
            done.compilations.append(None)
            done.programs.append({})
            continue
        say(f"== point {i}/{len(points)} {p.name}")
        with CompileCounter() as counter:
            run_experiment(exp, p.cfg, dest, stop_requested=stop_requested, compile_effort=compile_effort,
                           quick=quick, **run_options)
        done.ran.append(True)
        done.compilations.append(counter.count)
        done.programs.append(dict(counter.names.most_common()))
    return done
