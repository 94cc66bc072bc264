"""Derivative-free search: ensemble Kalman inversion over SPD matrices P (thesis §2.6)."""

from jaxdip.search.eki import EKI, EKIState, ensemble_update, run_eki

from jaxdip._public import public_dir

__all__ = ["EKI", "EKIState", "ensemble_update", "run_eki"]
__dir__ = public_dir(globals())
