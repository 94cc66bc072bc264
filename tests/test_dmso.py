"""DMSO (Stumfoll (3), (4), (6)) against a plain NumPy implementation, its Luenberger limit, the TWIP design
helpers (§7.1 discretisation, (150) LQR) against SciPy / python-control, and gradients of the noisy twip-dmso
loop against finite differences."""

import numpy as np
import jax
import jax.numpy as jnp
import pytest
import scipy.linalg

from jaxdip.control.twip_lqr import Q_THESIS, R_THESIS, twip_discrete, twip_dlqr
from jaxdip.estimators.dmso import DMSO, selection_matrix
from jaxdip.estimators.recorded import run
from jaxdip.plants import twip


def replay(est, ys, us):
    """The DMSO over recorded y_0..y_{T-1} and u_0..u_{T-1} (``us[k]`` applied after sample k): xhat_k, fhat_k for
    k = 0..T-2 (fhat_k needs y_{k+1}: the aux of sample k + 1) and W_k."""
    us_prev = np.concatenate([np.zeros((1, 1)), np.asarray(us)[:-1]])
    _, xs, aux = run(est, ys, us_prev, np.zeros(4))
    return xs, aux.fhat[1:], aux.W


def numpy_dmso(F, G, B, K, Gamma, s, c, ys, us):
    """(3), (4), (6) written out sample by sample: returns xhat_k, fhat_k and W_k for k = 0..T-1."""
    n, p = B.shape
    T = ys.shape[0]
    xhat = np.zeros(n)
    W = np.zeros((n + 1, p))
    xs, fs, Ws = [], [], []
    for k in range(T):
        phi = np.concatenate([[1.0], np.tanh(s * ys[k] + c)])
        fhat = W.T @ phi
        xs.append(xhat.copy())
        fs.append(fhat)
        Ws.append(W.copy())
        if k + 1 < T:
            xnext = F @ xhat + G @ us[k] + B @ fhat + K @ (ys[k] - xhat)  # (3) with (4)
            e = ys[k + 1] - xnext  # e_{k+1} = y_{k+1} - xhat_{k+1}
            W = W + Gamma * np.outer(phi, e) @ B  # (6): Gamma phi(y_k) e_{k+1}^T B
            xhat = xnext
    return np.array(xs), np.array(fs), np.array(Ws)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(7)
    T = 1000
    F, G, _, _ = (np.asarray(a) for a in twip_discrete(twip.TWIP(), 0.01))
    t = np.arange(T) * 0.01
    # measurements with the size and smoothness of a TWIP run, plus noise; inputs of a few volts
    ys = np.stack([np.cos(0.3 * t), 0.5 * np.sin(0.7 * t), 0.2 * np.sin(2.1 * t), 0.4 * np.cos(2.1 * t)], 1)
    ys = ys + 1e-3 * rng.normal(size=ys.shape)
    us = rng.uniform(-3, 3, size=(T, 1))
    K = np.eye(4) + 0.05 * rng.normal(size=(4, 4))
    s = rng.uniform(0.5, 2.0, size=4)
    c = rng.uniform(-0.2, 0.2, size=4)
    return F, G, K, s, c, ys, us


def test_dmso_equals_numpy_reference_over_1000_steps(data):
    F, G, K, s, c, ys, us = data
    B = np.asarray(selection_matrix(4, (1, 3)))
    assert np.array_equal(B, np.array([[0, 1, 0, 0], [0, 0, 0, 1]]).T)  # (173)
    Gamma = 0.1
    ref_x, ref_f, ref_W = numpy_dmso(F, G, B, K, Gamma, s, c, ys, us)
    est = DMSO.thesis(F, G, B, K=K, Gamma=Gamma, basis_scale=s, basis_offset=c)
    xs, fhat, W = replay(est, ys, us)  # the loop estimator, sample by sample
    scale = np.abs(ref_x).max()
    assert 0.1 < scale < 100 and np.abs(ref_W).max() > 1e-2  # the comparison is not of zeros or of a blow-up
    err = max(np.abs(np.asarray(xs) - ref_x).max(), np.abs(np.asarray(fhat) - ref_f[:-1]).max(),
              np.abs(np.asarray(W) - ref_W).max())
    print(f"max |JAX - NumPy| over 1000 steps: {err:.3g} (largest |xhat| {scale:.3g})")
    assert err < 1e-12


def test_matrix_gamma_equals_scalar_gamma(data):
    F, G, K, s, c, ys, us = data
    B = selection_matrix(4, (1, 3))
    a = replay(DMSO.thesis(F, G, B, K=K, Gamma=0.3), ys[:200], us[:200])[0]
    b = replay(DMSO.thesis(F, G, B, K=K, Gamma=0.3 * jnp.eye(5)), ys[:200], us[:200])[0]
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-14)


