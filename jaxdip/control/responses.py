"""Time responses of a ``StateSpace`` through the engine (python-control's ``step_response`` and
``initial_response``): the model becomes a discrete ``FunctionPlant`` (a continuous one sampled exactly by its
zero-order hold over the time step, exact for the piecewise-constant inputs here), a ``ConstantInput`` drives it,
and ``jaxdip.engine.simulate`` runs the loop, so the responses jit, vmap and differentiate like any experiment.

Times: ``T`` must start at 0 and be evenly spaced (the loop's sample period is T[1] - T[0]); for a discrete
system the spacing must be its dt. python-control also accepts uneven grids and picks T itself when none is
given. Outputs follow python-control's shapes: ``step_response`` gives y[p, m, k] (output p, input m stepped
alone), ``initial_response`` y[p, k]; a SISO result is squeezed to y[k], as python-control's default.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control.feedback import ConstantInput
from jaxdip.control.statespace import StateSpace
from jaxdip.engine import checks
from jaxdip.engine.function_plant import FunctionPlant
from jaxdip.engine.roles import Passthrough
from jaxdip.engine.simulate import Loop, simulate
from jaxdip.sim.discretize import sample
from jaxdip.sim.sensors import WhiteNoise

from jaxdip._public import public_dir

__all__ = ["step_response", "initial_response"]
__dir__ = public_dir(globals())


def _linear_map(x, u, p):
    Ad, Bd = p
    return Ad @ x + Bd @ u


def _times(owner: str, sys, T) -> tuple[np.ndarray, float]:
    if not isinstance(sys, StateSpace):
        raise checks.ArgumentTypeError(f"{owner}: sys must be a StateSpace, got {type(sys).__name__}")
    if not checks.is_concrete(T):
        raise checks.ArgumentTypeError(f"{owner}: T must be concrete (it sets the number of steps)")
    T = np.asarray(T, dtype=float)
    if T.ndim != 1 or T.size < 2 or T[0] != 0:
        checks.fail(owner, f"T must be a vector of at least two times starting at 0, got shape {T.shape}"
                    + (f" starting at {T[0]:g}" if T.ndim == 1 and T.size else ""))
    h = float(T[1] - T[0])
    if h <= 0 or not np.allclose(np.diff(T), h, rtol=1e-9, atol=0):
        checks.fail(owner, "T must be evenly spaced and increasing (the loop's sample period is T[1] - T[0])")
    if sys.isdtime() and not np.isclose(h, sys.dt, rtol=1e-9, atol=0):
        checks.fail(owner, f"T must be spaced by the system's dt={sys.dt:g} for a discrete system, got {h:g}")
    return T, h


def _run(sys: StateSpace, h: float, steps: int, x0, u):
    """Outputs y[k, p] of x+ = Ad x + Bd u from x0 under the constant input u, through ``simulate``."""
    n, m = sys.B.shape
    Ad, Bd = (sys.A, sys.B) if sys.isdtime() else sample(sys.A, sys.B, sys.C, sys.D, h, "zoh")[:2]
    plant = FunctionPlant(_linear_map, tuple(f"x{i}" for i in range(n)), params=(Ad, Bd),
                          input_names=tuple(f"u{j}" for j in range(m)), discrete=True)
    loop = Loop(plant, WhiteNoise(0.0), Passthrough(), ConstantInput(u), dt=h)
    X, U = simulate(loop, x0, jax.random.PRNGKey(0), steps, save=lambda s: (s.x, s.u_applied)).saved
    return X @ sys.C.T + U @ sys.D.T


def step_response(sys: StateSpace, T, X0=None) -> tuple[np.ndarray, jax.Array]:
    """(T, y): the response to a unit step in each input alone from X0 (zeros by default), y[p, m, k]."""
    T, h = _times("step_response", sys, T)
    n, m = sys.B.shape
    x0 = jnp.zeros(n) if X0 is None else jnp.broadcast_to(jnp.asarray(X0, dtype=jnp.float64), (n,))
    Y = jax.vmap(lambda u: _run(sys, h, T.size, x0, u))(jnp.eye(m))  # (m, k, p)
    Y = jnp.transpose(Y, (2, 0, 1))
    return T, (Y[0, 0] if Y.shape[:2] == (1, 1) else Y)


def initial_response(sys: StateSpace, T, X0) -> tuple[np.ndarray, jax.Array]:
    """(T, y): the free response from the initial state X0, y[p, k]."""
    T, h = _times("initial_response", sys, T)
    n, m = sys.B.shape
    checks.check_real("initial_response", "X0", X0)
    x0 = jnp.broadcast_to(jnp.asarray(X0, dtype=jnp.float64), (n,))
    Y = _run(sys, h, T.size, x0, jnp.zeros(m)).T
    return T, (Y[0] if Y.shape[0] == 1 else Y)
