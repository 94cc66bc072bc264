"""How far each readings row departs from the document, and the thresholds its numbers are decided against.

``experiments/fidelity/index.py`` gives every row of ``docs/fidelity/*.json`` a field ``support`` (one of
``claim_types.SUPPORT``: printed, supported, unprinted, contradicts) and ``support_where`` from the
rules below, and re-decides a row's ``holds`` on the 95% intervals printed in its ``ours`` where a threshold is
listed here (a readings study decides on points; an interval across the threshold is undecided).

A row's reading is often several choices at once ("Lagrangian model, published P squared"): every rule whose
pattern matches applies, and the row gets the weakest of them. A row that no rule matches is "unclassified"
(the tests refuse that for every committed row).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from experiments.fidelity.checks import run_size
from experiments.fidelity.claim_types import SUPPORT


@dataclass(frozen=True)
class Rule:
    claim: str  # a claim id, or the prefix of its part ids
    pattern: str  # regex searched in the row's reading
    support: str
    where: str

    def __post_init__(self):
        if self.support not in SUPPORT:
            raise ValueError(f"{self.claim}: support {self.support!r} not in {SUPPORT}")


@dataclass(frozen=True)
class RowThreshold:
    """Every ``value [lo, hi]`` that ``pattern`` finds in a row's ``ours`` (groups: value, lo, hi; or the value
    alone where the row prints no interval) must lie on the claim's side: ``ge``/``le`` ``value`` on the whole
    interval, or ``within`` (``value``, ``upper``)."""

    claim: str
    pattern: str
    rule: str
    value: float
    label: str
    upper: float | None = None
    readings: str = ""  # regex: only rows whose reading matches (default: all)


_LORENZ = ("thesis:fig-1.1", "thesis:claim-1.6-ekf2", "thesis:fig-1.2")
_DMSO = ("stumfoll:fig-8.2", "stumfoll:claim-8.1.1-25pct", "stumfoll:fig-8.6", "stumfoll:fig-8.7",
         "stumfoll:fig-8.11", "stumfoll:fig-8.13", "stumfoll:claim-8.1.3-position")
_NOISE_TEXT = "§1.6 gives sigma_eta 0.1, sigma_eps 5 at h = 0.001 without saying per step or per unit time"

RULES: tuple[Rule, ...] = (
    # ---- Lorenz (thesis §1.6)
    *(Rule(c, r"^printed", "printed", "sigma as a standard deviation per sample, the EKF given the true noise "
           "(§1.6)") for c in _LORENZ),
    *(Rule(c, r"\((filtered|prediction|mixed)\)", "supported", "§1.6 does not say whether e compares the "
           "filtered or the predicted estimate") for c in _LORENZ),
    *(Rule(c, r"variance", "contradicts", "sigma_eta, sigma_eps name standard deviations; read as variances")
      for c in _LORENZ),
    *(Rule(c, r"^EKF Q per unit time", "contradicts", "the EKF's Q per unit time gives it a noise 1000x smaller "
           "than the 'true noise parameters' §1.6 says it uses") for c in _LORENZ),
    *(Rule(c, r"^(data|both) per unit time", "supported", _NOISE_TEXT) for c in _LORENZ),
    # ---- DIP (thesis ch. 1-3, paper)
    *(Rule(c, r"^default", "printed", "the equations and Table 3.3 as printed (Mw on the cart)")
      for c in ("paper:table-1", "thesis:table-3.2")),
    *(Rule(c, r"\(3\.7\) printed", "printed", "the weight of (3.7)/(9) as printed")
      for c in ("paper:table-1", "thesis:table-3.2")),
    *(Rule(c, r"disturbance|offset|encoders|deadzone|backlash|Coulomb", "unprinted", "input disturbance, encoder "
           "resolution, deadzone, backlash or cart friction: values the documents do not print")
      for c in ("paper:table-1", "thesis:table-3.2")),
    Rule("thesis:table-3.1", r"library P", "unprinted", "the library's P, not (3.6) that §3.2.2 uses"),
    Rule("thesis:table-3.1", r"Lagrangian model", "contradicts", "the Lagrangian model; the thesis simulates the "
         "printed equations of §3.1.1"),
    Rule("thesis:table-3.1", r"published P squared", "contradicts", "P built as squares, not by (2.20)"),
    Rule("thesis:table-3.1", r"var of", "supported", "Table 3.1 does not say variance of the signal or of |.|"),
    Rule("thesis:procedure-1", r"^default|noise variance", "supported", "§3.2.1's N(0, 5 x 10^-5) does not say "
         "std or variance"),
    Rule("thesis:procedure-1", r"x0 per member", "supported", "Procedure 1: one initial state per member"),
    Rule("thesis:claim-3.2.1-one-vector", r"one free vector", "supported", "§3.2.1: one free vector, its "
         "singular value 1e6"),
    Rule("thesis:claim-3.2.1-one-vector", r"x0 per member", "supported", "Procedure 1: one initial state per "
         "member"),
    Rule("thesis:thm-1.3.2", r"growing gamma_k", "supported", "gamma_k growing as Theorem 1.3.2 asks"),
    Rule("thesis:prop-1.4.1", r"growing gamma_k", "supported", "gamma_k growing as Theorem 1.3.2 asks"),
    Rule("thesis:prop-2.4.2", r"P = LQR Riccati", "supported", "Prop. 2.4.2 holds for any admissible P; the "
         "Riccati P of the DIP linearisation is one instance"),
    Rule("thesis:claim-2.7.2-v", r"^(default --quick|printed scale)", "printed", "§2.7.2: J = 100, K = 4"),
    Rule("thesis:claim-2.7.2-v", r"noise as std|x0 per member|stabilising near", "supported", "§2.7.2 does not "
         "fix the noise reading, the initial states or the judge"),
    Rule("thesis:claim-2.7.2-v", r"500 iterations|K = 8|best member", "contradicts", "§2.7.2 prints about 250 "
         "iterations, K = 4 and the ensemble mean"),
    Rule("thesis:claim-2.7.2-v", r"initial spread", "unprinted", "an initial spread the text does not print"),
    Rule("thesis:eq-3.6", r"^default", "printed", "the printed model and (3.6) with (2.20) as printed"),
    Rule("thesis:eq-3.6", r"Mw = 0|gamma = 10", "supported", "Table 3.3 lists Mw that the equations leave "
         "out; §3.2.1 searches with gamma 10"),
    Rule("thesis:eq-3.6", r"order|flip|angles|units", "supported", "(3.6) does not say the state order, signs, "
         "angle reference or units of v1, v2"),
    Rule("thesis:eq-3.6", r"construction", "unprinted", "a construction of P from (v, s) other than (2.20)"),
    Rule("thesis:eq-3.6", r"variant = lagrangian", "contradicts", "the Lagrangian model; the thesis simulates "
         "the printed equations of §3.1.1"),
    # ---- TWIP (Stumfoll)
    *(Rule(c, r"kf_printed|Gamma 0\.1 \(175\)|Table 7\.1 as variances", "printed", "(170) and (175) as printed, "
           "Table 7.1's sigma^2 as variances") for c in _DMSO),
    *(Rule(c, r"(^|; )kf(;|$)|kf_posterior", "supported", "the KF's prediction or posterior, which (170) "
           "leaves open") for c in _DMSO),
    *(Rule(c, r"Gamma 0\.5|dt_fine_gamma|coarse Gamma 0\.5|fine Gamma 0\.5", "contradicts", "Gamma 0.5 is Fig. "
           "8.9's variant; the runs this claim describes use Gamma 0.1 (175)") for c in _DMSO
      if c not in ("stumfoll:fig-8.11",)),
    Rule("stumfoll:fig-8.11", r"coarse Gamma 0\.1 / fine Gamma 0\.1", "printed", "Gamma 0.1 (175) at both "
         "periods"),
    Rule("stumfoll:fig-8.11", r"Gamma 0\.5", "supported", "the text comes to dt = 0.001 s right after Fig. "
         "8.9's Gamma 0.5"),
    *(Rule(c, r"x0 only", "printed", "the printed x0 without our spread") for c in _DMSO),
    *(Rule(c, r"RMS|rms|peak|mean|median|convergence time|after 5 s|last 5 s|rel_|over_peak",
           "supported", "the text names no error metric; the row's metric is ours") for c in _DMSO),
    *(Rule("stumfoll:claim-8.1.1-25pct", p, "contradicts", "'up to 25%' prints the largest error; an average is "
           "not it") for p in (r"rel_rms", r"rms_over_peak", r"mean_abs_rel", r"median_pointwise")),
    Rule("stumfoll:claim-8.1.1-25pct", r"one_step|estimated|open_loop", "supported", "f of (153) evaluated "
         "one of three ways the text leaves open"),
    *(Rule(c, r"noise|gyro sigma_r\^2 read as a std", "supported", "Table 7.1 noise read as printed, scaled, or "
           "sigma_r^2 as a std") for c in ("stumfoll:fig-8.13", "stumfoll:claim-8.1.3-position")),
    *(Rule(c, r"biases stationary", "supported", "the bias walk's start, which §7.4 leaves open")
      for c in ("stumfoll:fig-8.13", "stumfoll:claim-8.1.3-position")),
    Rule("stumfoll:claim-8.1-15s", r"^(dmso|kf)", "supported", "which estimator feeds the LQR, and how 'reaching "
         "the desired states' is banded: the text says neither"),
    Rule("stumfoll:claim-8.1.2-5deg", r"^(dmso|kf)$", "supported", "which estimator feeds the LQR"),
    Rule("stumfoll:fig-5.5", r"printed model", "printed", "(72)-(73) as printed, 0 V"),
    Rule("stumfoll:fig-7.1", r"Table 7\.1 read as|quantised position", "printed", "Table 7.1 as printed"),
    *(Rule(c, r"Table 7\.1 read as", "unprinted", "Fig. 7.1 compares with a measured Allan curve whose numbers "
           "are not printed; the row checks the simulated sensor against Table 7.1's law")
      for c in ("stumfoll:fig-7.1-tilt", "stumfoll:fig-7.1-gyro")),
    Rule("aranovskiy:remark-3", r"^d_r", "supported", "Remark 3 holds for any constant d_r; three sizes"),
    Rule("stumfoll:table-8.3", r"^default", "printed", "Tables 8.1-8.2 and the printed gains"),
    Rule("stumfoll:table-8.3", r"printed backlash|deadzone on Table 8\.1", "supported", "§8.2 leaves which "
         "parameter table the nonlinear cases start from open"),
    Rule("stumfoll:table-8.3", r"k1=", "unprinted", "the gain k1, which §8.2 does not print"),
    Rule("stumfoll:table-8.3", r"virtual=printed", "printed", "the virtual control as printed"),
    Rule("stumfoll:table-8.3", r"virtual=effective", "supported", "the virtual control the printed one stands "
         "for"),
    Rule("stumfoll:table-8.3", r"virtual_sign=-1", "contradicts", "the virtual control with its sign flipped"),
    Rule("stumfoll:fig-8.18", r"^default", "supported", "a spread around the printed x0 (184)"),
    Rule("stumfoll:fig-8.18", r"x0 of \(184\) exactly", "printed", "the printed x0 (184)"),
    Rule("stumfoll:fig-8.18", r"sin in degrees", "supported", "(184)'s disturbance sin with its argument in "
         "degrees"),
    Rule("stumfoll:fig-8.18", r"gains swapped|virtual_sign=-1", "contradicts", "the unmodelled gains 3/4, 2/5 "
         "swapped, or the virtual control's sign flipped"),
    Rule("stumfoll:fig-8.18", r"virtual=printed", "printed", "the virtual control as printed"),
    Rule("stumfoll:fig-8.18", r"virtual=effective|gamma=\[0\.0", "supported", "the virtual control the printed "
         "one stands for; gamma off"),
    Rule("stumfoll:fig-8.18", r"k1=|gamma=\[1\.0", "unprinted", "the gain k1 (or gamma = 1), which §8.2 does not "
         "print"),
    Rule("aranovskiy:fig-3", r"^default|sampled observers|zero initial velocities|settle band", "supported",
         "Table 2's parameters; the settle band and the initial velocities are ours"),
    Rule("aranovskiy:fig-3", r"limit|clipped", "unprinted", "a current limit the paper does not print"),
    Rule("aranovskiy:fig-3", r"L matched|L = the HOMD|fast L", "unprinted", "a Luenberger gain the paper does "
         "not print"),
)

_CI = r"(-?[\d.e+-]+) \[(-?[\d.e+-]+), (-?[\d.e+-]+)\]"
THRESHOLDS: tuple[RowThreshold, ...] = (
    RowThreshold("stumfoll:fig-8.18", r"LQR fell " + _CI, "ge", 0.1, "LQR falls in at least 10%"),
    RowThreshold("stumfoll:fig-8.18", r"LQR \+ extra up " + _CI, "ge", 0.95, "LQR + extra keeps at least 95% up"),
    *(RowThreshold(c, r"stabilised fraction " + _CI, "ge", 0.95, "stabilised fraction at least 0.95")
      for c in ("thesis:procedure-1", "thesis:claim-3.2.1-one-vector")),
    # "up to 25%": the largest error is about 25% (within a factor of two), not at most 25%
    RowThreshold("stumfoll:claim-8.1.1-25pct", r"(?:x_dot|phi_dot) " + _CI, "within", 0.125,
                 "largest relative error between 12.5% and 50% ('up to 25%')", upper=0.5,
                 readings=r"peak_over_peak"),
    # "an order of magnitude" / "two orders of magnitude" as numbers, within a factor of two (the rows print
    # the mean ratio as a point)
    RowThreshold("stumfoll:fig-8.6", r"^mean (\S+) \(", "within", 5.0, "mean ratio about 10 (5 to 20)",
                 upper=20.0),
    RowThreshold("stumfoll:fig-8.11", r"^(\S+) \(x_dot", "within", 50.0, "ratio about 100 (50 to 200)",
                 upper=200.0),
)

# Rows of one claim id that measure different statements of the claim (not alternative readings of one): the
# part each belongs to, by its ``what``, so that the claim holds only when every part holds.
PARTS: tuple[tuple[str, str, str], ...] = (
    ("thesis:table-3.1", r"smallest mean \|alpha\|", "states-mean"),
    ("thesis:table-3.1", r"smallest variance of", "states-variance"),
    ("thesis:table-3.1", r"mean \|u\|", "u-mean"),
    ("thesis:table-3.1", r"variance of u", "u-variance"),
)

RANK = {s: i for i, s in enumerate(SUPPORT)}


def _applies(claim_prefix: str, row_claim: str) -> bool:
    return row_claim == claim_prefix or row_claim.startswith(claim_prefix + "-")


def support_of(row: dict) -> tuple[str, str]:
    """(support, where) of a row: the weakest of the rules that match its reading; ("unclassified", "")."""
    hits = [r for r in RULES if _applies(r.claim, row["claim"]) and re.search(r.pattern, row["reading"])]
    if not hits:
        return "unclassified", ""
    worst = max(RANK[r.support] for r in hits)
    return SUPPORT[worst], "; ".join(dict.fromkeys(r.where for r in hits if RANK[r.support] == worst))


def _interval_side(v: float, lo: float, hi: float, t: RowThreshold) -> str:
    if t.rule == "within":
        if t.value <= lo and hi <= t.upper:
            return "yes"
        return "no" if hi < t.value or lo > t.upper else "undecided"
    above = t.rule == "ge"
    if (lo >= t.value) if above else (hi <= t.value):
        return "yes"
    if (hi < t.value) if above else (lo > t.value):
        return "no"
    return "undecided"


def threshold_verdict(row: dict) -> tuple[str, str] | None:
    """(holds, why) of a row re-decided on the intervals in its ``ours``; None when no threshold applies."""
    verdicts, why = [], []
    for t in THRESHOLDS:
        if not _applies(t.claim, row["claim"]) or (t.readings and not re.search(t.readings, row["reading"])):
            continue
        for m in re.finditer(t.pattern, row["ours"]):
            g = [float(x) for x in m.groups()]
            v, lo, hi = g if len(g) == 3 else (g[0], g[0], g[0])
            h = _interval_side(v, lo, hi, t)
            verdicts.append(h)
            if h == "undecided" and t.rule != "within":
                # the sample size printed right after the interval, as in "(96/100)"
                n = re.match(r" \((\d+)/(\d+)\)", row["ours"][m.end():])
                why.append(f"{t.label}: {run_size(int(n.group(2)) if n else None, v, lo, hi, t.value)}")
            elif h != "yes":
                why.append(f"{t.label}: " + (f"[{lo:.4g}, {hi:.4g}]" if len(g) == 3 else f"{v:.4g}") + f" {h}")
    if not verdicts:
        return None
    holds = "yes" if all(v == "yes" for v in verdicts) else "no" if "no" in verdicts else "undecided"
    return holds, "; ".join(why)


def annotate(row: dict) -> dict:
    """The row with ``support``, ``support_where`` and, where a threshold applies, ``holds`` decided on its
    intervals (the study's own verdict kept as ``holds_study`` when it differs)."""
    support, where = support_of(row)
    out = {**row, "support": support, "support_where": where}
    for claim, what, part in PARTS:
        if row["claim"] == claim and re.search(what, row["what"]):
            out["claim"] = f"{claim}-{part}"
            break
    tv = threshold_verdict(row) if row["holds"] != "n/a" else None
    if tv is not None and tv[0] != row["holds"]:
        out.update(holds=tv[0], holds_study=row["holds"], holds_why=tv[1])
    return out


@dataclass(frozen=True)
class Study:
    """One reading reported first for every claim of a readings study, and which per-claim readings exclude
    each other."""

    title: str
    reading: str
    claims: tuple[str, ...]
    text: str
    exclusive: str


STUDIES: tuple[Study, ...] = (
    Study("Lorenz study (thesis §1.6)", "printed (filtered)",
          ("thesis:fig-1.1-norm", "thesis:fig-1.1-xL", "thesis:claim-1.6-ekf2", "thesis:fig-1.2"),
          "The one reading that takes §1.6 at its word: sigma_eta = 0.1 and sigma_eps = 5 are standard deviations "
          "per sample (h = 0.001), the EKF is given exactly these ('the true noise parameters'), EKF2 sigma_eta = "
          ".005, sigma_eps = 10, and the error compares the filtered estimate. Under it none of the four claims "
          "holds: the EKF has the smallest norm error and the smallest x_L error, and EKF2 is worse than the EKF.",
          "The per-claim readings cannot all hold at once (every reading against every claim below). CPX and SCPX "
          "beat the EKF (fig-1.1-norm, fig-1.2) only when the EKF's Q is per unit time, a noise 1000x smaller "
          "than the true noise it is said to use (contradicts the text), and under that reading EKF2 is worse "
          "than the EKF; EKF2 beats the EKF on x_L (claim-1.6-ekf2) only with the data's noise per unit time, "
          "under which the EKF beats CPX and SCPX. No single reading makes the EKF claims and the EKF2 claim "
          "hold together, and SCPX's smallest x_L error (fig-1.1-xL) holds under none."),
)
