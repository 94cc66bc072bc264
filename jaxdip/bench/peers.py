"""Peer benchmark: jaxdip's batch filter/smoother/likelihood against dynamax, and the weighted MHE against do-mpc's
MHE, on shared data from the linearised DIP loop of ``jaxdip.bench.estimators`` (ZOH 1 ms, outputs xc, alpha,
theta, LQR, true noise covariances).

    pip install -e ".[peers]"      # dynamax, do-mpc, casadi: imported by this module only, never by the tests
    python -m jaxdip.bench.peers [--seeds 1024] [--steps 2000] [--dyn-seeds 128] [--dompc-seeds 4]
                               [--dompc-steps 500] [--out peers.json]

Data: the closed loop driven by the Kalman filter is recorded (true state x_k, outputs y_k, inputs u_k), and every
estimator runs open-loop over the same records, so they all see the same noise.

* dynamax: ``lgssm_filter``/``lgssm_smoother`` against ``jaxdip.estimators.recorded`` (filtered and smoothed means
  and covariances, log-likelihood). dynamax's transition input is the *next* sample's (z_{t+1} = F z_t + B u_{t+1}),
  ours the current one (x_{k+1} = Phi x_k + W u_k), so dynamax gets the inputs shifted by one. dynamax's
  ``psd_solve`` adds a fixed diagonal 1e-9 to every matrix it solves with (the innovation covariance S and the
  smoother's predicted covariance), and its public API has no setting for it: the comparison is made as shipped
  and again with that boost set to 0 (``psd_solve`` replaced in dynamax's inference module for the second run).
  Here R = diag(1e-8, 1e-6, 1e-6), so the shipped boost is a 10% change of the cart-position noise.
* do-mpc: its MHE (CasADi + IPOPT) of the same discrete model with the true noise weights (P_v = R^{-1},
  P_w = Q^{-1}, P_x = P^{-1} with P the stationary a-priori KF covariance, as in ``WeightedMHE.from_noise``) and
  horizon N = 10 (states x_{j-10} .. x_j, as ours; it uses the 10 outputs y_{j-9} .. y_j, ours 11). The known
  input enters as a noise-free measurement (do-mpc's MHE otherwise treats inputs as unknowns). Its arrival prior
  is the previous window's second state (the smoothed prior). It is slow, so it runs on a few short records; our
  weighted MHE runs on those and on the whole set.

Velocity RMS error: sqrt(mean over seeds of the summed mean-square error of xc_dot, alpha_dot, theta_dot) over the
samples after a burn-in (``--burn``, and 100 on the short do-mpc records). Trajectory-steps per second: best of
``--repeats`` timed runs after compilation, one process, all cores JAX uses.
"""

from __future__ import annotations

import argparse
import datetime
import functools
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
from jaxdip.bench import estimators as base  # the shared loop
from jaxdip.control.riccati import dare
from jaxdip.estimators import recorded
from jaxdip.estimators.weighted_mhe import WeightedMHE

HORIZON = 10


def record(n_seeds: int, steps: int, seed: int = 0):
    """x (n, T, 6), y (n, T, 3), u (n, T, 1) of the KF-driven loop (``fold_in(seed, i)`` per record)."""
    model, K, Q, R, P0 = base.dip_problem()
    kf = jd.estimators.KalmanFilter(model.Phi, model.W, base.C3, Q, R, P0)
    ro = jd.Rollout(base.dip_loop(kf, model, K), jd.Ball(jnp.zeros(6), base.X0_RADIUS), steps,
                    save=lambda s: (s.x, s.y, s.u))
    x, y, u = jd.monte_carlo(ro, seed, n_seeds).saved
    return np.asarray(x), np.asarray(y), np.asarray(u)


def prev_inputs(u):
    """u_{k-1} at index k (zero at k = 0): what an estimator receives with y_k."""
    return np.concatenate([np.zeros_like(u[:, :1]), u[:, :-1]], axis=1)


