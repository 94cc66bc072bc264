"""Discretisation of a linear(ised) model (linearise a plant with ``jaxdip.linearize``): the exact zero-order hold
the plants use (``zoh``), and ``sample``, which also holds first-order (triangle) and Tustin (bilinear)
discretisations of a full (A, B, C, D) model, as SciPy's ``cont2discrete`` and python-control's
``sample_system`` compute them. All are differentiable in the matrices and in the period."""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["Discrete", "zoh", "sample", "METHODS"]
__dir__ = public_dir(globals())


class Discrete(NamedTuple):
    Phi: jnp.ndarray  # e^{A h}
    Phi_inv: jnp.ndarray  # e^{-A h}, exact rather than a numerical inverse
    W: jnp.ndarray  # int_0^h e^{A s} ds B


def zoh(A, B, h) -> Discrete:
    """Exact ZOH discretisation from one matrix exponential of the augmented matrix [[A, B], [0, 0]] h.

    exp([[A, B], [0, 0]] h) = [[Phi, W], [0, I]], so Phi and W come out of the same exponential with no
    integral approximated and no inverse of A (A may be singular: the DIP's cart position is an integrator).
    A is (n, n), B (n, m) or (n,), h > 0 a scalar: checked before anything is compiled.
    """
    for name, v in (("A", A), ("B", B), ("h", h)):
        checks.check_real("zoh", name, v)
    n = checks.check_square("zoh", "A", A)
    shape_b = checks.shape_of(B)
    if len(shape_b) not in (1, 2) or shape_b[0] != n:
        checks.fail("zoh", f"B must be ({n}, m) or ({n},) for a {n}-state model, got {checks.fmt_shape(shape_b)}")
    checks.check_ndim("zoh", "h", h, (0,), "a scalar (the sample period)")
    checks.check_finite("zoh", "A", A)
    checks.check_finite("zoh", "B", B)
    checks.check_positive("zoh", "h", h)
    return _zoh(A, B, h)


@jax.jit
def _zoh(A, B, h) -> Discrete:
    # float64, or float32 for float32 matrices (a design made inside a float32 loop: the LDF's filters)
    dt = jnp.float32 if jnp.result_type(A, B) == jnp.float32 else jnp.float64
    A = jnp.asarray(A, dtype=dt)
    B = jnp.asarray(B, dtype=dt)
    B = B.reshape(A.shape[0], -1)
    n, m = B.shape
    M = jnp.zeros((n + m, n + m), dtype=A.dtype).at[:n, :n].set(A).at[:n, n:].set(B)
    E = jsl.expm(M * h)
    Phi_inv = jsl.expm(-A * h)
    return Discrete(Phi=E[:n, :n], Phi_inv=Phi_inv, W=E[:n, n:])


METHODS = ("zoh", "foh", "tustin", "bilinear")  # "bilinear" is another name of "tustin"


def sample(A, B, C, D, h, method: str = "zoh", prewarp_frequency: Optional[float] = None) -> tuple:
    """(Ad, Bd, Cd, Dd) of the continuous model (A, B, C, D) sampled with period h.

    ``method``: "zoh" (zero-order hold, the same exponential as ``zoh``), "foh" (first-order hold: the input
    interpolated linearly between samples; Bd and Dd change, the state is SciPy's, so Cd = C) or "tustin"
    (bilinear s = 2/h (z - 1)/(z + 1), with SciPy's balanced realisation: Cd = C (I - A h/2)^-1,
    Dd = D + C Bd / 2). ``prewarp_frequency`` (Tustin only) makes the response exact at that frequency, as
    python-control's. Raises ``ArgumentError`` on bad shapes or values, and, on the host path, for a
    singular I - A h/2 (SciPy raises a ``LinAlgError`` there); under jit that case gives non-finite matrices."""
    owner = "sample"
    for name, v in (("A", A), ("B", B), ("C", C), ("D", D), ("h", h)):
        checks.check_real(owner, name, v)
    checks.check_choice(owner, "method", method, METHODS)
    n = checks.check_square(owner, "A", A)
    for name, v in (("B", B), ("C", C), ("D", D)):
        if len(checks.shape_of(v)) != 2:
            checks.fail(owner, f"{name} must be a matrix, got shape {checks.fmt_shape(checks.shape_of(v))}")
    m, p = checks.shape_of(B)[1], checks.shape_of(C)[0]
    checks.check_shape(owner, "B", B, (n, m), f"for a {n}-state model")
    checks.check_shape(owner, "C", C, (p, n), f"for a {n}-state model")
    checks.check_shape(owner, "D", D, (p, m), f"for {p} outputs and {m} inputs")
    checks.check_ndim(owner, "h", h, (0,), "a scalar (the sample period)")
    for name, v in (("A", A), ("B", B), ("C", C), ("D", D)):
        checks.check_finite(owner, name, v)
    checks.check_positive(owner, "h", h)
    if prewarp_frequency is not None:
        if method not in ("tustin", "bilinear"):
            checks.fail(owner, f"prewarp_frequency applies to the Tustin method only, got method {method!r}")
        checks.check_positive(owner, "prewarp_frequency", prewarp_frequency)
        h = 2 * jnp.tan(prewarp_frequency * h / 2) / prewarp_frequency
    A, B, C, D = (jnp.asarray(v, dtype=jnp.float64) for v in (A, B, C, D))
    if method == "zoh":
        d = _zoh(A, B, h)
        return d.Phi, d.W, C, D
    out = (_foh if method == "foh" else _tustin)(A, B, C, D, h)
    if checks.is_concrete(out) and not all(bool(jnp.all(jnp.isfinite(v))) for v in out):
        checks.fail(owner, f"the {method} discretisation is not finite (I - A h/2 is singular: A has the "
                           f"eigenvalue 2/h = {2 / float(h):.6g})" if method != "foh" else
                    f"the {method} discretisation is not finite")
    return out


@jax.jit
def _foh(A, B, C, D, h):
    # exp([[A h, B h, 0], [0, 0, I], [0, 0, 0]]) holds Phi and the two input integrals of the linear hold
    n, m = B.shape
    M = jnp.zeros((n + 2 * m, n + 2 * m), dtype=A.dtype)
    M = M.at[:n, :n].set(A * h).at[:n, n:n + m].set(B * h).at[n:n + m, n + m:].set(jnp.eye(m))
    E = jsl.expm(M)
    Phi, G1, G2 = E[:n, :n], E[:n, n:n + m], E[:n, n + m:]
    return Phi, G1 - G2 + Phi @ G2, C, D + C @ G2


@jax.jit
def _tustin(A, B, C, D, h):
    n = A.shape[0]
    ima = jnp.eye(n) - 0.5 * h * A
    Ad = jnp.linalg.solve(ima, jnp.eye(n) + 0.5 * h * A)
    Bd = jnp.linalg.solve(ima, h * B)
    Cd = jnp.linalg.solve(ima.T, C.T).T
    return Ad, Bd, Cd, D + 0.5 * C @ Bd
