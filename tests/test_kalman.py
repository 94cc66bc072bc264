"""KF and EKF against plain NumPy filters written here (Stumfoll (167)-(171), SciPy expm for the EKF)."""

import jaxdip  # noqa: F401  (float64)

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla

from jaxdip.engine.roles import Plant, param
from jaxdip.estimators.kalman import update
from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.recorded import run
from jaxdip.plants import lorenz
from jaxdip.engine.integrate import rk4_zoh


class LinearPlant(Plant):
    """xdot = A x + B u, for the EKF-on-a-linear-model checks."""

    A: jax.Array = param()
    B: jax.Array = param()
    state_names = ("x1", "x2", "x3", "x4")
    input_names = ("u1", "u2")

    def vector_field(self, x, u):
        return self.A @ x + self.B @ u


def filter_run(est, ys, us_prev, x0):
    """(final state, outputs) of ``est`` over recorded data."""
    st, out, _ = run(est, ys, us_prev, x0)
    return st, out


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def np_kf(F, G, H, Q, R, P0, x0, ys, us_prev):
    """Textbook discrete KF with explicit inverses; sample j predicts with u_{j-1} (from j = 1) and updates with y_j."""
    x, P = np.array(x0, float), np.array(P0, float)
    out, covs = [], []
    for j, (y, u) in enumerate(zip(ys, us_prev)):
        if j > 0:
            x = F @ x + G @ u
            P = F @ P @ F.T + Q
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x = x + K @ (y - H @ x)
        I_KH = np.eye(len(x)) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T
        out.append(x)
        covs.append(P)
    return np.array(out), np.array(covs)


def _system(rng, d=4, m=2, p=2, h=0.1):
    A = rng.standard_normal((d, d)) - 0.5 * np.eye(d)
    B = rng.standard_normal((d, m))
    M = np.zeros((d + m, d + m))
    M[:d, :d], M[:d, d:] = A, B
    E = sla.expm(M * h)
    return A, B, E[:d, :d], E[:d, d:], rng.standard_normal((p, d))


def _data(rng, F, G, H, T, q_std, r_std):
    d, m = G.shape
    x = rng.standard_normal(d)
    ys, us = [], []
    for j in range(T):
        ys.append(H @ x + r_std * rng.standard_normal(H.shape[0]))
        u = np.cos(0.2 * j) * np.ones(m)
        us.append(u)
        x = F @ x + G @ u + q_std * rng.standard_normal(d)
    us = np.array(us)
    return np.array(ys), np.vstack([np.zeros((1, m)), us[:-1]])


def test_kf_matches_numpy():
    rng = np.random.default_rng(0)
    A, B, F, G, H = _system(rng)
    ys, us_prev = _data(rng, F, G, H, 400, 0.1, 0.5)
    Q = 0.01 * np.eye(4) + 0.002 * np.ones((4, 4))
    R = np.array([[0.25, 0.05], [0.05, 0.3]])
    P0 = 2.0 * np.eye(4)
    x0 = np.array([1.0, -1.0, 0.0, 0.5])
    kf = KalmanFilter(*map(jnp.asarray, (F, G, H, Q, R, P0, x0)))
    st, out = jax.jit(lambda e: filter_run(e, ys, us_prev, jnp.zeros(4)))(kf)
    ref, covs = np_kf(F, G, H, Q, R, P0, x0, ys, us_prev)
    print(f"\nKF vs NumPy: state rel {rel(out, ref):.1e}, final covariance rel {rel(st.P, covs[-1]):.1e}")
    assert rel(out, ref) < 1e-9
    assert rel(st.P, covs[-1]) < 1e-9


def test_ekf_on_linear_plant_is_kf():
    rng = np.random.default_rng(1)
    A, B, F, G, H = _system(rng, h=0.05)
    ys, us_prev = _data(rng, F, G, H, 200, 0.05, 0.3)
    Q, R, P0 = 0.0025 * np.eye(4), 0.09 * np.eye(2), np.eye(4)
    x0 = np.zeros(4)
    ekf = ExtendedKalmanFilter(Q, R, P0, x0, model=LinearPlant(A, B), dt=0.05, C=H)
    _, out_e = filter_run(ekf, ys, us_prev, x0)
    _, out_k = filter_run(KalmanFilter(*map(jnp.asarray, (F, G, H, Q, R, P0, x0))), ys, us_prev, x0)
    assert rel(out_e, out_k) < 1e-10


