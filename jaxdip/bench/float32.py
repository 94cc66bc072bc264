"""The float32 study: which experiments' Monte Carlo loops keep their statistics in float32, and how much faster
they run. ``python -m jaxdip.bench.float32 [--only ID,...] [--repeats R] [--json FILE]``.

Each experiment of ``STUDY`` runs in this one process at its ``--quick`` config with the study's overrides
(more seeds where the quick intervals are too wide to say anything), once with ``precision = "float64"`` and
once with ``"float32"`` (its ``precision`` config key: the Monte Carlo loops in float32, the designs in
float64; ``jd.Loop.precision``). An experiment the study found unsafe has no key: its Monte Carlo loops are
then set to float32 where they enter ``jd.monte_carlo``. ``SCENARIOS`` are loops studied outside their
experiment. Every reported statistic ``X`` with a 95% interval ``X_ci95`` is compared:

- ``inside``: the float32 value lies in the float64 interval;
- ``overlap``: the two intervals overlap.

A loop is *safe* when every statistic is inside and every pair of intervals overlaps. The float32 loop draws
its noise in float32, another random stream than float64's: the two runs are independent samples of the same
statistics, so a statistic of an exact float32 loop still leaves the float64 95% interval in about one case
in six (the difference of two independent estimates has sqrt(2) times their spread); the count of such cases
over all statistics is what to read, next to the size of the differences (``z``: the difference over the
float64 interval's half-width).

Speed: after the first (compiling) run of each precision, ``repeats`` more runs alternate float64 and float32,
each timed in process CPU time (all threads); the ratio is median(float32) / median(float64) of the whole
experiment run (loops, analysis and figures: the analysis costs the same in both, so the ratio understates the
loops' own gain). On a machine shared with other work, trust these ratios, measured in one process, over any
absolute time.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import statistics
import time

# the study's scale per experiment: overrides on top of --quick where its intervals are too wide to test
STUDY: dict[str, dict] = {
    "dip-lqr": {"seeds": 256},
    "dip-controllers": {"seeds": 128},
    "rwp-remark3": {"seeds": 64},
    "rwp-bias": {"seeds": 64},
    "lorenz-mhe": {"seeds": 64},  # base seed 0, the default: 7 of 16 outside (base seed 1: 0)
    "dip-cpx-ldf": {"seeds": 64, "sweep_seeds": 16},
    "eki-dip-judge": {},
}


def _flat(x, prefix=""):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _flat(v, f"{prefix}.{k}" if prefix else str(k))
    else:
        yield prefix, x


def _number(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v)


def interval_statistics(results: dict) -> dict[str, tuple[float, float, float]]:
    """name -> (value, lo, hi) for every ``name`` of ``results`` (flattened with dots) that has a sibling
    ``name_ci95`` holding a [lo, hi] pair (or, where ``name`` is absent, ``name_mean`` beside ``name_ci95``)."""
    flat = dict(_flat(results))
    out = {}
    for key, ci in flat.items():
        if not key.endswith("_ci95") or not isinstance(ci, (list, tuple)) or len(ci) != 2:
            continue
        name = key[: -len("_ci95")]
        if name not in flat and f"{name}_mean" in flat:  # "error_ci95" beside "error_mean"
            name = f"{name}_mean"
        v, lo, hi = _number(flat.get(name)), _number(ci[0]), _number(ci[1])
        if v is not None and lo is not None and hi is not None:
            out[name] = (v, lo, hi)
    return out


def compare(r64: dict, r32: dict) -> list[dict]:
    """One row per statistic with an interval in both: the values, the float64 interval, ``inside``,
    ``overlap`` and ``z`` (|float32 - float64| over the float64 interval's half-width; 0 for a zero width and
    no difference)."""
    s64, s32 = interval_statistics(r64), interval_statistics(r32)
    rows = []
    for name in s64:
        if name not in s32:
            continue
        (v, lo, hi), (w, lo32, hi32) = s64[name], s32[name]
        finite = all(math.isfinite(a) for a in (v, lo, hi, w, lo32, hi32))
        if not finite and [str(a) for a in (v, lo, hi)] == [str(a) for a in (w, lo32, hi32)]:
            continue  # undefined alike in both (a settle time never reached: NaN): nothing to compare
        half = (hi - lo) / 2
        diff = abs(w - v)
        z = (0.0 if diff == 0 else math.inf) if half == 0 else diff / half
        rows.append({"statistic": name, "float64": v, "ci95": [lo, hi], "float32": w, "ci95_float32": [lo32, hi32],
                     "inside": bool(finite and lo <= w <= hi) or (v == w),
                     "overlap": bool(finite and lo <= hi32 and lo32 <= hi) or (v == w), "z": z})
    return rows


JUDGE_SEEDS = 256


def eki_dip_judge(precision: str, seeds: int = JUDGE_SEEDS, duration: float = 2.0) -> dict:
    """eki-dip's judge loop (``jaxdip.scenarios.eki_dip.judge_rollout``: (2.14) with gamma = 40 on the printed
    DIP, exact state measurement, state noise) with the weight P = P_v(v_LQR, 1e6) (singular values 1e6 and 1:
    the ill-conditioned weight the search works with), summarised as eki-dip summarises its judge."""
    import jax

    import jaxdip as jd
    from jaxdip.control.spd import P_v
    from jaxdip.plants import dip
    from jaxdip.runner.summaries import loop_summary
    from jaxdip.scenarios import eki_dip as S

    plant = S.plant()
    A, B = jd.linearize(plant)
    r = jd.with_precision(S.judge_rollout(P_v(S.lqr_direction(A, B), 1e6), duration=duration), precision)
    sol = jd.monte_carlo(r, jax.random.PRNGKey(0), seeds)
    return loop_summary(sol, dip.STATE_NAMES, (1, 2), 0.02, dt=0.001, bound=S.STATE_BOUND)


# loops studied outside their experiment: the eki-dip experiment runs a whole search before its judge
SCENARIOS = {"eki-dip-judge": eki_dip_judge}


def _config(exp, overrides: dict, precision: str):
    from jaxdip import config as C

    keyed = any(f.name == "precision" for f in dataclasses.fields(exp.config_cls))
    cfg = C.load(exp.config_cls, quick={**exp.quick, **overrides, **({"precision": precision} if keyed else {})})
    if hasattr(cfg, "validate"):
        cfg.validate()
    return cfg


@contextlib.contextmanager
def _loops_at(precision: str, cfg):
    """For an experiment without a ``precision`` key (one not found safe): every loop its ``jd.monte_carlo``
    calls receive runs at ``precision``, so the study can still measure it."""
    import jaxdip as jd

    if hasattr(cfg, "precision") or precision == "float64":
        yield
        return
    real = jd.monte_carlo
    jd.monte_carlo = lambda fn, *a, **kw: real(jd.with_precision(fn, precision), *a, **kw)
    try:
        yield
    finally:
        jd.monte_carlo = real


def _run(exp, cfg, precision: str) -> tuple[dict, float]:
    import matplotlib.pyplot as plt

    t0 = time.process_time()
    with _loops_at(precision, cfg):
        outcome = exp.run(cfg, None)
    cpu = time.process_time() - t0
    for fig in outcome.figures.values():
        plt.close(fig)
    return outcome.results, cpu


def _scenario_run(fn, precision: str) -> tuple[dict, float]:
    t0 = time.process_time()
    results = fn(precision)
    return results, time.process_time() - t0


def study(exp_id: str, overrides: dict | None = None, repeats: int = 3) -> dict:
    """Run one experiment (or ``SCENARIOS`` entry) in float64 and float32 (its ``precision`` key), compare its
    interval statistics and time ``repeats`` interleaved runs of each: the study's record of that experiment."""
    from jaxdip.runner import get

    overrides = STUDY.get(exp_id, {}) if overrides is None else overrides
    if exp_id in SCENARIOS:
        runs = {p: (lambda p=p: _scenario_run(SCENARIOS[exp_id], p)) for p in ("float64", "float32")}
        seeds = JUDGE_SEEDS
    else:
        exp = get(exp_id)
        cfgs = {p: _config(exp, overrides, p) for p in ("float64", "float32")}
        runs = {p: (lambda cfg=cfg, p=p: _run(exp, cfg, p)) for p, cfg in cfgs.items()}
        seeds = getattr(cfgs["float64"], "seeds", None)
    results, cpu = {}, {"float64": [], "float32": []}
    for p, run in runs.items():
        results[p], _ = run()  # compiles
    for _ in range(repeats):
        for p, run in runs.items():
            cpu[p].append(run()[1])
    rows = compare(results["float64"], results["float32"])
    med = {p: statistics.median(t) for p, t in cpu.items() if t}
    return {
        "experiment": exp_id, "overrides": overrides, "seeds": seeds,
        "statistics": len(rows), "outside": sum(not r["inside"] for r in rows),
        "disjoint": sum(not r["overlap"] for r in rows),
        "safe": bool(rows) and all(r["inside"] and r["overlap"] for r in rows),
        "max_z": max((r["z"] for r in rows), default=None),
        "cpu_s": cpu, "cpu_ratio_f32_f64": (med["float32"] / med["float64"]) if len(med) == 2 else None,
        "rows": rows,
    }


