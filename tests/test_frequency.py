"""freqresp/bode and margins against python-control 0.10 (60 random systems each), and the margins' gradients
(implicit differentiation at the refined crossovers) against finite differences."""

import warnings

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import StateSpace, bode, freqresp, from_control, margins, ss
from jaxdip.engine.checks import ArgumentError
from control_systems import batch, fd_grad, rel, stack

COUNT = 60
TOL = 1e-9
jmargins = jax.jit(margins)


@pytest.mark.parametrize("discrete", [False, True])
def test_freqresp_and_bode_match_python_control(discrete):
    systems = batch(COUNT, discrete=discrete, seed=1000)
    dt = 0.1 if discrete else 0.0
    omega = np.logspace(-2, np.log10(0.99 * np.pi / dt) if discrete else 2, 50)
    A, B, C, D = stack(systems)
    H = jax.jit(jax.vmap(lambda A, B, C, D: freqresp(StateSpace(A, B, C, D, dt), omega)))(A, B, C, D)
    for i, (kind, *_) in enumerate(systems):
        sys = control.ss(A[i], B[i], C[i], D[i], dt)
        Hc = sys.frequency_response(omega).complex
        assert rel(H[i], Hc) < TOL, (i, kind, rel(H[i], Hc))
    siso = control.ss(A[0], B[0][:, :1], C[0][:1], D[0][:1, :1], dt)
    mag, phase, w = bode(from_control(siso), omega)
    magc, phasec, _ = control.frequency_response(siso, omega)
    assert rel(mag, magc) < TOL and np.allclose(phase, phasec, rtol=0, atol=1e-12) and np.all(w == omega)


def _loops(count, seed):
    """SISO loops of four states: stable, unstable, marginal and badly scaled, with gains that make crossovers."""
    out = []
    for i, (kind, A, B, C, D) in enumerate(batch(count, m=1, p=1, seed=seed,
                                                 kinds=("generic", "marginal", "scaled", "stable"))):
        rng = np.random.default_rng(seed + i)
        if kind == "stable":
            A = A - (np.linalg.eigvals(A).real.max() + rng.uniform(0.1, 1.0)) * np.eye(4)
        D = D * (0.3 if i % 2 else 0.0)
        out.append((kind, A, B * 10 ** rng.uniform(-0.5, 1.5), C, D))
    return out


def test_margins_match_python_control():
    loops = _loops(COUNT, 1100)
    A, B, C, D = stack(loops)
    got = jax.jit(jax.vmap(lambda A, B, C, D: margins(StateSpace(A, B, C, D))))(A, B, C, D)
    got = np.stack([np.asarray(g) for g in got], axis=1)
    with_pc = with_gm = 0
    for i, (kind, *_) in enumerate(loops):
        ref = np.array(control.margin(control.ss(A[i], B[i], C[i], D[i])), dtype=float)
        assert np.allclose(got[i], ref, rtol=TOL, atol=0, equal_nan=True), (i, kind, got[i], ref)
        with_pc += np.isfinite(ref[1])
        with_gm += np.isfinite(ref[0])
    assert with_pc > COUNT // 2 and with_gm > COUNT // 4  # most loops have crossovers to compare


def test_margins_of_textbook_loops():
    # k / (s (s + 1) (s + 2)): phase crossover at sqrt(2), gain margin 6 / k (closed forms)
    for k in (0.5, 1.0, 3.0):
        sys = from_control(control.tf([k], [1, 3, 2, 0]))
        gm, pm, wpc, wgc = (float(v) for v in jmargins(sys))
        assert abs(wpc - np.sqrt(2)) < 1e-12 and abs(gm - 6 / k) < 1e-12 * 6 / k
        w = wgc  # at the gain crossover |L| = 1 and the phase margin is 180 + angle(L)
        L = k / (1j * w * (1j * w + 1) * (1j * w + 2))
        assert abs(abs(L) - 1) < 1e-12 and abs(pm - (180 + np.degrees(np.angle(L)))) < 1e-9
    # no crossover: inf margins, nan frequencies
    gm, pm, wpc, wgc = jmargins(from_control(control.tf([0.5], [1, 1])))
    assert np.isinf(gm) and np.isinf(pm) and np.isnan(wpc) and np.isnan(wgc)


