"""The experiment contract: an id, a typed config, a run function, and an atomic writer for its outputs.

``run_experiment`` produces, in the output folder: ``metrics.json`` (provenance + ``results``), ``report.md``,
the figures as PNG and ``config.toml`` (the resolved config). Everything is written into a temporary sibling
folder that is renamed into place only when complete, so an interrupted or failed run leaves nothing
half-written.
"""

from __future__ import annotations

import contextvars
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import jax

from jaxdip import config as cfgmod


@dataclass
class RunContext:
    """Where the current run writes, for experiments that checkpoint long searches."""

    out_dir: str
    resume: bool = False

    @property
    def checkpoint_path(self) -> str:
        # beside the output folder, not inside it: the folder itself only appears, complete, at the end
        return os.path.join(os.path.dirname(os.path.abspath(self.out_dir)),
                            f".{os.path.basename(os.path.abspath(self.out_dir))}.ckpt.npz")


_CONTEXT: contextvars.ContextVar[RunContext | None] = contextvars.ContextVar("jaxdip_run", default=None)


def current_run() -> RunContext | None:
    return _CONTEXT.get()


@dataclass
class Outcome:
    results: dict
    report: str  # markdown body (the runner adds a provenance header)
    figures: dict = field(default_factory=dict)  # name -> matplotlib Figure


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    config_cls: type
    run: Callable[[Any], Outcome]
    quick: dict = field(default_factory=dict)  # overrides applied by --quick
    source: str = ""  # which document, table or figure it reproduces


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if hasattr(o, "tolist"):
        return _jsonable(o.tolist())
    if isinstance(o, float) and not math.isfinite(o):
        return None if math.isnan(o) else ("inf" if o > 0 else "-inf")
    return o


def dump_json(obj) -> str:
    return json.dumps(_jsonable(obj), indent=2, sort_keys=False, allow_nan=False)


def write_atomic_dir(out_dir: str, write: Callable[[str], None]):
    """Call ``write(tmpdir)`` and move the finished folder to ``out_dir`` (replacing an older one)."""
    out_dir = os.path.abspath(out_dir)
    parent = os.path.dirname(out_dir)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out_dir)}.tmp-", dir=parent)
    try:
        write(tmp)
        if os.path.exists(out_dir):
            old = tempfile.mkdtemp(prefix=f".{os.path.basename(out_dir)}.old-", dir=parent)
            os.rmdir(old)
            os.rename(out_dir, old)
            os.rename(tmp, out_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def provenance(exp_id: str, seeds: int, wall_s: float) -> dict:
    return {
        "experiment": exp_id,
        "seeds": seeds,
        "dtype": "float64" if jax.config.jax_enable_x64 else "float32",
        "backend": jax.default_backend(),
        "devices": jax.device_count(),
        "jax_version": jax.__version__,
        "wall_s": round(wall_s, 3),
    }


def run_experiment(exp: Experiment, cfg, out_dir: str, resume: bool = False) -> dict:
    """Run an experiment with a validated config and write its folder; returns metrics.json's content.

    Experiments with long searches checkpoint beside ``out_dir`` (``current_run().checkpoint_path``) and, with
    ``resume``, continue from there; the checkpoint is removed once the folder is complete.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ctx = RunContext(out_dir, resume)
    token = _CONTEXT.set(ctx)
    try:
        t0 = time.perf_counter()
        outcome = exp.run(cfg)
        wall = time.perf_counter() - t0
    finally:
        _CONTEXT.reset(token)
    seeds = getattr(cfg, "seeds", 1)
    metrics = {**provenance(exp.id, seeds, wall), "results": outcome.results}
    header = (
        f"# {exp.id}: {exp.title}\n\n"
        f"Reproduces: {exp.source}. Seeds: {seeds}; {metrics['dtype']} on {metrics['backend']} "
        f"({metrics['devices']} device(s)), JAX {metrics['jax_version']}; wall time {wall:.1f} s.\n\n"
    )

    def write(tmp):
        with open(os.path.join(tmp, "metrics.json"), "w") as fh:
            fh.write(dump_json(metrics) + "\n")
        with open(os.path.join(tmp, "report.md"), "w") as fh:
            fh.write(header + outcome.report.strip() + "\n")
            if outcome.figures:
                fh.write("\n## Figures\n\n" + "".join(f"![{n}]({n}.png)\n" for n in outcome.figures))
        with open(os.path.join(tmp, "config.toml"), "w") as fh:
            fh.write(cfgmod.to_toml(cfgmod.to_dict(cfg), header=f"# resolved config of {exp.id}"))
        for name, fig in outcome.figures.items():
            fig.savefig(os.path.join(tmp, f"{name}.png"), dpi=120, bbox_inches="tight")
            plt.close(fig)

    write_atomic_dir(out_dir, write)
    if os.path.exists(ctx.checkpoint_path):
        os.remove(ctx.checkpoint_path)
    return metrics
