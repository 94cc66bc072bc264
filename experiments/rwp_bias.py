"""rwp-bias from Python: the same run as `jaxdip run rwp-bias`, for people who read code before a CLI.

    python experiments/rwp_bias.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("rwp-bias")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/rwp-bias")
    r = metrics["results"]
    b = r["bias"]
    print(f"e_p2: {b['ep2_sim']:.4g} (15): {b['ep2_formula']:.4g}; theta_r': {b['thetar_dot_sim']:.4g} "
          f"(16): {b['thetar_dot_formula']:.4g}")
    print(f"gamma_d_bar {r['gamma_d_bar']:.6g}; LMI feasible: {r['lmi']['feasible']}, s_M {r['lmi']['s_M']:.3f}")