def test_discrete_margins_match_python_control():
    # python-control's default falls back to interpolating a sampled response for discrete loops (its 'frd'
    # method); its 'poly' method finds the crossovers as polynomial roots on the unit circle, exact to rounding
    dt = 0.1
    loops = []
    for i, (kind, A, B, C, D) in enumerate(batch(COUNT, m=1, p=1, discrete=True, seed=2000,
                                                 kinds=("generic", "marginal", "scaled", "stable"))):
        rng = np.random.default_rng(i)
        if kind == "stable":
            A = A * 0.8 / np.abs(np.linalg.eigvals(A)).max()
        loops.append((kind, A, B * 10 ** rng.uniform(-0.5, 1.0), C, D * (0.3 if i % 2 else 0.0)))
    A, B, C, D = stack(loops)
    got = np.asarray(jax.jit(jax.vmap(lambda A, B, C, D: jnp.stack(margins(StateSpace(A, B, C, D, dt)))))(
        A, B, C, D))
    at_pole = []
    for i, (kind, *_) in enumerate(loops):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # python-control's warnings on the 'poly' method's accuracy
            ref = control.stability_margins(control.ss(A[i], B[i], C[i], D[i], dt), method="poly")
        ref = np.array([ref[0], ref[1], ref[3], ref[4]], dtype=float)
        if not np.allclose(got[i], ref, rtol=TOL, atol=0, equal_nan=True):
            # python-control counts a pole on the unit circle as a phase crossover (|L| = inf there, gm ~ 1e-16);
            # jaxdip does not; everything else agrees
            z = np.exp(1j * ref[2] * dt)
            assert kind == "marginal" and ref[0] < 1e-12 and np.abs(np.linalg.eigvals(A[i]) - z).min() < 1e-6
            assert np.allclose(got[i][[1, 3]], ref[[1, 3]], rtol=TOL, atol=0, equal_nan=True)
            at_pole.append(i)
    assert len(at_pole) <= COUNT // 10, at_pole


def test_margins_gradient_matches_finite_differences():
    # 20 / ((s + 1) (s + 2) (s + 3)) in a random state basis: both crossovers simple, away from w = 0
    rng = np.random.default_rng(5)
    V = rng.standard_normal((3, 3)) + 3 * np.eye(3)
    A = V @ np.diag([-1.0, -2.0, -3.0]) @ np.linalg.inv(V)
    B, C, D = V @ np.ones((3, 1)), np.array([[20.0 / 2, -20.0, 20.0 / 2]]) @ np.linalg.inv(V), np.zeros((1, 1))
    ref = np.array(control.margin(control.ss(A, B, C, D)), dtype=float)

    @jax.jit
    def f(A, B):
        return jnp.stack(margins(StateSpace(A, B, jnp.asarray(C), jnp.asarray(D))))

    assert np.allclose(f(A, B), ref, rtol=TOL) and np.all(np.isfinite(ref)) and ref[2] > 0
    JA, JB = jax.jacobian(f, argnums=(0, 1))(A, B)
    FA = fd_grad(lambda x: np.asarray(f(x, B)), A)  # (3, 3, 4): the four margins at once
    FB = fd_grad(lambda x: np.asarray(f(A, x)), B)
    for k in range(4):
        assert rel(JA[k], FA[..., k]) < 1e-6, k
        assert rel(JB[k], FB[..., k]) < 1e-6, k


def test_bad_arguments_raise():
    mimo = ss(-np.eye(2), np.eye(2), np.eye(2))
    with pytest.raises(ArgumentError, match="SISO"):
        margins(mimo)
    with pytest.raises(ArgumentError, match="StateSpace"):
        margins(control.tf([1], [1, 1]))