def _linear_run(F, G, K, x0, T, rng):
    """y = x of the exactly linear model x_{k+1} = F x_k + G u_k (no uncertainty) and the DMSO with Gamma = 0.
    u = LQR feedback plus a random excitation keeps the (open-loop unstable) state of order one."""
    Klqr = np.asarray(twip_dlqr(twip.TWIP(), Q_THESIS, R_THESIS, 0.01).K)
    xs = [np.asarray(x0, float)]
    us = []
    for _ in range(T):
        us.append(-Klqr @ xs[-1] + rng.uniform(-2, 2, size=1))
        xs.append(F @ xs[-1] + G @ us[-1])
    xs, us = np.array(xs[:T]), np.array(us)
    assert np.abs(xs).max() < 10
    xh, _, W = replay(DMSO.thesis(F, G, selection_matrix(4, (1, 3)), K=K, Gamma=0.0), xs, us)
    return xs, np.asarray(xh), np.asarray(W)


def test_gamma_zero_is_a_luenberger_observer_decaying_at_eig_F_minus_K():
    rng = np.random.default_rng(3)
    F, G, _, _ = (np.asarray(a) for a in twip_discrete(twip.TWIP(), 0.01))
    # K chosen so that F - K = M has eigenvalues 0.9, 0.7, 0.5, 0.3 (a random similarity)
    V = rng.normal(size=(4, 4))
    M = V @ np.diag([0.9, 0.7, 0.5, 0.3]) @ np.linalg.inv(V)
    K = F - M
    T = 150
    xs, xh, W = _linear_run(F, G, K, [0.5, -0.2, 0.1, 0.3], T, rng)
    e = xs - xh
    assert np.all(W == 0)
    pred = np.array([np.linalg.matrix_power(M, k) @ e[0] for k in range(T)])
    np.testing.assert_allclose(e, pred, rtol=0, atol=1e-12 * np.abs(e[0]).max())  # e_k = (F - K)^k e_0
    # the decay rate is the spectral radius of F - K
    k = np.arange(60, T)
    slope = np.polyfit(k, np.log(np.linalg.norm(e[k], axis=1)), 1)[0]
    print(f"fitted decay per step {np.exp(slope):.6f}, spectral radius of F - K 0.9")
    assert abs(np.exp(slope) - 0.9) < 1e-4


def test_thesis_gain_K_identity_has_error_matrix_F_minus_I():
    """With K_MSO = I (174) the error obeys e_{k+1} = (F - I) e_k, whose spectral radius is e^{6.29 dt} - 1."""
    rng = np.random.default_rng(4)
    F, G, A, _ = (np.asarray(a) for a in twip_discrete(twip.TWIP(), 0.01))
    xs, xh, _ = _linear_run(F, G, np.eye(4), [1.0, 0.3, 0.17, 0.017], 12, rng)
    e = xs - xh
    M = F - np.eye(4)
    # the error shrinks by ~15x per sample; x - xhat carries ~1e-16 |x| of rounding, so check while e >> that
    for k in range(1, 8):
        np.testing.assert_allclose(e[k], M @ e[k - 1], rtol=1e-8, atol=1e-14)
        assert np.linalg.norm(e[k]) < np.linalg.norm(e[k - 1])
    rho = np.abs(np.linalg.eigvals(M)).max()
    lam = np.linalg.eigvals(A).real.max()
    np.testing.assert_allclose(rho, np.expm1(lam * 0.01), rtol=1e-10)
    assert rho < 0.07


# ---- §7.1 discretisation and the (150) LQR ----------------------------------------------------------------


def test_section_7_1_G_formula_against_augmented_exponential():
    """G = F [I - exp(-A dt)] A^{-1} B (§7.1) is the ZOH integral when A is invertible; the TWIP's A is singular
    (the position is an integrator), where the integral is the power series, and ``zoh`` returns it."""
    from jaxdip.sim import zoh

    dt = 0.01
    A, B = (np.asarray(a) for a in twip.linear_model_closed_form(twip.TWIP()))
    assert np.linalg.matrix_rank(A) == 3
    # an invertible A of the same size: the printed formula and zoh agree
    A2 = A + np.diag([-0.5, 0.0, 0.0, 0.0])
    F2 = scipy.linalg.expm(A2 * dt)
    G_printed = F2 @ (np.eye(4) - scipy.linalg.expm(-A2 * dt)) @ np.linalg.solve(A2, B)
    # (I - exp(-A dt)) cancels two digits: the printed form is good to ~1e-11 relative
    np.testing.assert_allclose(np.asarray(zoh(A2, B, dt).W), G_printed, rtol=1e-9, atol=0)
    # the TWIP's singular A: sum_k A^k dt^(k+1) / (k+1)! B
    G_series = np.zeros_like(B)
    term = np.eye(4) * dt
    for k in range(1, 30):
        G_series += term @ B
        term = term @ A * dt / (k + 1)
    F, G, _, _ = twip_discrete(twip.TWIP(), dt)
    np.testing.assert_allclose(np.asarray(G), G_series, rtol=1e-13, atol=1e-18)
    np.testing.assert_allclose(np.asarray(F), scipy.linalg.expm(A * dt), rtol=1e-13, atol=1e-16)


