"""What an experiment gives the runner for ``per_seed.nc``: its per-seed arrays, labelled, and which statistic of
``results`` each one is summarised into.

An experiment fills ``Outcome.per_seed`` with a ``PerSeed``: variables (name -> (dims, values, attrs), the first
dimension ``seed``) and the labels of its other dimensions. A variable that a statistic of ``results`` is computed
from says so in three attributes, so the dataset documents itself and a test recomputes every such statistic
from the file: ``summarised_as`` (the dotted path in ``results``, with ``{dim}`` standing for a label of the
variable's dimension ``dim``, substituted after splitting at the dots, so a label may hold dots; a number
indexes a list), ``interval_as`` (the path of its interval), ``statistic`` (``mean_ci95``: the mean over the seeds and its interval, by
``jaxdip.stats.mean_ci``; ``fraction_wilson``: the fraction of true seeds and its Wilson interval) and ``over``
(the boolean variable selecting the seeds a mean is taken over). The runner writes the dataset only when asked
(``jaxdip run <id> --per-seed``); variables on a ``time`` dimension (trajectories) only with
``--per-seed trajectories``. docs/data.md describes the layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MEAN = "mean_ci95"
FRACTION = "fraction_wilson"


@dataclass
class PerSeed:
    """Per-seed variables (name -> (dims, values, attrs)) and the labels of their dimensions other than ``seed``
    (dimension -> labels)."""

    variables: dict = field(default_factory=dict)
    coords: dict = field(default_factory=dict)

    def add(self, name: str, dims: tuple, values, units: str, long_name: str = "", **attrs) -> None:
        self.variables[name] = (tuple(dims), np.asarray(values), {"units": units, "long_name": long_name, **attrs})

    def arrays(self) -> dict:
        """name -> values."""
        return {name: values for name, (_, values, _) in self.variables.items()}

    def update(self, other: PerSeed) -> None:
        self.variables.update(other.variables)
        self.coords.update(other.coords)


PATHS = ("summarised_as", "interval_as")


def mean_of(path: str, over: str | None = "ok", interval: str | None = None) -> dict:
    """The attributes of a variable whose mean over the seeds ``over`` selects (None: every seed) is
    ``results[path]``, with its 95% interval at ``interval`` (default ``<path>_ci95``; ``""``: none reported)."""
    return {"summarised_as": path, "interval_as": f"{path}_ci95" if interval is None else interval or None,
            "statistic": MEAN, "over": over}


def fraction_of(path: str, interval: str | None = None) -> dict:
    """The attributes of a boolean variable whose fraction of true seeds is ``results[path]``, with its Wilson
    interval at ``interval`` (default ``<path>_ci95``)."""
    return {"summarised_as": path, "interval_as": interval or f"{path}_ci95", "statistic": FRACTION}


def stacked(parts: dict[str, PerSeed], dim: str) -> PerSeed:
    """The parts' variables (the same names and dims in every part) stacked along a new dimension ``dim`` after
    ``seed``, labelled by the parts' names; ``summarised_as`` paths gain a leading ``{dim}.``."""
    names = list(parts)
    first = parts[names[0]]
    out = PerSeed(coords={**first.coords, dim: names})
    for var, (dims, _, attrs) in first.variables.items():
        values = np.stack([np.asarray(parts[n].variables[var][1]) for n in names], axis=1)
        attrs = {k: f"{{{dim}}}.{v}" if k in PATHS and v else v for k, v in attrs.items()}
        out.variables[var] = ((dims[0], dim, *dims[1:]), values, attrs)
    return out


def prefixed(part: PerSeed, name: str, path: str, seeds_key: str | None = None) -> PerSeed:
    """``part`` with every variable renamed ``<name>.<variable>`` and every ``summarised_as`` (and ``over``)
    under ``results[path]``; ``seeds_key``: the key its seeds were folded from, where it is not the run's."""
    out = PerSeed(coords=dict(part.coords))
    for var, (dims, values, attrs) in part.variables.items():
        attrs = {k: f"{path}.{v}" if k in PATHS and v else v for k, v in attrs.items()}
        if attrs.get("over"):
            attrs["over"] = f"{name}.{attrs['over']}"
        if seeds_key is not None:
            attrs["seeds_key"] = seeds_key
        out.variables[f"{name}.{var}"] = (dims, values, attrs)
    return out


def without_trajectories(part: PerSeed) -> PerSeed:
    """``part`` without the variables on a ``time`` dimension."""
    return PerSeed({k: v for k, v in part.variables.items() if "time" not in v[0]}, dict(part.coords))
