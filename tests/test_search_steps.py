"""Composable ensemble Kalman steps against closed forms: the linear-Gaussian posterior (UKI exactly, EKI within
sampling error), the data-misfit controller's rule and end time, ETKI's square-root update, localisation on a
200-parameter problem with 20 members, failure statuses, and the box transform."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.engine.checks import ArgumentError
from jaxdip.search import (EKI, Failure, SearchStopped, data_misfit, distance_kernel, fixed, run_steps,
                           make_step, run_eki, scheduled, schur, sec, sec_fisher, step_body)
from jaxdip.search.failures import NOT_FINITE, OK, TOO_FEW_SUCCESSES
from jaxdip.search.problems import box, tikhonov


def linear_gaussian(seed=0, p=4, m=6):
    """G, prior (m0, C0), noise R, data y and the closed-form posterior (mean, covariance)."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(m, p))
    m0 = rng.normal(size=p)
    A = rng.normal(size=(p, p))
    C0 = A @ A.T / p + 0.5 * np.eye(p)
    R = np.diag(rng.uniform(0.05, 0.2, m))
    y = G @ rng.normal(size=p) + rng.multivariate_normal(np.zeros(m), R)
    P = np.linalg.inv(G.T @ np.linalg.solve(R, G) + np.linalg.inv(C0))
    mu = P @ (G.T @ np.linalg.solve(R, y) + np.linalg.solve(C0, m0))
    return G, m0, C0, R, y, mu, P


def linear(G):
    return lambda X, key: X @ jnp.asarray(G).T


def test_uki_reaches_the_linear_gaussian_posterior():
    # the prior enters as extra outputs (TEKI's augmentation); UKI's fixed point is then the posterior
    G, m0, C0, R, y, mu, P = linear_gaussian()
    fwd, y2, R2 = tikhonov(linear(G), y, R, m0, C0)
    step = make_step("uki")
    s0 = step.init((jnp.asarray(m0), jnp.asarray(C0)), jax.random.PRNGKey(0))
    s, _, n = jax.jit(lambda s: run_steps(step_body(step, fwd, y2, R2), s, 40))(s0)
    assert int(n) == 40 and int(s.status) == OK
    np.testing.assert_allclose(s.aux["mean"], mu, rtol=1e-6, atol=1e-6 * np.abs(mu).max())
    np.testing.assert_allclose(s.aux["cov"], P, rtol=1e-6, atol=1e-6 * np.abs(P).max())


def test_eki_with_the_data_misfit_controller_samples_the_posterior():
    """From a prior ensemble to algorithmic time 1 the perturbed-observation EKI is an ensemble approximation
    of the posterior: its mean within 6 standard errors sqrt(diag(P) / J) of the posterior mean (the iid bound;
    the ensemble's own error is somewhat larger), its covariance within 10% (Frobenius)."""
    G, m0, C0, R, y, mu, P = linear_gaussian()
    J = 2000
    key = jax.random.PRNGKey(1)
    E0 = jnp.asarray(m0) + jax.random.normal(jax.random.fold_in(key, 1), (J, 4)) @ jnp.linalg.cholesky(C0).T
    step = make_step("eki", schedule=data_misfit())
    s, _, n = jax.jit(lambda s: run_steps(step_body(step, linear(G), jnp.asarray(y), jnp.asarray(R)), s, 50,
                                        end=1.0))(step.init(E0, key))
    assert int(n) < 50 and float(s.time) == pytest.approx(1.0, abs=1e-12)
    M = np.asarray(s.members)
    assert np.all(np.abs(M.mean(0) - mu) < 6 * np.sqrt(np.diag(P) / J)), (M.mean(0) - mu) / np.sqrt(np.diag(P) / J)
    assert np.linalg.norm(np.cov(M.T) - P) < 0.1 * np.linalg.norm(P)


