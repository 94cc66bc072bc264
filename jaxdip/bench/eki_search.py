"""Where the eki-dip search's time goes, per precision of its forward model.

``python -m jaxdip.bench.eki_search`` (thesis scale: J = 80, T = 3 s) prints, as JSON, per ``search_precision``
(``float64``, ``float32``): the first chunk's extra wall time over the later chunks' mean (compilation of the
one chunk program) and the wall time of one iteration (forward model of every member plus the update; host round
trips happen once per chunk). The precisions alternate search by search, so both see much the same load; the
figure is the median over the chunks after the first. ``--set KEY=VALUE`` overrides eki-dip's config (a smaller run:
``--set ensemble=8 --set T=0.5``). The search's other readings (the adaptive step, UKI) and their results are
eki-dip's variant table (``jaxdip run eki-dip``).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import numpy as np

from jaxdip import config as C
from jaxdip import xla_flags


def measure(overrides: dict, precisions=("float64", "float32"), chunks: int = 4, rounds: int = 2) -> dict:
    """The profile (see the module docstring) for eki-dip's config with ``overrides``: per precision, ``rounds``
    searches of ``chunks + 1`` chunks, the precisions alternating search by search."""
    import experiments.eki_dip as E
    from jaxdip.search.eki import run_eki

    base = jax.random.PRNGKey(0)
    out: dict = {"devices": len(jax.local_devices())}
    first, later = {p: [] for p in precisions}, {p: [] for p in precisions}
    for _ in range(rounds):
        for p in precisions:
            cfg = C.load(E.EkiDipConfig, quick={**overrides, "search_precision": p})
            _, _, eki, st, _, _ = E.build(cfg, base)
            marks = [time.perf_counter()]
            run_eki(eki, st, (chunks + 1) * cfg.chunk, chunk=cfg.chunk,
                    checkpoint=lambda s, h: marks.append(time.perf_counter()))
            d = np.diff(marks)
            first[p].append(d[0])
            later[p] += list(d[1:] / cfg.chunk)
    for p in precisions:
        it = float(np.median(later[p]))
        out[p] = {"compile_s": float(np.median(first[p]) - it * cfg.chunk), "iteration_s": it}
    if len(precisions) == 2:
        a, b = precisions
        out["speedup"] = out[a]["iteration_s"] / out[b]["iteration_s"]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m jaxdip.bench.eki_search", description=__doc__.splitlines()[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override eki-dip's config")
    ap.add_argument("--chunks", type=int, default=4, help="timed chunks per search")
    ap.add_argument("--rounds", type=int, default=2, help="searches per precision")
    args = ap.parse_args(argv)
    # as `jaxdip run` does: one XLA host device per core (the members split over them), before JAX starts
    xla_flags.append(xla_flags.pending({"xla_force_host_platform_device_count": os.cpu_count() or 1}))
    overrides = {}
    for kv in args.set:
        k, _, v = kv.partition("=")
        overrides[k] = json.loads(v)
    print(json.dumps(measure(overrides, chunks=args.chunks, rounds=args.rounds), indent=1))


if __name__ == "__main__":
    main()
