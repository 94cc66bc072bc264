"""Peer benchmark: jaxdip's constrained linear MPC (``jaxdip.control.mpc.LinearMPC``) against do-mpc's MPC
(CasADi + IPOPT) on the same DIP problem: the dip-mpc experiment's setup (``jaxdip.scenarios.dip_mpc.Setup``:
printed DIP, 10 ms periods, horizon 20, |u| <= 6 V, Q and R of Table 3.1, DARE terminal cost).

    pip install -e ".[peers]"      # do-mpc, casadi: imported by this module only, never by the tests
    python -m jaxdip.bench.peers_mpc [--seeds 4096] [--steps 100] [--dompc-steps 100] [--x0-scale 4]
                                     [--out peers_mpc.json]

Throughput: closed-loop periods per second, the nonlinear DIP (RK4) driven by the MPC: jaxdip over ``--seeds``
seeds at once (``jd.monte_carlo``, best of ``--repeats`` timed runs after compilation), do-mpc one loop at a time
(its ``make_step`` per period, the plant a jitted jaxdip period), both in this process. The track limit is left
out of both here: do-mpc's soft constraints price a slack linearly and jaxdip's quadratically, so with it the two
would solve different problems; without it they solve the same QP, and the inputs of the two along do-mpc's
trajectory are compared (``max_abs_u_difference``: IPOPT's tolerance against an exact active-set solution).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.control.mpc import LinearMPC
from jaxdip.control.riccati import dare
from jaxdip.plants import dip
from jaxdip.scenarios import dip_mpc as S


def problem(s: S.Setup) -> LinearMPC:
    """The benchmark's MPC: the dip-mpc setup without the (soft) track limit."""
    return LinearMPC.for_plant(dip.DIP(), s.dt, jnp.diag(jnp.asarray(s.Q)), jnp.array([[s.R]]), s.horizon,
                               u_min=-s.u_max, u_max=s.u_max)


def jaxdip_rate(s: S.Setup, ctrl: LinearMPC, seeds: int, steps: int, x0_scale: float, repeats: int) -> dict:
    ro = S.rollout(s, ctrl, x0_scale=x0_scale, steps=steps)
    key = jax.random.PRNGKey(0)
    t0 = time.perf_counter()
    sol = jax.block_until_ready(jd.monte_carlo(ro, key, seeds))
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(jd.monte_carlo(ro, key, seeds))
        best = min(best, time.perf_counter() - t0)
    ok = np.asarray(sol.result) == jd.RESULTS.ok
    return {"seeds": seeds, "steps": steps, "wall_s": best, "first_call_s": first,
            "periods_per_s": seeds * steps / best, "diverged": int((~ok).sum())}


def dompc_controller(ctrl: LinearMPC, s: S.Setup):
    import casadi
    import do_mpc

    try:  # do-mpc's own numpy calls on casadi values: keep their behaviour, without the notice
        casadi.GlobalOptions.setNumpyMode(-1)
    except AttributeError:
        pass
    A, B, Q, R = (np.asarray(v) for v in (ctrl.A, ctrl.B, ctrl.Q, ctrl.R))
    P = np.asarray(dare(ctrl.A, ctrl.B, ctrl.Q, ctrl.R))
    m = do_mpc.model.Model("discrete")
    x = m.set_variable("_x", "x", (6, 1))
    u = m.set_variable("_u", "u", (1, 1))
    m.set_rhs("x", casadi.mtimes(casadi.DM(A), x) + casadi.mtimes(casadi.DM(B), u))
    m.setup()
    mpc = do_mpc.controller.MPC(m)
    mpc.settings.n_horizon = s.horizon
    mpc.settings.t_step = s.dt
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes",
                                "ipopt.tol": 1e-10}
    # do-mpc's stage cost is at x_0 .. x_{N-1} and u_0 .. u_{N-1}; ours leaves out x_0' Q x_0, a constant
    lterm = casadi.mtimes([x.T, casadi.DM(Q), x]) + casadi.mtimes([u.T, casadi.DM(R), u])
    mpc.set_objective(mterm=casadi.mtimes([x.T, casadi.DM(P), x]), lterm=lterm)
    mpc.bounds["lower", "_u", "u"] = -s.u_max
    mpc.bounds["upper", "_u", "u"] = s.u_max
    mpc.setup()
    return mpc


def dompc_rate(ctrl: LinearMPC, s: S.Setup, steps: int, x0_scale: float) -> dict:
    import do_mpc

    mpc = dompc_controller(ctrl, s)
    plant = dip.DIP()
    period = jax.jit(lambda x, u: plant.period(x, u, s.dt, s.substeps))
    x = np.asarray(S.rollout(s, ctrl, x0_scale=x0_scale).x0(jax.random.PRNGKey(1)))
    mpc.x0 = x.reshape(-1, 1)
    mpc.set_initial_guess()
    jax.block_until_ready(period(jnp.asarray(x), jnp.zeros(1)))
    ours = jax.jit(lambda xk: ctrl.solve(xk).z[0])
    xs, us = [], []
    t0 = time.perf_counter()
    for _ in range(steps):
        u = np.asarray(mpc.make_step(x.reshape(-1, 1))).ravel()
        xs.append(x)
        us.append(u[0])
        x = np.asarray(period(jnp.asarray(x), jnp.asarray(u)))
    wall = time.perf_counter() - t0
    u_ours = np.array([float(ours(jnp.asarray(xk))) for xk in xs])
    return {"steps": steps, "wall_s": wall, "periods_per_s": steps / wall,
            "max_abs_u_difference": float(np.max(np.abs(u_ours - np.array(us)))),
            "periods_at_limit": int(np.sum(np.isclose(np.abs(us), s.u_max, atol=1e-6))),
            "version": do_mpc.__version__}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--dompc-steps", type=int, default=100)
    ap.add_argument("--x0-scale", type=float, default=4.0, help="initial-state spread, times eki-dip's")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-dompc", action="store_true")
    ap.add_argument("--out", default="peers_mpc.json")
    args = ap.parse_args()
    if not args.skip_dompc and any(importlib.util.find_spec(m) is None for m in ("do_mpc", "casadi")):
        sys.exit('error: peers_mpc: do-mpc or casadi not installed: pip install ".[peers]", or --skip-dompc')
    s = S.Setup()
    ctrl = problem(s)
    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.machine(),
           "cpu_count": __import__("os").cpu_count(), "jax": jax.__version__, "device": jax.devices()[0].platform,
           "horizon": s.horizon, "dt": s.dt, "u_max": s.u_max, "x0_scale": args.x0_scale}
    res["jaxdip"] = jaxdip_rate(s, ctrl, args.seeds, args.steps, args.x0_scale, args.repeats)
    print(json.dumps(res["jaxdip"], indent=1))
    if not args.skip_dompc:
        res["do_mpc"] = dompc_rate(ctrl, s, args.dompc_steps, args.x0_scale)
        res["ratio_jaxdip_over_dompc"] = res["jaxdip"]["periods_per_s"] / res["do_mpc"]["periods_per_s"]
        print(json.dumps(res["do_mpc"], indent=1))
    Path(args.out).write_text(json.dumps(res, indent=1))
    print("written", args.out)


if __name__ == "__main__":
    main()