def vel_rms(xhat, x, burn: int) -> float:
    e = np.asarray(xhat)[:, burn:, 3:6] - np.asarray(x)[:, burn:, 3:6]
    return float(np.sqrt(np.mean(np.sum(np.mean(e**2, axis=1), axis=1))))


def timed(fn, *args, repeats: int = 3):
    """(output, best wall seconds) of a jitted function, after one compiling call."""
    out = jax.block_until_ready(fn(*args))
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return out, best


def run_estimator(est, ys, us_prev, x0s):
    """An engine estimator over recorded sequences (vmapped scan): the estimates handed on, (n, T, d)."""
    key = jax.random.PRNGKey(0)

    def one(y, up, x0):
        def body(st, inp):
            k, yk, uk = inp
            st, out, _ = est.step(st, yk, uk, key, k)
            return st, out

        return jax.lax.scan(body, est.init(key, x0), (jnp.arange(y.shape[0]), y, up))[1]

    return jax.vmap(one)(ys, us_prev, x0s)


# ---- dynamax --------------------------------------------------------------------------------------------------

def compare_dynamax(x, y, u, repeats: int) -> dict:
    import dynamax.linear_gaussian_ssm.inference as dinf
    from dynamax.linear_gaussian_ssm import lgssm_filter, lgssm_smoother
    from dynamax.utils.utils import psd_solve

    model, _, Q, R, P0 = base.dip_problem()
    n, T = y.shape[:2]
    params = dinf.make_lgssm_params(jnp.zeros(6), jnp.asarray(P0), jnp.asarray(model.Phi), jnp.asarray(Q),
                                    jnp.asarray(base.C3), jnp.asarray(R),
                                    dynamics_input_weights=jnp.asarray(model.W))
    ys, us, us_dyn = jnp.asarray(y), jnp.asarray(u), jnp.asarray(prev_inputs(u))

    kf = jd.estimators.KalmanFilter(model.Phi, model.W, base.C3, Q, R, P0)
    ours_f = jax.jit(jax.vmap(lambda yy, uu: recorded.kalman_filter(kf, yy, uu)))
    ours_s = jax.jit(jax.vmap(lambda yy, uu: recorded.rts_smoother(kf, yy, uu)))
    f, t_f = timed(ours_f, ys, us, repeats=repeats)
    s, t_s = timed(ours_s, ys, us, repeats=repeats)
    out = {"records": n, "steps": T,
           "jaxdip": {"filter_steps_per_s": n * T / t_f, "smoother_steps_per_s": n * T / t_s,
                      "velocity_rms_filter": vel_rms(f.mean, x, 500 if T > 1000 else 100),
                      "velocity_rms_smoother": vel_rms(s.mean, x, 500 if T > 1000 else 100)}}

    def diffs(df, ds):
        rel = lambda a, b: float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(np.asarray(b))))
        ll_ours, ll_dyn = np.asarray(f.log_likelihood), np.asarray(df.marginal_loglik)
        return {"filtered_mean_max_abs": float(np.max(np.abs(np.asarray(df.filtered_means) - np.asarray(f.mean)))),
                "filtered_mean_rel": rel(df.filtered_means, f.mean),
                "filtered_cov_max_abs": float(np.max(np.abs(np.asarray(df.filtered_covariances) - np.asarray(f.cov)))),
                "filtered_cov_rel": rel(df.filtered_covariances, f.cov),
                "smoothed_mean_max_abs": float(np.max(np.abs(np.asarray(ds.smoothed_means) - np.asarray(s.mean)))),
                "smoothed_mean_rel": rel(ds.smoothed_means, s.mean),
                "smoothed_cov_max_abs": float(np.max(np.abs(np.asarray(ds.smoothed_covariances) - np.asarray(s.cov)))),
                "smoothed_cov_rel": rel(ds.smoothed_covariances, s.cov),
                "log_likelihood_max_abs": float(np.max(np.abs(ll_dyn - ll_ours))),
                "log_likelihood_max_rel": float(np.max(np.abs(ll_dyn - ll_ours) / np.abs(ll_ours)))}

    for label, boost in (("dynamax_shipped", None), ("dynamax_boost0", 0.0)):
        if boost is not None:  # dynamax's inference module calls psd_solve by its imported name
            dinf.psd_solve = functools.partial(psd_solve, diagonal_boost=boost)
        try:
            dyn_f = jax.jit(jax.vmap(lgssm_filter, in_axes=(None, 0, 0)))
            dyn_s = jax.jit(jax.vmap(lgssm_smoother, in_axes=(None, 0, 0)))
            df, t_df = timed(dyn_f, params, ys, us_dyn, repeats=repeats)
            ds, t_ds = timed(dyn_s, params, ys, us_dyn, repeats=repeats)
        finally:
            dinf.psd_solve = psd_solve
        out[label] = {"diagonal_boost": 1e-9 if boost is None else boost,
                      "filter_steps_per_s": n * T / t_df, "smoother_steps_per_s": n * T / t_ds,
                      "velocity_rms_filter": vel_rms(df.filtered_means, x, 500 if T > 1000 else 100),
                      "differences_to_jaxdip": diffs(df, ds)}
    return out


