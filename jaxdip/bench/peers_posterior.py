"""Peer benchmark of posterior sampling, EM and masked filtering: jaxdip's ``sample_posterior`` (FFBS), ``fit_em``
and ``recorded.kalman_filter(mask=...)`` against dynamax's ``lgssm_posterior_sample``, ``LinearGaussianSSM.fit_em``
and ``lgssm_filter``, on records of the linearised DIP loop of ``jaxdip.bench.peers`` (ZOH 1 ms, outputs xc,
alpha, theta, true noise covariances Q = 4e-8 I, R = diag(1e-8, 1e-6, 1e-6)).

    pip install -e ".[peers]"      # dynamax: imported by this module only, never by the tests
    python -m jaxdip.bench.peers_posterior [--steps 1000] [--samples 2000] [--batch 1 1024] [--em-records 8]
                                           [--em-iters 30] [--missing 0.2] [--out peers_posterior.json]

* Sampling: both draw ``--samples`` paths of one record; the draws' mean and variance at every (k, i) are compared
  with the RTS smoother's moments as z-scores (mean: (m_hat - m) / sqrt(P / N); variance: (v_hat - P) /
  (P sqrt(2 / (N - 1)))). Among T d = 6000 entries the largest |z| of an exact sampler is about 4. Throughput:
  samples x steps per second of a jitted call (compiled ahead, best of ``--repeats``) at each ``--batch`` draws.
* EM: from the same start (Q, R ten times the true ones) on the same records, the log-likelihood before each
  M-step. dynamax's ``fit_em`` (``LinearGaussianSSM``, no priors) fits all its parameters jointly (initial mean
  and covariance, F, B, H, D, Q, R: it refuses a partly frozen set), so it runs a different EM from jaxdip's
  Q, R only; the same dynamax E-step (``model.e_step``, its public sufficient statistics) followed by a Q, R-only
  M-step written here is the like-for-like peer, run with dynamax's boost as shipped and at 0. dynamax 1.0.3's
  M-step of the initial covariance, (sum x0 x0^T - sum x0 sum x0^T) / N, is right for one sequence only: with
  N > 1 sequences it can be indefinite and the next E-step gives NaN, so its ``fit_em`` is also run on the first
  record alone. Wall time per iteration: (t(n) - t(1)) / (n - 1) of two whole fits, which removes the compile
  time each fit pays.
* Masked filtering: dynamax's filter has no mask or NaN handling, but it takes time-varying emission weights.
  A missing entry j at step k is given to it as H_k[j] = 0 and y_k[j] = 0: with R diagonal the entry then carries
  no information on the state, and adds log N(0; 0, R_jj) to the log-likelihood, which is subtracted before the
  comparison with jaxdip's ``mask=``.

dynamax's transition takes the next sample's input (``jaxdip.bench.peers``), so it gets the inputs shifted by one;
its ``psd_solve`` adds 1e-9 to the diagonal of S, which shows in its differences: sampling and masked filtering
are also run with that boost at 0 (``boost``), as ``jaxdip.bench.peers`` does.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import functools
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.bench import estimators as base
from jaxdip.bench.peers import prev_inputs, record
from jaxdip.bench.peers_filters import timed
from jaxdip.estimators import KalmanFilter, recorded
from jaxdip.estimators.em import fit_em
from jaxdip.estimators.sampling import sample_posterior

START_SCALE = 10.0  # EM starts from Q, R this many times the true ones


def _matrices(Q=None, R=None):
    model, _, Q0, R0, P0 = base.dip_problem()
    Q = Q0 if Q is None else Q
    R = R0 if R is None else R
    return tuple(jnp.asarray(a) for a in (model.Phi, model.W, base.C3, Q, R, P0))


def _dynamax_params(Q=None, R=None):
    import dynamax.linear_gaussian_ssm.inference as dinf

    Phi, W, C, Q, R, P0 = _matrices(Q, R)
    return dinf.make_lgssm_params(jnp.zeros(Phi.shape[0]), P0, Phi, Q, C, R, dynamics_input_weights=W)


@contextlib.contextmanager
def boost(value):
    """dynamax's inference module with ``psd_solve``'s diagonal boost set to ``value`` (None: as shipped, 1e-9);
    a function must be traced inside the context to use it."""
    import dynamax.linear_gaussian_ssm.inference as dinf
    from dynamax.utils.utils import psd_solve

    if value is not None:
        dinf.psd_solve = functools.partial(psd_solve, diagonal_boost=value)
    try:
        yield
    finally:
        dinf.psd_solve = psd_solve


# ---- sampling -------------------------------------------------------------------------------------------------

def compare_sampling(y, u, n_samples: int, batches, repeats: int) -> dict:
    from dynamax.linear_gaussian_ssm import lgssm_posterior_sample

    kf = KalmanFilter(*_matrices())
    params = _dynamax_params()
    y, u = jnp.asarray(y), jnp.asarray(u)
    u_dyn = jnp.asarray(prev_inputs(np.asarray(u)[None])[0])
    T = y.shape[0]
    sm = recorded.rts_smoother(kf, y, u)
    m, v = np.asarray(sm.mean), np.asarray(jnp.diagonal(sm.cov, axis1=-2, axis2=-1))

    def ours(n):
        return jax.jit(lambda key: sample_posterior(key, kf, y, u, n))

    def theirs(n):
        return jax.jit(lambda key: jax.vmap(lambda k: lgssm_posterior_sample(k, params, y, u_dyn))(
            jax.random.split(key, n)))

    out = {"steps": T, "samples": n_samples}
    key = jax.random.PRNGKey(1)
    for name, make, diagonal_boost, timing in (("jaxdip", ours, None, True), ("dynamax", theirs, None, True),
                                               ("dynamax_boost0", theirs, 0.0, False)):
        with boost(diagonal_boost):
            xs = np.asarray(make(n_samples)(key))
        n = xs.shape[0]
        z_mean = (xs.mean(0) - m) / np.sqrt(v / n)
        z_var = (xs.var(0, ddof=1) - v) / (v * np.sqrt(2.0 / (n - 1)))
        out[name] = {"max_abs_z_mean": float(np.max(np.abs(z_mean))), "max_abs_z_var": float(np.max(np.abs(z_var))),
                     "rms_z_mean": float(np.sqrt(np.mean(z_mean**2))), "rms_z_var": float(np.sqrt(np.mean(z_var**2))),
                     "sample_steps_per_s": {str(b): b * T / timed(make(b), key, repeats=repeats)[1]
                                            for b in (batches if timing else [])}}
        print(name, json.dumps(out[name]), flush=True)
    return out


# ---- EM -------------------------------------------------------------------------------------------------------

def _dynamax_qr_step(model, params, ys, us):
    """dynamax's E-step (its sufficient statistics) and a Q, R-only M-step: F, B, H, D, m, S stay fixed."""

    def step(Q, R):
        p = params._replace(dynamics=params.dynamics._replace(cov=Q), emissions=params.emissions._replace(cov=R))
        (_, dyn, emi), lls = jax.vmap(lambda y, u: model.e_step(p, y, u))(ys, us)
        dyn, emi = jax.tree.map(lambda a: jnp.sum(a, 0), (dyn, emi))
        zz, zx, xx, n = dyn
        FB = jnp.concatenate([p.dynamics.weights, p.dynamics.input_weights], axis=1)
        Qn = (xx - FB @ zx - zx.T @ FB.T + FB @ zz @ FB.T) / n
        zz, zy, yy, n = emi
        HD = jnp.concatenate([p.emissions.weights, p.emissions.input_weights], axis=1)
        Rn = (yy - HD @ zy - zy.T @ HD.T + HD @ zz @ HD.T) / n
        return 0.5 * (Qn + Qn.T), 0.5 * (Rn + Rn.T), jnp.sum(lls)

    return jax.jit(step)


