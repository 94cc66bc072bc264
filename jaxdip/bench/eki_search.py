"""Where the eki-dip search's time goes, and the thesis's fixed step against the data-misfit schedule.

``python -m jaxdip.bench.eki_search`` (thesis scale: J = 80, T = 3 s, up to 1000 iterations) prints, as JSON:

* ``profile``: the first chunk's extra wall time over the later chunks' mean (compilation of the one chunk
  program) and the wall time of one iteration (forward model of every member plus the update); host round
  trips happen once per chunk;
* per schedule (``fixed``: the thesis's dt = 1 to the iteration budget or eki-dip's early stop; ``data_misfit``:
  adaptive steps until the algorithmic time reaches 1): iterations, forward evaluations, search wall time,
  the found P's stabilised fraction (eki-dip's judge) and its held-out performance (2.24), beside the starting
  mean's. ``--set KEY=VALUE`` overrides eki-dip's config (a smaller run: ``--set ensemble=8 --set T=0.5``).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from jaxdip import config as C
from jaxdip.search import data_misfit, run_eki
from jaxdip.search.p_search import performances


def measure(overrides: dict, schedules=("fixed", "data_misfit"), profile_chunks: int = 4) -> dict:
    """The profile and the comparison (see the module docstring) for eki-dip's config with ``overrides``."""
    import experiments.eki_dip as E

    cfg = C.load(E.EkiDipConfig, quick=overrides)
    base = jax.random.PRNGKey(cfg.seed)
    plant, scfg, eki, st0, members0, _ = E.build(cfg, base)
    out: dict = {"devices": len(jax.local_devices()), "ensemble": cfg.ensemble, "T": cfg.T}

    marks = [time.perf_counter()]
    run_eki(eki, st0, profile_chunks * cfg.chunk, chunk=cfg.chunk, checkpoint=lambda s, h: marks.append(time.perf_counter()))
    d = np.diff(marks)
    out["profile"] = {"compile_s": float(d[0] - d[1:].mean()), "iteration_s": float(d[1:].mean() / cfg.chunk)}

    def judged(m):
        y = np.asarray(performances(plant, scfg, m, jax.random.fold_in(base, 3), cfg.eval_states))
        j = E.judge(cfg, m, cfg.seed + 7)
        return {"performance": float(y.mean()), "failed": int((y >= scfg.penalty).sum()),
                "stabilized_fraction": j["stabilized_fraction"], "ci95": j["stabilized_fraction_ci95"]}

    out["start"] = judged(E.projection(cfg)(jax.tree_util.tree_map(lambda a: a.mean(0), members0)))
    stop = (lambda h: float(h[-cfg.chunk:, 0].mean()) < cfg.stop_below) if cfg.early_stop else None
    for name in schedules:
        e = eki._replace(schedule=data_misfit(1.0)) if name == "data_misfit" else eki
        t = time.perf_counter()
        st, _ = run_eki(e, st0, cfg.iterations, chunk=cfg.chunk, stop=stop)
        wall = time.perf_counter() - t
        out[name] = {"iterations": int(st.iteration), "evaluations": int(st.iteration) * cfg.ensemble * cfg.n_x0,
                     "search_wall_s": wall, **judged(e.mean(st))}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m jaxdip.bench.eki_search", description=__doc__.splitlines()[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override eki-dip's config")
    args = ap.parse_args(argv)
    overrides = {}
    for kv in args.set:
        k, _, v = kv.partition("=")
        overrides[k] = json.loads(v)
    print(json.dumps(measure(overrides), indent=1))


if __name__ == "__main__":
    main()
