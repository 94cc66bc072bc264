"""Procedure 1 on the engine: the native relaxed projection controller, the norm bound of a Loop, the (2.23)
and (2.24) evaluations through jd.simulate, and jaxdip.tune's projected steps, each against an independent
reference (the laws in NumPy, a hand-written loop, plain NumPy, optax by hand)."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxdip as jd
from jaxdip.control.projection import RelaxedProjection
from jaxdip.control.spd import P_v
from jaxdip.plants import dip, examples2d
from jaxdip.scenarios import eki_dip as S
from jaxdip.search.p_search import (
    BasisMember, continuous_performance, discrete_performance, member_P, performances, project_member,
)
from jaxdip.engine.integrate import rk4_zoh
from jaxdip.tune import tune


def _member():
    plant = S.plant()
    A, B = jd.linearize(plant)
    v1 = S.lqr_direction(A, B)
    v2 = jnp.asarray([0.1, 0.3, -0.1, 0.9, 0.0, 0.2])
    return project_member(BasisMember(jnp.stack([v1, v2]), jnp.log(jnp.asarray([1e6, 1e4]))))


def test_native_controller_matches_the_laws_in_numpy():
    """RelaxedProjection's step against (2.14), (2.10) with the weight (2.18), and (2.9) evaluated in NumPy from
    the plant's f(x) and g(x) (g by central differences of the DIP's field; the 2-D example's own f and g)."""
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    # continuous (2.14) on the DIP
    P = np.asarray(member_P(_member()))
    plant = dip.DIP(variant="printed")
    new = RelaxedProjection(plant, jnp.asarray(P), 40.0)
    field = jax.jit(lambda x, u: plant.vector_field(x, u))
    for i, k in enumerate(keys):
        x = 0.05 * jax.random.normal(k, (6,))
        fx = np.asarray(field(x, jnp.zeros(1)))
        gx = (np.asarray(field(x, jnp.ones(1))) - np.asarray(field(x, -jnp.ones(1)))) / 2  # affine in u
        xn = np.asarray(x)
        ref = -(40.0 * gx @ P @ xn + gx @ P @ fx) / (gx @ P @ gx)
        np.testing.assert_allclose(np.asarray(new.step((), x, k, i)[1]), [ref], rtol=1e-9)
    # discrete (2.10) with the weight (2.18), and the projection (2.9), on the nonlinear 2-D example
    pl = examples2d.Nonlinear()
    Pv = np.asarray(P_v(jnp.asarray([0.995, 0.1003])))
    for proj in (False, True):
        new = RelaxedProjection(pl, jnp.asarray(Pv), 0.1, 2.0, kind="discrete", projection_only=proj)
        for i, k in enumerate(keys):
            x = jax.random.normal(k, (2,))
            xn = np.asarray(x)
            fx = np.array([2.2 * np.sin(0.5 * xn[0]) + 0.1 * xn[1], 0.1 * xn[0] ** 2 + 1.8 * xn[1]])
            gx = np.array([0.0, 2.0 + 0.1 * np.cos(xn[1])])
            g_k = 0.1 / np.linalg.norm(xn) ** 2.0
            target = fx if proj else fx - xn / (1.0 + g_k)
            ref = -(gx @ Pv @ target) / (gx @ Pv @ gx)
            np.testing.assert_allclose(np.asarray(new.step((), x, k, i)[1]), [ref], rtol=1e-9)


def test_norm_bound_ends_a_trajectory_where_numpy_says():
    """x_{k+1} = 1.3 x_k from x0 = (0.6, 0.8): |x_k| = 1.3^k crosses 10 first at k = 9 (1.3^9 = 10.6)."""

    class Grow(jd.DiscretePlant):
        state_names = ("a", "b")

        def step(self, x, u):
            return 1.3 * x

    loop = jd.Loop(plant=Grow(), sensor=jd.Identity(), estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(jnp.zeros((1, 2))), dt=1.0, substeps=1, norm_bound=10.0,
                   state_bound=9.0)  # no component alone exceeds 9 before the norm exceeds 10
    sol = jd.simulate(loop, jnp.asarray([0.6, 0.8]), jax.random.PRNGKey(0), 20)
    k_np = int(np.argmax(1.3 ** np.arange(21) > 10.0))
    assert int(sol.result) == jd.RESULTS.out_of_bounds and int(sol.final.failed_at) == k_np == 9
    np.testing.assert_allclose(np.asarray(sol.final.x), 1.3 ** (k_np - 1) * np.asarray([0.6, 0.8]), rtol=1e-14)


