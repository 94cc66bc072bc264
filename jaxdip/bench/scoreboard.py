"""``jaxdip bench``: the scoreboard of the dip-lqr loop (printed DIP, LQR on noisy full-state measurements,
1 ms periods) against the ways one would write it without JAX, all measured in one process.

Contenders, each timed once per round, rounds interleaved, medians reported:

- ``numpy_rk4x10``: one trajectory, a Python loop over periods, RK4 with 10 sub-steps per period, the DIP
  right-hand side written out again in NumPy (``numpy_dip_f``, also the tests' independent check of the model);
- ``scipy_rk45``: ``scipy.integrate.solve_ivp`` RK45 restarted every period (the input is held over a period),
  rtol 1e-6 / atol 1e-9, and ``ode45_defaults``: the same at MATLAB ode45's defaults (rtol 1e-3, atol 1e-6),
  the documents' integrator;
- ``jaxdip_batch_B`` (one device) and ``jaxdip_batch_B_all`` (sharded over every device): ``jd.monte_carlo`` of
  the loop as dip-lqr runs it (the scenario's defaults: one RK4 step a period, the DIP's vectorised sin and
  cos, the sensor's normals drawn in float32), B seeds; at 4096 seeds also the loop before those two choices
  (``..._library_trig_float64_draw``: the C library's sin and cos, float64 normals) and with the float64 draw
  only (``..._float64_draw``, on every device), so the scoreboard shows what each choice is worth.

Accuracy: every contender runs the same fixed noise sequence (seed 0's sensor noise, read off jaxdip's own
run) from the same initial state, and its final state is compared with DOP853 at rtol 1e-12 / atol 1e-14 per
period on that sequence. Ratios are periods per second against ode45's defaults and against the NumPy loop.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import platform
import statistics
import time
import types
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.scenarios.dip_lqr import dip_lqr
from jaxdip.outdir import OutputError, check_file, shown, write_file_atomic
from jaxdip.outdir.files import read_own
from jaxdip.plants.dip import DIP


def numpy_dip_params() -> types.SimpleNamespace:
    """The DIP's Table 3.3 numbers as Python floats (NumPy code on 0-d JAX arrays would dispatch every op)."""
    d = DIP()
    return types.SimpleNamespace(**{f.name: float(getattr(d, f.name)) for f in dataclasses.fields(d)
                                    if f.name not in ("variant", "trig")})


def numpy_dip_f(p: types.SimpleNamespace, x, V):
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


def _wait(x):
    return jax.block_until_ready(x)


def scipy_loop(K, noise, x0, dt, method="RK45", rtol=1e-6, atol=1e-9):
    """The loop with ``solve_ivp`` restarted every period (input held): final state. ``noise``: (n, 6)."""
    from scipy.integrate import solve_ivp

    p = numpy_dip_params()
    x = np.array(x0, dtype=np.float64)
    for w in noise:
        u = float(-(K @ (x + w))[0])
        x = solve_ivp(lambda t, z: numpy_dip_f(p, z, u), (0.0, dt), x, method=method, rtol=rtol, atol=atol).y[:, -1]
    return x


def numpy_loop(K, noise, x0, dt, substeps=10):
    """The loop in plain NumPy, RK4 with ``substeps`` steps per period: final state. ``noise``: (n, 6)."""
    p = numpy_dip_params()
    x = np.array(x0, dtype=np.float64)
    h = dt / substeps
    for w in noise:
        u = float(-(K @ (x + w))[0])
        for _ in range(substeps):
            k1 = numpy_dip_f(p, x, u)
            k2 = numpy_dip_f(p, x + 0.5 * h * k1, u)
            k3 = numpy_dip_f(p, x + 0.5 * h * k2, u)
            k4 = numpy_dip_f(p, x + h * k3, u)
            x = x + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def _sensor_noise(rollout, key, n):
    """(x0, noise (n, 6), final state) of seed 0 of ``rollout`` over n periods: what the references replay."""
    r = dataclasses.replace(rollout, steps=n, save=_x_and_y, save_every=1)
    sol = jd.monte_carlo(r, key, 1)
    xs, ys = (np.asarray(a[0]) for a in sol.saved)
    return xs[0], ys - xs, np.asarray(sol.final.x[0])


