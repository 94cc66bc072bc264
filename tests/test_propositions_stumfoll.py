"""Stumfoll's Lemmas 1 and 2 (stability of x_{k+1} = F(k) x_k with F(k) = I - Gamma phi_k phi_k^T, the weight
recursion of the DMSO), checked with the thesis's basis phi(x) = [1, tanh(x_1), ..., tanh(x_4)] (§8.1.1, jaxdip's
tanh_basis) along TWIP-sized state signals sampled at the thesis's 0.01 s.

Reference: products of the F(k) formed in NumPy and their spectral norms (the state-transition matrix psi).

What was derived again. For a unit vector u, (I - Gamma phi phi^T) u has length at most 1 exactly when
0 <= Gamma ||phi||^2 <= 2, so the lemma's "0 < Gamma < 2" guarantees ||F(k)|| <= 1 only for ||phi|| <= 1. The
thesis's basis has a constant 1 in it, so ||phi||^2 lies in [1, 5] and the condition that holds is
0 < Gamma ||phi_k||^2 < 2 (for the thesis's Gamma = 0.1 and 0.5: Gamma ||phi||^2 <= 0.5 and 2.5, so 0.5 needs
states with some tanh below saturation). The test asserts the lemma under this condition and shows it fail
with Gamma = 1.9 < 2 on saturated states.
"""

import numpy as np

import jax.numpy as jnp

import jaxdip  # noqa: F401  (float64)
from jaxdip.estimators.dmso import DMSO, tanh_basis


def _phis(x):
    prm = DMSO.thesis(np.eye(4), np.zeros((4, 1)), np.eye(4)[:, [1, 3]])
    ph = np.stack([np.asarray(tanh_basis(prm, jnp.asarray(xi))) for xi in x])
    np.testing.assert_allclose(ph, np.concatenate([np.ones((len(x), 1)), np.tanh(x)], axis=1), atol=1e-15)
    return ph


def _psi_norms(phis, Gamma, L):
    """||psi(k0 + L, k0)|| for every window start k0, and the largest ||psi(k1, 0)|| over k1."""
    Fs = [np.eye(5) - Gamma * np.outer(p, p) for p in phis]
    window = []
    for k0 in range(0, len(Fs) - L, 7):
        psi = np.eye(5)
        for F in Fs[k0:k0 + L]:
            psi = F @ psi
        window.append(np.linalg.norm(psi, 2))
    psi, run = np.eye(5), []
    for F in Fs:
        psi = F @ psi
        run.append(np.linalg.norm(psi, 2))
    return np.array(window), np.array(run)


def test_lemmas_1_2_weight_recursion():
    """Persistently exciting states (four sinusoids, 0.5-1.7 Hz, amplitudes 0.05-0.5 like the TWIP's position,
    speed, tilt and tilt rate): with Gamma ||phi||^2 < 2 every psi(k1, k0) has norm <= 1 (Lemma 1's hypothesis:
    no weight error grows) and every window of L = 100 samples (1 s), over which sum phi phi^T > 0 (Definition 1),
    has norm < 1 (Lemma 2). A constant state (not PE: phi phi^T has rank 1) leaves norm 1 (no contraction), and
    Gamma = 1.9 (< 2 as printed) on saturated states (||phi||^2 near 5) makes psi grow."""
    t = np.arange(3000) * 0.01
    amp = np.array([0.3, 0.5, 0.05, 0.4])
    x = amp * np.sin(2 * np.pi * np.array([0.5, 0.9, 1.3, 1.7]) * t[:, None] + np.array([0.0, 1.0, 2.0, 3.0]))
    phis = _phis(x)
    for Gamma in (0.1, 0.5):
        assert (Gamma * np.sum(phis**2, axis=1)).max() < 2
        lam = min(np.linalg.eigvalsh(phis[k:k + 100].T @ phis[k:k + 100]).min() for k in range(0, 2900, 7))
        assert lam > 0
        window, run = _psi_norms(phis, Gamma, 100)
        print(f"\nLemma 2, Gamma {Gamma}: PE level {lam:.2e}, 1 - max ||psi|| over 1 s windows {1 - window.max():.1e}, "
              f"||psi(30 s, 0)|| {run[-1]:.1e}")
        assert run.max() <= 1 + 1e-12 and window.max() < 1 - 1e-7  # a margin far above rounding
    const = _phis(np.tile(x[:1], (300, 1)))
    window, _ = _psi_norms(const, 0.1, 100)
    assert np.all(np.abs(window - 1.0) < 1e-12)
    sat = _phis(np.tile([3.0, 3.0, 3.0, 3.0], (300, 1)) + 0.01 * x[:300])
    _, run = _psi_norms(sat, 1.9, 100)
    assert run[-1] > 1e6
