"""eki-nonlinear's judging: one sweep of initial states through jd.monte_carlo, compiled once for all calls,
and equal to the plain-NumPy rollout of the relaxed projection control (2.10) with the weight (2.18)."""

import logging

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import config as C
from jaxdip.control.spd import P_v
import experiments.eki_examples as E


class _Compiles(logging.Handler):
    def __init__(self):
        super().__init__()
        self.n = 0

    def emit(self, record):
        if record.getMessage().startswith("Compiling jit(_batch)"):
            self.n += 1


def _numpy_final(v, x0, cfg, steps):
    """x_{steps-1} under (2.10) + (2.18) on f(x) = [2.2 sin(.5 x1) + .1 x2, .1 x1^2 + 1.8 x2], g = [0, 2 + .1 cos x2]."""
    P = np.asarray(P_v(jnp.asarray(v), cfg.s))
    x = np.asarray(x0, dtype=float)
    for _ in range(steps - 1):
        f = np.array([2.2 * np.sin(0.5 * x[0]) + 0.1 * x[1], 0.1 * x[0] ** 2 + 1.8 * x[1]])
        g = np.array([0.0, 2.0 + 0.1 * np.cos(x[1])])
        gk = cfg.rp_gamma / max(np.linalg.norm(x), 1e-300) ** cfg.rp_alpha
        u = -(g @ P @ (f - x / (1.0 + gk))) / (g @ P @ g)
        x = f + g * u
    return x


def test_judging_sweep_compiles_once_and_matches_numpy():
    cfg = C.load(E.EkiNonlinearConfig, quick={"judge_steps": 30, "judge_tol": 10.0})
    h = _Compiles()
    log = logging.getLogger("jax")
    old_level = log.level
    log.addHandler(h)
    log.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles(True):
            for v in ([0.995, 0.1003], [0.99, 0.14], [0.0, 1.0]):
                E.stabilizes(cfg, jnp.asarray(v), jax.random.PRNGKey(1), 16)
    finally:
        log.removeHandler(h)
        log.setLevel(old_level)
    assert h.n == 1  # three sweeps of 16 initial states, one program
    # the judged states, x_{steps-1} of each swept rollout, against NumPy; the verdict at a tolerance that
    # splits them
    import dataclasses

    import jaxdip as jd

    v = jnp.asarray([0.995, 0.1003])
    x0s = cfg.judge_std * jax.random.normal(jax.random.PRNGKey(1), (16, 2))
    sol = jd.monte_carlo(E.rp_rollout(cfg, v, cfg.judge_steps), jax.random.PRNGKey(1), 1, sweep=(E.initial_state, x0s))
    finals = np.array([_numpy_final(v, x0, cfg, cfg.judge_steps) for x0 in np.asarray(x0s)])
    np.testing.assert_allclose(np.asarray(sol.saved[0][:, 0, -1]), finals, rtol=1e-9, atol=1e-15)
    norms = np.linalg.norm(finals, axis=1)
    tol = float(np.sort(norms)[4] * (1 + 1e-6))  # 5 of the 16 within
    ok, frac = E.stabilizes(dataclasses.replace(cfg, judge_tol=tol), v, jax.random.PRNGKey(1), 16)
    assert not bool(ok) and float(frac) == 5 / 16