def test_data_misfit_steps_follow_the_rule_and_end_at_time_one():
    G, m0, C0, R, y, mu, P = linear_gaussian(2)
    J = 30
    key = jax.random.PRNGKey(2)
    step = make_step("eki", schedule=data_misfit())
    s = step.init(jnp.asarray(m0) + jax.random.normal(key, (J, 4)) @ jnp.linalg.cholesky(C0).T, key)
    update = jax.jit(lambda s, Y: step.update(s, Y, jnp.asarray(y), jnp.asarray(R)))
    Rinv = np.linalg.inv(R)
    t = 0.0
    for _ in range(100):
        Y = np.asarray(s.members) @ G.T
        phi = 0.5 * np.einsum("ji,ik,jk->j", Y - y, Rinv, Y - y)
        want = min(max(len(y) / (2 * phi.mean()), np.sqrt(len(y) / (2 * phi.var(ddof=1)))), 1.0 - t)
        s = update(s, jnp.asarray(Y))
        assert float(s.time) - t == pytest.approx(want, rel=1e-9)
        t = float(s.time)
        if t >= 1.0:
            break
    assert t == pytest.approx(1.0, abs=1e-12) and 1 < int(s.iteration) < 100


def test_etki_update_is_the_square_root_kalman_analysis():
    # one ETKI step: the new mean and covariance are the Kalman analysis of the ensemble's own statistics
    rng = np.random.default_rng(3)
    J, p, m = 12, 3, 5
    V = rng.normal(size=(J, p))
    Gm = rng.normal(size=(m, p))
    R = np.diag(rng.uniform(0.1, 0.3, m))
    y = rng.normal(size=m)
    Y = V @ Gm.T
    C = np.cov(np.hstack([V, Y]).T)
    Cvv, Cvy, Cyy = C[:p, :p], C[:p, p:], C[p:, p:]
    K = Cvy @ np.linalg.inv(Cyy + R)
    step = make_step("etki")
    s = step.update(step.init(jnp.asarray(V), jax.random.PRNGKey(0)), jnp.asarray(Y), jnp.asarray(y), jnp.asarray(R))
    Vn = np.asarray(s.members)
    np.testing.assert_allclose(Vn.mean(0), V.mean(0) + K @ (y - Y.mean(0)), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.cov(Vn.T), Cvv - K @ Cvy.T, rtol=1e-10, atol=1e-12)


P_LOC, M_LOC, J_LOC = 200, 50, 20
X_LOC = np.arange(P_LOC, dtype=float)
OBS_LOC = np.arange(2, P_LOC, P_LOC // M_LOC)[:M_LOC]
# the prior: a smooth field on a line, correlation length 3; observed at every 4th point with noise 0.1
L_LOC = np.linalg.cholesky(np.exp(-0.5 * ((X_LOC[:, None] - X_LOC[None, :]) / 3.0) ** 2) + 1e-6 * np.eye(P_LOC))
G_LOC = np.zeros((M_LOC, P_LOC))
G_LOC[np.arange(M_LOC), OBS_LOC] = 1.0
LOCALISERS = {"plain": None,
              "schur": schur(distance_kernel(X_LOC, X_LOC[OBS_LOC], 5.0),
                             distance_kernel(X_LOC[OBS_LOC], X_LOC[OBS_LOC], 5.0)),
              "sec": sec(1.0), "sec_fisher": sec_fisher()}


def localisation_errors(names, reps=50):
    """Relative error of the EKI mean (data-misfit steps to time 1, 20 members, 200 parameters) against the
    posterior mean, per localiser, over ``reps`` problems (truth, data and initial ensemble drawn per key)."""
    L0, G, R = jnp.asarray(L_LOC), jnp.asarray(G_LOC), 0.1 * jnp.eye(M_LOC)
    C0 = L0 @ L0.T

    def one(key):
        k1, k2, k3 = jax.random.split(key, 3)
        y = G @ (L0 @ jax.random.normal(k1, (P_LOC,))) + jnp.sqrt(0.1) * jax.random.normal(k2, (M_LOC,))
        mu = C0 @ G.T @ jnp.linalg.solve(G @ C0 @ G.T + R, y)  # the posterior mean (prior mean 0)
        E0 = jax.random.normal(k3, (J_LOC, P_LOC)) @ L0.T
        out = []
        for name in names:
            step = make_step("eki", schedule=data_misfit(), localiser=LOCALISERS[name])
            s, _, _ = run_steps(step_body(step, lambda X, k: X @ G.T, y, R), step.init(E0, key), 30, end=1.0)
            out.append(jnp.linalg.norm(s.members.mean(0) - mu) / jnp.linalg.norm(mu))
        return jnp.stack(out)

    e = np.asarray(jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(4), reps)))
    return dict(zip(names, e.T))


def interval(e):
    """Mean and the half-width of its 95% interval."""
    return e.mean(), 1.96 * e.std(ddof=1) / np.sqrt(len(e))


