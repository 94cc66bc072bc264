"""The experiment contract: an id, a typed config, a run function, and an atomic writer for its outputs.

``run_experiment`` produces, in the output folder: ``metrics.json`` (provenance, ``results`` and a separate
``timing`` block), ``report.md``, the figures as PNG and ``config.toml`` (the resolved config). Before anything
compiles it checks the config's resource estimate and that the destination may be written
(``jaxdip.outdir``); everything is written into a temporary sibling folder that is moved into place only when
complete, so an interrupted or failed run leaves nothing half-written and never touches a user's files.

Time is not a result: wall times and anything derived from them go to ``Outcome.timing``, so a resumed or
repeated run has ``results`` identical to an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import os
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Callable

import jax

from jaxdip import checkpoint
from jaxdip import config as cfgmod
from jaxdip import dataset, distributed, outdir, resources
from jaxdip.engine.loop_checks import PRECISIONS
from jaxdip.runner import records
from jaxdip.runner.per_seed import PerSeed, without_trajectories
from jaxdip.runner.provenance import png_metadata, provenance_block
from jaxdip.runner.results import ResultError, check_writable, drop_missing
from jaxdip.runner.scale import scale, scale_line

FIGURE_DPI = 120  # every experiment's PNG figures


@dataclass
class RunContext:
    """Where the current run keeps its checkpoint, for experiments that checkpoint long searches.

    The checkpoint lies beside the output folder (the folder itself only appears, complete, at the end), under
    a name made of the folder's name, the experiment and ``fingerprint`` (of ``info``: the experiment, the
    resolved config and ``run_settings``; see ``run_context``): two runs that could give different results never
    share a file, and a resume finds only a checkpoint of the same run.
    """

    out_dir: str
    resume: bool = False
    exp_id: str = "run"
    fingerprint: str = ""
    info: dict | None = None  # what the fingerprint is made of, recorded in the checkpoint
    # what of the per-seed data is written (None, "final" or "trajectories"): an experiment that would keep
    # trajectories only for per_seed.nc keeps them when this says "trajectories"
    per_seed: str | None = None

    @property
    def checkpoint_path(self) -> str:
        return os.path.join(self.checkpoint_dir, f"{self.checkpoint_prefix}{self.fingerprint or 'any'}.ckpt.npz")

    @property
    def checkpoint_dir(self) -> str:
        return os.path.dirname(os.path.abspath(self.out_dir))

    @property
    def checkpoint_prefix(self) -> str:
        return f".{os.path.basename(os.path.abspath(self.out_dir))}.{self.exp_id}."


@dataclass
class Outcome:
    results: dict
    report: str  # markdown body (the runner adds a provenance header)
    figures: dict = field(default_factory=dict)  # name -> matplotlib Figure
    timing: dict = field(default_factory=dict)  # wall times and what is derived from them: never in results
    # name -> record (``runner.records``), written to record-NAME.csv (the output folder holds plain files only:
    # its marker digests each one, ``jaxdip.outdir``)
    records: dict = field(default_factory=dict)
    per_seed: PerSeed | None = None  # the per-seed arrays behind results (runner.per_seed), for per_seed.nc


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    config_cls: type
    run: Callable[[Any, RunContext | None], Outcome]  # run(cfg, ctx): ctx says where to checkpoint
    quick: dict = field(default_factory=dict)  # overrides applied by --quick
    source: str = ""  # which document, table or figure it reproduces
    # False for the supporting runs of the fidelity readings (docs/fidelity.md): `jaxdip run` and
    # `reproduce --only` run them, a plain `reproduce` (the headline reproduction) leaves them out
    reproduce: bool = True
    # True for experiments whose run checkpoints (``RunContext``) and so can continue with --resume
    resumable: bool = False
    # cold --quick wall time (s) in the parallel reproduce on a 2-core CPU at the quick compile effort: the
    # parallel reproduce starts the long ones first (10 where not measured)
    quick_cost_s: float = 10.0
    # the same for the full run: its wall time (s) in a full-scale reproduce worker kept to one core of a 2-core
    # CPU, cold compilation cache; the full reproduce starts the long ones first (60 where not measured)
    full_cost_s: float = 60.0
    # False for an experiment whose run gives no Outcome.per_seed yet: --per-seed is refused before it runs
    per_seed: bool = True


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


def _keep_unwritable(out_dir: str, exp_id: str, outcome: Outcome) -> str | None:
    """A run whose results the final check refuses (NaN, inf or None left in them) is not a result folder, but
    it may have computed for hours: its results and report go to one JSON file beside the destination (NaN as
    null, infinities as strings), named in the error line. None when even that cannot be written."""
    dest = os.path.abspath(out_dir)
    path = f"{dest}.unwritable-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.json"
    text = json.dumps({"experiment": exp_id, "results": _jsonable(outcome.results), "report": outcome.report},
                      indent=1, allow_nan=True)
    try:
        outdir.write_file_atomic(path, text + "\n")
    except OSError:
        return None
    return path


def precision_field():
    """The ``precision`` config key of an experiment whose Monte Carlo loops were measured safe in float32
    (docs/performance.md, "float32, per loop"): the loops' precision; designs stay float64."""
    return cfgmod.field("float64", cfgmod.one_of(*PRECISIONS),
                        doc="precision of the Monte Carlo closed loops (designs stay float64)")


