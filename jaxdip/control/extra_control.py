"""Extra control with two-layer networks for the TWIP's unmatched uncertainty (Stumfoll §6.2, §8.2).

The total input is u = u_nom + u_e (89): u_nom is the discrete LQR (84) around a desired trajectory, u_e a
backstepping-style extra control that uses the tilt x3 as a virtual control. State ``[x1, x2, x3, x4] =
[x, x_dot, phi, phi_dot]``; A1..A4, B1, B2 are the entries a22, a23, a42, a43, b2, b4 of the nominal linear
model (79) (so (87) reads x2' = A1 x2 + A2 x3 + B1 u + d1, x4' = A3 x2 + A4 x3 + B2 u + d2).

What is computed at control sample k (time t = k dt), in this order:

  desired   x1d = x1d0 + v_d t, x2d = v_d, x3d and u_d from (183) (constants), x4d = 0         (182)-(183)
  nominal   u_nom = sat(u_d - K (x - x_d))   (84) plus the feed-forward u_d (``ff`` = 0 drops it)
  errors    e1 = x1 - x1d, e2 = x2 - x2d  (91); "flat": e1 -= beta (x3 - x3d), e2 -= beta x4 (below)
  net 1     F1hat = W12^T tanh(W11^T tanh(V1^T P1)),  P1 = [1, x1..x4, e1, e2, x1d, x2d, u]   (109)
  virtual   xbar3 = x3d + A2^-1 (-k1 e2 - e1 - F1hat)                                          (93)
            xbar4_k = xbar4_{k-1} + a ((xbar3_k - xbar3_{k-1}) / dt - xbar4_{k-1}), a = dt / (tau_d + dt),
            xbar4_0 = 0: a filtered difference for (98)'s xbar4 = d xbar3/dt (tau_d = 0: the raw difference)
  errors    ebar2 = e2 (xbar2 = x2d), ebar3 = x3 - xbar3, ebar4 = x4 - xbar4                   (98)
  net 2     F2hat = W22^T tanh(W21^T tanh(V2^T P2)),
            P2 = [1, x1..x4, e1, e2, ebar3, ebar4, x1d, x2d, u_nom]                            (110)
  extra     u_e = sat(B2^-1 (-k2 ebar4 - F2hat - ebar3))                                       (101)
  total     u = sat(u_nom + u_e)                                                               (89)
  weights   forward Euler over one control period of the continuous laws (111)-(114):
            W11 += dt * -g11 (phi11 [W11^T phi11 + b1 ebar2]^T + s11 W11)
            W12 += dt *  g12 (phi12 ebar2 - s12 W12)
            W21 += dt * -g21 (phi21 [W21^T phi21 + b2 ebar4]^T + s21 W21)
            W22 += dt *  g22 (phi22 ebar4 - s22 W22)
            with phi11 = tanh(V1^T P1), phi12 = tanh(W11^T phi11), and likewise for network 2, all evaluated
            with the weights *before* the update (the ones that produced u_k).

Decisions where the printed text is ambiguous or mangled (re-derived; see also tests/test_extra_control.py):

* Input "u" of P1 is the total control of the *previous* sample: u_k depends on F1hat through u_e, so the
  current one is not available when F1hat is evaluated (an algebraic loop).
* Network naming: (108) writes F2 = W21^T phi21(W22^T phi22(.)) with W21 outer, but (110), (113) and (114) only
  make sense with W21 the inner (n_h x n_h) and W22 the outer (n_h) weights: [W21^T phi21 + B2 ebar4] must be
  an n_h-vector and phi22 ebar4^T an n_h-column. We use (110): W21 inner, W22 outer, the same layout as net 1.
* Signs of the update laws: as printed in (111)-(114). They are the ones the Lyapunov argument (124)-(130)
  needs: with W~ = W - What, (112) makes (1/g12) Tr(W~12^T W~12') = -ebar2^T W~12^T phi12 + s12 Tr(W~12^T What12),
  cancelling the cross term ebar2^T W~12^T phi12 of (122); likewise (114) with ebar4. (128) repeats (114) with
  the sign of W~22' = -What22', consistent with it.
* (105) prints e4bar' = F2 - F2hat + k2 ebar4 + ebar3; substituting (101) in (100) gives -k2 ebar4 - ebar3, as
  (106) has. We use (106).
* (97)/(106) substitute x3 = xbar3 in (94); with x3 = xbar3 + ebar3 the exact error dynamics are
      e2' = F1 - F1hat - k1 e2 - e1 + A2 ebar3,
  i.e. the linear part of (106) has an extra coupling A2 ebar3 in the ebar2 row (a standard backstepping law
  would cancel it with a -A2 ebar2 term in u_e; the thesis's (101) has none, and we implement (101) as printed).
  The coupled matrix is block upper-triangular, so its eigenvalues are those of (106): the roots of
  s^2 + k1 s + 1 and s^2 + k2 s + 1. The test with the networks replaced by the true F1, F2 checks the
  coupled linear system.
* "B1 = B2 = [1]_{10x1}" in (111), (113) are n_h-vectors of the network laws (``b1``, ``b2`` here), not the
  scalar input gains B1, B2 of (87) (``B1``, ``B2`` here).
* Saturation "on every control signal": u_nom, u_e and u are each clipped to +-u_max.
* xbar4 = d xbar3/dt is not available in closed form: xbar3 contains e2, whose derivative contains B1 u
  (and the derivative of F1hat). The raw backward difference feeds u_{k-1} back into u_e with gain about
  -k1 k2 B1 / (A2 B2) = -2.7 for Table 8.1 (B1 u_{k-1} dt moves e2, xbar3 by k1/A2 times that, xbar4 by 1/dt
  times that, u_e by k2/B2 times xbar4): the discrete loop then oscillates at the Nyquist frequency and
  diverges (measured: u_e alternates +-11.1 V from the first samples). The thesis does not say how it computed
  xbar4. We use a first-order filtered difference with time constant ``tau_d`` (default 0.05 s, loop gain
  about 2.7 dt / (tau_d + dt) = 0.45 at Nyquist); tau_d = 0 recovers the raw difference.

* The virtual control's gain (``virtual``). (93) inverts A2, the tilt's direct effect on the cart acceleration,
  as if u did not enter x2' as well. It does (B1 u), and (96) hands B1 (u_nom + u_e) to network 1: holding a
  tilt x3 takes u = -A4 x3 / B2, so the tilt's net effect on x2' is a = A2 - B1 A4 / B2 (-38.7 for Table 8.1,
  against A2 = +2.39): the printed law commands the tilt in the wrong direction and the networks cannot learn
  the 16-fold, sign-reversing correction before the robot falls. Variants:
    "printed"    a = A2, e1, e2 on the cart (93) as printed;
    "effective"  a = A2 - B1 A4 / B2, e1, e2 still on the cart: the sign is right but e2' keeps B1 u;
    "flat"       a = A2 - B1 A4 / B2 and e1, e2 measured on y = x1 - beta x3, y' = x2 - beta x4 with
                 beta = B1 / B2 (the flat output of the linear model (87)): y'' = (A1 - beta A3) x2 + a x3
                 + d1 - beta d2 has no u, so (87) in (y, y', x3, x4) is in strict-feedback form, x3 is a
                 genuine virtual control of (y, y'), and the steps (93)-(106) hold as derived with F1 =
                 (A1 - beta A3) x2 + a x3d + d1 - beta d2. It also removes the u feedthrough that makes a raw
                 difference for xbar4 ring (B1 - beta B2 = 0). x1d, x2d, x3d of (182) are unchanged (x4d = 0).

Every number is an array field of ``ExtraControl``, so ``jax.grad`` reaches k1, k2, the learning rates, the
damping factors, the LQR gain and the model coefficients. The network's random input weights V1, V2 are drawn
in ``init`` from the component's key (uniform in [-v_scale, v_scale]) and live in the state, with the adapted
weights (zero at start).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Controller, param

from jaxdip._public import public_dir

__all__ = ["N_IN1", "N_IN2", "VIRTUAL", "ExtraControlState", "model_coefficients", "desired_constants", "desired_state",
           "network", "virtual_tilt", "extra_law", "inner_rate", "outer_rate", "ExtraControlAux", "ExtraControl"]
__dir__ = public_dir(globals())

N_IN1 = 10  # P1 = [1, x1, x2, x3, x4, e1, e2, x1d, x2d, u]
N_IN2 = 12  # P2 = [1, x1, x2, x3, x4, e1, e2, ebar3, ebar4, x1d, x2d, u_nom]
VIRTUAL = ("printed", "effective", "flat")


class ExtraControlState(NamedTuple):
    V1: jnp.ndarray  # (N_IN1, n_h) fixed random input weights
    V2: jnp.ndarray  # (N_IN2, n_h)
    W11: jnp.ndarray  # (n_h, n_h) net 1 inner
    W12: jnp.ndarray  # (n_h,) net 1 outer
    W21: jnp.ndarray  # (n_h, n_h) net 2 inner
    W22: jnp.ndarray  # (n_h,) net 2 outer
    xbar3_prev: jnp.ndarray
    xbar4_prev: jnp.ndarray
    started: jnp.ndarray  # False before the first sample (no xbar3_prev yet)
    u_prev: jnp.ndarray  # total control of the previous sample (input of net 1)
    # diagnostics of the last sample (figures)
    u_nom: jnp.ndarray
    u_e: jnp.ndarray
    F1hat: jnp.ndarray
    F2hat: jnp.ndarray
    xbar3: jnp.ndarray


def _f(v):
    return jnp.asarray(v, dtype=jnp.float64)


def model_coefficients(A, B):
    """(A1, A2, A3, A4, B1, B2) of (87) from the (4x4, 4x1) linear model (79)."""
    return A[1, 1], A[1, 2], A[3, 1], A[3, 2], B[1, 0], B[3, 0]


# ---- the pieces of the law (pure functions, also used by the tests) --------------------------------------


def desired_constants(p: ExtraControl):
    """(x3d, u_d) of (183): [x3d, u_d] = -[[A2, B1], [A4, B2]]^-1 [A1, A3] x2d (closed-form 2x2 solve)."""
    det = p.A2 * p.B2 - p.B1 * p.A4
    r1, r2 = -p.A1 * p.v_d, -p.A3 * p.v_d
    x3d = (p.B2 * r1 - p.B1 * r2) / det
    u_d = (p.A2 * r2 - p.A4 * r1) / det
    return x3d, u_d


def desired_state(p: ExtraControl, t):
    """x_d(t) = [x1d0 + v_d t, v_d, x3d, 0] (182); the discrete x1d recursion is exact for constant v_d."""
    x3d, _ = desired_constants(p)
    t = jnp.asarray(t, jnp.float64)
    return jnp.stack([p.x1d0 + p.v_d * t, p.v_d * jnp.ones_like(t), x3d * jnp.ones_like(t), jnp.zeros_like(t)],
                     axis=-1)


def network(V, W_in, w_out, P):
    """Two-layer network (109)/(110): returns (F, phi_1 = tanh(V^T P), phi_2 = tanh(W_in^T phi_1))."""
    phi1 = jnp.tanh(V.T @ P)
    phi2 = jnp.tanh(W_in.T @ phi1)
    return w_out @ phi2, phi1, phi2


def virtual_tilt(p: ExtraControl, e1, e2, x3d, F1hat):
    """(93): xbar3 = x3d + A2^-1 (-k1 e2 - e1 - F1hat)."""
    return x3d + (-p.k1 * e2 - e1 - F1hat) / p.a_virtual


def extra_law(p: ExtraControl, ebar3, ebar4, F2hat):
    """(101) before saturation: u_e = B2^-1 (-k2 ebar4 - F2hat - ebar3)."""
    return (-p.k2 * ebar4 - F2hat - ebar3) / p.B2


def inner_rate(gamma, sigma, b, W, phi, ebar):
    """(111)/(113): W' = -gamma (phi [W^T phi + b ebar]^T + sigma W)."""
    return -gamma * (jnp.outer(phi, W.T @ phi + b * ebar) + sigma * W)


