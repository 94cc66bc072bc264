"""``jaxdip bench``: closed-loop throughput of dip-lqr, as ratios against a plain NumPy loop in the same process.

The NumPy baseline is the same loop written the way one would without JAX: one trajectory, a Python loop over
periods, RK4 with the same sub-steps, the same noise and the same LQR gain. Its DIP right-hand side is written
out again in NumPy (``numpy_dip_f``), which the tests also use as an independent check of the JAX model.
FLOPs come from XLA's cost analysis of one loop-free period (a loop body is counted once, so counting a
scanned program would undercount), and the machine's f64 matmul rate is measured for scale.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip import config as C
from jaxdip.experiments import dip_lqr
from jaxdip.outdir import write_file_atomic
from jaxdip.plants.dip import DIPParams


def numpy_dip_f(p: DIPParams, x, V):
    """Printed DIP equations of motion in plain NumPy (a second, independent transcription)."""
    xc, a, th, xcd, ad, thd = x
    ma = p.M1 * p.l1 + p.M2 * p.L1 + p.Mh * p.L1
    M = np.empty((3, 3))
    M[0, 0] = p.Mc + p.Mw + p.Jm * p.Kg**2 / p.rmp**2 + p.M1 + p.M2 + p.Mh
    M[0, 1] = M[1, 0] = -(ma * math.cos(a) + p.M2 * p.l2 * math.cos(a + th))
    M[0, 2] = M[2, 0] = -p.M2 * p.l2 * math.cos(a + th)
    M[1, 1] = (p.M1 * p.l1**2 + p.I1 + p.M2 * p.L1**2 + p.Mh * p.L1**2 + p.M2 * p.l2**2
               + 2 * p.M2 * p.L1 * p.l2 * math.cos(2 * a + th))
    M[1, 2] = M[2, 1] = p.M2 * p.L1 * p.l2 * math.cos(2 * a + th) + p.M2 * p.l2**2
    M[2, 2] = p.M2 * p.l2**2 + p.I2
    Fc = p.Kg * p.Kt * (p.rmp * V - p.Kg * p.Km * xcd) / (p.Rm * p.rmp**2)
    s1, s2 = math.sin(a + th), math.sin(2 * a + th)
    rhs = np.array([
        Fc - p.Bc * xcd - ((ma * math.sin(a) + p.M2 * p.l2 * s1) * ad + 2 * p.M2 * p.l2 * s1 * thd) * ad
        - p.M2 * p.l2 * s1 * thd**2,
        -(p.B1 - 2 * p.M2 * p.L1 * p.l2 * s2 * (ad + thd)) * ad + p.M2 * p.L1 * p.l2 * s2 * thd**2
        + p.g * ma * math.sin(a) + p.g * p.M2 * p.l2 * s1,
        p.M2 * p.L1 * p.l2 * s2 * ad**2 - p.B2 * thd + p.g * p.M2 * p.l2 * s1,
    ])
    return np.concatenate([x[3:], np.linalg.solve(M, rhs)])


def numpy_loop(K, noise_std, x0, n_periods, dt, substeps, seed=0):
    p = DIPParams()
    rng = np.random.default_rng(seed)
    x = np.array(x0, dtype=np.float64)
    h = dt / substeps
    for _ in range(n_periods):
        y = x + noise_std * rng.standard_normal(6)
        u = float(-(K @ y)[0])
        for _ in range(substeps):
            k1 = numpy_dip_f(p, x, u)
            k2 = numpy_dip_f(p, x + 0.5 * h * k1, u)
            k3 = numpy_dip_f(p, x + 0.5 * h * k2, u)
            k4 = numpy_dip_f(p, x + h * k3, u)
            x = x + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def _time(fn, repeat=2):
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t)
    return best


def matmul_peak(n=1024):
    a = jnp.ones((n, n))
    f = jax.jit(lambda a: a @ a)
    t = _time(lambda: f(a), repeat=3)
    return 2 * n**3 / t


def is_bench_file(text: str) -> bool:
    """Whether ``text`` is a bench.json that jaxdip wrote (so ``--out`` may replace it)."""
    try:
        d = json.loads(text)
    except ValueError:
        return False
    return isinstance(d, dict) and (d.get("tool") == "jaxdip bench" or {"machine", "periods_per_s"} <= set(d))


def run_bench(quick: bool = False, out: str = "bench.json") -> dict:
    cfg = C.load(dip_lqr.DipLqrConfig)
    n_periods = 200 if quick else 1000
    r = dip_lqr.build(cfg)
    r = jd.Rollout(r.loop, r.x0, n_periods, metrics=r.metrics)  # the statistics, no stored trajectory
    key = jax.random.PRNGKey(0)

    def batched(batch, shard):
        def run():
            return jd.monte_carlo(r, key, batch, shard=shard)

        jax.block_until_ready(run())  # compile
        t = _time(run)
        return batch * n_periods / t

    rows = {}
    for batch in (1, 1024, 4096):
        rows[f"jax_batch_{batch}"] = batched(batch, shard=False)
    if jax.device_count() > 1:
        rows["jax_batch_4096_sharded"] = batched(4096, shard=True)

    K = np.asarray(r.loop.controller.K)
    noise = np.asarray(cfg.noise_std)
    n_np = 100 if quick else 500
    t = time.perf_counter()
    numpy_loop(K, noise, np.full(6, 0.01), n_np, cfg.dt, cfg.substeps)
    np_rate = n_np / (time.perf_counter() - t)

    # FLOPs of one period, from a loop-free program (one RK4 sub-step, one period)
    import dataclasses

    import equinox as eqx

    arrays, static = eqx.partition(dataclasses.replace(r.loop, substeps=1), eqx.is_array)
    one = jax.jit(lambda a: jd.simulate(eqx.combine(a, static), jnp.zeros(6), key, 1, metrics=r.metrics))
    cost = one.lower(arrays).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    flops_sub = float(cost.get("flops", float("nan")))
    # one period = `substeps` RK4 steps; the sensor/controller part is counted once per period
    flops_period = flops_sub * cfg.substeps
    peak = matmul_peak(512 if quick else 1024)

    best = max(v for k, v in rows.items())
    result = {
        "tool": "jaxdip bench",
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "devices": jax.device_count(),
                    "backend": jax.default_backend(), "jax_version": jax.__version__},
        "periods_per_s": {**rows, "numpy_loop": np_rate},
        "ratio_vs_numpy": {k: v / np_rate for k, v in rows.items()},
        "flops_per_period_estimate": flops_period,
        "achieved_flops_per_s": best * flops_period,
        "matmul_peak_flops_per_s": peak,
        "fraction_of_matmul_peak": best * flops_period / peak,
        "n_periods": n_periods,
        "quick": quick,
    }
    write_file_atomic(out, json.dumps(result, indent=2))
    w = max(len(k) for k in result["periods_per_s"])
    for k, v in result["periods_per_s"].items():
        ratio = result["ratio_vs_numpy"].get(k)
        print(f"{k:<{w}}  {v:12.4g} periods/s" + (f"  {ratio:8.1f}x numpy" if ratio else ""))
    print(f"FLOPs/period ~{flops_period:.3g}; achieved {result['achieved_flops_per_s']:.3g} FLOP/s = "
          f"{100 * result['fraction_of_matmul_peak']:.2f}% of the f64 matmul rate ({peak:.3g} FLOP/s)")
    print(f"wrote {out}")
    return result