def run_dtype(cfg=None) -> str:
    """What a run computed in: the process's float width, or, for an experiment with a ``precision`` key, the
    precision of its closed loops (designs stay float64: ``jd.Loop.precision``)."""
    base = "float64" if jax.config.jax_enable_x64 else "float32"
    loops = getattr(cfg, "precision", None)
    return base if loops is None or loops == base else f"{loops} loops, {base} design"


def provenance(exp_id: str, seeds: int, wall_s: float, compile_effort: str = "full", cfg=None) -> dict:
    p = {
        "experiment": exp_id,
        "seeds": seeds,
        "dtype": run_dtype(cfg),
        "backend": jax.default_backend(),
        "devices": jax.device_count(),
        "jax_version": jax.__version__,
        "compile_effort": compile_effort,
        "wall_s": round(wall_s, 3),
    }
    if jax.process_count() > 1:
        p["processes"] = jax.process_count()  # jax.distributed: "devices" counts those of every process
    return p


def check_resources(cfg, flag_keys: dict[str, str] | None = None) -> None:
    """The config's resource estimate against this machine (a ConfigError naming the key to change)."""
    if hasattr(cfg, "loads"):
        resources.check(cfg.loads(), flag_keys=flag_keys)


def run_settings(compile_effort: str = "full") -> dict:
    """What besides the config changes a run's results in its last bits, all of it in a checkpoint's fingerprint.
    config.toml's ``[jaxdip]`` table records the compile effort, the one a user chooses; the others belong to
    the installation and the machine (metrics.json records them)."""
    import jaxdip

    return {"compile_effort": compile_effort, "dtype": "float64" if jax.config.jax_enable_x64 else "float32",
            "jaxdip": jaxdip.__version__, "devices": jax.device_count(), "processes": jax.process_count()}


def config_toml(exp: Experiment, cfg, compile_effort: str = "full") -> str:
    """The written config.toml: the resolved config and, in its ``[jaxdip]`` table, the compile effort, so that
    ``jaxdip run <id> --config <out>/config.toml`` (with or without ``--quick``) repeats the run to the last bit."""
    return (cfgmod.to_toml(cfgmod.to_dict(cfg), header=f"# resolved config of {exp.id}")
            + f"\n# run settings that change the last bits of the results\n[{cfgmod.RUN_TABLE}]\n"
            + f"compile_effort = \"{compile_effort}\"\n")


def run_context(exp: Experiment, cfg, out_dir: str, resume: bool = False,
                compile_effort: str = "full") -> RunContext:
    """The run's ``RunContext``; with ``resume``, a ``CheckpointError`` unless a checkpoint of this very run
    (same experiment, config and settings) is there to continue from."""
    info = {"experiment": exp.id, "config": cfgmod.to_dict(cfg), **run_settings(compile_effort)}
    ctx = RunContext(out_dir, resume, exp.id, checkpoint.fingerprint(info), info)
    if resume:
        _check_resume(exp, ctx, info)
    return ctx


def _check_resume(exp: Experiment, ctx: RunContext, info: dict) -> None:
    if not exp.resumable:
        raise checkpoint.CheckpointError(f"{exp.id} keeps no checkpoint, so there is nothing to resume")
    if os.path.lexists(ctx.checkpoint_path):
        checkpoint.read_meta(ctx.checkpoint_path)  # damaged: say so now, before anything compiles
        return
    try:
        others = sorted(n for n in os.listdir(ctx.checkpoint_dir)
                        if n.startswith(ctx.checkpoint_prefix) and n.endswith(".ckpt.npz"))
    except OSError:
        others = []
    for name in others:
        path = os.path.join(ctx.checkpoint_dir, name)
        try:
            run = checkpoint.read_meta(path).get("run")
        except checkpoint.CheckpointError:
            continue
        if isinstance(run, dict):
            raise checkpoint.CheckpointMismatch(
                f"the checkpoint of {exp.id} into {ctx.out_dir} ({path}) was written by a run with "
                f"{_difference(run, info)}: resume with the same settings, or run without --resume")
    raise checkpoint.CheckpointError(f"no checkpoint of an interrupted {exp.id} run into {ctx.out_dir} "
                                     f"(looked for {ctx.checkpoint_path})")