def np_ekf_lorenz(p, C, Q, R, P0, x0, ys, h):
    """NumPy EKF on the Lorenz system: Jacobian by hand, Phi and the exponential-Euler mean by SciPy expm."""
    s, b, r = p.sigma, p.beta, p.rho

    def f(x):
        return np.array([s * (x[1] - x[0]), x[0] * (r - x[2]) - x[1], x[0] * x[1] - b * x[2]])

    def jac(x):
        return np.array([[-s, s, 0.0], [r - x[2], -1.0, -x[0]], [x[1], x[0], -b]])

    x, P = np.array(x0, float), np.array(P0, float)
    out = []
    for j, y in enumerate(ys):
        if j > 0:
            M = np.zeros((4, 4))
            M[:3, :3], M[:3, 3] = jac(x), f(x)
            E = sla.expm(M * h)
            Phi = E[:3, :3]
            x = x + E[:3, 3]
            P = Phi @ P @ Phi.T + Q
        K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
        x = x + K @ (y - C @ x)
        IKC = np.eye(3) - K @ C
        P = IKC @ P @ IKC.T + K @ R @ K.T
        out.append(x)
    return np.array(out)


def test_ekf_lorenz_matches_numpy():
    p = lorenz.Lorenz()
    h, T = 1e-3, 500
    rng = np.random.default_rng(4)
    C = np.asarray(lorenz.output_matrix())
    flow = jax.jit(lambda x: rk4_zoh(lorenz.f, p, x, jnp.zeros(1), h, 1))
    x = jnp.array([-8.0, 7.0, 27.0])
    ys = []
    for _ in range(T):
        ys.append(C @ np.asarray(x) + 5.0 * rng.standard_normal(2))
        x = flow(x) + 0.1 * rng.standard_normal(3)
    ys = np.array(ys)
    Q, R, P0 = 0.01 * np.eye(3), 25.0 * np.eye(2), np.eye(3)
    x0 = np.array([-7.0, 6.0, 28.0])
    ekf = ExtendedKalmanFilter(Q, R, P0, x0, model=p, dt=h, C=C)
    _, out = jax.jit(lambda e: filter_run(e, ys, np.zeros((T, 1)), x0))(ekf)
    ref = np_ekf_lorenz(p, C, Q, R, P0, x0, ys, h)
    print(f"\nEKF (Lorenz) vs NumPy: rel {rel(out, ref):.1e}")
    assert rel(out, ref) < 1e-9


# ---- singular innovation covariance and jitter ----------------------------------------------------------------


def test_kf_update_singular_s_matches_pseudo_inverse():
    """R = 0 and a rank-2 prior seen by 3 sensors: S has rank 2. The gain is the limit P C^T S^+ (NumPy pinv)."""
    rng = np.random.default_rng(7)
    M = rng.standard_normal((5, 2))
    P = M @ M.T
    C = rng.standard_normal((3, 5))
    R = np.zeros((3, 3))
    x, y = rng.standard_normal(5), rng.standard_normal(3)
    S = C @ P @ C.T
    assert np.linalg.matrix_rank(S) == 2
    x_new, P_new, _ = jax.jit(lambda *a: update(*a, a[3] @ a[0], R))(x, P, y, C)
    K = P @ C.T @ np.linalg.pinv(S, rcond=1e-10, hermitian=True)
    IKC = np.eye(5) - K @ C
    x_ref, P_ref = x + K @ (y - C @ x), IKC @ P @ IKC.T
    # the posterior covariance is ~0 here (the prior's two directions are measured exactly): measure against P
    dP = np.linalg.norm(P_new - P_ref) / np.linalg.norm(P)
    print(f"\nsingular S: correction rel {rel(x_new - x, x_ref - x):.1e}, covariance error / |P| {dP:.1e}")
    assert np.all(np.isfinite(x_new)) and np.all(np.isfinite(P_new))
    # kalman.py: the regularised solve is within ~eps / 1e-10 of the pseudo-inverse gain
    assert rel(x_new - x, x_ref - x) < 1e-5
    assert dP < 1e-5