def _numpy_discrete(A, B, v, key, K, fail_norm, penalty):
    """(2.23) by hand: projection control on x+ = A x + B u, frozen at the last state inside fail_norm."""
    P = np.asarray(P_v(jnp.asarray(v), 1e6))
    x = np.asarray(jax.random.normal(key, (2,)))
    for _ in range(K):
        u = -np.linalg.solve(B.T @ P @ B, B.T @ P @ (A @ x))
        xn = A @ x + B @ u
        if not np.all(np.isfinite(xn)) or np.linalg.norm(xn) > fail_norm:
            return np.asarray([penalty, 1.0])
        x = xn
    d = A @ x - x
    pn = lambda z: np.sqrt(z @ P @ z)
    return np.asarray([x @ x, (d @ P @ x) / (pn(d) * pn(x))])


def test_discrete_performance_matches_numpy():
    pl = examples2d.Linear()
    A, B = np.asarray(pl.A), np.asarray(pl.B)
    G = jax.jit(discrete_performance(pl, 1e6, 8, fail_norm=100.0, penalty=1000.0))
    failed = 0
    for i in range(12):
        v = np.asarray(jax.random.normal(jax.random.PRNGKey(i), (2,)))
        v = v / np.linalg.norm(v)
        ref = _numpy_discrete(A, B, v, jax.random.PRNGKey(100 + i), 8, 100.0, 1000.0)
        failed += ref[0] == 1000.0
        np.testing.assert_allclose(np.asarray(G(jnp.asarray(v), jax.random.PRNGKey(100 + i))), ref, rtol=1e-9,
                                   atol=1e-12)
    assert 0 < failed < 12  # both branches are exercised


def _scan_performance(plant, P, cfg, key, penalize=True):
    """(2.24) as the hand-written loop the engine version replaced (the search's own scan)."""
    k0, kn = jax.random.split(key)
    x0 = cfg.x0_std * jax.random.normal(k0, (plant.n,))
    f = lambda p, x, u: p.vector_field(x, u)

    def body(c, k):
        x, acc, failed = c
        u = RelaxedProjection(plant, P, cfg.gamma).step((), x, None, k)[1]
        xn = rk4_zoh(f, plant, x, u, cfg.dt, cfg.substeps)
        xn = xn + cfg.noise_std * jax.random.normal(jax.random.fold_in(kn, k), xn.shape)
        failed = failed | ~jnp.all(jnp.isfinite(xn)) | (jnp.linalg.norm(xn) > cfg.fail_norm)
        xn = jnp.where(failed, x, xn)
        acc = acc + jnp.where((k >= cfg.t_star_steps) & ~failed, xn @ cfg.Qpos @ xn, 0.0)
        return (xn, acc, failed), None

    (_, acc, failed), _ = jax.lax.scan(body, (x0, 0.0, False), jnp.arange(cfg.n_steps))
    return jnp.where(failed & penalize, cfg.penalty, acc / (cfg.n_steps - cfg.t_star_steps))


