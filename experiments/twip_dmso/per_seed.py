"""twip-dmso's per-seed data: each case and estimator's per-seed metrics (``summarize``'s inputs), on the case's
own seed dimension ``<case>_seed`` (the cases run different seed counts)."""

from __future__ import annotations

import numpy as np

from jaxdip.runner.per_seed import PerSeed, mean_of
from experiments.twip_dmso.report import STATES, UNCERTAIN_NAMES, UNITS

# metric key -> (results name, units: "state" for each state's own, "log" for a log of them, else the units)
PER_STATE = {"rms": ("rms_error", "state"), "rms_1s": ("rms_error_first_1s", "state"),
             "rms_tail": ("rms_error_tail", "state"), "peak_1s": ("peak_error_first_1s", "state"),
             "logmean_tail": ("logmean_error_tail", "log"), "conv": ("convergence_time_s", "s")}
PER_UNCERTAIN = {"unc_rms_err": ("uncertainty_rms_error", "uncertain"),
                 "unc_conv_10": ("uncertainty_convergence_time_s_10pct", "s"),
                 "unc_conv_25": ("uncertainty_convergence_time_s_25pct", "s")}


def per_seed(m: dict, div: np.ndarray, case: str, est: str) -> PerSeed:
    """The variables ``<case>.<est>.<results name>`` on (``<case>_seed``, state or uncertain)."""
    seed, at = f"{case}_seed", f"{case}.{est}."
    d = PerSeed(coords={"state": list(STATES), "state_units": ("state", list(UNITS)),
                        "uncertain": list(UNCERTAIN_NAMES)})
    d.add(at + "ok", (seed,), ~div, "1", "the seed's |phi| stayed within tilt_bound_deg and its state finite")
    rows = [(k, n, u, "state") for k, (n, u) in PER_STATE.items()]
    if est == "dmso":
        rows += [(k, n, u, "uncertain") for k, (n, u) in PER_UNCERTAIN.items()]
    for key, name, units, dim in rows:
        units = {"state": "state_units", "log": "log of state_units", "uncertain": "m/s or rad/s (the velocity rows)"}.get(units, units)
        d.add(at + name, (seed, dim), m[key], units, f"per-seed {name}",
              **mean_of(f"{at}{name}.{{{dim}}}", at + "ok", f"{at}{name}_ci95.{{{dim}}}"))
    return d