def _difference(theirs: dict, ours: dict) -> str:
    """The first few settings and config keys in which a checkpoint's run differs from this one."""
    diff = [f"{k} {theirs.get(k)!r} (this run: {v!r})" for k, v in ours.items()
            if k not in ("config", "experiment") and theirs.get(k) != v]
    a, b = theirs.get("config"), ours["config"]
    if isinstance(a, dict):
        diff += [f"{k} = {json.dumps(a.get(k), default=str)} (this run: {json.dumps(b.get(k), default=str)})"
                 for k in sorted(set(a) | set(b)) if a.get(k) != json.loads(json.dumps(b.get(k), default=str))]
    return ", ".join(diff[:3]) or "different settings"


def write_per_seed(path: str, exp: Experiment, part: PerSeed | None, what: str, prov: dict, config_text: str) -> None:
    """per_seed.nc: the experiment's per-seed variables (without trajectories unless ``what`` asks for them), the
    provenance and the resolved config as global attributes."""
    if part is None:
        raise ResultError("--per-seed", f"{exp.id} keeps no per-seed data")
    if what != "trajectories":
        part = without_trajectories(part)
    head = {"experiment": exp.id, "title": exp.title, "source": exp.source, "what": what,
            **{k: v for k, v in prov.items() if k != "packages"},
            **{f"version_{k}": v for k, v in prov["packages"].items()}, "config_toml": config_text}
    dataset.write(dataset.build(part.variables, part.coords, head), path)


