"""Frequency responses and stability margins (python-control's ``frequency_response``/``bode`` data and
``margin``/``stability_margins``), differentiable in the model.

Margins. python-control finds the crossover frequencies as real roots of polynomials of the transfer function.
Here they are found on the state-space model: the response on a dense logarithmic grid (``GRID`` points over
``[w_lo, w_hi]``, bounds set by the eigenvalues of A and the size of B C, twelve decades beyond them on each
side) brackets every sign change of Im L (phase crossovers) and of |L| - 1 (gain crossovers); bisection refines
each bracket to rounding level, and one Newton step written through the implicit function theorem gives the
derivative of the crossover w with respect to the model, dw = -(df/dtheta) / (df/dw), at a simple crossover
(at a tangency, where df/dw = 0, the margin is not differentiable). Crossovers outside the grid's range, or two
within one grid cell, are not seen (python-control's polynomial roots see them; its roots are in turn inaccurate
for badly scaled models). At most ``MAX_CROSSINGS`` crossovers of each kind are refined.

Selection follows python-control: the phase crossovers are the w >= 0 with Im L = 0 and Re L <= 0 (w = 0 included
when the DC gain is negative; a pole on the stability boundary, where Im L passes through infinity, is not one), the gain margin is the one of 1 / |L| nearest 1 in log scale, the phase margin
the one of ``remainder(angle(L), 360) - 180`` (degrees) smallest in magnitude; with no crossover the margin is
inf and its frequency nan. Discrete systems (``dt`` > 0) are evaluated at z = exp(j w dt) for 0 <= w <= pi / dt.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.control.statespace import StateSpace
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["GRID", "MAX_CROSSINGS", "evalfr", "freqresp", "bode", "margins"]
__dir__ = public_dir(globals())

GRID = 4000  # grid points that bracket the crossovers
MAX_CROSSINGS = 32  # crossovers of each kind refined (the first ones in frequency)
_BISECT = 64  # bisection steps in log w: the grid cell ratio (<= ~1.03) shrinks below 2^-52


def _check_sys(owner: str, sys) -> None:
    if not isinstance(sys, StateSpace):
        raise checks.ArgumentTypeError(f"{owner}: sys must be a jaxdip StateSpace (see ss / from_control), "
                                       f"got {type(sys).__name__}")


def _point(sys: StateSpace, w):
    return jnp.exp(1j * w * sys.dt) if sys.dt else 1j * w


def _solve(M, B):
    """M^-1 B by Gaussian elimination with partial pivoting, written in jax.numpy (n is a model's state count).

    Not ``jnp.linalg.solve``: margins evaluates batches of these solves in several independent loops of one
    program, and jaxlib 0.10's CPU LAPACK kernels split a batch over the intra-op thread pool and wait for it
    while holding a pool thread; two such kernels side by side on a two-core machine wait on each other forever
    (seen as a hang of the margins tests on this project's CI machine). Elimination in jax.numpy compiles to
    ordinary fused kernels."""
    n = M.shape[0]
    rows = jnp.arange(n)

    # one loop step per column, not an unrolled copy of each: margins evaluates the solve in a dozen places
    # (and differentiates some), and the unrolled form made each margins program seconds to compile
    def eliminate(j, A):
        p = jnp.argmax(jnp.where(rows >= j, jnp.abs(A[:, j]), -1.0))
        A = A.at[jnp.stack([j, p])].set(A[jnp.stack([p, j])])  # swap rows j and p
        below = jnp.where(rows > j, A[:, j] / A[j, j], 0.0)
        return A - below[:, None] * A[j][None, :]

    A = jax.lax.fori_loop(0, n, eliminate, jnp.concatenate([M, B], axis=1))
    U = A[:, :n]

    def substitute(k, X):  # back substitution, last row first; the entries left of the diagonal multiply zeros
        j = n - 1 - k
        after = jnp.where(rows > j, U[j], 0.0)
        return X.at[j].set((X[j] - after @ X) / U[j, j])

    return jax.lax.fori_loop(0, n, substitute, A[:, n:])


def evalfr(sys: StateSpace, x) -> jax.Array:
    """The transfer matrix C (x I - A)^-1 B + D at the complex point x (python-control's ``evalfr``)."""
    n = sys.A.shape[0]
    X = _solve(x * jnp.eye(n) - sys.A.astype(complex), sys.B.astype(complex))
    return sys.C @ X + sys.D


def freqresp(sys: StateSpace, omega) -> jax.Array:
    """Complex response H[p, m, k] at the frequencies omega[k] (rad/s): python-control's
    ``frequency_response(sys, omega).complex`` (s = j w, or z = exp(j w dt) in discrete time)."""
    _check_sys("freqresp", sys)
    checks.check_real("freqresp", "omega", omega)
    omega = jnp.atleast_1d(jnp.asarray(omega, dtype=jnp.float64))
    H = jax.vmap(lambda w: evalfr(sys, _point(sys, w)))(omega)
    return jnp.moveaxis(H, 0, -1)


def bode(sys: StateSpace, omega) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(mag, phase, omega) as python-control's ``frequency_response`` unpacks: |H| and angle(H) in radians
    (wrapped to (-pi, pi]), shape (p, m, k), squeezed to (k,) for a SISO system as python-control does."""
    H = freqresp(sys, omega)
    if H.shape[0] == 1 and H.shape[1] == 1:
        H = H[0, 0]
    return jnp.abs(H), jnp.angle(H), jnp.atleast_1d(jnp.asarray(omega, dtype=jnp.float64))


def _siso(sys: StateSpace, w):
    return evalfr(sys, _point(sys, w))[0, 0]


def _phase_f(sys, w):
    return jnp.imag(_siso(sys, w))


def _gain_f(sys, w):
    return jnp.log(jnp.abs(_siso(sys, w)))


def _grid(sys: StateSpace):
    lam = jnp.abs(jnp.linalg.eigvals(jax.lax.stop_gradient(sys.A)))
    bc = jax.lax.stop_gradient(jnp.linalg.norm(sys.B) * jnp.linalg.norm(sys.C))
    nz = jnp.where(lam > 0, lam, jnp.inf)
    lo = 1e-12 * jnp.minimum(jnp.minimum(1.0, jnp.min(nz)), jnp.where(bc > 0, bc, 1.0))
    hi = 1e12 * jnp.maximum(jnp.maximum(1.0, jnp.max(lam)), bc)
    if sys.dt:  # the unit circle's upper half: the grid is dense near w = 0 and ends at the Nyquist frequency
        hi = jnp.pi / sys.dt
        lo = jnp.minimum(lo, 1e-6 * hi)
    return jnp.exp(jnp.linspace(jnp.log(lo), jnp.log(hi), GRID))


def _crossings(sys, f, grid):
    """The first MAX_CROSSINGS roots of f(w) bracketed by sign changes on the grid, refined; (w, found)."""
    fs = jax.lax.stop_gradient(jax.vmap(lambda w: f(sys, w))(grid))
    change = jnp.sign(fs[:-1]) * jnp.sign(fs[1:]) < 0
    idx = jnp.nonzero(change, size=MAX_CROSSINGS, fill_value=0)[0]
    found = change[idx]
    sys0 = jax.lax.stop_gradient(sys)

    def refine(i):
        a, b = jnp.log(grid[i]), jnp.log(grid[i + 1])
        fa = fs[i]

        def step(_, ab):
            a, b = ab
            m = 0.5 * (a + b)
            left = jnp.sign(f(sys0, jnp.exp(m))) == jnp.sign(fa)
            return jnp.where(left, m, a), jnp.where(left, b, m)

        a, b = jax.lax.fori_loop(0, _BISECT, step, (a, b))
        return jnp.exp(0.5 * (a + b))

    w0 = jax.vmap(refine)(idx)
    # implicit function theorem: the value stays w0 (to rounding), the derivative is -f_theta / f_w
    fw = jax.vmap(jax.grad(lambda w: f(sys0, w)))(w0)
    w = w0 - jax.vmap(lambda w: f(sys, w))(w0) / jnp.where(fw != 0, fw, 1.0)
    w = jnp.where(fw != 0, w, w0)
    return w, found


def margins(sys: StateSpace) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """(gm, pm, wpc, wgc) of the SISO loop transfer function ``sys``: gain margin (a factor, not dB), phase margin
    (degrees), the phase-crossover frequency (where the gain margin is read) and the gain-crossover frequency
    (where the phase margin is read), all in python-control's conventions: ``control.margin(sys)``, equal to
    entries 0, 1, 3, 4 of ``control.stability_margins(sys)``. Differentiable in the model at simple crossovers;
    jit-able and vmap-able (see the module notes for what the grid can miss)."""
    _check_sys("margins", sys)
    if sys.B.shape[-1] != 1 or sys.C.shape[-2] != 1:
        checks.fail("margins", f"sys must be SISO (one input, one output), got {sys.C.shape[-2]} outputs and "
                               f"{sys.B.shape[-1]} inputs")
    grid = _grid(sys)

    # phase crossovers: Im L = 0 where Re L <= 0, w = 0 included (not w = pi/dt, as python-control)
    wp, fp = _crossings(sys, _phase_f, grid)
    wp = jnp.concatenate([jnp.zeros(1), wp])
    Lp = jax.vmap(lambda w: _siso(sys, w))(wp)
    finite = jnp.isfinite(Lp)
    fp = jnp.concatenate([finite[:1], fp]) & finite & (jnp.real(Lp) <= 0)
    # a sign change of Im L through a pole on the axis is not a crossover: there |Im L| is not small
    fp = fp & (jnp.abs(jnp.imag(Lp)) <= 1e-6 * jnp.abs(Lp))
    absL = jnp.where(fp, jnp.abs(Lp), 1.0)
    gm_all = 1.0 / absL
    score = jnp.where(fp & (absL > 0), jnp.abs(jnp.log(absL)), jnp.inf)
    i = jnp.argmin(score)
    any_p = jnp.isfinite(score[i])
    gm = jnp.where(any_p, gm_all[i], jnp.inf)
    wpc = jnp.where(any_p, wp[i], jnp.nan)

    # gain crossovers: |L| = 1 for w > 0
    wg, fg = _crossings(sys, _gain_f, grid)
    Lg = jax.vmap(lambda w: _siso(sys, w))(wg)
    pm_all = jnp.remainder(jnp.degrees(jnp.angle(Lg)), 360.0) - 180.0
    score = jnp.where(fg, jnp.abs(pm_all), jnp.inf)
    j = jnp.argmin(score)
    any_g = jnp.any(fg)
    pm = jnp.where(any_g, pm_all[j], jnp.inf)
    wgc = jnp.where(any_g, wg[j], jnp.nan)
    return gm, pm, wpc, wgc
