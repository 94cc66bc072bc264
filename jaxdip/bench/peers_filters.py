"""Peer benchmark of the Kalman filter's forms: jaxdip's covariance (sequential), square-root and parallel-in-time
filters against cuthbert's square-root Kalman filter (sequential and parallel, one associative kernel) and
dynamax's ``lgssm_filter``, on records of the linearised DIP loop of ``jaxdip.bench.peers`` (ZOH 1 ms, outputs
xc, alpha, theta, true noise covariances).

    pip install -e ".[peers]"      # dynamax and cuthbert: imported by this module only, never by the tests
    python -m jaxdip.bench.peers_filters [--steps 1000 10000] [--batch 1 1024] [--repeats 2] [--max-total N]
                                         [--skip dynamax|cuthbert] [--out peers_filters.json]

Equal results: the largest absolute difference of the filtered means and of the log-likelihood to jaxdip's
covariance form (means compared on the first 16 records). Throughput: trajectory-steps per second of a jitted
call returning the filtered means and the log-likelihood, best of ``--repeats`` after a compiling call; a batch is
vmapped, and for the parallel forms run as ``lax.map`` over chunks of at most 2^17 trajectory-steps (``vmap``
inside a chunk), which bounds their memory (their elements are (T, d, d) per trajectory).

Timing conventions. cuthbert's state at time 0 is the prior before any measurement; jaxdip's prior (xhat0, P0)
is that of x_0 before y_0 is read. cuthbert gets a first transition x_0 = x_prior (F = I, c = 0, chol Q = 0) so
its states 1..T are jaxdip's 0..T-1. dynamax reads y_0 at its first state as jaxdip does, but its transition
takes the next sample's input (z_{t+1} = F z_t + B u_{t+1}), so it gets the inputs shifted by one; its
``psd_solve`` adds 1e-9 to the diagonal of S (see ``jaxdip.bench.peers``), which shows in its differences.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.bench import estimators as base
from jaxdip.bench import peers
from jaxdip.bench.peers import record
from jaxdip.estimators import KalmanFilter, recorded
from jaxdip.estimators._linear_gaussian import psd_factor

COMPARE = 16  # records whose means are compared
CHUNK_STEPS = 2**17


def _problem():
    model, _, Q, R, P0 = base.dip_problem()
    return (jnp.asarray(model.Phi), jnp.asarray(model.W), jnp.asarray(base.C3), jnp.asarray(Q), jnp.asarray(R),
            jnp.asarray(P0))


def jaxdip_filter(form: str):
    Phi, W, C, Q, R, P0 = _problem()
    kf = KalmanFilter(Phi, W, C, Q, R, P0)

    def one(y, u):
        f = recorded.kalman_filter(kf, y, u, form=form)
        return f.mean, f.log_likelihood

    return one


def cuthbert_filter(parallel: bool):
    import cuthbert
    from cuthbert.gaussian import kalman

    Phi, W, C, Q, R, P0 = _problem()
    d = Phi.shape[0]
    cQ, cR = psd_factor(Q), psd_factor(R)

    def dynamics(inp):
        first = inp["t"] == 0  # the prior of x_0 carried over unchanged
        return (jnp.where(first, jnp.eye(d), Phi), inp["c"], jnp.where(first, jnp.zeros_like(cQ), cQ))

    def observation(inp):
        return C, jnp.zeros(C.shape[0]), cR, inp["y"]

    filt = kalman.build_filter(jnp.zeros(d), psd_factor(P0), dynamics, observation)

    def one(y, u):
        T = y.shape[0]
        c = jnp.concatenate([jnp.zeros((1, d)), u[:-1] @ W.T])  # W u_{k-1} brings x_{k-1} to x_k
        inputs = {"t": jnp.arange(T), "c": c, "y": y}
        states = cuthbert.filter(filt, inputs, filt.init_prepare(), parallel=parallel)
        return states.mean[1:], states.log_normalizing_constant[-1]

    return one


def dynamax_filter():
    import dynamax.linear_gaussian_ssm.inference as dinf

    Phi, W, C, Q, R, P0 = _problem()
    params = dinf.make_lgssm_params(jnp.zeros(Phi.shape[0]), P0, Phi, Q, C, R, dynamics_input_weights=W)

    def one(y, u):
        f = dinf.lgssm_filter(params, y, jnp.concatenate([jnp.zeros_like(u[:1]), u[:-1]]))
        return f.filtered_means, f.marginal_loglik

    return one


def timed(fn, *args, repeats: int):
    """``jaxdip.bench.peers.timed`` of ``fn`` compiled ahead of time. (Called through ``jit`` a second time,
    cuthbert's vmapped parallel filter hung here with no CPU use, JAX 0.10.2 on CPU; the compiled executable runs
    normally.)"""
    return peers.timed(fn.lower(*args).compile(), *args, repeats=repeats)


def batched(one, batch: int, T: int, chunked: bool):
    """``one`` over a batch: ``vmap``, or for a parallel form (``chunked``) ``lax.map`` over chunks of at most
    CHUNK_STEPS trajectory-steps, vmapped inside (its elements are (T, d, d) per trajectory)."""
    if batch == 1:
        return jax.jit(lambda ys, us: jax.tree.map(lambda a: a[None], one(ys[0], us[0])))
    if not chunked:
        return jax.jit(jax.vmap(one))
    chunk = int(min(batch, max(1, CHUNK_STEPS // T)))
    return jax.jit(lambda ys, us: jax.lax.map(lambda a: one(*a), (ys, us), batch_size=chunk))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 1024])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--max-total", type=float, default=float("inf"),
                    help="skip a (steps, batch) pair with more trajectory-steps than this (recorded as skipped)")
    ap.add_argument("--skip", choices=["dynamax", "cuthbert"], action="append", default=[])
    ap.add_argument("--out", default="peers_filters.json")
    args = ap.parse_args()
    needed = {"dynamax": "dynamax", "cuthbert": "cuthbert"}
    missing = [m for part, m in needed.items() if part not in args.skip and importlib.util.find_spec(m) is None]
    if missing:
        sys.exit(f"error: peers_filters: {', '.join(missing)} not installed: pip install \".[peers]\", or --skip it")
    methods = {"jaxdip_covariance": jaxdip_filter("covariance"), "jaxdip_sqrt": jaxdip_filter("sqrt"),
               "jaxdip_parallel": jaxdip_filter("parallel")}
    if "cuthbert" not in args.skip:
        methods["cuthbert_sequential"] = cuthbert_filter(parallel=False)
        methods["cuthbert_parallel"] = cuthbert_filter(parallel=True)
    if "dynamax" not in args.skip:
        methods["dynamax"] = dynamax_filter()
    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.machine(),
           "cpu_count": __import__("os").cpu_count(), "jax": jax.__version__, "device": jax.devices()[0].platform,
           "load_average": list(__import__("os").getloadavg()), "runs": []}
    _, y, u = record(max(args.batch), max(args.steps))
    for T in args.steps:
        for B in args.batch:
            run = {"steps": T, "batch": B}
            if B * T > args.max_total:
                res["runs"].append({**run, "skipped": f"more than --max-total {args.max_total:g} trajectory-steps"})
                continue
            ys, us = jnp.asarray(y[:B, :T]), jnp.asarray(u[:B, :T])
            ref = None
            for name, one in methods.items():
                (mean, ll), wall = timed(batched(one, B, T, "parallel" in name), ys, us, repeats=args.repeats)
                mean, ll = np.asarray(mean[:COMPARE]), np.asarray(ll)
                if ref is None:
                    ref = (mean, ll)
                run[name] = {"steps_per_s": B * T / wall,
                             "mean_max_abs_diff": float(np.max(np.abs(mean - ref[0]))),
                             "loglik_max_abs_diff": float(np.max(np.abs(ll - ref[1]))),
                             "loglik_max_rel_diff": float(np.max(np.abs(ll - ref[1]) / np.abs(ref[1])))}
                print(f"T={T:6d} batch={B:5d} {name:20s} {B * T / wall:10.3g} steps/s  "
                      f"mean diff {run[name]['mean_max_abs_diff']:.2g}  ll diff {run[name]['loglik_max_abs_diff']:.2g}",
                      flush=True)
            base_rate = run["jaxdip_covariance"]["steps_per_s"]
            for name in methods:
                run[name]["speed_vs_jaxdip_covariance"] = run[name]["steps_per_s"] / base_rate
            res["runs"].append(run)
            res["load_average_after"] = list(__import__("os").getloadavg())
            Path(args.out).write_text(json.dumps(res, indent=1))  # after every pair: a long run keeps what it did
    print("written", args.out)


if __name__ == "__main__":
    main()
