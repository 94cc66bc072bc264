"""``jaxdip run <id> --sweep key=v1,v2,...``: the command-line side of ``jaxdip.runner.sweep``.

Every point's config is built and checked (the same checks and one-line errors as ``--set``) and every
destination is checked before the first point runs; an interrupt keeps the finished points, and the same
command continues with the next one.
"""

from __future__ import annotations

import json
import os
import sys

from jaxdip import xla_flags
from jaxdip.cli_errors import Signals, emit, error, note, run_refusal


def cmd_sweep(args, exp, command: str) -> int:
    """The exit status of a sweep of the experiment ``exp`` (its base config checked already); ``command``: the
    command line, recorded by every point."""
    from jaxdip import config as C
    from jaxdip.config import ConfigError
    from jaxdip.runner import sweep as S
    from jaxdip.runner.experiment import is_complete
    from jaxdip.runner.sweep_table import summary_files

    if args.resume:
        return error("--resume", "a sweep continues where it stopped without it: give the same command again")
    try:
        axes = S.parse_sweeps(args.sweep, args.set)
        points = S.plan(axes, lambda sets: C.load(exp.config_cls, path=args.config,
                                                  quick=exp.quick if args.quick else None, seeds=args.seeds,
                                                  sets=list(args.set) + sets))
    except ConfigError as e:
        return error(e.key, e.why)
    out = args.out or os.path.join("results", f"{exp.id}-sweep")
    folder = S.SweepFolder(out, exp.id)
    done = S.SweepRun()
    level = xla_flags.effort()
    with Signals() as sig:
        try:
            S.run_sweep(exp, points, folder, done, compile_effort=level, quick=args.quick,
                        stop_requested=sig.requested, say=lambda s: print(s, file=sys.stderr, flush=True),
                        per_seed=args.per_seed, command=command)
        except KeyboardInterrupt:
            kept = sum(is_complete(exp, p.cfg, folder.point(p), level, args.per_seed) for p in points)
            note(f"interrupted: {kept} of {len(points)} points are complete in {os.path.join(out, S.POINTS)}; "
                 "give the same command again to continue")
            return 130
        except Exception as e:
            cfg = points[min(len(done.ran), len(points) - 1)].cfg
            if (code := run_refusal(e, cfg, exp.id)) is None:
                raise
            return code
    results = []
    for p in points:
        with open(os.path.join(folder.point(p), "metrics.json")) as fh:
            results.append(json.load(fh)["results"])
    described = [{"name": p.name, "texts": p.texts, "values": p.values} for p in points]
    folder.write(summary_files(exp.id, axes, described, results, done.compilations, done.programs))
    ran = [c for c in done.compilations if c is not None]
    emit(f"{exp.id}: swept {len(points)} points into {out} ({len(ran)} run, {len(points) - len(ran)} kept; "
         f"{sum(ran)} programs built)")
    return 0
