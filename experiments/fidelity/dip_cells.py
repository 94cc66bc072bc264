"""How the DIP readings read a run and write an interval, a verdict and a JSON row."""

from __future__ import annotations

import math
import shlex

from experiments.fidelity.runs import run


def run_metrics(cmd: list[str], workdir: str) -> dict:
    """The metrics.json of the ``jaxdip ...`` line ``cmd`` (``runs.run``), nulls read as NaN."""
    return _nan(run(cmd, workdir))


def _nan(v):
    """metrics.json writes a statistic over no trials as null: read it as NaN."""
    if isinstance(v, dict):
        return {k: _nan(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_nan(x) for x in v]
    return float("nan") if v is None else v


def num_ci(v, ci, d=3) -> str:
    return f"{v:.{d}g} [{ci[0]:.{d}g}, {ci[1]:.{d}g}]"


def below(a, b) -> str:
    """'yes' if interval a lies entirely below interval b, 'no' if entirely above, else 'undecided'."""
    if any(math.isnan(x) for x in (*a, *b)):
        return "undecided"
    return "yes" if a[1] < b[0] else "no" if a[0] > b[1] else "undecided"


def all_hold(vs) -> str:
    vs = list(vs)
    return "yes" if all(v == "yes" for v in vs) else "no" if "no" in vs else "undecided"


def row(claim, reading, what, cmd, ours, document, holds) -> dict:
    return {"claim": claim, "reading": reading, "what": what, "command": shlex.join(cmd) if cmd else "",
            "ours": ours, "document": document, "holds": holds}
