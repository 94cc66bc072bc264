"""eki-dip's variant table (a helper of experiments.eki_dip; the leading underscore keeps the registry from looking
for experiments here): the config readings run beside the main search, through the table mechanism of
``experiments._eki_variants_table``.

Each reading changes the variant and the step schedule of the main config and keeps everything else (the
ensemble, the iteration budget and early stop, the forward model, the judge). A row: the iterations and forward
evaluations (simulations: members, or UKI's 2p + 1 sigma points, times initial states, per iteration) the search
took, how it ended (``status``: ``ok``, or the search's stopping status, e.g. ``not_finite`` when the update
diverged), and for a search that ended well the judge's stabilised fraction with its 95% interval and the mean
(2.24) on the common evaluation states; the search's wall time goes to ``timing``.
"""

from __future__ import annotations

from experiments._eki_variants_table import REFERENCE, fraction, run_readings, variants_table, wall_time

READINGS = {
    REFERENCE: {"variant": "eki", "schedule": "fixed"},
    "eki_adaptive_end1": {"variant": "eki", "schedule": "adaptive", "adaptive_end": 1.0},
    "eki_adaptive_end20": {"variant": "eki", "schedule": "adaptive", "adaptive_end": 20.0},
    # UKI moves one Gaussian: failed sigma points can only take the penalty
    "uki_fixed": {"variant": "uki", "schedule": "fixed", "failure": "penalty"},
}


def reading_key(cfg) -> str:
    """The row key of a config's own reading, e.g. ``eki_fixed`` or ``eki_adaptive_end20``."""
    key = f"{cfg.variant}_{cfg.schedule}"
    return key + (f"_end{cfg.adaptive_end:g}" if cfg.schedule == "adaptive" else "")


def row(iterations: int, points: int, n_x0: int, status: str, judged: dict | None = None,
        performance: dict | None = None) -> dict:
    """One row; ``judged`` (the judge's summary) and ``performance`` (the evaluation states' (2.24)) are None for
    a search that did not end well."""
    return {"iterations": iterations, "simulations": iterations * points * n_x0, "status": status,
            "stabilized_fraction": judged["stabilized_fraction"] if judged else None,
            "stabilized_fraction_ci95": judged["stabilized_fraction_ci95"] if judged else None,
            "performance": performance["mean"] if performance else None,
            "performance_failed": performance["failed"] if performance else None}


def compare(cfg, main: dict, main_wall: float, one) -> tuple[dict, dict]:
    """Rows and search wall times by key: the main search's own reading first (``main``, not repeated), then
    every other reading of ``READINGS`` as ``one(key, changed config) -> (row, wall)``."""
    key = reading_key(cfg)
    rows, walls = run_readings(cfg, {k: ch for k, ch in READINGS.items() if k != key}, one)
    return {key: main, **rows}, {key: main_wall, **walls}


def _number(name: str, fmt: str):
    return lambda key, r, wall: "-" if r.get(name) is None else format(r[name], fmt)


def table(cfg, rows: dict, walls: dict) -> list[str]:
    return variants_table(
        f"Variants, each reading one search with this config (J = {cfg.ensemble}, at most {cfg.iterations} "
        f"iterations, the same early stop), judged like the main search ({cfg.seeds} states) and scored on the "
        f"same {cfg.eval_states} evaluation states; adaptive: the data-misfit controller, ending at the algorithmic "
        "time given; wall time of the search alone, compilation included, under whatever load the machine had:",
        rows, walls,
        [("simulations", _number("simulations", "d")), ("iterations", _number("iterations", "d")),
         ("stabilised fraction [95% CI]", fraction("stabilized_fraction")),
         ("mean (2.24)", _number("performance", ".3g")), ("failed (2.24) runs", _number("performance_failed", "d")),
         ("status", lambda key, r, wall: r["status"]), ("search wall time (s)", wall_time)])