def run_experiment(exp: Experiment, cfg, out_dir: str, resume: bool = False, force: bool = False,
                   flag_keys: dict[str, str] | None = None, stop_requested: Callable[[], bool] | None = None,
                   compile_effort: str = "full", quick: bool = False, per_seed: str | None = None,
                   command: str | None = None) -> dict:
    """Run an experiment with a validated config and write its folder; returns metrics.json's content.

    Raises ``ConfigError`` (resources), ``outdir.OutputError`` (destination) or ``CheckpointError`` (``resume``
    without a checkpoint of this run) before anything is compiled, and ``ResultError`` instead of writing NaN,
    inf or null.
    Experiments with long searches checkpoint beside ``out_dir`` (``ctx.checkpoint_path`` of the ``RunContext``
    passed to ``run``) and, with ``resume``, continue from there; the checkpoint is removed once the folder is
    complete, if this run wrote it or resumed from it. ``stop_requested``
    is asked once more before the folder is moved into place, so an interrupt that a library swallowed still
    leaves no folder behind. ``compile_effort``: the level this process compiles at (``jaxdip.xla_flags.effort()``;
    results agree across levels to the last bits), recorded in the provenance. ``quick``: ``cfg`` holds the
    experiment's ``--quick`` overrides; metrics.json's ``scale`` and the report's first line say so
    (``runner.scale``). ``per_seed``: also write ``per_seed.nc`` (``"final"``: final values, per-seed metrics and
    failures; ``"trajectories"``: with the saved trajectories), a ``dataset.MissingExtra`` before anything runs
    without the ``data`` extra. ``command``: the command line, recorded in the provenance (default: the command
    that regenerates the folder from its config.toml).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if per_seed not in (None, "final", "trajectories"):
        raise ValueError(f"per_seed must be None, 'final' or 'trajectories', got {per_seed!r}")
    if per_seed:
        if not exp.per_seed:
            raise ResultError("--per-seed", f"{exp.id} keeps no per-seed data (docs/data.md)")
        dataset.require()
    check_resources(cfg, flag_keys)
    ctx = run_context(exp, cfg, out_dir, resume, compile_effort)
    ctx.per_seed = per_seed
    # With jax.distributed every process runs the experiment (its Monte Carlo is split over all of them) and
    # process 0 alone writes; the others learn whether process 0 could prepare its folder before computing.
    main = distributed.is_main()
    staging, refused = None, None
    if main:
        try:
            staging = outdir.prepare(out_dir, exp.id, force=force)
        except outdir.OutputError as e:
            refused = e
    if not distributed.agree(refused is None):
        raise refused or outdir.OutputError("--out", f"process 0 cannot write {out_dir} (see its error)")
    try:
        t0 = time.perf_counter()
        with checkpoint.owning(uuid.uuid4().hex, ctx.info) as owner:
            outcome = exp.run(cfg, ctx)
        wall = time.perf_counter() - t0
        # a statistic over no seed is left out, never written as NaN or null; anything else non-finite is refused
        outcome.results = drop_missing(outcome.results)
        try:
            check_writable(outcome.results, outcome.report)
        except ResultError as e:  # a defect of the experiment, found after the whole run: keep what it computed
            kept = _keep_unwritable(out_dir, exp.id, outcome) if main else None
            raise ResultError(e.key, f"{e.why}; nothing replaced" + (f"; results kept in {kept}" if kept else "")) from None
        seeds = getattr(cfg, "seeds", 1)
        kind = scale(exp, cfg, quick)
        config_text = config_toml(exp, cfg, compile_effort)
        prov = provenance_block(exp.id, cfg, config_text, out_dir, command)
        metrics = {**provenance(exp.id, seeds, wall, compile_effort, cfg), "scale": kind, "provenance": prov,
                   "results": outcome.results, "timing": outcome.timing}
        if not main:
            for fig in outcome.figures.values():
                plt.close(fig)
            return metrics
        where = f"{metrics['devices']} device(s)" + (
            f" in {metrics['processes']} processes" if "processes" in metrics else "")
        line = scale_line(exp, cfg, kind)  # first, so a quick report is never read as the full run's numbers
        header = (
            f"# {exp.id}: {exp.title}\n\n" + (f"{line}\n\n" if line else "")
            + f"Reproduces: {exp.source}. Seeds: {seeds}; {metrics['dtype']} on {metrics['backend']} "
            f"({where}), JAX {metrics['jax_version']}; wall time {wall:.1f} s.\n\n"
        )
        tmp = staging.tmp
        with open(os.path.join(tmp, "metrics.json"), "w") as fh:
            fh.write(dump_json(metrics) + "\n")
        with open(os.path.join(tmp, "report.md"), "w") as fh:
            fh.write(header + outcome.report.strip() + "\n")
            if outcome.figures:
                fh.write("\n## Figures\n\n" + "".join(f"![{n}]({n}.png)\n" for n in outcome.figures))
            fh.write(f"\n---\n\nRegenerate this folder: `{prov['command']}`"
                     + (f" (or from its own resolved config: `{prov['regenerate']}`)" if command else "") + "\n")
        with open(os.path.join(tmp, "config.toml"), "w") as fh:
            fh.write(config_text)
        for name, rec in outcome.records.items():
            records.write_csv(os.path.join(tmp, f"record-{name}.csv"), rec)
        for name, fig in outcome.figures.items():
            # laid out here, once, for every experiment's figures, at the resolution it is drawn in (the text
            # measured for the layout is then measured once, and the layout fits the pixels drawn); then no layout
            # engine, so savefig draws once: tight_layout leaves a placeholder engine behind, and savefig answers
            # any engine with a whole extra draw pass before the real one
            fig.set_dpi(FIGURE_DPI)
            fig.tight_layout()
            fig.set_layout_engine(None)
            fig.savefig(os.path.join(tmp, f"{name}.png"), dpi=FIGURE_DPI, metadata=png_metadata(prov))
            plt.close(fig)
        if per_seed:
            write_per_seed(os.path.join(tmp, "per_seed.nc"), exp, outcome.per_seed, per_seed, prov, config_text)
        if stop_requested is not None and stop_requested():
            raise KeyboardInterrupt
        staging.commit()
    except OSError as e:  # a full disk, a vanished staging folder: nothing was replaced
        raise outdir.OutputError("--out", f"cannot write {outdir.shown(out_dir)}: {e.strerror or e}") from None
    finally:
        if staging is not None:
            staging.discard()  # a no-op once committed
    checkpoint.remove_own(ctx.checkpoint_path, owner)  # never a checkpoint another run keeps there
    return metrics


def is_complete(exp: Experiment, cfg, folder: str, compile_effort: str, per_seed: str | None = None) -> bool:
    """Whether ``folder`` holds a finished run of ``exp`` with ``cfg``: a jaxdip folder of the experiment with
    its files unchanged (the marker's digests), the config.toml this run would write (config and run settings),
    and per_seed.nc when ``per_seed`` asks for it. A sweep keeps such points, ``reproduce --resume`` such
    experiments."""
    try:
        verdict = outdir.check_destination(folder, exp.id)
    except outdir.OutputError:
        return False
    if verdict.kind != "ours" or (per_seed and "per_seed.nc" not in verdict.files):
        return False
    try:
        with open(os.path.join(folder, "config.toml")) as fh:
            written = fh.read()
        with open(os.path.join(folder, "metrics.json")) as fh:
            return written == config_toml(exp, cfg, compile_effort) and "results" in json.load(fh)
    except (OSError, ValueError):
        return False
