"""Ensemble Kalman inversion (thesis §2.6.3, eqs. (2.21)-(2.22)), generic over the performance map.

Minimises 1/2 ||G(v) - yhat||^2 over v with an ensemble {v^j}. Each iteration:

    y^j = G(v^j)                       (vmapped over the ensemble)
    C_vy, C_yy                         ensemble cross- and auto-covariances (1 / (J - 1))
    yhat^j ~ N(yhat, R)                perturbed objectives, so the ensemble does not collapse
    v^j <- v^j + C_vy (C_yy + R)^-1 (yhat^j - y^j) + w^j,   w^j ~ N(0, Sigma_w)

Sign: (2.22) is printed with (y^j - yhat^j), which would push members *away* from the objective; the Kalman
rule (and the thesis's own description, "a minimizer of the difference") needs yhat^j - y^j. We use the latter;
a test checks that the mean converges to the least-squares solution of a linear problem.

Members are pytrees (flattened internally). A member whose performance is not finite gets ``penalty`` (the
thesis's rule: a diverged simulation scores 1000), so one failure never poisons the statistics with NaN.
``failure="resample"`` goes further, as EnsembleKalmanProcesses.jl does: failed members are left out of the
statistics and redrawn from the Gaussian of the successful ones, so a cliff of penalties cannot drag the
ensemble over it; iterations with too few successes are skipped, and a whole chunk of them stops the run with a clear error. The PRNG key
lives in the state, so a run is reproducible and resumable from any checkpoint.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree



from jaxdip._public import public_dir

__all__ = ["EKIState", "ensemble_update", "ensemble_update_resample", "sanitize", "EKI", "run_eki", "align_signs"]
__dir__ = public_dir(globals())


class EKIState(NamedTuple):
    members: jnp.ndarray  # (J, p) flattened members
    key: jnp.ndarray
    iteration: jnp.ndarray


def ensemble_update(V, Y, Yhat, R, W):
    """(2.22) with the Kalman sign, for given perturbed objectives Yhat (J, m) and perturbations W (J, p)."""
    J = V.shape[0]
    dV = V - V.mean(axis=0)
    dY = Y - Y.mean(axis=0)
    Cvy = dV.T @ dY / (J - 1)
    Cyy = dY.T @ dY / (J - 1)
    # (C_yy + R) is SPD: solve rather than invert
    gain_T = jnp.linalg.solve(Cyy + R, Cvy.T)  # (m, p)
    return V + (Yhat - Y) @ gain_T + W


def ensemble_update_resample(V, Y, Yhat, R, W, ok, key):
    """(2.22) over the successful members only (``ok``); failed members are redrawn from the Gaussian of the
    updated successful members (the EnsembleKalmanProcesses.jl failure handling). Needs >= 2 successes."""
    w = ok.astype(V.dtype)
    n = jnp.maximum(w.sum(), 2.0)
    vbar = (w[:, None] * V).sum(0) / w.sum()
    ybar = (w[:, None] * Y).sum(0) / w.sum()
    dV = (V - vbar) * w[:, None]
    dY = (Y - ybar) * w[:, None]
    Cvy = dV.T @ dY / (n - 1)
    Cyy = dY.T @ dY / (n - 1)
    gain_T = jnp.linalg.solve(Cyy + R, Cvy.T)
    Vn = V + (Yhat - Y) @ gain_T + W
    mu = (w[:, None] * Vn).sum(0) / w.sum()
    D = (Vn - mu) * w[:, None]
    cov = D.T @ D / (n - 1) + 1e-12 * jnp.eye(V.shape[1])
    L = jnp.linalg.cholesky(cov)
    draws = mu + jax.random.normal(key, V.shape) @ L.T
    return jnp.where(ok[:, None], Vn, draws)


def sanitize(Y, penalty):
    return jnp.where(jnp.isfinite(Y), Y, penalty)


class EKI(NamedTuple):
    """An EKI process over members shaped like ``template`` (a pytree)."""

    G: Callable  # G(member_pytree, key) -> (m,) performance; key shared by the ensemble unless member_keys
    template: object
    y_target: jnp.ndarray
    R: jnp.ndarray
    sigma_w: float = 0.0
    penalty: float = 1000.0
    project: Optional[Callable] = None  # member pytree -> member pytree, after each update (re-orthonormalise)
    failure: str = "penalty"  # "penalty" (thesis) or "resample" (failed members redrawn from the successful ones)
    min_success: int = 2  # resample mode: an iteration with fewer successes leaves the ensemble unchanged
    align: Optional[Callable] = None  # (J, p) flat ensemble -> (J, p), e.g. resolve v ~ -v sign symmetries
    # run_eki evaluates the members split over this process's devices (one XLA device per core under the
    # CLI); None: when there is more than one and they divide J
    shard: Optional[bool] = None
    member_keys: bool = False  # True: member j is evaluated with fold_in(key, j) (its own x0 and noise)

    def unravel(self):
        return ravel_pytree(self.template)[1]

    def init(self, members_tree, key) -> EKIState:
        flat = jax.vmap(lambda m: ravel_pytree(m)[0])(members_tree)
        if self.align is not None:
            flat = self.align(flat)
        return EKIState(flat, key, jnp.zeros((), jnp.int32))

    def evaluate(self, state: EKIState, key, axis: Optional[str] = None):
        """Y (J, m). ``axis``: inside ``shard_map`` over that mesh axis, each device evaluates its block of
        members and the blocks are gathered, so every device returns the whole Y."""
        unravel = self.unravel()
        V = state.members
        first = jnp.zeros((), jnp.int32)
        if axis is not None:
            n = jax.lax.psum(1, axis)
            J = V.shape[0] // n
            first = jax.lax.axis_index(axis) * J
            V = jax.lax.dynamic_slice_in_dim(V, first, J)
        if self.member_keys:
            keys = jax.vmap(lambda j: jax.random.fold_in(key, j))(first + jnp.arange(V.shape[0]))
            Y = jax.vmap(lambda v, k: self.G(unravel(v), k))(V, keys)
        else:
            Y = jax.vmap(lambda v: self.G(unravel(v), key))(V)
        if axis is not None:
            Y = jax.lax.all_gather(Y, axis, tiled=True)
        return sanitize(jnp.atleast_2d(Y.reshape(state.members.shape[0], -1)), self.penalty)

    def step(self, state: EKIState, axis: Optional[str] = None):
        """One iteration; returns (new state, performances of the members before the update).

        With ``failure="resample"``, a member is failed when any of its performances reaches ``penalty``; when
        fewer than two succeed the ensemble is left unchanged (``run_eki`` then stops with an error).
        """
        k_eval, k_obj, k_w, k_res = jax.random.split(jax.random.fold_in(state.key, state.iteration), 4)
        Y = self.evaluate(state, k_eval, axis)
        J, m = Y.shape
        Lr = jnp.linalg.cholesky(self.R)
        Yhat = self.y_target + jax.random.normal(k_obj, (J, m)) @ Lr.T
        W = self.sigma_w * jax.random.normal(k_w, state.members.shape)
        if self.failure == "resample":
            ok = jnp.all(Y < self.penalty, axis=1)
            # a shared initial state that (nearly) every member fails on says more about the state than the
            # members: skip such an iteration rather than collapse the ensemble onto the few survivors
            enough = ok.sum() >= max(2, self.min_success)
            V = jnp.where(enough, ensemble_update_resample(state.members, Y, Yhat, self.R, W, ok, k_res),
                          state.members)
        elif self.failure == "penalty":
            V = ensemble_update(state.members, Y, Yhat, self.R, W)
        else:
            raise ValueError(f"failure must be 'penalty' or 'resample', got {self.failure!r}")
        if self.project is not None:
            unravel = self.unravel()
            V = jax.vmap(lambda v: ravel_pytree(self.project(unravel(v)))[0])(V)
        if self.align is not None:
            V = self.align(V)
        return EKIState(V, state.key, state.iteration + 1), Y

    def mean(self, state: EKIState):
        m = self.unravel()(state.members.mean(axis=0))
        return self.project(m) if self.project is not None else m


def run_eki(eki: EKI, state: EKIState, iterations: int, *, chunk: int = 10, progress=None, checkpoint=None,
            stop: Optional[Callable] = None):
    """Iterate ``eki`` to ``iterations`` in jitted chunks.

    ``progress``: a ``Progress`` to update; ``checkpoint(state, history)`` is called after every chunk;
    ``stop(history) -> bool`` ends early (checked between chunks, so results do not depend on the chunking
    only if ``stop`` is None or deterministic in the history). Returns (state, history) where history holds
    the ensemble-mean performance per iteration (numpy, (n, m)).
    """

    devices = jax.local_devices()
    J = int(state.members.shape[0])
    shard = eki.shard if eki.shard is not None else (len(devices) > 1 and J % len(devices) == 0)
    if shard and J % len(devices):
        raise ValueError(f"shard=True needs the ensemble size ({J}) to be a multiple of the number of devices "
                         f"({len(devices)})")
    axis = "members" if shard else None

    def advance(st, n_dummy):
        def body(s, _):
            s, Y = eki.step(s, axis)
            return s, (Y.mean(axis=0), jnp.sum(jnp.all(Y < eki.penalty, axis=1)))

        return jax.lax.scan(body, st, None, length=n_dummy.shape[0])

    if shard:
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        # every device holds the whole ensemble, evaluates its block of members and runs the (small) update
        # itself on the gathered performances: one collective per iteration, the same numbers everywhere
        mesh = Mesh(np.array(devices), (axis,))
        advance = jax.shard_map(advance, mesh=mesh, in_specs=PartitionSpec(), out_specs=PartitionSpec(),
                                check_vma=False)
        # the first chunk's state laid out as the chunks return it (whole on every device), so the second
        # chunk finds the program the first compiled instead of compiling it again
        state = jax.device_put(state, NamedSharding(mesh, PartitionSpec()))
    advance = jax.jit(advance)

    history = []
    done = int(state.iteration)
    while done < iterations:
        n = min(chunk, iterations - done)
        state, (ys, n_ok) = advance(state, jnp.zeros(n))
        ys = np.asarray(ys)
        if eki.failure == "resample" and int(np.max(n_ok)) < max(2, eki.min_success):
            raise RuntimeError(f"EKI: fewer than {max(2, eki.min_success)} ensemble members succeeded in every one "
                               f"of iterations {done + 1}..{done + n}; cannot update (widen or move the initial "
                               "ensemble, or relax the failure bound)")
        history.append(ys)
        done += n
        if progress is not None:
            progress.update(n, postfix=f"mean perf {np.array2string(ys[-1], precision=3)}")
        if checkpoint is not None:
            checkpoint(state, np.concatenate(history))
        if stop is not None and stop(np.concatenate(history)):
            break
    hist = np.concatenate(history) if history else np.zeros((0, int(eki.y_target.shape[0])))
    return state, hist


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
