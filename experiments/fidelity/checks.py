"""How one ``Check`` of the fidelity inventory is decided on a run's ``metrics.json`` results: the rules of
``claim_types.Check``, on 95% intervals where the results have them (``experiments/fidelity/index.py``
turns the verdicts into the status column of ``docs/fidelity.md``)."""

from __future__ import annotations

import math

from experiments.fidelity import claim_types as FC


def get(results: dict, path: str):
    """The value at ``a/b/c`` in nested dicts (an integer step indexes a list). KeyError when absent."""
    cur = results
    for step in path.split("/"):
        if isinstance(cur, list):
            try:
                cur = cur[int(step)]
            except (ValueError, IndexError):
                raise KeyError(path) from None
        elif isinstance(cur, dict) and step in cur:
            cur = cur[step]
        else:
            raise KeyError(path)
    return cur


def _interval(results: dict, path: str, explicit: str | None):
    """The 95% interval of the value at ``path``: at ``explicit``, else the sibling ``<path>_ci95``, else, for a
    per-state value ``a/name/state``, at ``a/name_ci95/state`` (how the experiments store per-state intervals)."""
    head, _, last = path.rpartition("/")
    candidates = [explicit] if explicit else [f"{path}_ci95"] + ([f"{head}_ci95/{last}"] if head else [])
    for c in candidates:
        try:
            ci = get(results, c)
            break
        except KeyError:
            continue
    else:
        return None
    if (isinstance(ci, list) and len(ci) == 2 and all(isinstance(x, (int, float)) for x in ci)
            and not any(math.isnan(x) for x in ci)):
        return float(ci[0]), float(ci[1])
    return None


def fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "none"
    if isinstance(v, (int, float)):
        return f"{v:.4g}"
    return str(v)


def _with_ci(v, ci) -> str:
    return fmt(v) + (f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci else "")


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v)


def run_size(n: int | None, v: float, lo: float, hi: float, threshold: float) -> str:
    """Why an interval across a threshold is undecided, and about how many samples would decide it: the
    interval's half-width on the threshold's side scales as 1/sqrt(n), so it clears the threshold (if the point
    stays) at n (half-width / distance)^2."""
    d = abs(v - threshold)
    h = (v - lo) if v >= threshold else (hi - v)
    text = f"interval [{lo:.4g}, {hi:.4g}] across {threshold:.4g}"
    if d == 0 or not n:
        return text + ("; the point sits on it" if d == 0 else "")
    return text + f"; about {math.ceil(n * (h / d) ** 2)} samples would decide it (now {n})"


def _side(v, ci, threshold, above: bool, n) -> tuple[str, str]:
    """ours >= threshold (``above``) or <= threshold, decided on the interval when there is one."""
    if ci is None:
        ok = v >= threshold if above else v <= threshold
        return ("yes" if ok else "no"), ""
    lo, hi = ci
    if (lo >= threshold) if above else (hi <= threshold):
        return "yes", ""
    if (hi < threshold) if above else (lo > threshold):
        return "no", ""
    return "undecided", run_size(n, v, lo, hi, threshold)


def evaluate(check: FC.Check, results: dict, seeds: int | None = None) -> tuple[str, str]:
    """(holds: yes/no/undecided, our number as text) of one check on a run's ``results``; ``seeds``: the run's
    sample size, for the run size that would decide an interval across a threshold."""
    try:
        v = get(results, check.key)
    except KeyError:
        return "undecided", f"{check.label}: no value ({check.key} is absent: a statistic over no seed, e.g. none settled within the run)"
    ci = _interval(results, check.key, check.ci)
    ours = _with_ci(v, ci)
    w = wci = None
    if check.other is not None:
        try:
            w = get(results, check.other)
        except KeyError:
            return "undecided", f"{check.label}: no value ({check.other} is absent: a statistic over no seed)"
        wci = _interval(results, check.other, check.other_ci)
        ours += " vs " + _with_ci(w, wci)
    text = f"{check.label}: {ours}"
    rule = check.rule
    if rule in ("true", "false"):
        if not isinstance(v, bool):
            return "undecided", text
        return ("yes" if v == (rule == "true") else "no"), text
    if not _number(v) or (check.other is not None and not _number(w)):
        return "undecided", text
    n = seeds
    if check.n is not None:
        try:
            n = int(get(results, check.n))
        except (KeyError, TypeError, ValueError):
            n = None

    def decided(verdict, why):
        return verdict, text + (f" ({why})" if why else "")

    if rule == "close":
        target = check.value if check.other is None else w
        band = (target - check.tol * abs(target), target + check.tol * abs(target))
        if ci is None:
            return ("yes" if band[0] <= v <= band[1] else "no"), text
        if band[0] <= ci[0] and ci[1] <= band[1]:
            return "yes", text
        if ci[1] < band[0] or ci[0] > band[1]:
            return "no", text
        edge = band[0] if ci[0] < band[0] else band[1]
        return decided("undecided", run_size(n, v, *ci, edge))
    if rule == "in_ci":
        if ci is None:
            return "undecided", text
        return ("yes" if ci[0] <= check.value <= ci[1] else "no"), text
    if rule in ("ge", "le"):
        return decided(*_side(v, ci, check.value, rule == "ge", n))
    if rule == "ratio_ge":
        if w == 0:
            return "undecided", text
        text += f" (ratio {v / w:.3g})"
        if ci is not None and wci is not None and wci[0] > 0:
            rci = (ci[0] / wci[1], ci[1] / wci[0])
            text = text[:-1] + f", [{rci[0]:.3g}, {rci[1]:.3g}])"
            return decided(*_side(v / w, rci, check.value, True, n))
        return ("yes" if v / w >= check.value else "no"), text
    # below: intervals where both have one, else the points
    a = ci or (v, v)
    b = wci or (w, w)
    return ("yes" if a[1] < b[0] else "no" if a[0] > b[1] else "undecided"), text


def combine(verdicts: list[str]) -> str:
    if verdicts and all(v == "yes" for v in verdicts):
        return "yes"
    return "no" if "no" in verdicts else "undecided"
