"""dip-cpx-ldf: the LDF against its analytic frequency response, the encoders, the input disturbance, the gamma
criterion against an independent computation, and a tiny CLI run."""

import json
import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla

from jaxdip import config as C
from jaxdip.estimators.ldf import LDFParams, ldf
from jaxdip.estimators.run import filter_sequence
from jaxdip.experiments import dip_cpx_ldf as E
from jaxdip.plants import dip
from jaxdip.sim import dip_sensors, linearize
from jaxdip.sim.disturbance import input_disturbance, input_disturbance_params
from jaxdip.theory import mhe

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _analytic_H(w, wc, zeta):
    s = 1j * w
    return wc**2 * s / (s**2 + 2 * zeta * wc * s + wc**2)


def _zoh_H(w, wc, zeta, dt):
    """The exact zero-order-hold equivalent of H(s), by scipy (independent of jaxdip's expm), at z = e^{j w dt}."""
    import scipy.signal as ss

    A = np.array([[0.0, 1.0], [-wc**2, -2 * zeta * wc]])
    B = np.array([[0.0], [wc**2]])
    Ad, Bd, Cd, _, _ = ss.cont2discrete((A, B, np.array([[0.0, 1.0]]), np.zeros((1, 1))), dt, method="zoh")
    z = np.exp(1j * w * dt)
    return (Cd @ np.linalg.solve(z * np.eye(2) - Ad, Bd))[0, 0]


@pytest.mark.parametrize("w", [5.0, 20.0, 62.8, 150.0])
def test_ldf_frequency_response_matches_analytic(w):
    """Drive each channel with sin(w t) and fit the steady-state derivative estimate by least squares at w.

    Against the continuous H(jw) = wc^2 jw / (-w^2 + 2 zeta wc jw + wc^2): the k-th estimate is the filter state
    before y_k enters, i.e. the continuous filter driven by the held samples, so its phase trails H by the hold's
    w dt / 2, and its gain differs from |H| by the discretisation at the sample rate, about (wc dt)^2 / 12 (0.8%
    for the cart's 100 pi rad/s at 1 ms), its phase by about (w dt / 2) (wc dt)^2. Against scipy's exact ZOH equivalent it must agree to rounding.
    """
    dt = 1e-3
    wc = np.array([100 * np.pi, 20 * np.pi, 35.0])
    zeta = 0.9
    T = 4000
    t = np.arange(T) * dt
    ys = np.repeat(np.sin(w * t)[:, None], 3, axis=1)
    params = LDFParams(jnp.asarray(wc), jnp.asarray(zeta))
    _, out = filter_sequence(ldf(3, dt), params, ys, np.zeros((T, 1)), jnp.zeros(6))
    v = np.asarray(out)[:, 3:]
    keep = t >= 1.0  # transients decay at zeta * wc >= 31 /s
    M = np.stack([np.sin(w * t[keep]), np.cos(w * t[keep])], axis=1)
    for i in range(3):
        a, b = np.linalg.lstsq(M, v[keep, i], rcond=None)[0]
        measured = a + 1j * b  # |H| sin(w t + phi) = |H| cos(phi) sin + |H| sin(phi) cos
        H = _analytic_H(w, wc[i], zeta)
        gain_tol = (wc[i] * dt) ** 2 / 12 + 2e-3
        assert abs(abs(measured) / abs(H) - 1) < gain_tol, (w, i, abs(measured), abs(H))
        phase_tol = 0.5 * w * dt * (wc[i] * dt) ** 2 + 2e-3  # the same discretisation effect, on the phase
        assert abs(np.angle(measured / H) + 0.5 * w * dt) < phase_tol, (w, i, np.angle(measured / H))
        Hd = _zoh_H(w, wc[i], zeta, dt)
        assert abs(measured / Hd - 1) < 1e-6, (w, i, measured, Hd)


