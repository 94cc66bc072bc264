"""Registry of experiments: id -> Experiment (config dataclass, run function, --quick overrides)."""

from __future__ import annotations

from jaxdip.experiments.base import Experiment, Outcome, run_experiment

# the built-in experiments, by module; each module defines EXPERIMENT (or EXPERIMENTS) and registers nothing
# on import, so importing one experiment module has no effect on the registry
BUILTIN = ("dip_controllers", "dip_cpx_ldf", "dip_lqr", "eki_dip", "eki_examples", "ifn_protection", "lorenz_mhe",
           "rwp_bias", "rwp_remark3", "thesis_theory", "tune", "twip_allan", "twip_dmso", "twip_extra_control",
           "twip_transients")


def registry() -> dict[str, Experiment]:
    """id -> Experiment for every built-in experiment (modules are imported here, on first use)."""
    import importlib

    out: dict[str, Experiment] = {}
    for name in BUILTIN:
        mod = importlib.import_module(f"jaxdip.experiments.{name}")
        exps = getattr(mod, "EXPERIMENTS", None) or (mod.EXPERIMENT,)
        for exp in exps:
            if exp.id in out:
                raise ValueError(f"experiment id {exp.id!r} defined twice")
            out[exp.id] = exp
    return out


def get(exp_id: str) -> Experiment:
    reg = registry()
    if exp_id not in reg:
        import difflib

        close = difflib.get_close_matches(exp_id, reg, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(sorted(reg))})"
        raise KeyError(f"{exp_id}: unknown experiment{hint}")
    return reg[exp_id]


__all__ = ["Experiment", "Outcome", "run_experiment", "registry", "get", "BUILTIN"]
