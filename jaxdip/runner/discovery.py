"""The registry of experiments: id -> Experiment, found by walking a package, with no list kept by hand.

Every module and sub-package directly inside the experiments package (``experiments``, the top-level package of a
clone, installed beside ``jaxdip`` by ``pip install .``) is an experiment's home and defines ``EXPERIMENT`` (one
``Experiment``) or ``EXPERIMENTS`` (several). The package is named, not imported, here: experiments sit above
the runner, which finds them at run time as a plugin host finds its plugins. docs/registry.md says how to add one.
"""

from __future__ import annotations

import importlib
import pkgutil

from jaxdip.messages import suggestion
from jaxdip.runner.experiment import Experiment

PACKAGE = "experiments"
# the one home in the package that holds no experiment: the fidelity studies (scripts that run `jaxdip` in
# child processes and gather their results)
NOT_EXPERIMENTS = frozenset({"fidelity"})


def homes(package: str = PACKAGE) -> list[str]:
    """The full names of the experiment modules and sub-packages of ``package``, sorted."""
    pkg = importlib.import_module(package)
    return sorted(f"{package}.{m.name}" for m in pkgutil.iter_modules(pkg.__path__)
                  if m.name not in NOT_EXPERIMENTS and not m.name.startswith("_"))


def experiments_of(module) -> tuple[Experiment, ...]:
    """The experiments a home defines; a ``TypeError`` naming the module when it defines none, or not an
    ``Experiment``, so a misspelt definition is an error rather than a missing id."""
    exps = getattr(module, "EXPERIMENTS", None)
    if exps is None:
        exp = getattr(module, "EXPERIMENT", None)
        if exp is None:
            raise TypeError(f"{module.__name__} defines neither EXPERIMENT nor EXPERIMENTS")
        exps = (exp,)
    for exp in exps:
        if not isinstance(exp, Experiment):
            raise TypeError(f"{module.__name__}: {exp!r} is not an Experiment")
    return tuple(exps)


def registry(package: str = PACKAGE) -> dict[str, Experiment]:
    """id -> Experiment for every experiment of ``package`` (its modules are imported here, on first use)."""
    out: dict[str, Experiment] = {}
    for name in homes(package):
        for exp in experiments_of(importlib.import_module(name)):
            if exp.id in out:
                raise ValueError(f"experiment id {exp.id!r} defined twice")
            out[exp.id] = exp
    return out


def get(exp_id: str, package: str = PACKAGE) -> Experiment:
    """The experiment ``exp_id``; a ``KeyError`` naming the closest id, or every id, when there is none.

    The home named after the id (``dip-lqr``: ``experiments.dip_lqr``) is looked in first, so running one
    experiment imports its own plant, scenario and figure code and not every other experiment's (seconds of a
    ``--quick`` run); the whole package is imported only for an id defined elsewhere or unknown. A duplicate id
    is still refused by ``registry``, which ``jaxdip list`` and ``reproduce`` use."""
    name = f"{package}.{exp_id.replace('-', '_')}"
    if name in homes(package):
        for exp in experiments_of(importlib.import_module(name)):
            if exp.id == exp_id:
                return exp
    reg = registry(package)
    if exp_id not in reg:
        raise KeyError(f"{exp_id}: unknown experiment{suggestion(exp_id, sorted(reg))}")
    return reg[exp_id]