def test_encoder_outputs_are_whole_counts():
    names = dip.STATE_NAMES
    sp = dip_sensors.encoder_params(names, noise_counts=0.7)
    assert np.allclose(sp.quantum, [2.2749e-5, 2 * np.pi / 4096, 2 * np.pi / 4096], rtol=1e-4)
    sensor = dip_sensors.encoder_sensor(1e-3)
    xs = jax.random.uniform(jax.random.PRNGKey(1), (500, 6), minval=-0.3, maxval=0.3)
    keys = jax.random.split(jax.random.PRNGKey(2), 500)
    st = sensor.init(sp, keys[0], xs[0])
    ys = jax.vmap(lambda x, k: sensor.step(sp, st, x, k, 0)[1])(xs, keys)
    counts = np.asarray(ys) / np.asarray(sp.quantum)
    assert np.allclose(counts, np.round(counts), atol=1e-9)
    idx = [names.index(n) for n in ("xc", "alpha", "theta")]
    err = (np.asarray(ys) - np.asarray(xs)[:, idx]) / np.asarray(sp.quantum)
    # noise of 0.7 count plus rounding (variance 1/12 count^2) -- and not just rounding
    assert np.all(np.abs(err.std(axis=0) - math.sqrt(0.49 + 1 / 12)) < 0.1)
    # without noise: exactly the nearest count
    clean = dip_sensors.encoder_params(names, noise_counts=0.0)
    y0 = sensor.step(clean, st, xs[3], keys[3], 0)[1]
    q = np.asarray(clean.quantum)
    assert np.allclose(np.asarray(y0), q * np.round(np.asarray(xs[3])[idx] / q), atol=1e-15)


def test_input_disturbance_offset_and_white_part():
    act = input_disturbance()
    p = input_disturbance_params(offset_std=0.3, white_std=2.0)
    offs, outs = [], []
    for s in range(400):
        st = act.init(p, jax.random.PRNGKey(s), jnp.zeros(6))
        offs.append(float(st[0]))
    st = act.init(p, jax.random.PRNGKey(0), jnp.zeros(6))
    keys = jax.random.split(jax.random.PRNGKey(9), 4000)
    outs = np.asarray(jax.vmap(lambda k: act.step(p, st, jnp.ones(1), k, 0)[1])(keys))[:, 0]
    assert abs(np.std(offs) - 0.3) < 0.05
    assert abs(np.mean(outs) - (1.0 + float(st[0]))) < 0.1 and abs(np.std(outs) - 2.0) < 0.1


def test_gamma_criterion_matches_theory_and_thesis():
    cfg = E.DipCpxLdfConfig()
    got = E.gamma_criterion(cfg)
    plant = dip.make("printed")
    A, _ = linearize(plant.f, plant.default_params(), jnp.zeros(6), 0.0)
    A = np.asarray(A)
    Cm = np.zeros((3, 6))
    for i, n in enumerate(("xc", "alpha", "theta")):
        Cm[i, plant.index(n)] = 1.0
    ref, _, _ = mhe.cpx_gamma_criterion(jnp.asarray(sla.expm(A * 1e-3)), jnp.asarray(sla.expm(-A * 1e-3)),
                                        jnp.asarray(Cm))
    assert abs(got["gamma"] / float(ref) - 1) < 1e-6
    assert abs(got["gamma"] / 24400.0 - 1) < 0.02


def test_q_is_mapped_by_name():
    Q = np.asarray(E.DipCpxLdfConfig().Q)
    named = {n: Q[dip.STATE_NAMES.index(n)] for n in ("xc", "alpha", "theta")}
    assert named == {"xc": 80.0, "alpha": 100.0, "theta": 300.0}  # paper: diag(80, 300, 100) on [xc, theta, alpha]
    assert np.all(Q[3:] == 0) and E.DipCpxLdfConfig().R == 0.5


def test_cli_tiny_run_writes_results(tmp_path):
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", "dip-cpx-ldf", "--quick", "--seeds", "4",
                        "--set", "duration=0.2", "--set", "sweep_points=2", "--set", "sweep_seeds=2",
                        "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, JAXDIP_NO_PROGRESS="1"), timeout=600)
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())["results"]
    for est in ("cpx", "ldf"):
        for k in ("xc_mean_cm", "xc_var", "alpha_mean_deg", "alpha_var", "theta_mean_deg", "theta_var"):
            assert k in m[est] and f"{k}_ci95" in m[est], (est, k)
        assert "diverged" in m[est]
    assert abs(m["gamma_criterion"]["gamma"] / 24400.0 - 1) < 0.02
    sw = m["gamma_sweep"]
    assert len(sw["gamma"]) == 2 and len(sw["theta_var"]) == 2 and len(sw["diverged_fraction"]) == 2
    for f in ("gamma_sweep.png", "velocity_estimates.png", "report.md", "config.toml"):
        assert (out / f).is_file(), f
    cfg = C.load(E.DipCpxLdfConfig, path=str(out / "config.toml"))
    assert cfg.seeds == 4 and cfg.sweep_points == 2
