"""The vocabulary of the fidelity inventory: ``Check`` (one comparison of a run's result with a document),
``Choice`` (a modelling choice a claim's verdict depends on), ``Claim`` and ``Qualitative``.

The inventory itself is ``experiments/fidelity/claims.py`` (which re-exports these names); the generator of
``docs/fidelity.md`` is ``experiments/fidelity/index.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

DOCUMENTS = {
    "paper": "Bernstein, King, Tran: A moving horizon state estimator for real-time stabilization of a DIP",
    "thesis": "King: Nonlinear feedback controllers and state estimators (PhD thesis)",
    "stumfoll": "Stumfoll: Discrete-time neural network based state observer ... (MS thesis)",
    "aranovskiy": "Aranovskiy et al.: Bias propagation and estimation in homogeneous differentiators",
}
RULES = ("close", "in_ci", "below", "true", "false", "ge", "le", "ratio_ge")


@dataclass(frozen=True)
class Check:
    """One comparison of a run's result with the document. ``key`` (and ``other``) are paths into
    ``metrics.json["results"]`` with ``/`` between levels (a list level takes an integer index).

    rule: ``close`` |ours - value| <= tol |value| (``other``'s value in place of ``value`` when given); ``in_ci`` value inside ours' 95% interval; ``below`` ours'
    interval entirely below ``other``'s (entirely above: fails; overlapping: undecided; a value without interval
    counts as a point); ``true``/``false`` a boolean result; ``ge``/``le`` ours >= / <= value; ``ratio_ge``
    ours / other >= value.

    Where ours has a 95% interval, ``close``, ``ge``, ``le`` and ``ratio_ge`` are decided on it, not on the point:
    the whole interval on the claim's side holds, the whole interval on the other side fails, an interval across
    the threshold (or the tolerance band's edge) is undecided, with the run size that would decide it.
    """

    exp: str
    rule: str
    key: str
    label: str
    value: float | None = None
    other: str | None = None
    tol: float | None = None
    ci: str | None = None  # path of key's interval when it is not the sibling ``<key>_ci95``
    other_ci: str | None = None
    n: str | None = None  # path of the sample size behind key's interval (default: the run's seeds)

    def __post_init__(self):
        if self.rule not in RULES:
            raise ValueError(f"{self.key}: unknown rule {self.rule!r}")
        if self.rule in ("below", "ratio_ge") and self.other is None:
            raise ValueError(f"{self.key}: rule {self.rule} needs other")
        if self.rule == "close" and (self.value is None) == (self.other is None):
            raise ValueError(f"{self.key}: rule close needs value or other")
        if self.rule in ("in_ci", "ge", "le", "ratio_ge") and self.value is None:
            raise ValueError(f"{self.key}: rule {self.rule} needs value")
        if self.rule == "close" and self.tol is None:
            raise ValueError(f"{self.key}: rule close needs tol")


@dataclass(frozen=True)
class Claim:
    id: str
    where: str  # section and the document's own words that locate it
    claim: str  # what the document claims, in our words, with its numbers
    document: str  # the document's number(s) as text
    exp: str | None = None  # the jaxdip experiment that addresses it
    keys: str = ""  # config keys / readings that address it
    checks: tuple[Check, ...] = ()
    readings: bool = False
    test: str | None = None
    input: bool = False
    not_attempted: str | None = None
    notes: str = ""
    # the modelling choices the verdict depends on (each named in the row with the number without it)
    choices: tuple[Choice, ...] = ()
    # non-empty: the claim is checked only as an ordering on a metric we chose, not on a printed number; says
    # what the ordering leaves out (the weaker class "an ordering holds")
    ordering: str = ""

    @property
    def doc(self) -> str:
        return self.id.split(":", 1)[0]

    def __post_init__(self):
        doc, _, rest = self.id.partition(":")
        if doc not in DOCUMENTS or not rest or "-" not in rest:
            raise ValueError(f"{self.id}: not <doc>:<kind>-<number>")
        ways = [bool(self.readings or self.checks), self.test is not None, self.input,
                self.not_attempted is not None]
        if sum(ways) != 1:
            raise ValueError(f"{self.id}: give exactly one of readings/checks, test, input, not_attempted")
        if any(c.exp != self.exp for c in self.checks):
            raise ValueError(f"{self.id}: a check names another experiment than the claim's")


@dataclass(frozen=True)
class Qualitative:
    id: str
    what: str
    doc: str = field(init=False)

    def __post_init__(self):
        object.__setattr__(self, "doc", self.id.split(":", 1)[0])



# How far a reading, or a modelling choice, departs from the document (strongest first): the text as printed;
# a reading the text supports (the row says where); a value the text does not print; a reading that contradicts
# what the text prints.
SUPPORT = ("printed", "supported", "unprinted", "contradicts")


@dataclass(frozen=True)
class Choice:
    """A modelling choice a claim's verdict depends on, named in its row with the number without it.

    ``support``: one of ``SUPPORT``; ``where``: the document's place that supports it or that it departs from;
    ``without``: what we find without the choice (the number, or a sentence)."""

    name: str
    support: str
    where: str
    without: str
    key: str | None = None  # path of the number without it in the run's results, shown beside ``without``

    def __post_init__(self):
        if self.support not in SUPPORT:
            raise ValueError(f"{self.name}: support {self.support!r} not in {SUPPORT}")


def _below(exp, a, b, label, **kw):
    return Check(exp, "below", a, label, other=b, **kw)
