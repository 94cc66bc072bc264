"""Thesis §1.6 (Fig. 1.1-1.2): linearised CPX and SCPX against two EKFs on the Lorenz system.

    python experiments/lorenz_mhe.py [--quick] [--seeds N] [--out DIR] [--set key=value ...]

The same as ``jaxdip run lorenz-mhe``; the defaults are in configs/lorenz-mhe.toml. The library pieces:
``jaxdip.estimators.LinearizedCPX`` (CPX, SCPX) / ``ExtendedKalmanFilter`` and ``jaxdip.experiments.lorenz_mhe``.
"""

import argparse
import os

from jaxdip import config as C
from jaxdip.experiments import get, run_experiment

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="16 trials of 2 time units")
    ap.add_argument("--seeds", type=int)
    ap.add_argument("--out", default=os.path.join("results", "lorenz-mhe"))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    exp = get("lorenz-mhe")
    cfg = C.load(exp.config_cls, path=os.path.join(HERE, "..", "configs", "lorenz-mhe.toml"),
                 quick=exp.quick if args.quick else None, seeds=args.seeds, sets=args.set)
    metrics = run_experiment(exp, cfg, args.out)
    for m, r in metrics["results"].items():
        print(f"{m:5s} e = {r['mean_norm_error']:.3f}  e_xL = {r['mean_xL_error']:.3f}  diverged {r['diverged']}")


if __name__ == "__main__":
    main()
