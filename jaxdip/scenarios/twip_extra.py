"""The TWIP extra-control study of Stumfoll §8.2: loops, initial states and Table 8.3's score.

Closed loop per sample: the true state -> tilt output (backlash (161) on phi, ``OutputBacklash``; zero width
passes phi unchanged) -> passthrough -> ``ExtraControl`` (u = sat(u_nom + u_e), or LQR alone with u_e switched
off, ``extra = 0``) -> deadzone (160) on the voltage (zero width: none) -> ``TWIPUnmodeled`` ((72)-(73) plus
the d1, d2 of (185)) over dt by RK4 sub-steps. Every case and system is the same structure with other numbers,
so a whole study is one ``monte_carlo`` sweep over stacked loops (``stack``).

Cases: param (Table 8.2 truth), unmodeled (+ d1, d2 of (185)), unmodeled_unstable (their larger gains),
deadzone (deadzone +-0.5 V on ``nonlinear_truth``), deadzone_backlash (+ tilt backlash). Systems: lqr
(perturbed truth, LQR), extra (perturbed truth, LQR + extra control), nominal (Table 8.1 truth without
unmodeled dynamics, LQR, with the case's deadzone/backlash).

Score (Table 8.3): sum over k = 0 .. N-1 of ||x_k - x_d,k||. A trajectory that leaves the bounds keeps its last
good state for the remaining samples (the loop freezes it), so its score keeps growing with them: ``Scored``
adds those terms to the engine's ``Sum`` over the live periods.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

import jaxdip as jd
from jaxdip.control.extra_control import ExtraControl, desired_state
from jaxdip.control.twip_lqr import twip_dlqr
from jaxdip.plants import twip
from jaxdip.scenarios.twip_initial import Spread, exact_first
from jaxdip.sim.actuators import Deadzone, OutputBacklash
from jaxdip.sim.twip_sensors import DEG

CASES = ("param", "unmodeled", "unmodeled_unstable", "deadzone", "deadzone_backlash")
SYSTEMS = ("lqr", "extra", "nominal")


def controller(*, dt=0.01, lqr_Q=(1.0, 1.0, 0.1, 0.1), lqr_R=1.0, v_d=0.1, k1=2.5, k2=2.5, n_hidden=10, b=1.0,
               gamma=(0.1, 0.1, 0.1, 0.1), sigma=(0.01, 0.01, 0.01, 0.01), u_max=11.1, v_scale=1.0,
               feedforward=True, tau_d=0.05, virtual="flat", virtual_sign=1.0, extra=1.0) -> ExtraControl:
    """The LQR (180)-(181) on the nominal model (79), Table 8.1, plus the extra control (module doc of
    ``jaxdip.control.extra_control``); ``gamma``, ``sigma``: [11, 12, 21, 22] of (111)-(114)."""
    d = twip_dlqr(twip.TWIP(), Q=tuple(lqr_Q), R=lqr_R, dt=dt)
    c = ExtraControl.design(d.K, d.A, d.B, dt=dt, v_d=v_d, k1=k1, k2=k2, n_hidden=n_hidden, b=b, gamma=0.0,
                            sigma=0.0, u_max=u_max, extra=extra, v_scale=v_scale, ff=1.0 if feedforward else 0.0,
                            tau_d=tau_d, virtual=virtual, virtual_sign=virtual_sign)
    g = [jnp.asarray(v, jnp.float64) for v in gamma]
    s = [jnp.asarray(v, jnp.float64) for v in sigma]
    names = ("gamma11", "gamma12", "gamma21", "gamma22", "sigma11", "sigma12", "sigma21", "sigma22")
    return eqx.tree_at(lambda m: tuple(getattr(m, n) for n in names), c, tuple(g + s))


def loop(case: str, system: str, ctrl: ExtraControl, *, dt=0.01, substeps=10, d_gains=(0.5, 0.25),
         d_gains_unstable=(0.75, 0.4), d1_freq=180.0 / math.pi, deadzone=0.5, backlash_deg=0.1,
         nonlinear_truth="table_8_2", tilt_bound_deg=90.0, state_bound=(100.0, 50.0, 1000.0, 1000.0),
         backlash_law="standard") -> jd.Loop:
    """One case and system; ``ctrl``'s ``extra`` is set by the system (1 for ``extra``, else 0)."""
    if case not in CASES or system not in SYSTEMS:
        raise ValueError(f"unknown case/system {case!r}/{system!r}")
    nominal = system == "nominal"
    if nominal or (case.startswith("deadzone") and nonlinear_truth == "table_8_1"):
        table = "8.1"
    else:
        table = "8.2"
    g = (0.0, 0.0)
    if not nominal and case == "unmodeled":
        g = d_gains
    if not nominal and case == "unmodeled_unstable":
        g = d_gains_unstable
    plant = twip.TWIPUnmodeled.table(table, g1=g[0], g2=g[1], freq=d1_freq)
    dz = deadzone if case.startswith("deadzone") else 0.0
    bl = backlash_deg * DEG if case == "deadzone_backlash" else 0.0
    ctrl = eqx.tree_at(lambda c: c.extra, ctrl, jnp.asarray(1.0 if system == "extra" else 0.0))
    bound = [state_bound[0], state_bound[1], tilt_bound_deg * DEG, state_bound[3]]
    return jd.Loop(plant=plant, sensor=OutputBacklash(1.0, -bl, bl, law=backlash_law), estimator=jd.Passthrough(),
                   controller=ctrl, actuator=Deadzone(-dz, dz), dt=dt, substeps=substeps, state_bound=bound)


