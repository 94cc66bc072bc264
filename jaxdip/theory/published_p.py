"""Readings of the published P (thesis (3.6)) and what each does to the linearised DIP closed loop.

The thesis gives P for the relaxed projection control (2.14), u = -(g^T P g)^{-1} (gamma g^T P x + g^T P f), by
two basis vectors v1, v2 and singular values s of the construction (2.20). How those numbers map onto a model
is left open in several places; each is a field of ``Reading``:

  variant       "printed" equations of motion (the default model) or the "lagrangian" derivation;
  Mw            the extra cart weight Mw on board (0.37 kg, Table 3.3) or off (0);
  order         the basis in the state order [xc, alpha, theta, ...] ("alpha_theta", ours) or the paper's
                [xc, theta, alpha, ...] ("theta_alpha");
  flip          one coordinate (with its rate) counted with the opposite sign: "none", "xc", "alpha", "theta".
                These four cover every sign pattern of (xc, alpha, theta): reversing all coordinates leaves the
                closed loop unchanged (P -> T^T P T with T = -I), so flipping two is flipping the third. The
                sign of the input does not matter either: g u is even in g;
  angles        theta relative to the lower link ("relative", ours) or the upper link's absolute angle
                alpha + theta ("absolute");
  units         angles and rates in radians ("rad") or degrees ("deg"), or also xc in centimetres ("cm_deg");
  construction  how (2.20) turns (v, s) into P: "gram_schmidt" (as printed: v1, v2 re-orthonormalised in that
                order, the rest of the basis completed, singular values (s1, s2, 1, ..., 1)), "gram_schmidt_v2_first"
                (the same with v2 first), "rank_update" (the printed vectors normalised but not re-orthogonalised:
                P = I + sum (s_i - 1) v_i v_i^T), "squared" (s read as singular values of a factor L, P = L L^T,
                so diag(s1^2, s2^2, 1, ...));
  gamma         the weight of (2.14): 40 (the laboratory comparison, §3.2.2) or 10 (the search, §3.2.1).

How the completion of the basis is chosen does not matter: with the remaining singular values all 1, P = I +
sum (s_i - 1) q_i q_i^T for the orthonormalised q_i, whatever vectors complete the basis.

Coordinates. A reading says the published vectors are components in coordinates z = T x of our state x
(``basis_transform``); the quadratic form is the same, so in our coordinates P_x = T^T P_z T. The control law
depends on P only through g^T P g, g^T P x and g^T P f, which are invariant when x, f and g change by the same T,
so this is the law the laboratory would have applied in its coordinates.

Linearisation at upright: f(0) = 0 and u(0) = 0, so the derivative of g(x) u(x) is g(0) u'(0), and
A_cl = A - B (B^T P B)^{-1} B^T P (gamma I + A) (``closed_loop``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields, replace

import jax.numpy as jnp
import numpy as np

from jaxdip.control.spd import P_Vs
from jaxdip.engine.roles import linearize
from jaxdip.plants import dip

# thesis (3.6): the P basis and singular values used on the laboratory system
PUBLISHED_V = [[0.0758, -0.2888, -0.9414, 0.0699, -0.1077, -0.0904],
               [0.4917, 0.5334, -0.2177, -0.5440, 0.3085, 0.1877]]
PUBLISHED_S = [9.99e5, 3.37e4]
MW_ON = next(f.default for f in fields(dip.DIP) if f.name == "Mw")  # Table 3.3, as a Python float

CHOICES = {
    "variant": ("printed", "lagrangian"),
    "Mw": (MW_ON, 0.0),
    "order": ("alpha_theta", "theta_alpha"),
    "flip": ("none", "xc", "alpha", "theta"),
    "angles": ("relative", "absolute"),
    "units": ("rad", "deg", "cm_deg"),
    "construction": ("gram_schmidt", "gram_schmidt_v2_first", "rank_update", "squared"),
    "gamma": (40.0, 10.0),
}


@dataclass(frozen=True)
class Reading:
    """One reading of (3.6); the defaults are the one dip-controllers uses unless told otherwise."""

    variant: str = "printed"
    Mw: float = MW_ON
    order: str = "alpha_theta"
    flip: str = "none"
    angles: str = "relative"
    units: str = "rad"
    construction: str = "gram_schmidt"
    gamma: float = 40.0

    def __post_init__(self):
        for f in fields(self):
            if f.name != "Mw" and f.name != "gamma" and getattr(self, f.name) not in CHOICES[f.name]:
                raise ValueError(f"{f.name} must be one of {CHOICES[f.name]}, got {getattr(self, f.name)!r}")
        if not (self.Mw >= 0 and self.gamma > 0):
            raise ValueError("Mw must be non-negative and gamma positive")

    def changes(self) -> dict:
        """The fields that differ from the default reading."""
        d = Reading()
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) != getattr(d, f.name)}


def basis_transform(r: Reading) -> np.ndarray:
    """T with z = T x: our state x = [xc, alpha, theta, rates] in the coordinates the reading gives (3.6) in."""
    T = np.eye(6)
    if r.angles == "absolute":  # upper link's angle from the vertical: alpha + theta
        T[2, 1] = T[5, 4] = 1.0
    scale = np.ones(6)
    if r.units in ("deg", "cm_deg"):
        scale[[1, 2, 4, 5]] = 180.0 / math.pi
    if r.units == "cm_deg":
        scale[[0, 3]] = 100.0
    if r.flip != "none":
        i = ("xc", "alpha", "theta").index(r.flip)
        scale[[i, i + 3]] *= -1.0
    T = scale[:, None] * T
    if r.order == "theta_alpha":
        T = T[[0, 2, 1, 3, 5, 4]]
    return T


def document_P(construction: str = "gram_schmidt") -> np.ndarray:
    """P built from (3.6)'s numbers in the document's own coordinates."""
    V, s = np.asarray(PUBLISHED_V), np.asarray(PUBLISHED_S)
    if construction == "gram_schmidt":
        return np.asarray(P_Vs(jnp.asarray(V).T, jnp.asarray(s)))
    if construction == "gram_schmidt_v2_first":
        return np.asarray(P_Vs(jnp.asarray(V[::-1]).T, jnp.asarray(s[::-1])))
    if construction == "squared":
        return np.asarray(P_Vs(jnp.asarray(V).T, jnp.asarray(s**2)))
    if construction == "rank_update":
        Vn = V / np.linalg.norm(V, axis=1, keepdims=True)
        return np.eye(6) + sum((si - 1.0) * np.outer(v, v) for si, v in zip(s, Vn))
    raise ValueError(f"unknown construction {construction!r}")


def P_of(r: Reading) -> np.ndarray:
    """The published P under reading ``r``, in our coordinates [xc, alpha, theta, rates] (SI units)."""
    Pz = document_P(r.construction)
    T = basis_transform(r)
    if np.array_equal(T, np.eye(6)):  # keep the default bit for bit
        return Pz
    return T.T @ Pz @ T


def plant_of(r: Reading) -> dip.DIP:
    return dip.DIP(variant=r.variant, Mw=r.Mw)


def linear_rp_eigs(A, B, P, gamma) -> np.ndarray:
    """Eigenvalues of the linearised closed loop of (2.14) with g = B."""
    A, B, P = (jnp.asarray(a, jnp.float64) for a in (A, B, P))
    Kc = jnp.linalg.solve(B.T @ P @ B, gamma * B.T @ P + B.T @ P @ A)
    return np.asarray(jnp.linalg.eigvals(A - B @ Kc))


_AB: dict = {}


def _linearised(variant: str, Mw: float):
    key = (variant, float(Mw))
    if key not in _AB:
        _AB[key] = tuple(np.asarray(a) for a in linearize(dip.DIP(variant=variant, Mw=Mw)))
    return _AB[key]


def closed_loop_eigs(r: Reading) -> np.ndarray:
    A, B = _linearised(r.variant, r.Mw)
    return linear_rp_eigs(A, B, P_of(r), r.gamma)


def max_real(r: Reading) -> float:
    """Largest real part of the linearised closed loop: the reading stabilises the upright iff negative."""
    return float(closed_loop_eigs(r).real.max())


def all_readings() -> list[Reading]:
    """Every combination of ``CHOICES``."""
    names = list(CHOICES)
    return [Reading(**dict(zip(names, combo))) for combo in itertools.product(*(CHOICES[n] for n in names))]


def one_at_a_time() -> list[Reading]:
    """The default reading and each other choice changed alone."""
    base = Reading()
    out = [base]
    for name, values in CHOICES.items():
        out += [replace(base, **{name: v}) for v in values if v != getattr(base, name)]
    return out


# the dip-controllers config key of each field
CONFIG_KEYS = {"variant": "variant", "Mw": "Mw", "order": "published_P_order", "flip": "published_P_flip",
               "angles": "published_P_angles", "units": "published_P_units",
               "construction": "published_P_construction", "gamma": "rp_gamma"}


def set_args(r: Reading) -> list[str]:
    """``--set key=value`` items that make ``jaxdip run dip-controllers`` use reading ``r``."""
    return [f"{CONFIG_KEYS[k]}={v:g}" if isinstance(v, float) else f"{CONFIG_KEYS[k]}={v}"
            for k, v in r.changes().items()]