def _x_and_y(sample):
    return sample.x, sample.y


def integration_errors(substeps=(1, 2, 5, 10), n=6500, dt=0.001, key=0) -> dict:
    """Final-state error (max abs over the state) after ``n`` periods on seed 0's noise sequence, against DOP853
    at rtol 1e-12: jaxdip at each sub-step count, at the default count with the C library's sin/cos, the NumPy
    RK4 x 10 loop and SciPy's RK45 per period, all on a float64 draw (replayed exactly); and the loop as dip-lqr
    runs it (float32 draw), against DOP853 on that run's own noise."""
    key = jax.random.PRNGKey(key)
    base = dip_lqr(dt=dt, substeps=1, duration=n * dt, record_every=None, noise_draw="loop")
    x0, noise, _ = _sensor_noise(base, key, n)
    K = np.asarray(base.loop.controller.K)
    ref = scipy_loop(K, noise, x0, dt, method="DOP853", rtol=1e-12, atol=1e-14)
    err = {}
    for s in substeps:
        r = dip_lqr(dt=dt, substeps=s, duration=n * dt, record_every=None, noise_draw="loop")
        err[f"jaxdip_rk4x{s}"] = float(np.max(np.abs(_sensor_noise(r, key, n)[2] - ref)))
    # the loop's noise does not depend on the plant's trig, so the same reference judges the C library's sin/cos
    lib = dip_lqr(dt=dt, substeps=DEFAULT_SUBSTEPS, duration=n * dt, record_every=None, trig="library",
                  noise_draw="loop")
    err[f"jaxdip_rk4x{DEFAULT_SUBSTEPS}_library_trig"] = float(np.max(np.abs(_sensor_noise(lib, key, n)[2] - ref)))
    # a float32 draw is another noise sequence: its own reference. XLA may round a float32 normal once differently
    # in the saved y than in the loop's (a few % of draws, 1e-10 absolute), so this error bounds the integration's
    x0_32, noise_32, final_32 = _sensor_noise(dip_lqr(dt=dt, substeps=DEFAULT_SUBSTEPS, duration=n * dt,
                                                      record_every=None), key, n)
    ref_32 = scipy_loop(K, noise_32, x0_32, dt, method="DOP853", rtol=1e-12, atol=1e-14)
    err[f"jaxdip_rk4x{DEFAULT_SUBSTEPS}_float32_draw"] = float(np.max(np.abs(final_32 - ref_32)))
    err["numpy_rk4x10"] = float(np.max(np.abs(numpy_loop(K, noise, x0, dt, 10) - ref)))
    err["scipy_rk45"] = float(np.max(np.abs(scipy_loop(K, noise, x0, dt) - ref)))
    err["ode45_defaults"] = float(np.max(np.abs(scipy_loop(K, noise, x0, dt, rtol=1e-3, atol=1e-6) - ref)))
    return {"periods": n, "dt": dt, "reference": "DOP853 rtol 1e-12 atol 1e-14, restarted every period",
            "max_abs_final_state_error": err}


def matmul_peak(n=1024):
    a = jnp.ones((n, n))
    f = jax.jit(lambda a: a @ a)
    f(a).block_until_ready()
    t = time.perf_counter()
    for _ in range(3):
        f(a).block_until_ready()
    return 3 * 2 * n**3 / (time.perf_counter() - t)


def is_bench_file(data: bytes | str) -> bool:
    """Whether ``data`` is a bench JSON that jaxdip wrote (so ``--out`` may replace it)."""
    try:
        d = json.loads(data)
    except (ValueError, RecursionError):
        return False
    return isinstance(d, dict) and d.get("tool") == "jaxdip bench"


def figure_path(out: str) -> str:
    """The figure ``bench --out out`` writes beside its JSON."""
    return os.path.splitext(out)[0] + ".png"


