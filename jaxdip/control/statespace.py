"""A state-space model (A, B, C, D, dt) as a pytree, its sampling (``c2d``) and the converters to and from
python-control's ``StateSpace`` (python-control is optional: imported only by the converters).

``dt`` follows python-control: 0 for continuous time, the sample period for discrete time. It is a static field
(it decides which formulas apply), so a batch of systems for ``vmap`` shares one dt; the matrices are array leaves,
so ``jit``, ``vmap`` and ``grad`` reach them.
"""

from __future__ import annotations

from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import checks
from jaxdip.sim.discretize import sample

from jaxdip._public import public_dir

__all__ = ["StateSpace", "ss", "c2d", "from_control", "to_control"]
__dir__ = public_dir(globals())


class StateSpace(eqx.Module):
    """x' = A x + B u, y = C x + D u (or x_{k+1} = A x_k + B u_k when ``dt`` > 0)."""

    A: jax.Array
    B: jax.Array
    C: jax.Array
    D: jax.Array
    dt: float = eqx.field(static=True, default=0.0)

    @property
    def nstates(self) -> int:
        return self.A.shape[-1]

    @property
    def ninputs(self) -> int:
        return self.B.shape[-1]

    @property
    def noutputs(self) -> int:
        return self.C.shape[-2]

    def isdtime(self) -> bool:
        return bool(self.dt)


def ss(A, B, C, D=None, dt: float = 0.0) -> StateSpace:
    """A checked ``StateSpace`` from matrices (python-control's ``ss(A, B, C, D, dt)``); D defaults to zero.
    Vectors and scalars are read as python-control reads them (B a column, C a row)."""
    for name, v in (("A", A), ("B", B), ("C", C)):
        checks.check_real("ss", name, v)
        checks.check_finite("ss", name, v)
    A = jnp.atleast_2d(jnp.asarray(A, dtype=jnp.float64))
    n = checks.check_square("ss", "A", A)
    B = jnp.asarray(B, dtype=jnp.float64)
    B = B.reshape(n, -1) if B.ndim < 2 else B
    C = jnp.atleast_2d(jnp.asarray(C, dtype=jnp.float64))
    checks.check_shape("ss", "B", B, (n, None), f"for a {n}-state model")
    checks.check_shape("ss", "C", C, (None, n), f"for a {n}-state model")
    p, m = C.shape[0], B.shape[1]
    if D is None:
        D = jnp.zeros((p, m))
    checks.check_real("ss", "D", D)
    checks.check_finite("ss", "D", D)
    D = jnp.asarray(D, dtype=jnp.float64)
    D = jnp.broadcast_to(D, (p, m)) if D.ndim == 0 else jnp.atleast_2d(D)
    checks.check_shape("ss", "D", D, (p, m), f"for {p} outputs and {m} inputs")
    checks.check_nonnegative("ss", "dt", dt)
    return StateSpace(A, B, C, D, float(dt))


def c2d(sys: StateSpace, Ts: float, method: str = "zoh", prewarp_frequency: Optional[float] = None) -> StateSpace:
    """python-control's ``c2d`` / ``sample_system``: the continuous ``sys`` sampled with period ``Ts`` by "zoh",
    "foh" or "tustin" (see ``jaxdip.sim.discretize.sample``). Ts must be a concrete number (it becomes the static
    ``dt``); to differentiate with respect to the period call ``sample`` with the matrices."""
    if not isinstance(sys, StateSpace):
        raise checks.ArgumentTypeError(f"c2d: sys must be a StateSpace, got {type(sys).__name__}")
    if sys.isdtime():
        checks.fail("c2d", f"sys must be a continuous-time system, got dt={sys.dt}")
    if not checks.is_concrete(Ts):
        raise checks.ArgumentTypeError("c2d: Ts must be a concrete number (it is the result's static dt)")
    return StateSpace(*sample(sys.A, sys.B, sys.C, sys.D, Ts, method, prewarp_frequency), float(Ts))


def from_control(sys: Any) -> StateSpace:
    """The ``StateSpace`` of a python-control system (a transfer function is converted by python-control's
    ``ss`` first). dt=None (unspecified timebase) reads as continuous, dt=True (discrete, no period) as 1."""
    import control  # optional: only the converters need it

    if not isinstance(sys, control.StateSpace):
        if not isinstance(sys, control.LTI):
            raise checks.ArgumentTypeError(f"from_control: expected a python-control LTI system, got "
                                           f"{type(sys).__name__}")
        sys = control.ss(sys)
    dt = 0.0 if sys.dt is None else (1.0 if sys.dt is True else float(sys.dt))
    return ss(np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C), np.asarray(sys.D), dt)


def to_control(sys: StateSpace) -> Any:
    """The python-control ``StateSpace`` of ``sys`` (NumPy copies of the matrices; not traceable)."""
    import control  # optional: only the converters need it

    if not isinstance(sys, StateSpace):
        raise checks.ArgumentTypeError(f"to_control: sys must be a StateSpace, got {type(sys).__name__}")
    if not checks.is_concrete(sys):
        raise checks.ArgumentTypeError("to_control: sys must hold concrete arrays (not inside jit, vmap or grad)")
    return control.ss(*(np.asarray(v) for v in (sys.A, sys.B, sys.C, sys.D)), sys.dt)
