"""twip-dmso from Python: the same run as `jaxdip run twip-dmso`, for people who read code before a CLI.

    python experiments/twip_dmso.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("twip-dmso")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/twip-dmso")
    r = metrics["results"]
    for case in ("nominal", "param", "noise"):
        if case in r:
            dm, kf = r[case]["dmso"], r[case]["kf"]
            print(f"{case:8s} tilt-rate convergence (s): DMSO {dm['convergence_time_s']['phi_dot']:.3g}, "
                  f"KF {kf['convergence_time_s']['phi_dot']:.3g}; tail RMS (rad/s): DMSO "
                  f"{dm['rms_error_tail']['phi_dot']:.3g}, KF {kf['rms_error_tail']['phi_dot']:.3g}")
