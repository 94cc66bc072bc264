"""ifn-protection from Python: the same run as `jaxdip run ifn-protection`, for people who read code before a CLI.

    python experiments/ifn_protection.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("ifn-protection")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/ifn-protection")
    r = metrics["results"]
    m = r["model"]
    print(f"R0 {m['R0_formula']:.4g}: Monte Carlo {m['R0_mc']:.4f} {m['R0_ci95']} from {m['virions']} virions")
    for cost, t in r["theorem"].items():
        print(f"h {cost}: r_bar {t['r_bar']:.4g}, level set cheapest against {t['level_set_cheapest_count']} "
              f"alternatives (ball +{100 * t['ball_extra_cost']:.1f}%)")
