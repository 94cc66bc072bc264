"""How the TWIP and reaction-wheel readings write a number, an interval, a verdict and a JSON row."""

from __future__ import annotations

import numpy as np

def num(v, d=4) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.{d}g}"


def num_ci(v, ci, d=4) -> str:
    return f"{num(v, d)} [{num(ci[0], d)}, {num(ci[1], d)}]"


def inside(doc: float, ci) -> str:
    if any(not np.isfinite(c) for c in ci):
        return "undecided"
    return "yes" if ci[0] <= doc <= ci[1] else "no"


def row(claim, reading, what, command, ours, document, holds) -> dict:
    return {"claim": claim, "reading": reading, "what": what, "command": command, "ours": ours,
            "document": document, "holds": holds}
