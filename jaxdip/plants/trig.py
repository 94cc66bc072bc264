"""``sincos``: sine and cosine of one angle together, in operations XLA's CPU backend vectorises.

Why not ``jnp.sin`` / ``jnp.cos``: in float64, XLA's CPU backend calls the C library once per element for each
(about 7.5 ns an element on this project's CPU, docs/performance.md), and a right-hand side that needs both for
two angles spends most of its time there. A polynomial in their place is cheap (about 1 ns for the pair) but XLA
treats it as cheap too and copies it into every fused kernel that reads it, which in the DIP's RK4 step made the
period 2.7 times slower than the library calls. A value that ends in a division is one XLA does not copy, so this
form ends in one by construction:

    x = n pi/2 + r,  |r| <= pi/4          (Cody-Waite: pi/2 in three parts, the first two products exact for |n| < 2^30)
    t = tan(r/2)                           (Cephes' rational approximation of tan, |r/2| <= pi/8)
    sin r = 2t / (1 + t^2),  cos r = (1 - t^2) / (1 + t^2)

where the quadrant n mod 4 swaps and negates the numerators, so that the division comes last. Since
|t| <= tan(pi/8) < 0.42, neither numerator cancels, so the relative error stays within a few ulp, except within
about 1e-12 |x| of a zero other than x = 0, where the three-part reduction leaves an absolute error of about
1e-28 |x| (tests/test_trig.py measures both against NumPy). Beyond |x| ~ 1e9 the reduction loses accuracy (as
Cephes' own sin does); no loop of this library comes near. ``inf`` and ``nan`` give ``nan``; sin(-0) is +0.
Derivatives are defined, not traced through the formula: d sin = cos dx and d cos = -sin dx from the computed
values, to every order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip._public import public_dir

__all__ = ["sincos"]
__dir__ = public_dir(globals())

# pi/2 = _PIO2_1 + _PIO2_2 + _PIO2_3: the first two have short mantissas, so n * _PIO2_1 and n * _PIO2_2 are exact
# for the n that matter (Cephes' DP1..DP3 for pi/4, doubled)
_PIO2_1 = 1.57079625129699707031e0
_PIO2_2 = 7.54978941586159635335e-8
_PIO2_3 = 5.39030285815811905290e-15
_TWO_OVER_PI = 0.63661977236758134308

# Cephes tan.c: tan(h) = h + h * z P(z) / Q(z), z = h^2, |h| <= pi/4, relative error ~2e-16
_TAN_P = (-1.30936939181383777646e4, 1.15351664838587416140e6, -1.79565251976484877988e7)
_TAN_Q = (1.0, 1.36812963470692954678e4, -1.32089234440210967447e6, 2.50083801823357915839e7,
          -5.38695755929454629881e7)


def _horner(z, coefficients):
    out = coefficients[0]
    for c in coefficients[1:]:
        out = out * z + c
    return out


def sincos(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(sin x, cos x)`` elementwise, each within a few ulp of the correctly rounded value for |x| < 1e9.

    Float64 only; other dtypes get ``jnp.sin`` and ``jnp.cos``, which XLA already vectorises in float32 (and the
    coefficients here are tuned to float64)."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float64:
        return jnp.sin(x), jnp.cos(x)
    return _sincos64(x)


@jax.custom_jvp
def _sincos64(x):
    n = jnp.round(x * _TWO_OVER_PI)
    r = ((x - n * _PIO2_1) - n * _PIO2_2) - n * _PIO2_3
    h = 0.5 * r
    z = h * h
    t = h + h * (z * _horner(z, _TAN_P) / _horner(z, _TAN_Q))
    tt = t * t
    den = 1.0 + tt
    # the quadrant's swaps and signs act on the numerators, so each output's last operation is its division: a
    # division last is what keeps XLA from copying the formula into every consumer (selects last were copied, and
    # three nested derivatives of the DIP, the power-series control's, ran 3x slower than with them first)
    s_r, c_r = 2.0 * t, 1.0 - tt
    q = n - 4.0 * jnp.floor(0.25 * n)  # n mod 4, exact in floating point
    odd = (q == 1.0) | (q == 3.0)
    s = jnp.where(odd, c_r, s_r)
    c = jnp.where(odd, s_r, c_r)
    s = jnp.where(q >= 2.0, -s, s)
    c = jnp.where((q == 1.0) | (q == 2.0), -c, c)
    # sin(-0) is +0 here (the C library gives -0); no loop here depends on the sign of a zero
    return s / den, c / den


@_sincos64.defjvp
def _sincos64_jvp(primals, tangents):
    # d sin = cos dx, d cos = -sin dx, from the values already computed: differentiating the formula instead
    # gave tangents of cheap operations that XLA copies into every consumer again (a CPX loop, which linearises
    # the model every period, ran 12.7x slower than with the C library's trig); this rule is its own derivative's
    # rule too, so every order is consistent with the values
    (x,), (dx,) = primals, tangents
    s, c = _sincos64(x)
    return (s, c), (c * dx, -s * dx)
