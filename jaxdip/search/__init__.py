"""Derivative-free search: ensemble Kalman inversion and its variants as composable steps (thesis §2.6)."""

from jaxdip.search.eki import EKI, EKIState, ensemble_update, run_eki
from jaxdip.search.failures import Failure, SearchStopped
from jaxdip.search.localisers import distance_kernel, schur, sec, sec_fisher
from jaxdip.search.schedules import data_misfit, fixed, scheduled
from jaxdip.search.steps import SearchState, make_step, run_steps, step_body

from jaxdip._public import public_dir

__all__ = ["EKI", "EKIState", "ensemble_update", "run_eki", "Failure", "SearchStopped", "distance_kernel", "schur",
           "sec", "sec_fisher", "data_misfit", "fixed", "scheduled", "SearchState", "step_body", "run_steps",
           "make_step"]
__dir__ = public_dir(globals())