# ---- do-mpc ---------------------------------------------------------------------------------------------------

def dompc_mhe(model, Q, R, P_arr):
    import casadi
    import do_mpc

    try:  # do-mpc's own numpy calls on casadi values: keep their behaviour, without the notice
        casadi.GlobalOptions.setNumpyMode(-1)
    except AttributeError:
        pass
    m = do_mpc.model.Model("discrete")
    xs = m.set_variable("_x", "x", (6, 1))
    us = m.set_variable("_u", "u", (1, 1))
    m.set_rhs("x", casadi.mtimes(casadi.DM(np.asarray(model.Phi)), xs)
              + casadi.mtimes(casadi.DM(np.asarray(model.W)), us), process_noise=True)
    m.set_meas("y", casadi.mtimes(casadi.DM(base.C3), xs), meas_noise=True)
    m.set_meas("u_meas", us, meas_noise=False)  # the known input: an exact measurement
    m.setup()
    mhe = do_mpc.estimator.MHE(m)
    mhe.settings.n_horizon = HORIZON
    mhe.settings.t_step = base.DT
    mhe.settings.store_full_solution = False
    mhe.settings.meas_from_data = True  # the window's outputs from the measurements given to make_step
    mhe.settings.nlpsol_opts = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes"}
    mhe.set_default_objective(np.linalg.inv(P_arr), P_v=np.linalg.inv(R), P_w=np.linalg.inv(Q))
    mhe.setup()
    return mhe


