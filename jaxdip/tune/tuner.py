"""A small gradient tuner for Monte Carlo objectives J(theta, key), and a random-search baseline.

``tune`` runs an optax optimiser (Adam by default, after global-norm gradient clipping) on the unconstrained
parameters u (``jaxdip.tune.transforms``), with either common random numbers (the same key at every step, so J is
one deterministic function of theta and the steps are comparable) or a fresh key per step (``fold_in(key, step)``,
an unbiased stochastic gradient of E J). It records theta, J and the gradient norm of every step, keeps the best
theta seen, stops early when J has not improved by ``min_delta`` for ``early_stop_patience`` steps, and
checkpoints its whole state atomically (``jaxdip.checkpoint``) so that ``resume=True`` continues a killed run to
the identical trajectory.
"""

from __future__ import annotations

import time
from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from jaxdip import checkpoint as ckpt
from jaxdip import program_cache
from jaxdip.progress import Progress
from jaxdip.tune.objective import Objective
from jaxdip.tune.transforms import unconstrained_spec, to_constrained, to_unconstrained


from jaxdip._public import public_dir

__all__ = ["TuneResult", "default_optimizer", "value_and_grad_fn", "tune", "SearchResult", "random_search"]
__dir__ = public_dir(globals())


class TuneResult(NamedTuple):
    theta: Any  # best theta seen (lowest J)
    loss: float  # J at the best theta (on the key used at that step)
    theta_history: Any  # pytree of arrays with leading axis = steps taken (theta *before* each update)
    loss_history: np.ndarray  # J at each step
    grad_norm_history: np.ndarray  # norm of the (unclipped) gradient in u at each step
    steps: int  # steps taken
    stopped_early: bool
    wall_s: float
    # wall time of each step taken in this call (the first includes compilation; NaN for steps restored from a
    # checkpoint): the cost of a gradient step against a plain evaluation is measured, not assumed
    step_wall: Optional[np.ndarray] = None


class _State(NamedTuple):
    step: jnp.ndarray
    u: Any
    opt_state: Any
    theta_hist: Any
    loss_hist: jnp.ndarray
    gnorm_hist: jnp.ndarray
    best_u: Any
    best_loss: jnp.ndarray
    since_best: jnp.ndarray


def default_optimizer(lr: float, clip: Optional[float]):
    import optax

    parts = [optax.clip_by_global_norm(clip)] if clip else []
    return optax.chain(*parts, optax.adam(lr))


def value_and_grad_fn(f: Callable, mode: str = "forward") -> Callable:
    """``(u, *args) -> (f(u, *args), df/du)`` by reverse mode or by forward mode over the flattened u."""
    if mode == "reverse":
        return jax.value_and_grad(f)
    if mode != "forward":
        raise ValueError(f"mode must be 'forward' or 'reverse', got {mode!r}")
    from jax.flatten_util import ravel_pytree

    def vg(u, *args):
        flat, unravel = ravel_pytree(u)

        def g(v):
            val = f(unravel(v), *args)
            return val, val

        if flat.shape == (1,):
            # one hyperparameter: one jvp. jacfwd would vmap the jvp over a batch of one tangent, and batching
            # the loop again (its nested scans each re-batched to a fixed point) doubles the tracing time
            val, dval = jax.jvp(lambda v: g(v)[0], (flat,), (jnp.ones_like(flat),))
            return val, unravel(jnp.reshape(dval, (1,)))
        jac, val = jax.jacfwd(g, has_aux=True)(flat)
        return val, unravel(jac)

    return vg