def _duplicated_sensor_case(T=200):
    """Sensors 0 and 1 read state 0 exactly (R = 0 there), sensor 2 reads state 2 with noise: S is singular at
    every step. Duplicating an exact reading adds no information, so the filter must equal the KF that has the
    reading once (an invertible S: the NumPy reference with explicit inverses)."""
    rng = np.random.default_rng(3)
    A, B, F, G, _ = _system(rng)
    C1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    ys1, us_prev = _data(rng, F, G, C1, T, 0.1, 0.0)
    ys1[:, 1] += 0.3 * rng.standard_normal(T)
    C2 = C1[[0, 0, 1]]
    ys2 = ys1[:, [0, 0, 1]]
    Q, P0, x0 = 0.01 * np.eye(4), np.eye(4), np.zeros(4)
    R1, R2 = np.diag([0.0, 0.09]), np.diag([0.0, 0.0, 0.09])
    return A, B, F, G, C1, C2, ys1, ys2, us_prev, Q, R1, R2, P0, x0


def test_kf_duplicated_exact_sensor_is_finite_and_matches_single_sensor():
    A, B, F, G, C1, C2, ys1, ys2, us_prev, Q, R1, R2, P0, x0 = _duplicated_sensor_case()
    kf = KalmanFilter(*map(jnp.asarray, (F, G, C2, Q, R2, P0, x0)))
    st, out = jax.jit(lambda e: filter_run(e, ys2, us_prev, jnp.zeros(4)))(kf)
    ref, covs = np_kf(F, G, C1, Q, R1, P0, x0, ys1, us_prev)
    print(f"\nduplicated exact sensor vs single: state rel {rel(out, ref):.1e}, covariance rel {rel(st.P, covs[-1]):.1e}")
    assert np.all(np.isfinite(out))
    assert rel(out, ref) < 1e-6
    assert rel(st.P, covs[-1]) < 1e-6
    # the EKF shares the guarded update
    ekf = ExtendedKalmanFilter(Q, R2, P0, x0, model=LinearPlant(A, B), dt=0.1, C=C2)
    _, out_e = filter_run(ekf, ys2, us_prev, x0)
    assert rel(out_e, ref) < 1e-6


def test_kf_singular_s_gradient_is_finite_and_matches_finite_differences():
    _, _, F, G, _, C2, _, ys2, us_prev, Q, _, R2, P0, x0 = _duplicated_sensor_case(T=50)

    def loss(q):
        kf = KalmanFilter(*map(jnp.asarray, (F, G, C2, q * Q, R2, P0, x0)))
        return jnp.sum(filter_run(kf, ys2, us_prev, jnp.zeros(4))[1] ** 2)

    g = jax.jit(jax.grad(loss))(1.0)
    h = 1e-5
    fd = (loss(1.0 + h) - loss(1.0 - h)) / (2 * h)
    assert np.isfinite(g)
    assert abs(g - fd) < 1e-5 * abs(fd), (g, fd)


def np_kf_jitter(F, G, H, Q, R, P0, x0, ys, us_prev, jitter):
    """The NumPy KF with the gain from S + jitter I and the Joseph update with the true R."""
    x, P = np.array(x0, float), np.array(P0, float)
    out = []
    for j, (y, u) in enumerate(zip(ys, us_prev)):
        if j > 0:
            x = F @ x + G @ u
            P = F @ P @ F.T + Q
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R + jitter * np.eye(len(y)))
        x = x + K @ (y - H @ x)
        I_KH = np.eye(len(x)) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T
        out.append(x)
    return np.array(out), P


def test_kf_jitter_matches_numpy():
    rng = np.random.default_rng(0)
    A, B, F, G, H = _system(rng)
    ys, us_prev = _data(rng, F, G, H, 400, 0.1, 0.5)
    Q, R, P0 = 0.01 * np.eye(4), np.array([[0.25, 0.05], [0.05, 0.3]]), 2.0 * np.eye(4)
    x0 = np.array([1.0, -1.0, 0.0, 0.5])
    kf = KalmanFilter(*map(jnp.asarray, (F, G, H, Q, R, P0, x0)), jitter=0.05)
    st, out = jax.jit(lambda e: filter_run(e, ys, us_prev, jnp.zeros(4)))(kf)
    ref, P_ref = np_kf_jitter(F, G, H, Q, R, P0, x0, ys, us_prev, 0.05)
    plain, _ = np_kf_jitter(F, G, H, Q, R, P0, x0, ys, us_prev, 0.0)
    assert rel(out, ref) < 1e-9
    assert rel(st.P, P_ref) < 1e-9
    # the jitter does change the estimates (the system is unstable, so compare the first samples)
    assert rel(plain[:50], ref[:50]) > 1e-3
