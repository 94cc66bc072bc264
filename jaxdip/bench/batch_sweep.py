"""Periods per second of the scoreboard's loop (dip-lqr: printed DIP, LQR on noisy full-state measurements,
1 ms periods) against the number of seeds, on whatever backend JAX runs on: where a GPU overtakes the CPU.

    python -m jaxdip.bench.batch_sweep 1,256,1024,4096 --out sweep.json [--precision float32]

``--precision float32`` runs the loop in float32 (``jd.with_precision``: the whole period, noise included; the
float32 study in docs/performance.md found this loop's statistics safe in float32).

Each batch size is timed on a horizon grown until a call lasts about ``budget / 4`` seconds, after a compiling
call; the rate is the median of three calls. docs/performance.md has the figures for one H200 and this CPU.
"""

from __future__ import annotations

import argparse
import json
import time

import jax

from jaxdip.bench.scoreboard import DEFAULT_SUBSTEPS
from jaxdip.engine.driver import monte_carlo
from jaxdip.engine.simulate import with_precision
from jaxdip.scenarios.dip_lqr import dip_lqr

__all__ = ["sweep"]


def sweep(batches: list[int], budget: float = 1.0, max_periods: int = 200_000, precision: str = "float64") -> dict:
    """{"backend", "devices", "jax", "x64", "precision", "rates": {batch: {periods, s, periods_per_s,
    first_call_s}}}."""
    key = jax.random.PRNGKey(0)
    out = {"backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()], "jax": jax.__version__,
           "x64": bool(jax.config.jax_enable_x64), "precision": precision, "rates": {}}
    for b in batches:
        n = 100
        while True:
            r = with_precision(dip_lqr(dt=0.001, substeps=DEFAULT_SUBSTEPS, duration=n * 0.001, record_every=None),
                               precision)

            def run(r=r, b=b):
                return jax.block_until_ready(monte_carlo(r, key, b).final.x)

            t0 = time.perf_counter()
            run()
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            run()
            t = time.perf_counter() - t0
            if t > budget / 4 or n >= max_periods:
                break
            n = min(max_periods, int(n * max(2.0, budget / max(t, 1e-4) / 2)))
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            run()
            times.append(time.perf_counter() - t0)
        t = sorted(times)[1]
        out["rates"][b] = {"periods": n, "s": t, "periods_per_s": b * n / t, "first_call_s": first}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m jaxdip.bench.batch_sweep", description=__doc__.split("\n\n")[0])
    ap.add_argument("batches", help="comma-separated seed counts, e.g. 1,256,1024,4096")
    ap.add_argument("--out", default="batch_sweep.json", help="JSON file written (default: batch_sweep.json)")
    ap.add_argument("--precision", choices=("float64", "float32"), default="float64",
                    help="the loop's precision (default float64)")
    ap.add_argument("--budget", type=float, default=1.0, help="seconds per timed call, roughly (default 1)")
    args = ap.parse_args(argv)
    try:
        batches = [int(b) for b in args.batches.split(",")]
    except ValueError:
        ap.error(f"batches must be comma-separated integers, got {args.batches!r}")
    if any(b < 1 for b in batches):
        ap.error("every batch size must be at least 1")
    result = sweep(batches, args.budget, precision=args.precision)
    for b, r in result["rates"].items():
        print(f"batch {b:>8}: {r['periods_per_s']:.3e} periods/s ({r['periods']} periods, {r['s']:.3f} s)")
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