def check_outputs(out: str) -> None:
    """Raise ``OutputError`` unless both files bench would write (``out`` and its figure) are new or bench's
    own, in an existing writable folder: checked before the bench runs. The figure is bench's only if the JSON
    beside it is, and records the figure's SHA-256."""
    if os.path.splitext(out)[1].lower() == ".png":
        raise OutputError("--out", f"{shown(out)} would be both the JSON and the figure; give a .json name")
    check_file(out, is_bench_file, parent_must_exist=True)
    recorded = None
    data = read_own(out)
    if data is not None and is_bench_file(data):
        recorded = (json.loads(data).get("figure") or {}).get("sha256")

    def png_is_ours(png: bytes) -> bool:
        return recorded is not None and hashlib.sha256(png).hexdigest() == recorded

    check_file(figure_path(out), png_is_ours, parent_must_exist=True)


def _contenders(quick: bool, substeps: int, dt: float) -> dict[str, tuple[Callable[[], object], int]]:
    """name -> (a function running it once, periods it runs): compiled and warmed up."""
    key = jax.random.PRNGKey(0)
    probe = dip_lqr(dt=dt, substeps=substeps, duration=dt, record_every=None)
    K = np.asarray(probe.loop.controller.K)
    rng = np.random.default_rng(0)
    x0 = np.full(6, 0.01)
    out = {}
    n_np = 40 if quick else 200
    noise_np = rng.standard_normal((n_np, 6)) * np.asarray((1e-3,) * 3 + (1e-2,) * 3)
    out["numpy_rk4x10"] = (lambda: numpy_loop(K, noise_np, x0, dt, 10), n_np)
    n_sp = 40 if quick else 200
    out["scipy_rk45"] = (lambda: scipy_loop(K, noise_np[:n_sp], x0, dt), n_sp)
    out["ode45_defaults"] = (lambda: scipy_loop(K, noise_np[:n_sp], x0, dt, rtol=1e-3, atol=1e-6), n_sp)
    # periods per call chosen so a call lasts ~0.1-1 s on a 2-core CPU
    batches = {1: 2000, 1024: 200, 4096: 100} if quick else {1: 5000, 1024: 500, 4096: 250, 16384: 100}
    shards = (False, True) if jax.device_count() > 1 else (False,)
    for b, n in batches.items():
        r = dip_lqr(dt=dt, substeps=substeps, duration=n * dt, record_every=None)
        for shard in shards:
            if shard and b == 1:
                continue
            name = f"jaxdip_batch_{b}" + ("_all" if shard else "")

            def run(r=r, b=b, shard=shard):
                return _wait(jd.monte_carlo(r, key, b, shard=shard).final.x)

            run()  # compile
            out[name] = (run, n * b)
    # at 4096 seeds, the loop before its two choices (the C library's sin and cos, float64 normals), and with
    # the float64 draw only: what each choice is worth
    n = batches[4096]
    before = dip_lqr(dt=dt, substeps=substeps, duration=n * dt, record_every=None, trig="library", noise_draw="loop")
    f64 = dip_lqr(dt=dt, substeps=substeps, duration=n * dt, record_every=None, noise_draw="loop")
    variants = [(before, shard, "_library_trig_float64_draw") for shard in shards]
    variants.append((f64, len(shards) > 1, "_float64_draw"))
    for r, shard, suffix in variants:
        name = "jaxdip_batch_4096" + ("_all" if shard else "") + suffix

        def run(r=r, shard=shard):
            return _wait(jd.monte_carlo(r, key, 4096, shard=shard).final.x)

        run()
        out[name] = (run, n * 4096)
    return out