def check_localisers_beat_plain(errors):
    for name, e in errors.items():
        if name != "plain":
            mean, half = interval(errors["plain"] - e)  # paired: the same problems and ensembles
            assert mean - half > 0, (name, interval(errors["plain"]), interval(e))


def test_localisation_beats_plain_eki_with_200_parameters_and_20_members():
    check_localisers_beat_plain(localisation_errors(("plain", "schur", "sec")))


@pytest.mark.slow
def test_every_localiser_beats_plain_eki():
    check_localisers_beat_plain(localisation_errors(tuple(LOCALISERS)))


def test_every_member_failing_stops_within_one_iteration():
    G = lambda X, key: jnp.full((X.shape[0], 2), jnp.nan)  # noqa: E731
    E0 = jax.random.normal(jax.random.PRNGKey(0), (10, 3))
    for failure in (Failure(), Failure("ignore", min_success=3), Failure("resample")):
        step = make_step("eki", failure=failure)
        s, hist, n = jax.jit(lambda s: run_steps(step_body(step, G, jnp.zeros(2), jnp.eye(2)), s, 20))(
            step.init(E0, jax.random.PRNGKey(1)))
        assert int(n) == 1 and int(s.status) == TOO_FEW_SUCCESSES and int(s.n_ok) == 0
        np.testing.assert_array_equal(s.members, E0)  # unchanged, finite
        assert np.all(np.isfinite(np.asarray(hist[0])))


def test_run_eki_raises_one_line_when_all_fail():
    eki = EKI(G=lambda v, key: jnp.full(1, jnp.nan), template=jnp.zeros(2), y_target=jnp.zeros(1), R=jnp.eye(1),
              failure="ignore", patience=0)
    st = eki.init(jnp.ones((6, 2)), jax.random.PRNGKey(0))
    with pytest.raises(SearchStopped) as e:
        run_eki(eki, st, 50, chunk=10)
    assert "\n" not in str(e.value) and "iteration 1:" in str(e.value) and int(e.value.state.iteration) == 1


def test_an_update_that_overflows_is_not_applied():
    G = lambda X, key: 1e300 * jnp.concatenate([X, X], axis=1)  # noqa: E731  C_yy overflows to inf
    E0 = jax.random.normal(jax.random.PRNGKey(0), (8, 2))
    step = make_step("eki", failure=Failure(penalty=np.inf))
    s = step.update(step.init(E0, jax.random.PRNGKey(1)), G(E0, None), jnp.zeros(4), jnp.eye(4))
    assert int(s.status) == NOT_FINITE
    np.testing.assert_array_equal(s.members, E0)


@pytest.mark.parametrize("variant,accelerate", [("eki", None), ("eki", "nesterov"), ("etki", None),
                                                 ("etki", "nesterov"), ("uki", None)])
def test_schedules_and_localisers_compose_with_every_variant(variant, accelerate):
    G, m0, C0, R, y, mu, P = linear_gaussian(5)
    fwd, y2, R2 = tikhonov(linear(G), y, R, m0, C0)
    E0 = jnp.asarray(m0) + jax.random.normal(jax.random.PRNGKey(6), (40, 4)) @ jnp.linalg.cholesky(C0).T
    schedules = [fixed(0.5), scheduled(lambda i: 0.5 + 0.1 * i), data_misfit(20.0)]
    localisers = [None, sec_fisher(), sec(1.0)] if variant == "eki" else [None] * 3
    for schedule, loc in zip(schedules, localisers):
        step = make_step(variant, schedule=schedule, localiser=loc, accelerate=accelerate)
        s, _, n = run_steps(step_body(step, fwd, y2, R2), step.init(E0, jax.random.PRNGKey(7)), 15, end=schedule.end)
        mean = s.aux["mean"] if variant == "uki" else s.members.mean(0)
        assert int(s.status) == OK and np.all(np.isfinite(np.asarray(s.members)))
        # every combination moves the prior mean at least half way to the posterior mean (SEC shrinks this small
        # problem's real correlations too, so it gets least close)
        assert np.linalg.norm(mean - mu) < 0.5 * np.linalg.norm(m0 - mu), (schedule.name, loc)


def test_invalid_compositions_are_refused():
    for variant in ("etki", "uki"):
        with pytest.raises(ArgumentError, match=variant):
            make_step(variant, localiser=sec())
    with pytest.raises(ArgumentError, match="uki"):
        make_step("uki", failure=Failure("resample"))
    with pytest.raises(ArgumentError, match="variant"):
        make_step("enkf")


