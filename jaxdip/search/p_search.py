"""Procedure 1 (thesis §2.6.4): performance maps for the ensemble Kalman search over P.

* discrete systems: the projection control (2.9) with P = P_v (2.19) is simulated for K steps from x_0 and
  scored by (2.23): y_1 = ||x_K||^2 and y_2 = <f(x_K) - x_K, x_K>_P / (||f(x_K) - x_K||_P ||x_K||_P);
* continuous systems: the relaxed projection control (2.14) with P = P_{V,s} (2.20) is simulated over [0, T]
  and scored by (2.24): y = 1/(T - t*) int_{t*}^T x^T Q x dt, with the thesis's failure rule (a state norm
  above ``fail_norm`` ends the simulation with performance ``penalty``).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

import jaxdip as jd
from jaxdip import program_cache
from jaxdip.control.projection import RelaxedProjection
from jaxdip.control.spd import P_v, P_Vs, orthonormalize
from jaxdip.search import steps


from jaxdip._public import public_dir

__all__ = ["discrete_performance", "BasisMember", "project_member", "member_P", "member_blocks", "ContinuousSearch",
           "NoiseStream", "QuadraticFrom", "performance_loop", "rp_performance", "continuous_performance",
           "performances", "lowest_y1", "direction_search"]
__dir__ = public_dir(globals())


def _loop(plant, controller, **kw):
    # full-state feedback: the state is measured exactly and is the estimate
    return jd.Loop(plant=plant, sensor=jd.Identity(), estimator=jd.Passthrough(), controller=controller, **kw)


def discrete_performance(plant, s: float, K: int, x0_std: float = 1.0, fail_norm: float = 10.0,
                         penalty: float = 1000.0, n_x0: int = 1):
    """G(v, key) of (2.23) for a discrete engine plant under the projection control with P_v(v, s).

    The thesis's failure rule applies here too: a state norm above ``fail_norm`` scores y = (penalty, 1)
    (the worst angle). Without it, members just across the stability boundary score 1e17 and their
    covariances swamp the ensemble update, which then stalls on the unstable side. With ``n_x0 > 1`` the
    measures are averaged over that many initial states (split from the key; the thesis used one).
    """

    def one(P, key):
        x0 = x0_std * jax.random.normal(key, (plant.n,))
        loop = _loop(plant, RelaxedProjection(plant, P, kind="discrete", projection_only=True), dt=1.0,
                     substeps=1, norm_bound=fail_norm)
        sol = jd.simulate(loop, x0, key, K)  # deterministic: the key only names the trajectory
        xK, failed = sol.final.x, sol.result != jd.RESULTS.ok  # xK: the last state before any failure
        # the measures of (2.23) at x_K: library math on the final state, not a loop
        d = plant.step(xK, jnp.zeros(plant.m)) - xK
        pn = lambda z: jnp.sqrt(z @ P @ z)
        y1 = xK @ xK
        y2 = (d @ P @ xK) / (pn(d) * pn(xK))
        return jnp.where(failed, jnp.array([penalty, 1.0]), jnp.stack([y1, y2]))

    def G(v, key):
        P = P_v(v, s)
        if n_x0 == 1:
            return one(P, key)
        return jax.vmap(lambda k: one(P, k))(jax.random.split(key, n_x0)).mean(axis=0)

    return G


class BasisMember(NamedTuple):
    V: jnp.ndarray  # (N, d): the N free basis vectors as rows (contiguous in the flat member)
    log_s: jnp.ndarray  # (N,) log singular values (keeps them positive under the additive EKI update)


def project_member(m: BasisMember) -> BasisMember:
    """Procedure 1 step 8: re-orthonormalise the basis after each update."""
    return BasisMember(orthonormalize(m.V.T).T, m.log_s)


def member_P(m: BasisMember):
    return P_Vs(m.V.T, jnp.exp(m.log_s))


def member_blocks(N: int, d: int):
    """(start, stop) of each basis vector in the flat member, for ``align_signs``."""
    return [(i * d, (i + 1) * d) for i in range(N)]


class ContinuousSearch(NamedTuple):
    dt: float
    n_steps: int
    t_star_steps: int
    gamma: float
    Qpos: jnp.ndarray  # (n, n) weight of (2.24)
    noise_std: float  # state noise added every period
    x0_std: jnp.ndarray  # (n,) std of the random initial state
    fail_norm: float = 10.0
    penalty: float = 1000.0
    substeps: int = 2
    # the evaluations' closed loops in "float32" (``jd.Loop.precision``): performances come back as float32
    precision: str = "float64"


class NoiseStream(jd.KeySchedule):
    """The random stream of Procedure 1's evaluations: x0 from ``split(key)[0]`` (drawn by the caller), the
    state noise of period k from ``fold_in(split(key)[1], k)``; the components are deterministic and get the
    same key (unused)."""

    def base(self, key):
        return jax.random.split(key)[1]

    def period(self, base, k):
        return jnp.broadcast_to(jax.random.fold_in(base, k), (5,) + base.shape)


class QuadraticFrom(jd.metrics.Reducer):
    """sum of x_k^T Q x_k over the periods k >= start (x_k: the state at the start of the period)."""

    Q: jax.Array
    start: int = eqx.field(static=True)

    def init(self, template):
        return jnp.zeros((), template.x.dtype)

    def update(self, state, sample):
        return state + jnp.where(sample.k >= self.start, sample.x @ self.Q @ sample.x, 0.0)

    def finalize(self, state):
        return state


def performance_loop(plant, P, cfg: ContinuousSearch, noise_ahead: bool = False) -> jd.Loop:
    """The closed loop of one evaluation of (2.24): (2.14) with P and cfg.gamma, state noise every period, a
    state norm above ``fail_norm`` ends it. ``noise_ahead``: draw the noise before the loop (``jd.Loop``), the
    fast choice when the evaluations of a batch share their key (the ensemble judged on one sequence)."""
    return _loop(plant, RelaxedProjection(plant, P, cfg.gamma), dt=cfg.dt, substeps=cfg.substeps,
                 process_noise_std=cfg.noise_std, norm_bound=cfg.fail_norm, keys=NoiseStream(),
                 noise_ahead=noise_ahead, precision=cfg.precision)


def rp_performance(plant, P, cfg: ContinuousSearch, key, penalize: bool = True, noise_ahead: bool = False):
    """(2.24) of one evaluation: 1/(T - t*) sum of x^T Q x over the states x_{t*+1} .. x_n (up to a failure),
    or ``penalty`` if the state norm left ``fail_norm`` (``penalize=False``: the sum up to the failure)."""
    n, s = cfg.n_steps, cfg.t_star_steps
    loop = performance_loop(plant, P, cfg, noise_ahead)
    dtype = loop.dtype
    x0 = jnp.asarray(cfg.x0_std, dtype) * jax.random.normal(jax.random.split(key)[0], (plant.n,), dtype)
    Q = jnp.asarray(cfg.Qpos, dtype)
    sol = jd.simulate(loop, x0, key, n, metrics=QuadraticFrom(Q, s + 1))
    failed = sol.result != jd.RESULTS.ok
    # the reducer saw x_k for the periods whose successor was good; the last good state (x_n, or the one
    # before the failure, where the state is frozen) is the final state
    last = jnp.where(failed, sol.final.failed_at - 1, n)
    xf = sol.final.x
    acc = sol.metrics + jnp.where(last >= s + 1, xf @ Q @ xf, 0.0)
    y = acc / (n - s)
    return jnp.where(failed & penalize, cfg.penalty, y)


def continuous_performance(plant, cfg: ContinuousSearch, n_x0: int = 1, penalize: bool = True,
                           noise_ahead: bool = False):
    """G(member, key) of (2.24) for a continuous engine plant under (2.14) with P = P_{V,s}, averaged over
    n_x0 initial states (keys ``split(key, n_x0)``; the thesis used one). ``penalize=False`` returns the
    integral up to the failure instead of the penalty (a smooth objective for gradients)."""

    def G(member: BasisMember, key):
        P = member_P(member)
        ys = jax.vmap(lambda k: rp_performance(plant, P, cfg, k, penalize, noise_ahead))(jax.random.split(key, n_x0))
        return jnp.atleast_1d(ys.mean())

    return G


@program_cache.jit
def performances(plant, cfg: ContinuousSearch, member: BasisMember, key, n: int, penalize: bool = True):
    """``n`` independent evaluations G(member, k) (one initial state each), k in ``split(key, n)``: a vector."""
    G = continuous_performance(plant, cfg, 1, penalize)
    return jax.vmap(lambda k: G(member, k)[0])(jax.random.split(key, n))


def lowest_y1(eki, vs, key, n_states: int):
    """The row of ``vs`` (candidate unit vectors) with the lowest mean y_1 = ||x_K||^2 over ``n_states`` initial
    states common to all candidates (keys ``split(key, n_states)``)."""
    sel = jax.random.split(key, n_states)
    score = jax.vmap(lambda v: jax.vmap(lambda k: eki.G(v, k))(sel)[:, 0].mean())(vs)
    return vs[jnp.argmin(score)]


@program_cache.jit
def direction_search(eki, key, *, ensemble: int, init_var: float, iterations: int, restarts: int = 1,
                     select_states: int = 64, final: str = "mean"):
    """Procedure 1 over unit vectors v (P = P_v): one whole search as a pure function of its key; returns
    (final normalised v, mean-performance history). Compiled on its own (a batch of searches
    vmaps it instead: the EKI amplifies the last-bit differences between a batched and an unbatched program,
    so one search is run unbatched).

    Members start from N(0, init_var I), normalised. ``final``: what a search ends with, the normalised
    ensemble mean (the thesis) or, with ``"best_member"``, the final member (normalised) with the lowest mean
    y_1 over ``select_states`` initial states common to the members. With ``restarts > 1`` independent
    ensembles run side by side and the final v with the lowest mean y_1 over ``select_states`` common initial
    states wins.
    """
    if final not in ("mean", "best_member"):
        raise ValueError(f"final: 'mean' or 'best_member', got {final!r}")

    def single(k):
        k_init, k_run = jax.random.split(k)
        d = eki.template.shape[0]
        members = jnp.sqrt(init_var) * jax.random.normal(k_init, (ensemble, d))
        members = members / jnp.linalg.norm(members, axis=1, keepdims=True)
        # the pure loop of the composed step (vmappable: a batch of searches is a vmap of it)
        st, hist, _ = steps.run_steps(eki.step, eki.init(members, k_run), iterations,
                                      end=eki.kalman().schedule.end, penalty=eki.penalty)
        if final == "best_member":
            unravel = eki.unravel()
            vs = jax.vmap(lambda m: eki.project(unravel(m)) if eki.project is not None else unravel(m))(st.members)
            return lowest_y1(eki, vs, jax.random.fold_in(k, 2), select_states), hist
        return eki.mean(st), hist

    if restarts == 1:
        return single(key)
    keys = jax.random.split(key, restarts + 1)
    vs, hists = jax.vmap(single)(keys[1:])
    sel = jax.random.split(keys[0], select_states)
    score = jax.vmap(lambda v: jax.vmap(lambda k: eki.G(v, k))(sel)[:, 0].mean())(vs)
    best = jnp.argmin(score)
    return vs[best], hists[best]