def other_loops(quick: bool) -> dict:
    """Periods per second of the other plants' loops at batch 256 (one call each, after compiling)."""
    from jaxdip.estimators import homd
    from jaxdip.plants.rwp import DT as RWP_DT
    from jaxdip.scenarios import lorenz_mhe, rwp, twip_dmso

    key = jax.random.PRNGKey(0)
    n = 100 if quick else 500
    d = twip_dmso.design(0.01)
    loops = {
        "twip_dmso_10ms": jd.Rollout(twip_dmso.loop(twip_dmso.estimator("dmso", d), twip_dmso.sensors(0.01, True), d),
                                     jnp.asarray([0.1, 0.0, 0.05, 0.0]), n),
        "rwp_homd_2ms": rwp.rollout(homd.HOMDObserver.build(RWP_DT, substeps=10, hold="foh"),
                                    steps=n),
        "lorenz_cpx_1ms": lorenz_mhe.build(steps=n),
    }
    out = {}
    for name, r in loops.items():
        run = lambda r=r: _wait(jd.monte_carlo(r, key, 256).result)  # noqa: E731
        run()
        t = time.perf_counter()
        run()
        out[name] = 256 * n / (time.perf_counter() - t)
    return out


def run_bench(quick: bool = False, out: str = "bench.json", substeps: Optional[int] = None,
              progress: bool = True) -> dict:
    """The scoreboard (module docstring); writes ``out`` (JSON) and a figure beside it."""
    dt = 0.001
    substeps = DEFAULT_SUBSTEPS if substeps is None else substeps
    rounds = 3 if quick else 5
    errors = integration_errors(substeps=(1, 2, 10) if quick else (1, 2, 5, 10), n=1000 if quick else 6500)
    cont = _contenders(quick, substeps, dt)
    times: dict[str, list[float]] = {k: [] for k in cont}
    for i in range(rounds):
        for name, (fn, _) in cont.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
        if progress:
            print(f"bench: round {i + 1}/{rounds}", flush=True)
    rate = {k: cont[k][1] / statistics.median(v) for k, v in times.items()}
    ode45 = rate["ode45_defaults"]
    result = {
        "tool": "jaxdip bench",
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "devices": jax.device_count(),
                    "backend": jax.default_backend(), "jax_version": jax.__version__},
        "loop": {"plant": "DIP (printed)", "dt": dt, "jaxdip_rk4_substeps": substeps, "rounds": rounds},
        "periods_per_s": rate,
        "ratio_vs_ode45": {k: v / ode45 for k, v in rate.items()},
        "ratio_vs_numpy": {k: v / rate["numpy_rk4x10"] for k, v in rate.items()},
        "integration": errors,
        "other_loops_periods_per_s": other_loops(quick),
        "matmul_peak_flops_per_s": matmul_peak(512 if quick else 1024),
        "quick": quick,
    }
    check_outputs(out)  # again: the user had the whole bench to put a file of their own there
    fig_path = figure_path(out)
    png = _figure(result)
    result["figure"] = {"file": os.path.basename(fig_path), "sha256": hashlib.sha256(png).hexdigest()}
    write_file_atomic(fig_path, png)
    write_file_atomic(out, json.dumps(result, indent=2))
    w = max(len(k) for k in rate)
    for k, v in rate.items():
        print(f"{k:<{w}}  {v:12.4g} periods/s  {result['ratio_vs_ode45'][k]:9.1f}x ode45  "
              f"{result['ratio_vs_numpy'][k]:8.1f}x numpy")
    for k, v in errors["max_abs_final_state_error"].items():
        print(f"error {k:<{w - 6}}  {v:.2g}")
    print(f"wrote {out} and {fig_path}")
    return result


# the measured default (docs/performance.md): one RK4 step per 1 ms period is 1e-11 from DOP853 after 6.5 s
DEFAULT_SUBSTEPS = 1


def _figure(result: dict) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rate = result["periods_per_s"]
    names = sorted(rate, key=rate.get)
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(names) + 1.5))
    ax.barh(names, [rate[n] for n in names], color=["C1" if n.startswith("jaxdip") else "C0" for n in names])
    ax.set_xscale("log")
    ax.set_xlabel("periods per second (median of rounds)")
    for i, n in enumerate(names):
        ax.text(rate[n], i, f" {result['ratio_vs_ode45'][n]:.3g}x ode45", va="center", fontsize=8)
    ax.set_title(f"dip-lqr loop, {result['machine']['cpu_count']} CPU cores, "
                 f"RK4 x{result['loop']['jaxdip_rk4_substeps']} per period in jaxdip")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
