"""Composable ensemble Kalman steps (optax-like): a state and an update function, built from parts.

``make_step(variant, schedule=..., localiser=..., failure=..., accelerate=..., sigma_w=...)`` returns a ``Step``
of three pure functions:

* ``init(start, key) -> SearchState``: ``start`` is the initial ensemble (J, p) (UKI also takes ``(mean, cov)``);
* ``eval_key(state)``: the key of this iteration's forward evaluations;
* ``update(state, Y, y, R) -> SearchState``: ``Y`` (J, m) are the forward outputs at ``state.members`` (the points
  to evaluate: the ensemble, UKI's sigma points, or Nesterov's extrapolated ensemble), ``y`` the data and ``R``
  its noise covariance.

A search is then ``Y = G(state.members); state = step.update(state, Y, y, R)`` until ``done(state)``;
``run_steps`` (with the body ``step_body(step, forward, y, R)``, ``forward(points, key) -> Y``) is that loop as
one ``lax.while_loop`` (jit- and vmap-able), and it ends within the iteration whose update set a status other
than ``OK`` (``jaxdip.search.failures``) or took the algorithmic time to the schedule's end::

    step = make_step("eki", schedule=data_misfit(), localiser=sec(), failure=Failure("ignore", min_success=5))
    state = step.init(ensemble0, key)
    state, history, n = run_steps(step_body(step, forward, y, R), state, 100, end=step.schedule.end)

Any variant (``eki``, ``etki``, ``uki``) combines with any schedule (``fixed``, ``scheduled``, ``data_misfit``),
localiser (``schur``, ``sec``, ``sec_fisher``: for EKI, whose sample covariances they correct), failure policy
and, for the ensemble variants, Nesterov acceleration (``accelerate="nesterov"``: the momentum rule of
EnsembleKalmanProcesses.jl's ``NesterovAccelerator``, theta_k from theta_{k-1}^2 (1 - theta_k) dt_k =
dt_{k-1} theta_k^2 and v = u_k + theta_k (1/theta_{k-1} - 1)(u_k - u_{k-1})). Tikhonov regularisation (TEKI) and
box constraints are transformations of the problem (``jaxdip.search.problems``), so they combine with all of it.
``jaxdip.search.eki.EKI`` is the thesis's configuration: ``eki()``, ``fixed(1.0)``, no localiser, penalty or
resampled failures.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp

from jaxdip.engine.checks import ArgumentError, check_choice, check_nonnegative
from jaxdip.search.failures import NOT_FINITE, OK, TOO_FEW_SUCCESSES, Failure, sanitize
from jaxdip.search.schedules import Schedule, fixed
from jaxdip.search.variants import Variant, eki, etki, uki
from jaxdip._public import public_dir

__all__ = ["SearchState", "Step", "make_step", "step_body", "run_steps", "done"]
__dir__ = public_dir(globals())

VARIANTS = {"eki": eki, "etki": etki, "uki": uki}


class SearchState(NamedTuple):
    members: jnp.ndarray  # (J, p): the points the forward map is evaluated at next
    key: jnp.ndarray  # the search's PRNG key; iteration i draws from fold_in(key, i)
    iteration: jnp.ndarray  # int32: updates so far (skipped ones included)
    time: jnp.ndarray  # algorithmic time: the sum of the applied steps dt
    status: jnp.ndarray  # int32: failures.OK, TOO_FEW_SUCCESSES or NOT_FINITE
    skipped: jnp.ndarray  # int32: consecutive iterations with too few successes
    n_ok: jnp.ndarray  # int32: successful members in the last update
    aux: dict  # the variant's and the accelerator's own state (UKI's mean and covariance, Nesterov's u_prev)


class Step(NamedTuple):
    init: Callable  # (start, key) -> SearchState
    eval_key: Callable  # (state) -> key of this iteration's forward evaluations
    update: Callable  # (state, Y, y, R) -> SearchState
    variant: Variant
    schedule: Schedule
    failure: Failure


def _keys(state):
    # the thesis's split, kept so that its searches give the same numbers: evaluation, perturbed objectives,
    # additive noise, resampling
    return jax.random.split(jax.random.fold_in(state.key, state.iteration), 4)


def _resample(Vn, ok, key):
    """Failed members redrawn from the Gaussian of the updated successful members."""
    w = ok.astype(Vn.dtype)
    n = jnp.maximum(w.sum(), 2.0)
    mu = (w[:, None] * Vn).sum(0) / w.sum()
    D = (Vn - mu) * w[:, None]
    cov = D.T @ D / (n - 1) + 1e-12 * jnp.eye(Vn.shape[1])
    draws = mu + jax.random.normal(key, Vn.shape) @ jnp.linalg.cholesky(cov).T
    return jnp.where(ok[:, None], Vn, draws)


def _nesterov(U, dt, aux):
    dt = jnp.asarray(dt, U.dtype)
    a = jnp.sqrt(aux["theta"] ** 2 * dt / aux["dt_prev"])
    theta = 0.5 * (-a + jnp.sqrt(a * a + 4.0))
    V = U + theta * (1.0 / aux["theta"] - 1.0) * (U - aux["u_prev"])
    return V, {**aux, "u_prev": U, "theta": theta, "dt_prev": dt}


def make_step(variant="eki", *, schedule: Optional[Schedule] = None, localiser: Optional[Callable] = None,
              failure: Optional[Failure] = None, accelerate: Optional[str] = None, sigma_w: float = 0.0) -> Step:
    """Compose an ensemble Kalman step (see the module docstring). ``variant``: a ``Variant`` or its name;
    ``schedule``: default ``fixed(1.0)``; ``failure``: default ``Failure()`` (penalty, at least 2 successes,
    stop at once); ``sigma_w``: std of the additive member noise w_j of (2.22) (ensemble variants)."""
    if isinstance(variant, str):
        check_choice("make_step", "variant", variant, tuple(VARIANTS))
        variant = VARIANTS[variant]()
    schedule = fixed(1.0) if schedule is None else schedule
    failure = (Failure() if failure is None else failure).check()
    if accelerate is not None:
        check_choice("make_step", "accelerate", accelerate, ("nesterov",))
    check_nonnegative("make_step", "sigma_w", sigma_w)
    if not variant.ensemble and (failure.kind != "penalty" or accelerate is not None):
        raise ArgumentError(f"make_step: variant {variant.name!r} moves a Gaussian, not an ensemble: it takes "
                            f"failure kind 'penalty' and no accelerator, got {failure.kind!r} and {accelerate!r}")
    if variant.name != "eki" and localiser is not None:
        # ETKI never forms the (p, m) cross-covariance; UKI's covariance update with a localised gain is not
        # positive semidefinite in general (its next sigma points would not exist)
        raise ArgumentError(f"make_step: a localiser corrects the sample covariances of variant 'eki'; variant "
                            f"{variant.name!r} takes none")

    def init(start, key) -> SearchState:
        aux = variant.init(start, key)
        members = variant.points(aux, None if isinstance(start, tuple) else jnp.asarray(start))
        if accelerate == "nesterov":
            aux = {**aux, "u_prev": members, "theta": jnp.ones((), members.dtype),
                   "dt_prev": jnp.ones((), members.dtype)}
        zero = jnp.zeros((), jnp.int32)
        return SearchState(members, key, zero, jnp.zeros((), members.dtype), zero, zero, zero, aux)

    def eval_key(state):
        return _keys(state)[0]

    def update(state: SearchState, Y, y, R) -> SearchState:
        _, k_obj, k_w, k_res = _keys(state)
        V = state.members
        Y = sanitize(jnp.atleast_2d(Y.reshape(V.shape[0], -1)), failure.penalty)
        ok = jnp.all(Y < failure.penalty, axis=1)
        n_ok = ok.sum()
        dt = schedule.step(state.iteration, state.time, Y, ok, y, R)
        new, aux, finite = variant.analysis(V, Y, ok, y, R, dt, k_obj, localiser, failure.kind != "penalty",
                                            state.aux)
        if variant.ensemble:
            new = new + sigma_w * jax.random.normal(k_w, V.shape)
            if failure.kind == "resample":
                new = _resample(new, ok, k_res)
            elif failure.kind == "ignore":
                new = jnp.where(ok[:, None], new, V)
        if accelerate == "nesterov":
            new, aux = _nesterov(new, dt, aux)
            finite = finite & jnp.all(jnp.isfinite(new))
        enough = n_ok >= failure.min_success
        skipped = jnp.where(enough, 0, state.skipped + 1).astype(jnp.int32)
        status = jnp.where(~enough, jnp.where(skipped > failure.patience, TOO_FEW_SUCCESSES, OK),
                           jnp.where(finite, OK, NOT_FINITE)).astype(jnp.int32)
        apply = enough & finite
        keep = lambda a, b: jnp.where(apply, a, b)  # noqa: E731
        return SearchState(keep(new, V), state.key, state.iteration + 1,
                           keep(state.time + dt, state.time), status, skipped, n_ok.astype(jnp.int32),
                           jax.tree_util.tree_map(keep, aux, state.aux))

    return Step(init, eval_key, update, variant, schedule, failure)


def done(state: SearchState, end: float = math.inf):
    """True once the search must stop: a status other than OK, or the algorithmic time at ``end``."""
    return (state.status != OK) | (state.time >= end)


def step_body(step: Step, forward: Callable, y, R) -> Callable:
    """The loop body ``state -> (state, Y)``: evaluate ``forward(state.members, step.eval_key(state))`` and
    update with it."""

    def body(state):
        Y = forward(state.members, step.eval_key(state))
        return step.update(state, Y, y, R), Y

    return body


def run_steps(body: Callable, state: SearchState, iterations: int, *, end: float = math.inf,
            penalty: float = 1000.0):
    """Up to ``iterations`` calls of ``body(state) -> (state, Y)`` (e.g. ``step_body(step, forward, y, R)``) as one
    ``lax.while_loop`` (jit- and vmap-able). Ends early after the iteration that set a status other than OK or
    took the algorithmic time to ``end`` (``step.schedule.end``). Returns (state, history (iterations, m): the
    mean output per iteration, non-finite outputs counted as ``penalty``, NaN after the last; iterations done)."""
    m = jax.eval_shape(body, state)[1].shape
    m = int(math.prod(m[1:])) if len(m) > 1 else 1

    def cond(c):
        s, i, _ = c
        return (i < iterations) & ~done(s, end)

    def loop(c):
        s, i, hist = c
        s, Y = body(s)
        return s, i + 1, hist.at[i].set(sanitize(Y.reshape(Y.shape[0], -1), penalty).mean(axis=0))

    hist = jnp.full((iterations, m), jnp.nan, state.members.dtype)
    if iterations == 0:  # nothing to run (the loop body could not even index its empty history)
        return state, hist, jnp.zeros((), jnp.int32)
    state, n, hist = jax.lax.while_loop(cond, loop, (state, jnp.zeros((), jnp.int32), hist))
    return state, hist, n