def test_twip_dlqr_matches_python_control():
    control = pytest.importorskip("control")
    d = twip_dlqr(twip.TWIP(), Q_THESIS, R_THESIS, 0.01)
    K, S, E = control.dlqr(np.asarray(d.F), np.asarray(d.G), np.diag(Q_THESIS), R_THESIS)
    np.testing.assert_allclose(np.asarray(d.K), K, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(d.S), S, rtol=1e-8)
    assert np.abs(np.asarray(d.E)).max() < 1  # stabilises the nominal model
    # (150) written out
    Kp = np.linalg.solve(R_THESIS + d.G.T @ d.S @ d.G, d.G.T @ d.S @ d.F)
    np.testing.assert_allclose(np.asarray(d.K), Kp, rtol=1e-10)


# ---- the DMSO in the closed loop --------------------------------------------------------------------------


def _noise_loop(est_name="dmso", duration=1.0, **sensor_kw):
    import jaxdip as jd  # noqa: F401
    from jaxdip.scenarios import twip_dmso as S

    d = S.design(0.01)
    return S.loop(S.estimator(est_name, d), S.sensors(0.01, True, **sensor_kw), d), d, int(round(duration / 0.01))


def test_in_loop_fhat_equals_the_replay_on_recorded_data():
    """The DMSO's aux (fhat_{k-1}, W_k) recorded in the loop equals the DMSO replayed on the recorded
    (y, u): the network's estimate comes out of the loop, no replay needed."""
    import jaxdip as jd
    from jaxdip.scenarios.twip_initial import thesis_x0

    lp, d, n = _noise_loop()
    save = lambda s: (s.y, s.u, s.xhat, s.aux.estimator.fhat, s.aux.estimator.W)  # noqa: E731
    sol = jd.monte_carlo(jd.Rollout(lp, thesis_x0(), n, save=save), jax.random.PRNGKey(0), 1)
    ys, us, xh, fh, W = sol.saved
    tr_x, tr_f, tr_W = replay(lp.estimator, ys[0], us[0])
    np.testing.assert_array_equal(np.asarray(tr_x), np.asarray(xh[0]))
    np.testing.assert_allclose(np.asarray(fh[0, 1:]), np.asarray(tr_f), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.asarray(W[0]), np.asarray(tr_W), rtol=0, atol=1e-15)
    assert np.abs(np.asarray(tr_f)).max() > 1e-3  # the network did learn something


def test_kf_timing_wrappers_are_the_readings():
    """``Prior(kf)`` hands out F x+ + G u (x0 at k = 0) made before the update, ``DelayedMeasurement(kf, C xhat0)``
    is the filter fed y_{k-1} (C xhat0 at k = 0), the bare filter its posterior; bit for bit against the bare
    filter's own steps."""
    from jaxdip.estimators.kf import KalmanFilter
    from jaxdip.estimators.wrappers import DelayedMeasurement, Prior

    d = twip_dlqr(twip.TWIP(), Q_THESIS, R_THESIS, 0.01)
    kf = KalmanFilter(d.F, d.G, jnp.eye(4), 1e-3 * jnp.eye(4), 1e-4 * jnp.eye(4), 0.01 * jnp.eye(4), jnp.zeros(4))
    key = jax.random.PRNGKey(2)
    ys = jnp.cumsum(0.01 * jax.random.normal(key, (60, 4)), axis=0)
    us = jax.random.normal(jax.random.fold_in(key, 1), (60, 1))
    kfs = {"posterior": kf, "prior": Prior(kf), "delayed": DelayedMeasurement(kf, kf.C @ kf.xhat0)}
    so_k = kf.init(key, ys[0])
    so_kd = kf.init(key, ys[0])
    sn = {o: f.init(key, ys[0]) for o, f in kfs.items()}
    y_prev = kf.C @ kf.xhat0
    for k in range(ys.shape[0]):
        u_prev = us[k - 1] if k else jnp.zeros(1)
        prior = so_k.x if k == 0 else kf.Phi @ so_k.x + kf.W @ u_prev
        so_k, post, _ = kf.step(so_k, ys[k], u_prev, key, k)
        so_kd, delayed, _ = kf.step(so_kd, y_prev, u_prev, key, k)
        y_prev = ys[k]
        for o, ref in (("posterior", post), ("prior", prior), ("delayed", delayed)):
            sn[o], x, _ = kfs[o].step(sn[o], ys[k], u_prev, key, k)
            np.testing.assert_array_equal(np.asarray(x), np.asarray(ref), err_msg=f"{o} at {k}")