def stack(modules):
    """Modules of one structure stacked along a new leading axis of every array leaf (the values of a sweep)."""
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *modules)


def distance(sample: jd.Sample):
    """One term of the score: ||x_k - x_d,k||."""
    return jnp.linalg.norm(sample.x - sample.aux.controller.xd)


def trace(sample: jd.Sample):
    """What the figures show of a period: x, u, and the controller's split into u_nom and u_e."""
    st = sample.aux.controller.state
    return {"x": sample.x, "u": sample.u[0], "u_nom": st.u_nom, "u_e": st.u_e}


class Scored(eqx.Module):
    """One trial: (Table 8.3's score, diverged, what ``rollout.save`` recorded). Called as ``scored(key, i)``
    (``monte_carlo(..., index=True)``), seed 0 starts at x0 exactly (``exact_first``)."""

    rollout: jd.Rollout

    def __call__(self, key, i=None):
        ro = self.rollout if i is None else exact_first(self.rollout, key, i)
        sol = ro(key)
        # periods from the one whose successor left the bounds (failed_at - 1) on hold the frozen state
        k = jnp.arange(ro.steps)
        frozen = jnp.linalg.norm(sol.final.x - desired_state(ro.loop.controller, k * ro.loop.dt), axis=-1)
        failed = sol.result != jd.RESULTS.ok
        tail = jnp.sum(jnp.where(failed & (k >= sol.final.failed_at - 1), frozen, 0.0))
        return sol.metrics + tail, failed, sol.saved


def scored(lp: jd.Loop, x0, spread, steps: int, save=None) -> Scored:
    return Scored(jd.Rollout(lp, Spread(x0, spread), steps, save=save, metrics=jd.metrics.Sum(distance)))


def split_trace(out):
    """``monte_carlo(detail=...)`` for a ``Scored`` that saves: ((score, diverged) per seed, the record)."""
    return (out[0], out[1]), out[2]


def sweep_of(loops):
    """The ``sweep`` argument of ``monte_carlo`` running a ``Scored`` over each of ``loops``."""
    return (lambda s: s.rollout.loop), stack(loops)


def scores_at(lp: jd.Loop, x0, spread, steps: int, key, seeds):
    """(scores, diverged) of the given seed indices (increasing; seed 0 starts at x0 exactly), as arrays over
    the seeds: differentiable in ``lp``'s leaves (the tuning target's objective)."""
    from jaxdip.tune import monte_carlo_at

    return monte_carlo_at(scored(lp, x0, spread, steps), key, seeds, index=True)
