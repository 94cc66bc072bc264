"""The arguments of the Riccati solvers and LQR functions, checked before anything is solved (python-control's
convention: A (n, n), B (n, m), Q (n, n), R (m, m))."""

from __future__ import annotations

import numpy as np

from jaxdip.engine import checks


def check_problem(owner: str, A, B, Q, R, r_error: type = checks.ArgumentError, values: bool = True) -> None:
    """Shapes, dtypes and values of (A, B, Q, R) before anything is solved: A (n, n), B (n, m), Q (n, n)
    symmetric PSD, R (m, m) symmetric positive definite, all finite (values only when concrete). Scalars and
    vectors are read as ``jnp.atleast_2d`` reads them (the solvers' convention). ``values=False``: shapes and
    dtypes only (the ``*_checked`` solvers report bad values as a code, never raise on them). An R that is not
    positive definite raises ``r_error`` (the Riccati module passes an error that is also its ``RiccatiError``)."""
    shapes = {}
    for name, v in (("A", A), ("B", B), ("Q", Q), ("R", R)):
        checks.check_real(owner, name, v)
        shape = checks.shape_of(v)
        if len(shape) > 2:
            checks.fail(owner, f"{name} must be a matrix, got shape {checks.fmt_shape(shape)}")
        shapes[name] = (1,) * (2 - len(shape)) + shape

    given = {"A": A, "B": B, "Q": Q, "R": R}

    def expect(name, shape, why):
        got = shapes[name]
        if tuple(got) != tuple(e if e is not None else g for e, g in zip(shape, got)):
            original = checks.fmt_shape(checks.shape_of(given[name]))
            checks.fail(owner, f"{name} must be {checks.fmt_shape(shape)} {why}, got {original}")

    n = shapes["A"][0]
    if shapes["A"][1] != n:
        checks.fail(owner, f"A must be a square matrix, got {checks.fmt_shape(checks.shape_of(A))}")
    a = f"(A is {checks.fmt_shape(shapes['A'])})"
    expect("B", (n, None), f"for a {n}-state model {a}")
    m = shapes["B"][1]
    expect("Q", (n, n), f"for a {n}-state model {a}")
    expect("R", (m, m), f"for {m} input{'s' if m != 1 else ''} (B is {checks.fmt_shape(shapes['B'])})")
    if not values:
        return
    for name, v in (("A", A), ("B", B)):
        checks.check_finite(owner, name, v)
    if checks.is_concrete(Q):
        checks.check_psd(owner, "Q", np.atleast_2d(np.asarray(Q, dtype=float)))
    if checks.is_concrete(R):
        try:
            checks.check_psd(owner, "R", np.atleast_2d(np.asarray(R, dtype=float)), definite=True)
        except checks.ArgumentError as e:
            raise r_error(f"{e}: R is not positive definite") from None
