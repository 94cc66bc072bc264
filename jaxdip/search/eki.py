"""Ensemble Kalman inversion (thesis §2.6.3, eqs. (2.21)-(2.22)) over a performance map of pytree members.

Minimises 1/2 ||G(v) - yhat||^2 over v with an ensemble {v^j}. Each iteration:

    y^j = G(v^j)                       (vmapped over the ensemble)
    C_vy, C_yy                         ensemble cross- and auto-covariances (1 / (J - 1))
    yhat^j ~ N(yhat, R)                perturbed objectives, so the ensemble does not collapse
    v^j <- v^j + C_vy (C_yy + R)^-1 (yhat^j - y^j) + w^j,   w^j ~ N(0, Sigma_w)

Sign: (2.22) is printed with (y^j - yhat^j), which would push members *away* from the objective; the Kalman
rule (and the thesis's own description, "a minimizer of the difference") needs yhat^j - y^j. We use the latter;
a test checks that the mean converges to the least-squares solution of a linear problem.

``EKI`` is the problem (the performance map over pytree members, the objective, how members are evaluated over
devices, re-projected and sign-aligned) around one composed step of ``jaxdip.search.steps``: by default the
thesis's configuration (``variant="eki"``, a fixed step dt = 1, no localiser), with the fields ``variant``,
``schedule``, ``localiser`` and ``accelerate`` choosing any other. A member whose performance is not finite gets
``penalty`` (the thesis's rule: a diverged simulation scores 1000), so one failure never poisons the statistics
with NaN. ``failure="resample"`` goes further, as EnsembleKalmanProcesses.jl does: failed members are left out
of the statistics and redrawn from the Gaussian of the successful ones; ``failure="ignore"`` leaves them out and
in place. In those two modes an iteration with fewer than ``min_success`` successes is skipped, and more than
``patience`` skipped in a row stop the search with a status, which ``run_eki`` raises as ``SearchStopped``
(one line). The PRNG key lives in the state, so a run is reproducible and resumable from any checkpoint.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from jaxdip.search.failures import OK, Failure, SearchStopped, sanitize, status_message
from jaxdip.search.schedules import Schedule
from jaxdip.search.spread import AXIS, by_member, member_devices, on_devices, to_local
from jaxdip.search.steps import SearchState, Step, make_step, run_steps
from jaxdip.search.variants import ensemble_update

from jaxdip._public import public_dir

__all__ = ["EKIState", "ensemble_update", "sanitize", "EKI", "run_eki", "align_signs"]
__dir__ = public_dir(globals())

EKIState = SearchState  # the state of an EKI search (one state type for every composed step)


class EKI(NamedTuple):
    """An ensemble Kalman search over members shaped like ``template`` (a pytree)."""

    G: Callable  # G(member_pytree, key) -> (m,) performance; key shared by the ensemble unless member_keys
    template: object
    y_target: jnp.ndarray
    R: jnp.ndarray
    sigma_w: float = 0.0
    penalty: float = 1000.0
    project: Optional[Callable] = None  # member pytree -> member pytree, after each update (re-orthonormalise)
    failure: str = "penalty"  # "penalty" (thesis), "resample" or "ignore" (failed members left out)
    min_success: int = 2  # resample/ignore: an iteration with fewer successes leaves the ensemble unchanged
    align: Optional[Callable] = None  # (J, p) flat ensemble -> (J, p), e.g. resolve v ~ -v sign symmetries
    # run_eki evaluates the members split over this process's devices (one XLA device per core under the
    # CLI), and with jax.distributed over those of every process; None: when there is more than one and they
    # divide J, and always with jax.distributed (jaxdip.search.spread.member_devices)
    shard: Optional[bool] = None
    member_keys: bool = False  # True: member j is evaluated with fold_in(key, j) (its own x0 and noise)
    variant: object = "eki"  # "eki", "etki", "uki" or a jaxdip.search.variants.Variant
    schedule: Optional[Schedule] = None  # None: the thesis's fixed step dt = 1
    localiser: Optional[Callable] = None
    accelerate: Optional[str] = None  # None or "nesterov"
    patience: int = 9  # resample/ignore: skipped iterations in a row tolerated before the search stops

    def unravel(self):
        return ravel_pytree(self.template)[1]

    def kalman(self) -> Step:
        """The composed step of this search (``jaxdip.search.steps.make_step``)."""
        # the thesis's penalty rule never stops: every member enters the update with its penalty
        floor = 0 if self.failure == "penalty" else max(2, self.min_success)
        return make_step(self.variant, schedule=self.schedule, localiser=self.localiser,
                         failure=Failure(self.failure, floor, self.patience, self.penalty),
                         accelerate=self.accelerate, sigma_w=self.sigma_w)

    def init(self, members_tree, key) -> EKIState:
        flat = jax.vmap(lambda m: ravel_pytree(m)[0])(members_tree)
        if self.align is not None:
            flat = self.align(flat)
        return self.kalman().init(flat, key)

    def evaluate(self, state: EKIState, key, axis: Optional[str] = None):
        """Y (J, m). ``axis``: inside ``shard_map`` over that mesh axis, each device evaluates its block of
        members and the blocks are gathered, so every device returns the whole Y (``spread.by_member``)."""
        unravel = self.unravel()
        if self.project is not None and not self.kalman().variant.ensemble:
            # UKI's sigma points stay as drawn (the update needs them): G sees them projected
            unravel = lambda v, u=self.unravel(): self.project(u(v))  # noqa: E731

        def forward(V, key, first):
            if self.member_keys:
                keys = jax.vmap(lambda j: jax.random.fold_in(key, j))(first + jnp.arange(V.shape[0]))
                return jax.vmap(lambda v, k: self.G(unravel(v), k))(V, keys)
            return jax.vmap(lambda v: self.G(unravel(v), key))(V)

        Y = by_member(forward, axis)(state.members, key)
        return sanitize(jnp.atleast_2d(Y.reshape(state.members.shape[0], -1)), self.penalty)

    def step(self, state: EKIState, axis: Optional[str] = None):
        """One iteration; returns (new state, performances of the members before the update).

        An ensemble variant's members are re-projected (``project``) and sign-aligned (``align``) after the
        update; UKI's sigma points are left as drawn (``evaluate`` and ``mean`` project them).
        """
        kalman = self.kalman()
        Y = self.evaluate(state, kalman.eval_key(state), axis)
        state = kalman.update(state, Y, self.y_target, self.R)
        V = state.members
        if kalman.variant.ensemble:
            if self.project is not None:
                unravel = self.unravel()
                V = jax.vmap(lambda v: ravel_pytree(self.project(unravel(v)))[0])(V)
            if self.align is not None:
                V = self.align(V)
        return state._replace(members=V), Y

    def mean(self, state: EKIState):
        flat = state.aux["mean"] if "mean" in state.aux else state.members.mean(axis=0)
        m = self.unravel()(flat)
        return self.project(m) if self.project is not None else m


def run_eki(eki: EKI, state: EKIState, iterations: int, *, chunk: int = 10, progress=None, checkpoint=None,
            stop: Optional[Callable] = None):
    """Iterate ``eki`` to ``iterations`` (or the end of its schedule) in jitted chunks.

    ``progress``: a ``Progress`` to update; ``checkpoint(state, history)`` is called after every chunk;
    ``stop(history) -> bool`` ends early (checked between chunks, so results do not depend on the chunking
    only if ``stop`` is None or deterministic in the history). Returns (state, history) where history holds
    the ensemble-mean performance per iteration (numpy, (n, m)). A search whose status leaves OK (too few
    successes, a non-finite update) is checkpointed and raises ``SearchStopped`` with a one-line message.
    """

    devices = member_devices(int(state.members.shape[0]), eki.shard)
    axis = AXIS if devices is not None else None
    kalman = eki.kalman()
    end = kalman.schedule.end

    def advance(st, n_dummy):
        return run_steps(lambda s: eki.step(s, axis), st, n_dummy.shape[0], end=end, penalty=eki.penalty)

    advance, state = on_devices(advance, state, devices)

    history = []
    done = int(state.iteration)
    while done < iterations and float(state.time) < end and int(state.status) == OK:
        n = min(chunk, iterations - done)
        state, ys, n_done = advance(state, jnp.zeros(n))
        ys = np.asarray(ys)[: int(n_done)]
        history.append(ys)
        done += int(n_done)
        if progress is not None:
            progress.update(int(n_done), postfix=f"mean perf {np.array2string(ys[-1], precision=3)}")
        if checkpoint is not None:
            checkpoint(to_local(state), np.concatenate(history))
        if int(state.status) != OK:
            raise SearchStopped(status_message(int(state.status), done, int(state.n_ok), kalman.failure),
                                int(state.status), to_local(state), np.concatenate(history))
        if stop is not None and stop(np.concatenate(history)):
            break
    hist = np.concatenate(history) if history else np.zeros((0, int(eki.y_target.shape[0])))
    # with jax.distributed: the state (whole and the same on every process) as this process's plain arrays
    return to_local(state), hist


def align_signs(V, blocks=None):
    """Flip members so each block of coordinates points along the ensemble's principal axis of that block.

    P_v(v) = P_v(-v) (and each column of P_{V,s} has the same symmetry), so an ensemble may hold both signs of
    one solution; its mean is then meaningless. The principal axis (leading eigenvector of sum_j v_j v_j^T) does
    not depend on the members' signs, so aligning to it is well defined. ``blocks`` lists (start, stop) slices
    of the flat member (default: the whole member).
    """
    blocks = blocks or [(0, V.shape[1])]
    for a, b in blocks:
        X = V[:, a:b]
        w, U = jnp.linalg.eigh(X.T @ X)
        axis = U[:, -1]
        sgn = jnp.where(X @ axis < 0, -1.0, 1.0)
        V = V.at[:, a:b].set(X * sgn[:, None])
    return V
