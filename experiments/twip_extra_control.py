"""twip-extra-control from Python: the same run as `jaxdip run twip-extra-control`.

    python experiments/twip_extra_control.py --quick
"""

import sys

import jaxdip  # noqa: F401  (float64)
from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

if __name__ == "__main__":
    exp = get("twip-extra-control")
    cfg = C.load(exp.config_cls, quick=exp.quick if "--quick" in sys.argv else None)
    metrics = run_experiment(exp, cfg, "results/twip-extra-control")
    r = metrics["results"]
    for case in cfg.cases:
        c = r[case]
        print(f"{case:20s} " + "  ".join(f"{s} {c[s]['score_mean']:.4g} ({c[s]['diverged']} diverged)"
                                         for s in ("lqr", "extra", "nominal"))
              + f"  improvement {c['improvement']:.3g}")