def _over_processes(objective, spec, mode: str) -> Optional[Callable]:
    """With ``jax.distributed`` and an objective that knows its seeds (``mc_objective``): (loss, gradient) with
    the seed batch split over the processes, each evaluating its block (``Objective.share``), the
    fraction-weighted blocks summed in process order, the same numbers on every process. ``None`` otherwise
    (every process then evaluates the whole objective itself)."""
    if jax.process_count() == 1 or not isinstance(objective, Objective) or objective.seeds is None:
        return None
    from jax.experimental import multihost_utils

    part, weight = objective.share(jax.process_index(), jax.process_count())
    local = None if part is None else jax.jit(value_and_grad_fn(lambda u, k: part(to_constrained(spec, u), k), mode))

    def value_and_grad(u, k):
        if local is None:
            loss, g = jnp.zeros(()), jax.tree_util.tree_map(jnp.zeros_like, u)
        else:
            loss, g = local(u, k)
        flat, unravel = ravel_pytree((loss, g))
        total = np.asarray(multihost_utils.process_allgather(weight * np.asarray(flat))).sum(axis=0)
        return unravel(jnp.asarray(total))

    return value_and_grad


def tune(objective: Callable, init_params, key, *, steps: int = 100, lr: float = 0.05, spec=None,
         optimizer=None, clip: Optional[float] = 1.0, common_random_numbers: bool = True,
         early_stop_patience: Optional[int] = None, min_delta: float = 0.0,
         checkpoint_path: Optional[str] = None, checkpoint_every: int = 1, resume: bool = False,
         fingerprint: str = "", progress: bool = True, desc: str = "tune",
         callback: Optional[Callable] = None, mode: str = "forward", project: Optional[Callable] = None,
         zero_nonfinite_grads: bool = False) -> TuneResult:
    """Minimise ``objective(theta, key) -> scalar`` from ``init_params``.

    ``spec``: pytree of transforms (default: all ``Unconstrained``). ``optimizer``: an optax GradientTransformation
    (default ``clip_by_global_norm(clip)`` then ``adam(lr)``). ``callback(step, theta, loss)`` is called after
    every step (host side). ``mode``: "forward" (``jacfwd``: one forward pass carrying one tangent per
    unconstrained coordinate; no stored trajectory, and far cheaper to compile for a handful of
    hyperparameters) or "reverse" (``grad``: for many hyperparameters; pair it with ``jaxdip.tune.checkpointed``).
    With ``checkpoint_path`` the state is saved every ``checkpoint_every`` steps and at
    the end; ``resume`` continues from it (refused if ``fingerprint`` differs).
    ``project(theta) -> theta``: applied after every update (projected gradient descent, e.g. re-orthonormalising
    a basis), in the constrained space. ``zero_nonfinite_grads``: non-finite gradient entries count as 0 (a
    trajectory that fails inside the loss gives NaN derivatives through the engine's freeze).
    With ``jax.distributed``, an ``mc_objective``'s seed batch is split over the processes (each evaluates the
    loss and gradient of its block, the weighted blocks are summed), so every process takes the same steps as
    one process would, to rounding; any other objective is evaluated whole on every process.
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    spec = unconstrained_spec(init_params) if spec is None else spec
    opt = optimizer or default_optimizer(lr, clip)
    u0 = to_unconstrained(spec, init_params)

    def j_of_u(u, k):
        return objective(to_constrained(spec, u), k)

    value_and_grad = _over_processes(objective, spec, mode) or program_cache.jit(value_and_grad_fn(j_of_u, mode))

    @jax.jit
    def apply(st: _State, loss, g):
        if zero_nonfinite_grads:
            g = jax.tree_util.tree_map(lambda x: jnp.where(jnp.isfinite(x), x, 0.0), g)
        gnorm = jnp.sqrt(sum(jnp.sum(x**2) for x in jax.tree_util.tree_leaves(g)))
        theta = to_constrained(spec, st.u)
        upd, opt_state = opt.update(g, st.opt_state, st.u)
        import optax

        u = optax.apply_updates(st.u, upd)
        if project is not None:
            u = to_unconstrained(spec, project(to_constrained(spec, u)))
        i = st.step
        theta_hist = jax.tree_util.tree_map(lambda h, t: h.at[i].set(t), st.theta_hist, theta)
        better = loss < st.best_loss - min_delta
        best_u = jax.tree_util.tree_map(lambda b, x: jnp.where(better, x, b), st.best_u, st.u)
        return _State(i + 1, u, opt_state, theta_hist, st.loss_hist.at[i].set(loss),
                      st.gnorm_hist.at[i].set(gnorm), best_u, jnp.where(better, loss, st.best_loss),
                      jnp.where(better, 0, st.since_best + 1))

    theta0 = to_constrained(spec, u0)
    st = _State(jnp.zeros((), jnp.int32), u0, opt.init(u0),
                jax.tree_util.tree_map(lambda t: jnp.full((steps,) + jnp.shape(t), jnp.nan), theta0),
                jnp.full(steps, jnp.nan), jnp.full(steps, jnp.nan), u0, jnp.asarray(jnp.inf),
                jnp.zeros((), jnp.int32))
    fp = ckpt.fingerprint({"user": fingerprint, "steps": steps, "lr": lr, "clip": clip,
                           "crn": common_random_numbers, "mode": mode, "patience": early_stop_patience, "min_delta": min_delta})
    if resume and checkpoint_path is not None:
        import os

        if os.path.exists(checkpoint_path):
            st, _ = ckpt.load(checkpoint_path, st, fp)

    t0 = time.perf_counter()
    done = int(st.step)
    bar = Progress(steps, desc=desc, enabled=progress)
    bar.update(done)
    step_wall = [float("nan")] * done
    stopped = bool(early_stop_patience is not None and done > 0 and int(st.since_best) >= early_stop_patience)
    while done < steps and not stopped:
        k = key if common_random_numbers else jax.random.fold_in(key, done)
        ts = time.perf_counter()
        loss, g = value_and_grad(st.u, k)
        st = apply(st, loss, g)
        done += 1
        lv = float(loss)
        step_wall.append(time.perf_counter() - ts)
        bar.update(1, postfix=f"J={lv:.4g} best={float(st.best_loss):.4g}")
        stopped = early_stop_patience is not None and int(st.since_best) >= early_stop_patience
        if checkpoint_path is not None and (done % checkpoint_every == 0 or done == steps or stopped):
            ckpt.save(checkpoint_path, st, fp)
        if callback is not None:
            callback(done - 1, jax.tree_util.tree_map(lambda h: h[done - 1], st.theta_hist), lv)
    bar.close()
    n = done
    return TuneResult(
        theta=to_constrained(spec, st.best_u), loss=float(st.best_loss),
        theta_history=jax.tree_util.tree_map(lambda h: np.asarray(h[:n]), st.theta_hist),
        loss_history=np.asarray(st.loss_hist[:n]), grad_norm_history=np.asarray(st.gnorm_hist[:n]),
        steps=n, stopped_early=bool(stopped), wall_s=time.perf_counter() - t0, step_wall=np.asarray(step_wall))


class SearchResult(NamedTuple):
    theta: Any  # best sample
    loss: float
    samples: Any  # pytree of arrays, leading axis = budget
    losses: np.ndarray
    wall_s: float
    eval_wall: Optional[np.ndarray] = None  # wall time of each evaluation (the first includes compilation)


def random_search(objective_eval: Callable, sampler: Callable, budget: int, key, *, progress: bool = True,
                  desc: str = "random search") -> SearchResult:
    """Evaluate ``objective_eval(theta)`` at ``budget`` samples ``theta = sampler(fold_in(key, i))``."""
    if budget < 1:
        raise ValueError(f"budget must be >= 1, got {budget}")
    t0 = time.perf_counter()
    samples, losses, walls = [], [], []
    bar = Progress(budget, desc=desc, enabled=progress)
    for i in range(budget):
        th = sampler(jax.random.fold_in(key, i))
        samples.append(th)
        ts = time.perf_counter()
        losses.append(float(objective_eval(th)))
        walls.append(time.perf_counter() - ts)
        bar.update(1, postfix=f"best={np.nanmin(losses):.4g}")
    bar.close()
    losses = np.asarray(losses)
    finite = np.where(np.isfinite(losses), losses, np.inf)
    b = int(np.argmin(finite))
    stacked = jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a]), *samples)
    return SearchResult(samples[b], float(losses[b]), stacked, losses, time.perf_counter() - t0, np.asarray(walls))