def outer_rate(gamma, sigma, w, phi, ebar):
    """(112)/(114): w' = gamma (phi ebar - sigma w)."""
    return gamma * (phi * ebar - sigma * w)


def _sat(u, u_max):
    return jnp.clip(u, -u_max, u_max)


def _init_state(p, key, n_hidden: int) -> ExtraControlState:
    k1, k2 = jax.random.split(key)
    V1 = jax.random.uniform(k1, (N_IN1, n_hidden), jnp.float64, -1.0, 1.0) * p.v_scale
    V2 = jax.random.uniform(k2, (N_IN2, n_hidden), jnp.float64, -1.0, 1.0) * p.v_scale
    z = jnp.zeros(())
    return ExtraControlState(V1=V1, V2=V2, W11=jnp.zeros((n_hidden, n_hidden)), W12=jnp.zeros(n_hidden),
                             W21=jnp.zeros((n_hidden, n_hidden)), W22=jnp.zeros(n_hidden), xbar3_prev=z,
                             xbar4_prev=z, started=jnp.zeros((), bool), u_prev=z, u_nom=z, u_e=z, F1hat=z,
                             F2hat=z, xbar3=z)


def _law(p, s: ExtraControlState, xhat, k):
    """One control sample (module doc): (new state, u_k, x_d at t_k) of the controller ``p``."""
    x = jnp.asarray(xhat, jnp.float64)
    xd = desired_state(p, k * p.dt)
    x3d, u_d = desired_constants(p)
    u_nom = _sat(p.ff * u_d - (p.K @ (x - xd))[0], p.u_max)
    # flat output y = x1 - beta x3 (beta = 0: the printed cart errors); xd[3] = 0
    e1 = x[0] - xd[0] - p.beta * (x[2] - xd[2])
    e2 = x[1] - xd[1] - p.beta * (x[3] - xd[3])
    P1 = jnp.stack([jnp.ones(()), x[0], x[1], x[2], x[3], e1, e2, xd[0], xd[1], s.u_prev])
    F1hat, phi11, phi12 = network(s.V1, s.W11, s.W12, P1)
    xbar3 = virtual_tilt(p, e1, e2, x3d, F1hat)
    a = p.dt / (p.tau_d + p.dt)
    xbar4 = jnp.where(s.started, s.xbar4_prev + a * ((xbar3 - s.xbar3_prev) / p.dt - s.xbar4_prev), 0.0)
    ebar2, ebar3, ebar4 = e2, x[2] - xbar3, x[3] - xbar4
    P2 = jnp.stack([jnp.ones(()), x[0], x[1], x[2], x[3], e1, e2, ebar3, ebar4, xd[0], xd[1], u_nom])
    F2hat, phi21, phi22 = network(s.V2, s.W21, s.W22, P2)
    u_e = _sat(p.extra * extra_law(p, ebar3, ebar4, F2hat), p.u_max)
    u = _sat(u_nom + u_e, p.u_max)
    W11 = s.W11 + p.dt * inner_rate(p.gamma11, p.sigma11, p.b1, s.W11, phi11, ebar2)
    W12 = s.W12 + p.dt * outer_rate(p.gamma12, p.sigma12, s.W12, phi12, ebar2)
    W21 = s.W21 + p.dt * inner_rate(p.gamma21, p.sigma21, p.b2, s.W21, phi21, ebar4)
    W22 = s.W22 + p.dt * outer_rate(p.gamma22, p.sigma22, s.W22, phi22, ebar4)
    new = ExtraControlState(V1=s.V1, V2=s.V2, W11=W11, W12=W12, W21=W21, W22=W22, xbar3_prev=xbar3,
                            xbar4_prev=xbar4, started=jnp.ones((), bool), u_prev=u, u_nom=u_nom, u_e=u_e,
                            F1hat=F1hat, F2hat=F2hat, xbar3=xbar3)
    return new, jnp.reshape(u, (1,)), xd


