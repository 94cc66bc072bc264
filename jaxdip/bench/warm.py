"""Where a ``--quick`` run's time goes, cold and warm: ``python -m jaxdip.bench.warm [--only ID,...]``.

Each experiment runs ``jaxdip run ID --quick`` twice in a fresh process with its own compilation-cache folder:
first with the folder empty (cold), then again with what the first run left there (warm). The child process
times its imports (jaxdip's CLI, the registry and the experiment's module) and listens to JAX's public
``jax.monitoring`` time spans: tracing to a jaxpr (``/jax/core/compile/jaxpr_trace_duration``), lowering to an
MLIR module (``jaxpr_to_mlir_module_duration``) and compiling or loading from the cache
(``backend_compile_duration``). Spans nest (a jit traced inside another's trace), so each phase is the length
of the union of its spans, not their sum. Per run the table gives:

- ``process``: the whole subprocess, interpreter start to exit, as the parent saw it;
- ``import``: importing jaxdip's CLI and the experiment's module;
- ``trace`` / ``lower`` / ``compile``: the union of the phase's spans (``compile`` is a cache load when warm);
- ``programs``: executables built (compiled or loaded), ``hits`` of them served by the persistent cache;
- ``stored``: traced programs read from the program cache (``jaxdip.program_cache``; ``exported`` in the JSON:
  those traced and written), ``ordinary``: calls that could not go through it (several devices, a tracer);
- ``run``: the experiment's own wall time (metrics.json's ``wall_s``) less trace, lower and compile;
- ``write``: the rest of the command (config, output folder, figures saved as PNG, report).

The JSON (``--json``) also holds, per run, the executables per function name and the twelve names that cost the
most trace + lower + compile time.

Wall times on a shared machine: compare runs of one invocation, and say the load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

PHASES = {
    "trace": "/jax/core/compile/jaxpr_trace_duration",
    "lower": "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "compile": "/jax/core/compile/backend_compile_duration",
}
_HIT = "/jax/compilation_cache/cache_hits"
_COLUMNS = ("process", "import", "trace", "lower", "compile", "programs", "hits", "stored", "ordinary", "run", "write")


def _union(spans: list[tuple[float, float]]) -> float:
    total, end = 0.0, float("-inf")
    for a, b in sorted(spans):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def _child(exp_id: str, out: str, result: str) -> int:
    t0 = time.perf_counter()
    from jaxdip import cli
    from jaxdip.runner import get

    # the host device count first, as `jaxdip run` sets it before it imports the experiment: a module that builds
    # arrays on import (ifn-protection's) would otherwise start JAX with one device
    cli._use_all_cores(1)
    get(exp_id)
    imported = time.perf_counter() - t0
    import jax.monitoring as mon

    spans: dict[str, list] = {k: [] for k in PHASES.values()}
    names: dict[str, int] = {}
    cost: dict[str, float] = {}  # seconds of trace, lower and compile per function name (nested spans counted twice)
    hits = [0]

    def on_span(event: str, start: float, end: float, **kw) -> None:
        if event in spans:
            spans[event].append((start, end))
            name = str(kw.get("fun_name", "?"))
            if event == PHASES["compile"]:
                names[name] = names.get(name, 0) + 1
            cost[name] = cost.get(name, 0.0) + end - start

    def on_event(event: str, **kw) -> None:
        hits[0] += event == _HIT

    mon.register_event_time_span_listener(on_span)
    mon.register_event_listener(on_event)
    t1 = time.perf_counter()
    rc = cli.main(["run", exp_id, "--quick", "--force", "--out", out])
    command = time.perf_counter() - t1
    with open(os.path.join(out, "metrics.json")) as fh:
        wall = json.load(fh)["wall_s"]
    phase = {k: _union(spans[v]) for k, v in PHASES.items()}
    from jaxdip import program_cache

    stored = program_cache.counts()
    rec = {"import": imported, **phase, "programs": sum(names.values()), "hits": hits[0],
           "stored": stored["read"], "exported": stored["exported"], "ordinary": stored["ordinary"],
           "run": max(wall - sum(phase.values()), 0.0), "write": max(command - wall, 0.0),
           "program_names": names, "costliest": sorted(cost.items(), key=lambda kv: -kv[1])[:12], "rc": rc}
    with open(result, "w") as fh:
        json.dump(rec, fh)
    return rc


def measure(exp_id: str, cache_dir: str, out: str) -> dict:
    """One ``jaxdip run ID --quick`` in a fresh process with ``cache_dir`` as its compilation cache; the
    breakdown as a dict (seconds; ``programs`` and ``hits`` counts; ``program_names``: executables per name)."""
    fd, result = tempfile.mkstemp(suffix=".json")
    os.close(fd)
    env = {**os.environ, "JAXDIP_CACHE_DIR": cache_dir}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "jaxdip.bench.warm", "--child", exp_id, out, result], env=env,
                          capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    try:
        if proc.returncode != 0:
            raise RuntimeError(f"{exp_id} --quick failed ({proc.returncode}): {proc.stderr[-2000:]}")
        with open(result) as fh:
            return {"process": elapsed, **json.load(fh)}
    finally:
        os.remove(result)


def breakdown(ids: list[str], work: str, partial: str | None = None) -> list[dict]:
    """Cold and warm breakdown of each experiment in ``ids``, each with its own (first empty) cache folder under
    ``work``; a list of ``{"id", "cold", "warm"}``, also written to ``partial`` after each experiment."""
    rows = []
    for exp_id in ids:
        cache, out = os.path.join(work, "cache", exp_id), os.path.join(work, "out", exp_id)
        if os.path.exists(cache) and os.listdir(cache):
            raise RuntimeError(f"{cache} is not empty: a cold run needs an empty cache folder")
        os.makedirs(cache, exist_ok=True)
        cold = measure(exp_id, cache, out)
        warm = measure(exp_id, cache, out)
        rows.append({"id": exp_id, "cold": cold, "warm": warm})
        if partial:  # a long breakdown interrupted keeps what it measured
            with open(partial, "w") as fh:
                json.dump(rows, fh, indent=1)
        print(f"{exp_id}: cold {cold['process']:.1f} s, warm {warm['process']:.1f} s", file=sys.stderr, flush=True)
    return rows


def _cell(v) -> str:
    return str(v) if isinstance(v, int) else f"{v:.2f}"


def table(rows: list[dict], which: str) -> str:
    """A markdown table of one kind of run (``"cold"`` or ``"warm"``), a totals row last."""
    head = f"| experiment ({which}) | " + " | ".join(_COLUMNS) + " |\n|---" + "|---" * len(_COLUMNS) + "|\n"
    body = "".join(f"| {r['id']} | " + " | ".join(_cell(r[which][c]) for c in _COLUMNS) + " |\n" for r in rows)
    tot = {c: sum(r[which][c] for r in rows) for c in _COLUMNS}
    return head + body + "| **total** | " + " | ".join(_cell(tot[c]) for c in _COLUMNS) + " |\n"


def main(argv: list[str] | None = None) -> int:
    """The command line: ``--only`` (default: the experiments ``jaxdip reproduce`` runs), ``--work`` (cache and
    output folders; default a temporary folder), ``--json`` (also write the rows there)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        return _child(*argv[1:4])
    p = argparse.ArgumentParser(prog="python -m jaxdip.bench.warm", description=__doc__.splitlines()[0])
    p.add_argument("--only", help="comma-separated experiment ids")
    p.add_argument("--work", help="folder for the caches and outputs (its cache/ must not hold them yet)")
    p.add_argument("--json", help="write the rows to this file")
    args = p.parse_args(argv)
    from jaxdip.runner import registry

    reg = registry()
    ids = [i.strip() for i in args.only.split(",")] if args.only else sorted(i for i, e in reg.items() if e.reproduce)
    if bad := [i for i in ids if i not in reg]:
        p.error(f"unknown experiment(s) {', '.join(bad)}; known: {', '.join(sorted(reg))}")
    work = args.work or tempfile.mkdtemp(prefix="jaxdip-warm-")
    rows = breakdown(ids, work, args.json)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    print(table(rows, "cold") + "\n" + table(rows, "warm"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