def table(records: list[dict]) -> str:
    """The per-experiment markdown table of the study."""
    lines = ["| experiment | seeds | statistics | outside f64 CI | disjoint CIs | max z | CPU f32/f64 | safe |",
             "|---|---|---|---|---|---|---|---|"]
    for r in records:
        ratio = "" if r["cpu_ratio_f32_f64"] is None else f"{r['cpu_ratio_f32_f64']:.2f}"
        mz = "" if r["max_z"] is None else f"{r['max_z']:.2f}"
        lines.append(f"| {r['experiment']} | {r['seeds']} | {r['statistics']} | {r['outside']} | {r['disjoint']} | "
                     f"{mz} | {ratio} | {'yes' if r['safe'] else 'no'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m jaxdip.bench.float32", description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="", help="comma-separated experiment ids (default: all of STUDY)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per precision after the compiling one")
    ap.add_argument("--json", default=None, help="write every row to this file")
    args = ap.parse_args(argv)
    os.environ.setdefault("JAXDIP_NO_PROGRESS", "1")
    ids = [i for i in args.only.split(",") if i] or list(STUDY)
    unknown = [i for i in ids if i not in STUDY]
    if unknown:
        ap.error(f"not in the study: {', '.join(unknown)} (studied: {', '.join(STUDY)})")
    records = []
    for exp_id in ids:
        records.append(study(exp_id, repeats=args.repeats))
        print(table(records[-1:]).splitlines()[-1], flush=True)
    print(table(records))
    for r in records:
        for row in r["rows"]:
            if not (row["inside"] and row["overlap"]):
                print(f"{r['experiment']}: {row['statistic']} float64 {row['float64']:.6g} {row['ci95']} "
                      f"float32 {row['float32']:.6g} {row['ci95_float32']} z={row['z']:.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(records, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
