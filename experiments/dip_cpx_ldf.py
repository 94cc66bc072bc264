"""dip-cpx-ldf from Python: the same run as `jaxdip run dip-cpx-ldf`, for people who read code before a CLI.

    python experiments/dip_cpx_ldf.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("dip-cpx-ldf")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/dip-cpx-ldf")
    r = metrics["results"]
    for est in ("cpx", "ldf"):
        e = r[est]
        print(f"{est}: theta var {e['theta_var']:.4g} deg^2, alpha var {e['alpha_var']:.4g} deg^2, "
              f"xc var {e['xc_var']:.4g} cm^2, diverged {e['diverged']}")
    print(f"gamma criterion (Prop. 1.4.3): {r['gamma_criterion']['gamma']:.1f} (thesis 24400)")
