"""Registry of experiments: id -> Experiment (config dataclass, run function, --quick overrides)."""

from __future__ import annotations

from jaxdip.experiments.base import Experiment, Outcome, run_experiment

_REGISTRY: dict[str, Experiment] = {}


def register(exp: Experiment) -> Experiment:
    if exp.id in _REGISTRY:
        raise ValueError(f"experiment id {exp.id!r} registered twice")
    _REGISTRY[exp.id] = exp
    return exp


def _load_builtin():
    from jaxdip.experiments import dip_controllers  # noqa: F401
    from jaxdip.experiments import dip_lqr  # noqa: F401
    from jaxdip.experiments import eki_dip  # noqa: F401
    from jaxdip.experiments import eki_examples  # noqa: F401
    from jaxdip.experiments import lorenz_mhe  # noqa: F401
    from jaxdip.experiments import twip_dmso  # noqa: F401
    from jaxdip.experiments import rwp_bias  # noqa: F401
    from jaxdip.experiments import twip_extra_control  # noqa: F401
    from jaxdip.experiments import dip_cpx_ldf  # noqa: F401
    from jaxdip.experiments import tune  # noqa: F401
    from jaxdip.experiments import ifn_protection  # noqa: F401


def registry() -> dict[str, Experiment]:
    # always: importing one experiment module directly registers only that one (module imports are cached,
    # so this is cheap and registers each experiment once)
    _load_builtin()
    return dict(_REGISTRY)


def get(exp_id: str) -> Experiment:
    reg = registry()
    if exp_id not in reg:
        import difflib

        close = difflib.get_close_matches(exp_id, reg, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(sorted(reg))})"
        raise KeyError(f"{exp_id}: unknown experiment{hint}")
    return reg[exp_id]


__all__ = ["Experiment", "Outcome", "run_experiment", "register", "registry", "get"]
