"""dip-lqr from Python: the same run as `jaxdip run dip-lqr`, for people who read code before a CLI.

    python experiments/dip_lqr.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("dip-lqr")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/dip-lqr")
    r = metrics["results"]
    print(f"stabilised {r['stabilized_fraction']:.4f} {r['stabilized_fraction_ci95']}, diverged {r['diverged']}")