def test_box_transform_keeps_members_inside():
    b = box([0.0, -1.0, -np.inf], [1.0, np.inf, 2.0])
    target = jnp.array([0.999, 5.0, 1.9])  # near and past the bounds
    fwd = b.wrap(lambda X, key: X)
    E0 = jax.random.normal(jax.random.PRNGKey(8), (30, 3))
    step = make_step("eki", failure=Failure("resample"))
    s, _, _ = run_steps(step_body(step, fwd, target, 1e-4 * jnp.eye(3)), step.init(E0, jax.random.PRNGKey(9)), 60)
    X = np.asarray(b.to_constrained(s.members))
    assert np.all(X[:, 0] > 0) and np.all(X[:, 0] < 1) and np.all(X[:, 1] > -1) and np.all(X[:, 2] < 2)
    np.testing.assert_allclose(X.mean(0), target, atol=0.05)
    u = jnp.array([0.3, 0.5, 1.5])
    np.testing.assert_allclose(b.to_constrained(b.to_unconstrained(u)), u, rtol=1e-12)


def test_localiser_formulas_match_numpy():
    rng = np.random.default_rng(10)
    A = rng.normal(size=(12, 7))
    C = np.cov(A.T)
    p = 3
    Cvy, Cyy, var_v = C[:p, p:], C[p:, p:], np.diag(C)[:p]
    s = np.sqrt(np.diag(C))
    R = C / np.outer(s, s)
    Cvy_s, Cyy_s = sec(1.0, 0.1)(jnp.asarray(Cvy), jnp.asarray(Cyy), jnp.asarray(var_v), 12)
    Rs = R * np.abs(R)
    Rs = np.where(np.abs(Rs) > 0.1, Rs, 0.0)
    np.fill_diagonal(Rs, 1.0)
    want = Rs * np.outer(s, s)
    np.testing.assert_allclose(Cvy_s, want[:p, p:], rtol=1e-12)
    np.testing.assert_allclose(Cyy_s, want[p:, p:], rtol=1e-12)
    k = np.asarray(distance_kernel(np.arange(5.0), np.array([0.0]), 1.0))[:, 0]
    # Gaspari-Cohn: 1 at 0, 5/24 at one length, continuous there, 0 from two lengths on
    np.testing.assert_allclose(k[:3], [1.0, 5 / 24, 0.0], atol=1e-12)
    near = np.asarray(distance_kernel(np.array([1 - 1e-9, 1 + 1e-9]), np.array([0.0]), 1.0))[:, 0]
    assert abs(near[0] - near[1]) < 1e-7


def test_nesterov_momentum_follows_its_rule():
    # the accelerated step is the plain step's ensemble u_k extrapolated by theta_k (1/theta_{k-1} - 1)(u_k - u_{k-1})
    G, m0, C0, R, y, mu, P = linear_gaussian(11)
    E0 = jnp.asarray(m0) + jax.random.normal(jax.random.PRNGKey(12), (30, 4)) @ jnp.linalg.cholesky(C0).T
    plain = make_step("eki", schedule=scheduled(lambda i: 0.5 + 0.25 * i))
    acc = make_step("eki", schedule=scheduled(lambda i: 0.5 + 0.25 * i), accelerate="nesterov")
    s_acc = acc.init(E0, jax.random.PRNGKey(13))
    s_plain = plain.init(E0, jax.random.PRNGKey(13))
    u_prev, theta_prev, dt_prev = np.asarray(E0), 1.0, 1.0
    for k in range(3):
        Y = s_acc.members @ jnp.asarray(G).T
        u = np.asarray(plain.update(s_plain._replace(members=s_acc.members), Y, jnp.asarray(y), jnp.asarray(R)).members)
        s_acc = acc.update(s_acc, Y, jnp.asarray(y), jnp.asarray(R))
        s_plain = s_plain._replace(iteration=s_plain.iteration + 1)
        dt = 0.5 + 0.25 * k
        a = np.sqrt(theta_prev**2 * dt / dt_prev)
        theta = (-a + np.sqrt(a * a + 4)) / 2
        np.testing.assert_allclose(s_acc.members, u + theta * (1 / theta_prev - 1) * (u - u_prev), rtol=1e-12)
        u_prev, theta_prev, dt_prev = u, theta, dt