def _wall(fn, iters: int) -> tuple:
    """(result of fn(iters), seconds per iteration without the compile time: (t(n) - t(1)) / (n - 1))."""
    t = time.perf_counter()
    fn(1)
    t1 = time.perf_counter() - t
    t = time.perf_counter()
    out = fn(iters)
    return out, (time.perf_counter() - t - t1) / (iters - 1)


def compare_em(y, u, iters: int) -> dict:
    from dynamax.linear_gaussian_ssm import LinearGaussianSSM

    _, _, _, Q_true, R_true, _ = _matrices()
    Q0, R0 = START_SCALE * Q_true, START_SCALE * R_true
    Phi, W, C, _, _, P0 = _matrices()
    ys, us = jnp.asarray(y), jnp.asarray(u)
    us_dyn = jnp.asarray(prev_inputs(np.asarray(u)))
    kf0 = KalmanFilter(Phi, W, C, Q0, R0, P0)

    def ours(n):
        r = fit_em(kf0, ys, us, tol=1e-300, max_iter=n)  # tol: run all n M-steps unless the likelihood stalls
        return r.log_likelihood, np.asarray(r.model.Q), np.asarray(r.model.R), r.status

    model = LinearGaussianSSM(6, 3, input_dim=1, has_dynamics_bias=False, has_emissions_bias=False)
    params, props = model.initialize(jax.random.PRNGKey(0), initial_mean=jnp.zeros(6), initial_covariance=P0,
                                     dynamics_weights=Phi, dynamics_input_weights=W, dynamics_covariance=Q0,
                                     emission_weights=C, emission_input_weights=jnp.zeros((3, 1)),
                                     emission_covariance=R0)

    def theirs_full(n, records=None):
        p, lps = model.fit_em(params, props, ys[:records], us_dyn[:records], num_iters=n, verbose=False)
        return np.asarray(lps), np.asarray(p.dynamics.cov), np.asarray(p.emissions.cov)

    def theirs_qr(step):
        def run(n):
            Q, R, lls = Q0, R0, []
            for _ in range(n):
                Q, R, ll = step(Q, R)
                lls.append(float(ll))
            return np.asarray(lls), np.asarray(Q), np.asarray(R)

        return run

    (ll_o, Q_o, R_o, status), w_o = _wall(ours, iters)
    (ll_f, Q_f, R_f), w_f = _wall(theirs_full, iters)
    ll_f1, Q_f1, _ = theirs_full(iters, records=1)  # one record: clear of its initial-covariance update (doc)
    step = _dynamax_qr_step(model, params, ys, us_dyn)
    step(Q0, R0)  # compiled once, outside the timing
    (ll_q, Q_q, R_q), w_q = _wall(theirs_qr(step), iters)
    with boost(0.0):
        step0 = _dynamax_qr_step(model, params, ys, us_dyn)
        ll_0, Q_0, R_0 = theirs_qr(step0)(iters)
    ll_o = ll_o[:iters]  # the likelihood of the model before each of the n M-steps, as dynamax reports it
    rel = lambda a, b: float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
    out = {"records": int(ys.shape[0]), "steps": int(ys.shape[1]), "iterations": iters, "start_scale": START_SCALE,
           "jaxdip_status": status,
           "loglik": {"jaxdip": ll_o.tolist(), "dynamax_qr": ll_q.tolist(), "dynamax_fit_em": ll_f.tolist(),
                       "dynamax_fit_em_one_record": ll_f1.tolist()},
           "monotone": {"jaxdip": bool(np.all(np.diff(ll_o) >= 0)), "dynamax_qr": bool(np.all(np.diff(ll_q) >= 0)),
                        "dynamax_fit_em": bool(np.all(np.diff(ll_f) >= 0)),
                        "dynamax_fit_em_one_record": bool(np.all(np.diff(ll_f1) >= 0))},
           "loglik_max_abs_diff_dynamax_qr": float(np.max(np.abs(ll_q - ll_o))),
           "Q_rel_diff_dynamax_qr": rel(Q_q, Q_o), "R_rel_diff_dynamax_qr": rel(R_q, R_o),
           "loglik_max_abs_diff_dynamax_qr_boost0": float(np.max(np.abs(ll_0 - ll_o))),
           "Q_rel_diff_dynamax_qr_boost0": rel(Q_0, Q_o), "R_rel_diff_dynamax_qr_boost0": rel(R_0, R_o),
           "Q_rel_diff_dynamax_fit_em": rel(Q_f, Q_o), "R_rel_diff_dynamax_fit_em": rel(R_f, R_o),
           "Q_rel_err_to_true": {"jaxdip": rel(Q_o, np.asarray(Q_true)), "dynamax_fit_em": rel(Q_f, np.asarray(Q_true)),
                                 "dynamax_fit_em_one_record": rel(Q_f1, np.asarray(Q_true))},
           "R_diag": {"true": np.diag(R_true).tolist(), "jaxdip": np.diag(R_o).tolist(),
                      "dynamax_qr": np.diag(R_q).tolist(), "dynamax_fit_em": np.diag(R_f).tolist()},
           "seconds_per_iteration": {"jaxdip": w_o, "dynamax_qr": w_q, "dynamax_fit_em": w_f}}
    print("em", json.dumps({k: v for k, v in out.items() if k != "loglik"}), flush=True)
    return out


