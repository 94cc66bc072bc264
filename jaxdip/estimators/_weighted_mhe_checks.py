"""Argument checks of the estimators whose modules are long (the checks themselves: ``jaxdip.engine.checks``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import checks


def wmhe_args(self, model, C, meas_weight, arrival_weight, proc_weight, gamma, xhat0, N, anchor, prior) -> int:
    """``WeightedMHE.__init__``'s arguments, before any is converted; returns the state size d."""
    if not isinstance(model, tuple) or len(model) != 3:
        raise checks.ArgumentTypeError(f"WeightedMHE: model must be a Discrete(Phi, Phi_inv, W) (jd.zoh), "
                                       f"got {type(model).__name__}")
    for name, v in (("C", C), ("meas_weight", meas_weight), ("arrival_weight", arrival_weight),
                    ("proc_weight", proc_weight), ("gamma", gamma), ("xhat0", xhat0)):
        if v is not None:
            checks.check_real(self, name, v)
    d = checks.check_square(self, "model.Phi", model[0])
    checks.check_int(self, "N", N, 1)
    checks.check_int(self, "anchor", anchor, 0)
    if not anchor < N:
        checks.fail(self, f"anchor must satisfy 0 <= anchor < N = {N}, got {anchor}")
    checks.check_choice(self, "prior", prior, ("smoothed", "filtered"))
    return d


def check_weighted_mhe(self) -> None:
    """A built ``WeightedMHE``'s fields (model, weights PSD, gamma > 0, box lower <= upper)."""
    d, _, _ = checks.check_lti(self, self.model.Phi, self.model.W, self.C, self.model.Phi_inv, prefix="model.")
    why = f"for a {d}-state model"
    if self.C is not None:
        p = self.C.shape[0]
        checks.check_shape(self, "meas_weight", self.meas_weight, (p, p),
                           f"for {p} measurements (C is {checks.fmt_shape(self.C.shape)})")
    else:
        checks.check_square(self, "meas_weight", self.meas_weight)
    checks.check_psd(self, "meas_weight", self.meas_weight)
    checks.check_covariance(self, "arrival_weight", self.arrival_weight, d, why)
    if self.proc_weight is not None:
        checks.check_covariance(self, "proc_weight", self.proc_weight, d, why)
    checks.check_ndim(self, "gamma", self.gamma, (0,), "a scalar")
    checks.check_positive(self, "gamma", self.gamma)
    checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
    for name in ("lower", "upper"):
        checks.check_shape(self, name, getattr(self, name), (d,), why)
    checks.check_limits(self, "lower", self.lower, "upper", self.upper)
    if self.box_iters is not None:
        checks.check_int(self, "box_iters", self.box_iters, 1)


def weighted_mhe_sizes(self) -> dict:
    shape = checks.fmt_shape
    sizes = {"out": (self.model.Phi.shape[0], f"model.Phi is {shape(self.model.Phi.shape)}"),
             "u": (self.model.W.shape[1], f"model.W is {shape(self.model.W.shape)}")}
    if self.C is not None:
        sizes["in"] = (self.C.shape[0], f"C is {shape(self.C.shape)}")
    return sizes


def bounded_coordinates(lower, upper) -> tuple:
    """Indices with a finite lower or upper bound (all of them when the bounds are traced at construction)."""
    try:
        lo, hi = np.asarray(lower), np.asarray(upper)
    except (TypeError, jax.errors.TracerArrayConversionError):
        return tuple(range(jnp.shape(lower)[0]))
    return tuple(int(i) for i in np.flatnonzero(np.isfinite(lo) | np.isfinite(hi)))