def compare_dompc(x, y, u, x_all, y_all, u_all, burn: int, repeats: int) -> dict:
    import do_mpc

    model, _, Q, R, P0 = base.dip_problem()
    P_arr = np.asarray(dare(jnp.asarray(model.Phi).T, jnp.asarray(base.C3).T, jnp.asarray(Q), jnp.asarray(R)))
    n, T = y.shape[:2]
    up = prev_inputs(u)
    est = np.zeros_like(x)
    wall, iters_failed = 0.0, 0
    for i in range(n):
        mhe = dompc_mhe(model, Q, R, P_arr)
        mhe.x0 = np.zeros(6)
        mhe.set_initial_guess()
        for k in range(T):
            t = time.perf_counter()
            est[i, k] = np.asarray(mhe.make_step(np.concatenate([y[i, k], up[i, k]]))).ravel()
            wall += time.perf_counter() - t
            iters_failed += int(not mhe.solver_stats["success"])
    dompc = {"records": n, "steps": T, "burn": burn, "steps_per_s": n * T / wall,
             "velocity_rms": vel_rms(est, x, burn), "failed_solves": iters_failed, "version": do_mpc.__version__}

    # ours: the weighted MHE (and the KF) over the same short records, then over the whole set
    mhe = WeightedMHE.from_noise(model, base.C3, Q, R, N=HORIZON)
    run = jax.jit(lambda yy, uu, xx: run_estimator(mhe, yy, uu, xx))
    ours_short = np.asarray(run(jnp.asarray(y), jnp.asarray(up), jnp.asarray(x[:, 0])))
    kf_est = jd.estimators.KalmanFilter(model.Phi, model.W, base.C3, Q, R, P0)
    kf = jax.vmap(lambda yy, uu: recorded.kalman_filter(kf_est, yy, uu).mean)
    kf_short = np.asarray(kf(jnp.asarray(y), jnp.asarray(u)))
    na, Ta = y_all.shape[:2]
    burn_all = 500 if Ta > 1000 else burn
    args = (jnp.asarray(y_all), jnp.asarray(prev_inputs(u_all)), jnp.asarray(x_all[:, 0]))
    ours_all, t_all = timed(run, *args, repeats=repeats)
    kf_all = np.asarray(jax.jit(kf)(jnp.asarray(y_all), jnp.asarray(u_all)))
    ours = {"records": na, "steps": Ta, "burn": burn_all, "steps_per_s": na * Ta / t_all,
            "velocity_rms": vel_rms(ours_all, x_all, burn_all), "kf_velocity_rms": vel_rms(kf_all, x_all, burn_all),
            "velocity_rms_on_dompc_records": vel_rms(ours_short, x, burn),
            "kf_velocity_rms_on_dompc_records": vel_rms(kf_short, x, burn),
            "max_abs_difference_to_dompc_on_its_records": float(np.max(np.abs(ours_short[:, HORIZON:]
                                                                             - est[:, HORIZON:])))}
    return {"dompc_mhe": dompc, "jaxdip_weighted_mhe": ours,
            "speed_ratio": ours["steps_per_s"] / dompc["steps_per_s"],
            "velocity_rms_ratio_mhe_over_kf": ours["velocity_rms"] / ours["kf_velocity_rms"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--dyn-seeds", type=int, default=128)
    ap.add_argument("--dompc-seeds", type=int, default=4)
    ap.add_argument("--dompc-steps", type=int, default=500)
    ap.add_argument("--burn", type=int, default=100, help="burn-in of the short do-mpc records")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip", choices=["dynamax", "dompc"], action="append", default=[])
    ap.add_argument("--out", default="peers.json")
    args = ap.parse_args()
    # the peers are an optional extra: say what is missing before recording anything
    needed = {"dynamax": ("dynamax",), "dompc": ("do_mpc", "casadi")}
    missing = [m for part, mods in needed.items() if part not in args.skip for m in mods
               if importlib.util.find_spec(m) is None]
    if missing:
        sys.exit(f"error: peers: {', '.join(missing)} not installed: pip install \".[peers]\", or --skip that peer")
    x, y, u = record(args.seeds, args.steps)
    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "cpu_count": __import__("os").cpu_count(),
           "jax": jax.__version__, "device": jax.devices()[0].platform, "seeds": args.seeds, "steps": args.steps}
    if "dynamax" not in args.skip:
        import dynamax
        res["dynamax"] = compare_dynamax(x[:args.dyn_seeds], y[:args.dyn_seeds], u[:args.dyn_seeds], args.repeats)
        res["dynamax"]["version"] = getattr(dynamax, "__version__", "?")
        print(json.dumps(res["dynamax"], indent=1))
    if "dompc" not in args.skip:
        sl = (slice(0, args.dompc_seeds), slice(0, args.dompc_steps))
        res["mhe"] = compare_dompc(x[sl], y[sl], u[sl], x, y, u, args.burn, args.repeats)
        print(json.dumps(res["mhe"], indent=1))
    Path(args.out).write_text(json.dumps(res, indent=1))
    print("written", args.out)


if __name__ == "__main__":
    main()