@pytest.mark.slow  # three DIP loops compiled twice each: over a minute on a shared 2-core machine
def test_continuous_performance_equals_the_hand_loop():
    """Through jd.simulate (a KeySchedule for the evaluation's noise stream, a reducer plus the final state for
    the window) the numbers are the hand loop's, failing evaluations included (gamma 0 with a large x0 fails
    after the window has started, so the integral up to the failure is compared too)."""
    plant = S.plant()
    m = _member()
    P = member_P(m)
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    refs = []
    for cfg in (S.search_setup(T=0.15, t_star=0.05),
                S.search_setup(T=0.15, t_star=0.05, gamma=0.0, x0_std=[0.3, 0.3, 0.3, 0, 0, 0]),
                S.search_setup(T=0.15, t_star=0.01, gamma=0.0, x0_std=[0.3, 0.3, 0.3, 0, 0, 0])):

        @jax.jit
        def both(k):
            ref = [_scan_performance(plant, P, cfg, jax.random.split(k, 1)[0], pen) for pen in (True, False)]
            new = [continuous_performance(plant, cfg, 1, pen)(m, k)[0] for pen in (True, False)]
            return jnp.stack(ref), jnp.stack(new)

        ref, new = jax.vmap(both)(keys)
        np.testing.assert_allclose(np.asarray(new), np.asarray(ref), rtol=1e-12)
        refs.append(np.asarray(ref))
    ref = np.concatenate(refs)
    # both failure cases occur: after the window started (a partial integral) and before it (zero)
    assert np.any((ref[:, 0] == cfg.penalty) & (ref[:, 1] > 0)) and np.any((ref[:, 0] == cfg.penalty) & (ref[:, 1] == 0))
    # performances: one evaluation per key of split(key, n)
    ys = performances(plant, cfg, m, jax.random.PRNGKey(5), 3)
    one = jax.vmap(lambda k: continuous_performance(plant, cfg)(m, k)[0])(jax.random.split(jax.random.PRNGKey(5), 3))
    np.testing.assert_allclose(np.asarray(ys), np.asarray(one), rtol=1e-12)


def test_an_ensemble_sharing_one_key_with_the_noise_drawn_ahead_is_the_hand_loop():
    """The eki-dip search's evaluation (members batched, one key, ``noise_ahead``): each member's number is
    the hand loop's on the same noise sequence."""
    plant = S.plant()
    cfg = S.search_setup(T=0.15, t_star=0.05)
    m0 = _member()
    scales = jnp.array([0.5, 1.0, 2.0])
    key = jax.random.PRNGKey(3)

    def member(c):
        return BasisMember(m0.V, m0.log_s + jnp.log(c))

    new = jax.jit(jax.vmap(lambda c: continuous_performance(plant, cfg, noise_ahead=True)(member(c), key)[0]))(scales)
    ref = jax.jit(jax.vmap(lambda c: _scan_performance(plant, member_P(member(c)), cfg, jax.random.split(key, 1)[0],
                                                       True)))(scales)
    np.testing.assert_allclose(np.asarray(new), np.asarray(ref), rtol=1e-12)
    assert len(set(np.asarray(new).tolist())) == 3  # the members differ: the test compares three numbers


def test_tune_projected_steps_equal_optax_by_hand():
    """tune(project=, zero_nonfinite_grads=) is Adam after clipping, non-finite derivatives as 0, then the
    projection, keeping the best iterate before its update: the loop written out with optax."""

    def J(theta, key):
        v = theta["v"]
        # the first coordinate's derivative is NaN (sqrt at 0 times 0), the rest finite
        return jnp.sum((v - jnp.asarray([0.0, 0.6, 0.8])) ** 2) + 0.0 * jnp.sqrt(jnp.abs(v[0]) - jnp.abs(v[0]))

    proj = lambda th: {"v": th["v"] / jnp.linalg.norm(th["v"])}
    init = {"v": jnp.asarray([0.0, 1.0, 0.0])}
    res = tune(J, init, jax.random.PRNGKey(0), steps=6, lr=0.1, clip=1.0, mode="reverse", project=proj,
               zero_nonfinite_grads=True, progress=False)
    opt = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(0.1))
    th, o, best, best_val, losses = init, opt.init(init), init, np.inf, []
    for _ in range(6):
        val, g = jax.value_and_grad(J)(th, None)
        g = jax.tree_util.tree_map(lambda x: jnp.where(jnp.isfinite(x), x, 0.0), g)
        upd, o = opt.update(g, o, th)
        losses.append(float(val))
        if losses[-1] < best_val:
            best, best_val = th, losses[-1]
        th = proj(optax.apply_updates(th, upd))
    np.testing.assert_allclose(res.loss_history, losses, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(res.theta["v"]), np.asarray(best["v"]), rtol=1e-13)
    assert abs(float(jnp.linalg.norm(res.theta["v"])) - 1.0) < 1e-14