def _objective(n_seeds, duration, **sensor_kw):
    """(J, DMSO): J(dmso) = mean over seeds 0..n_seeds-1 of the noisy case and over the four states of the RMS
    estimation error (samples 1..T-1) of the DMSO-in-the-loop (``twip_dmso.rms_error``)."""
    import equinox as eqx

    import jaxdip as jd
    from jaxdip.scenarios import twip_dmso as S
    from jaxdip.scenarios.twip_initial import thesis_x0

    lp, _, n = _noise_loop(duration=duration, **sensor_kw)
    run = S.rms_error(lp, thesis_x0(), n)

    def J(est):
        r = eqx.tree_at(lambda t: t.rollout.loop.estimator, run, est)
        return jnp.mean(jd.monte_carlo(r, jax.random.PRNGKey(0), n_seeds)[0])

    return J, lp.estimator


def _fd(J, p, field, direction, h):
    import equinox as eqx

    plus = eqx.tree_at(lambda m: getattr(m, field), p, getattr(p, field) + h * direction)
    minus = eqx.tree_at(lambda m: getattr(m, field), p, getattr(p, field) - h * direction)
    return float((J(plus) - J(minus)) / (2 * h))


def test_gradients_of_noisy_mean_rms_error_match_finite_differences():
    """d/dGamma and d/dK_MSO of the noisy case's mean RMS error (4 seeds, 2 s, all sensor models on).

    The encoder quantiser makes the objective piecewise smooth with jumps; autodiff gives the derivative of the
    smooth piece. Central differences agree with it for steps small enough that no quantisation threshold is
    crossed; the step is chosen where halving it changes the difference quotient by < 1e-4 (relative)."""
    J, p0 = _objective(n_seeds=4, duration=2.0)
    Jj = eqx_jit(J)
    g = eqx_grad(J)(p0)
    D = jnp.asarray(np.random.default_rng(0).normal(size=(4, 4)))
    checks = {"Gamma": (jnp.ones(()), float(g.Gamma)), "K": (D, float(jnp.sum(g.K * D)))}
    for field, (direction, ad) in checks.items():
        for h in (2e-9, 1e-9, 5e-10, 2.5e-10):
            a, b = _fd(Jj, p0, field, direction, h), _fd(Jj, p0, field, direction, h / 2)
            if abs(a - b) < 1e-4 * abs(b):
                break
        else:
            pytest.fail(f"{field}: no jump-free finite-difference step found")
        print(f"d J / d {field}: autodiff {ad:.8g}, finite difference {b:.8g} (h = {h / 2:g}), "
              f"rel. diff {abs(ad - b) / abs(b):.2g}")
        assert abs(ad) > 1e-5
        assert abs(ad - b) < 1e-4 * abs(b)


@pytest.mark.slow
def test_pathwise_gradient_vs_monte_carlo_mean_derivative():
    """Over 256 seeds the derivative of the *mean* RMS error includes the quantiser's jumps, which the exact
    pathwise gradient misses; the straight-through encoder gradient recovers it (measured, not assumed)."""
    D = jnp.asarray(np.random.default_rng(0).normal(size=(4, 4)))
    res = {}
    for mode in ("exact", "straight_through"):
        J, p0 = _objective(n_seeds=256, duration=2.0, encoder_gradient=mode)
        Jj = eqx_jit(J)
        g = eqx_grad(J)(p0)
        fd_g = _fd(Jj, p0, "Gamma", jnp.ones(()), 1e-2)
        fd_k = _fd(Jj, p0, "K", D, 1e-2)
        res[mode] = (float(g.Gamma) / fd_g, float(jnp.sum(g.K * D)) / fd_k)
        print(f"{mode}: autodiff / finite difference (h = 0.01): Gamma {res[mode][0]:.3f}, K {res[mode][1]:.3f}")
    assert all(abs(r - 1) < 0.1 for r in res["straight_through"])
    assert all(r > 1.5 for r in res["exact"])


def eqx_jit(J):
    import equinox as eqx

    return eqx.filter_jit(J)


def eqx_grad(J):
    import equinox as eqx

    return eqx.filter_jit(eqx.filter_grad(J))