_SCALARS = ("dt", "A1", "A2", "A3", "A4", "B1", "B2", "v_d", "x1d0", "k1", "k2", "u_max", "extra", "v_scale",
            "a_virtual", "beta", "tau_d", "ff")
_RATES = ("gamma11", "gamma12", "gamma21", "gamma22", "sigma11", "sigma12", "sigma21", "sigma22")
_SCALARS = _SCALARS + _RATES


class ExtraControlAux(NamedTuple):
    state: ExtraControlState  # after the sample: the adapted weights W11..W22, u_nom, u_e, F1hat, F2hat, xbar3
    xd: jnp.ndarray  # the desired state x_d(t_k) (182) the sample tracked


class ExtraControl(Controller):
    """LQR + extra control as an engine controller: the gains, rates and model coefficients below are array
    fields, ``n_hidden`` (neurons per layer) is static. ``aux`` is an ``ExtraControlAux``: the controller's new state
    (network outputs F1hat, F2hat, the split u_nom / u_e, the adapted weights) and x_d(t_k), so a run records
    them with ``save`` instead of replaying the loop. Build it with ``ExtraControl.design(K, A, B, ...)``."""

    K: jax.Array = param()  # (1, 4) LQR gain of the nominal control (84)
    dt: jax.Array = param()  # control period (s); also the Euler step of the weight laws
    A1: jax.Array = param()  # entries of the nominal linear model (79), named as in (87)
    A2: jax.Array = param()
    A3: jax.Array = param()
    A4: jax.Array = param()
    B1: jax.Array = param()
    B2: jax.Array = param()
    v_d: jax.Array = param()  # desired constant velocity (182)
    x1d0: jax.Array = param()  # desired position at k = 0
    k1: jax.Array = param()  # (93)
    k2: jax.Array = param()  # (101)
    b1: jax.Array = param()  # (n_h,) coefficient vector of (111)
    b2: jax.Array = param()  # (n_h,) coefficient vector of (113)
    gamma11: jax.Array = param()
    gamma12: jax.Array = param()
    gamma21: jax.Array = param()
    gamma22: jax.Array = param()
    sigma11: jax.Array = param()
    sigma12: jax.Array = param()
    sigma21: jax.Array = param()
    sigma22: jax.Array = param()
    u_max: jax.Array = param()  # saturation of u_nom, u_e and u
    extra: jax.Array = param()  # 1: apply u_e; 0: LQR alone (the networks still adapt, unused)
    v_scale: jax.Array = param()  # V1, V2 ~ U(-v_scale, v_scale)
    a_virtual: jax.Array = param()  # the gain inverted in (93): A2 as printed (see the module doc for the alternatives)
    # 0 as printed; B1/B2 in the "flat" variant: e1, e2 are errors of x1 - beta x3, x2 - beta x4
    beta: jax.Array = param()
    tau_d: jax.Array = param()  # time constant (s) of the filtered difference that gives xbar4 (0: raw difference)
    ff: jax.Array = param()  # 1: u_nom includes the desired input u_d of (183); 0: (84) literally, u = -K (x - x_d)
    n_hidden: int = eqx.field(default=10, static=True)

    def __check_init__(self):
        checks.check_int(self, "n_hidden", self.n_hidden, 1)
        checks.check_shape(self, "K", self.K, (1, 4), "(the LQR gain of the 4-state TWIP model)")
        for name in ("b1", "b2"):
            checks.check_shape(self, name, getattr(self, name), (self.n_hidden,), f"(n_hidden={self.n_hidden})")
        for name in _SCALARS:
            checks.check_ndim(self, name, getattr(self, name), (0,), "a scalar")
        checks.check_finite(self, "K", self.K)
        for name in _SCALARS + ("b1", "b2"):
            if name != "u_max":
                checks.check_finite(self, name, getattr(self, name))
        checks.check_positive(self, "dt", self.dt)
        checks.check_positive(self, "u_max", self.u_max, allow_inf=True)  # inf: no saturation
        # k1, k2 < 0 make the error dynamics s^2 + k s + 1 of (106) unstable; 0 is an ablation, not a mistake
        for name in ("k1", "k2", "tau_d", "v_scale") + _RATES:
            checks.check_nonnegative(self, name, getattr(self, name))
        for name, where in (("a_virtual", "(93)"), ("B2", "(101)")):  # divided by in these laws
            v = getattr(self, name)
            if checks.is_concrete(v) and float(v) == 0.0:
                checks.fail(self, f"{name} must be nonzero (it is inverted in {where}), got 0")

    @classmethod
    def design(cls, K, A, B, *, dt=0.01, v_d=0.1, x1d0=0.0, k1=2.5, k2=2.5, n_hidden=10, b=1.0, gamma=0.1,
               sigma=0.01, u_max=11.1, extra=1.0, v_scale=1.0, ff=1.0, tau_d=0.05, virtual="printed",
               virtual_sign=1.0) -> "ExtraControl":
        """The controller for the LQR gain ``K`` and the linear model (A, B) of (79). The §8.2 values by default:
        k1 = k2 = 2.5, B1 = B2 = ones(10), all gamma = 0.1, all sigma = 0.01.

        ``virtual``: "printed" (93) as printed; "effective" inverts A2 - B1 A4 / B2 instead of A2; "flat" also
        measures e1, e2 on the flat output (see the module doc). ``virtual_sign`` = -1 reverses the sign in front
        of the inverted gain in (93) (the reading "(93) carries a sign slip"; flipping the tilt's orientation does
        not do this: it reverses A2 and A2 - B1 A4 / B2 together)."""
        checks.check_choice(cls, "virtual", virtual, VIRTUAL)
        checks.check_int(cls, "n_hidden", n_hidden, 1)
        numbers = dict(dt=dt, v_d=v_d, x1d0=x1d0, k1=k1, k2=k2, gamma=gamma, sigma=sigma, u_max=u_max,
                       extra=extra, v_scale=v_scale, ff=ff, tau_d=tau_d, virtual_sign=virtual_sign)
        for name, v in numbers.items():  # before they become arrays below, so a string is named here
            checks.check_real(cls, name, v)
            checks.check_ndim(cls, name, v, (0,), "a scalar")
        checks.check_real(cls, "b", b)
        checks.check_scalar_or_vector(cls, "b", b, n_hidden, f"(n_hidden={n_hidden})")
        for name, v, shape in (("K", K, (1, 4)), ("A", A, (4, 4)), ("B", B, (4, 1))):
            checks.check_real(cls, name, v)
            # K may come as (4,) or (1, 4): the law reshapes it
            if not (name == "K" and checks.shape_of(v) == (4,)):
                checks.check_shape(cls, name, v, shape, "(the 4-state TWIP model (79))")
        A1, A2, A3, A4, B1, B2 = model_coefficients(jnp.asarray(A), jnp.asarray(B))
        ones = jnp.ones(n_hidden)
        a_virtual = _f(virtual_sign) * (A2 if virtual == "printed" else A2 - B1 * A4 / B2)
        beta = B1 / B2 if virtual == "flat" else jnp.zeros_like(B1)
        return cls(
            K=jnp.reshape(_f(K), (1, 4)), dt=_f(dt), A1=A1, A2=A2, A3=A3, A4=A4, B1=B1, B2=B2, v_d=_f(v_d),
            x1d0=_f(x1d0), k1=_f(k1), k2=_f(k2), b1=_f(b) * ones, b2=_f(b) * ones,
            gamma11=_f(gamma), gamma12=_f(gamma), gamma21=_f(gamma), gamma22=_f(gamma),
            sigma11=_f(sigma), sigma12=_f(sigma), sigma21=_f(sigma), sigma22=_f(sigma),
            u_max=_f(u_max), extra=_f(extra), v_scale=_f(v_scale), ff=_f(ff),
            tau_d=_f(tau_d), a_virtual=a_virtual, beta=beta, n_hidden=n_hidden)

    def init(self, key, x0):
        return _init_state(self, key, self.n_hidden)

    def step(self, state, xhat, key, k):
        new, u, xd = _law(self, state, xhat, k)
        return new, u, ExtraControlAux(new, xd)