# ---- masked filtering -----------------------------------------------------------------------------------------

def compare_masked(y, u, missing: float, diagonal_boost=None) -> dict:
    import dynamax.linear_gaussian_ssm.inference as dinf

    Phi, W, C, Q, R, P0 = _matrices()
    y, u = jnp.asarray(y), jnp.asarray(u)
    T, p = y.shape
    obs = jax.random.uniform(jax.random.PRNGKey(2), (T, p)) >= missing
    f = recorded.kalman_filter(KalmanFilter(Phi, W, C, Q, R, P0), y, u, mask=obs)
    params = _dynamax_params()
    Ht = jnp.where(obs[:, :, None], C[None], 0.0)  # time-varying emission weights: a missing row carries nothing
    params = params._replace(emissions=params.emissions._replace(weights=Ht))
    with boost(diagonal_boost):
        d = dinf.lgssm_filter(params, jnp.where(obs, y, 0.0), jnp.asarray(prev_inputs(np.asarray(u)[None])[0]))
    offset = -0.5 * float(jnp.sum(jnp.where(obs, 0.0, jnp.log(2 * jnp.pi * jnp.diag(R))[None])))
    ll_dyn = float(d.marginal_loglik) - offset
    out = {"steps": T, "diagonal_boost": 1e-9 if diagonal_boost is None else diagonal_boost,
           "missing_fraction": float(1 - jnp.mean(obs)),
           "filtered_mean_max_abs_diff": float(jnp.max(jnp.abs(d.filtered_means - f.mean))),
           "filtered_mean_rel_diff": float(jnp.max(jnp.abs(d.filtered_means - f.mean)) / jnp.max(jnp.abs(f.mean))),
           "filtered_cov_rel_diff": float(jnp.max(jnp.abs(d.filtered_covariances - f.cov)) / jnp.max(jnp.abs(f.cov))),
           "loglik_jaxdip": float(f.log_likelihood), "loglik_dynamax_corrected": ll_dyn,
           "loglik_abs_diff": abs(ll_dyn - float(f.log_likelihood))}
    print("masked", json.dumps(out), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 1024], help="draws per timed sampling call")
    ap.add_argument("--em-records", type=int, default=8)
    ap.add_argument("--em-iters", type=int, default=30)
    ap.add_argument("--missing", type=float, default=0.2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default="peers_posterior.json")
    args = ap.parse_args()
    if importlib.util.find_spec("dynamax") is None:
        sys.exit('error: peers_posterior: dynamax not installed: pip install ".[peers]"')
    import dynamax

    _, y, u = record(max(args.em_records, 1), args.steps)
    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.machine(),
           "cpu_count": os.cpu_count(), "jax": jax.__version__, "dynamax": getattr(dynamax, "__version__", "?"),
           "device": jax.devices()[0].platform, "load_average": list(os.getloadavg())}
    res["sampling"] = compare_sampling(y[0], u[0], args.samples, args.batch, args.repeats)
    res["masked"] = [compare_masked(y[0], u[0], args.missing, b) for b in (None, 0.0)]
    res["em"] = compare_em(y[:args.em_records], u[:args.em_records], args.em_iters)
    res["load_average_after"] = list(os.getloadavg())
    Path(args.out).write_text(json.dumps(res, indent=1))
    print("written", args.out)


if __name__ == "__main__":
    main()
