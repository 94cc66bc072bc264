"""dip-controllers from Python: LQR vs power-series vs relaxed projection on the DIP (thesis Table 3.1, Fig. 3.3).

    python experiments/dip_controllers.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("dip-controllers")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    r = run_experiment(exp, cfg, "results/dip-controllers")["results"]
    for name in ("lqr", "ps", "rp", "rp_published"):
        print(f"{name:13s} stabilised {r[name]['stabilized_fraction']:.3f}")
    print("published P linearised max Re(eig):", r["published_P"]["linearised_max_real_eig"])
