"""Readings of the published P (3.6): the linearised closed loop against independent NumPy/SciPy routes."""

import jaxdip  # noqa: F401  (float64)

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import jaxdip as jd
from jaxdip import config as C
import experiments.dip_controllers as DC
from jaxdip.plants import dip
from jaxdip.theory import published_p as pp


def _fd_jacobians(plant, eps=1e-6):
    """(A, B) at upright by central differences of the vector field (no autodiff)."""
    f = jax.jit(lambda x, u: plant.vector_field(x, u))
    x0, u0 = np.zeros(6), np.zeros(1)
    A = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        A[:, i] = (np.asarray(f(x0 + d, u0)) - np.asarray(f(x0 - d, u0))) / (2 * eps)
    B = ((np.asarray(f(x0, u0 + eps)) - np.asarray(f(x0, u0 - eps))) / (2 * eps))[:, None]
    return A, B


def _numpy_P(V, s):
    """I + sum (s_i - 1) q_i q_i^T with q the orthonormalised V (numpy QR: Gram-Schmidt up to signs)."""
    Q, _ = np.linalg.qr(np.asarray(V, dtype=float).T)
    return np.eye(6) + sum((si - 1.0) * np.outer(q, q) for si, q in zip(s, Q.T))


def _numpy_T(order, units, angles):
    """z = T x written out by hand: [xc, a, th, ...] -> the reading's coordinates."""
    k = 180.0 / math.pi if units == "deg" else 1.0
    xc, a, th, xcd, ad, thd = np.eye(6)
    th_z, thd_z = (a + th, ad + thd) if angles == "absolute" else (th, thd)
    rows = [xc, k * a, k * th_z, xcd, k * ad, k * thd_z]
    if order == "theta_alpha":
        rows = [rows[0], rows[2], rows[1], rows[3], rows[5], rows[4]]
    return np.stack(rows)


@pytest.mark.parametrize("variant,order,units,angles", [
    ("printed", "alpha_theta", "rad", "relative"),
    ("printed", "theta_alpha", "deg", "absolute"),
    ("lagrangian", "theta_alpha", "rad", "relative"),
])
def test_max_real_part_matches_scipy_closed_loop(variant, order, units, angles):
    """The table's entry equals scipy's eigenvalues of a closed loop built in NumPy from finite-difference
    Jacobians, a QR-orthonormalised P and a hand-written change of coordinates."""
    r = pp.Reading(variant=variant, order=order, units=units, angles=angles)
    A, B = _fd_jacobians(dip.DIP(variant=variant))
    T = _numpy_T(order, units, angles)
    P = T.T @ _numpy_P(pp.PUBLISHED_V, pp.PUBLISHED_S) @ T
    K = np.linalg.solve(B.T @ P @ B, B.T @ P @ (r.gamma * np.eye(6) + A))
    ref = scipy.linalg.eigvals(A - B @ K).real.max()
    got = pp.max_real(r)
    print(f"\n{variant} {order} {units} {angles}: module {got:.6f}, scipy {ref:.6f}")
    assert abs(got - ref) < 1e-5 * max(1.0, abs(ref))


def test_closed_loop_is_the_jacobian_of_the_nonlinear_law():
    """The linearisation formula against finite differences of x -> f(x, u_RP(x)) with the library's (2.14)."""
    r = pp.Reading(order="theta_alpha")
    plant = dip.DIP()
    ctrl = jd.control.RelaxedProjection(plant, jnp.asarray(pp.P_of(r)), r.gamma)

    @jax.jit
    def field(x):
        _, u, _ = ctrl.step(None, x, None, 0)
        return plant.vector_field(x, u)

    eps = 1e-6
    J = np.stack([(np.asarray(field(jnp.asarray(eps * e))) - np.asarray(field(jnp.asarray(-eps * e)))) / (2 * eps)
                  for e in np.eye(6)], axis=1)
    ref = np.sort_complex(scipy.linalg.eigvals(J))
    got = np.sort_complex(pp.closed_loop_eigs(r))
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-4)


def test_sign_of_all_coordinates_changes_nothing():
    """Why four flips cover every sign pattern: flipping alpha equals flipping (xc, theta) together."""
    A, B = pp._linearised("printed", pp.MW_ON)
    S = np.diag([-1.0, 1, -1, -1, 1, -1])  # xc and theta reversed
    P2 = S @ pp.document_P() @ S
    both = pp.linear_rp_eigs(A, B, P2, 40.0)
    alpha = pp.closed_loop_eigs(pp.Reading(flip="alpha"))
    np.testing.assert_allclose(np.sort_complex(both), np.sort_complex(alpha), rtol=1e-9)


def test_default_reading_is_dip_controllers_published_P():
    """The default reading is the P dip-controllers has always used (P_Vs of (3.6), unchanged)."""
    from jaxdip.control.spd import P_Vs

    ref = np.asarray(P_Vs(jnp.asarray(pp.PUBLISHED_V).T, jnp.asarray(pp.PUBLISHED_S)))
    np.testing.assert_array_equal(pp.P_of(pp.Reading()), ref)
    assert DC.reading_of(DC.DipControllersConfig()) == pp.Reading()
    # every reading's --set items give back the reading through the experiment's config
    for r in pp.one_at_a_time():
        cfg = C.load(DC.DipControllersConfig, sets=pp.set_args(r))
        assert DC.reading_of(cfg) == r


@pytest.mark.parametrize("item,key", [("published_P_flip=beta", "published_P_flip"),
                                      ("published_P_units=grad", "published_P_units"),
                                      ("variant=euler", "variant"), ("Mw=-1", "Mw")])
def test_bad_reading_keys_are_refused(item, key):
    with pytest.raises(C.ConfigError) as e:
        C.load(DC.DipControllersConfig, sets=[item])
    assert e.value.key == key
