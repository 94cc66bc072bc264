"""Controllers: Riccati/LQR, state feedback, power-series and relaxed projection control, constrained linear MPC
(engine controllers), and the dense QP solver under the MPC."""

from jaxdip.control.feedback import ConstantInput, SaturatedFeedback, StateFeedback
from jaxdip.control.riccati import (RiccatiCode, RiccatiError, care, care_checked, dare, dare_checked, dlqr,
                                   error_if_failed, lqr, lyap, riccati_status)

from jaxdip._public import public_dir

__all__ = ["ConstantInput", "SaturatedFeedback", "StateFeedback", "care", "dare", "dlqr", "lqr", "lyap",
           "care_checked", "dare_checked", "riccati_status", "error_if_failed", "RiccatiCode", "RiccatiError"]
__dir__ = public_dir(globals())
from jaxdip.control.power_series import PowerSeries  # noqa: E402
from jaxdip.control.projection import RelaxedProjection  # noqa: E402

__all__ += ["PowerSeries", "RelaxedProjection"]
from jaxdip.control.mpc import LinearMPC  # noqa: E402
from jaxdip.control.qp import QPCode, QPSolution, solve_qp  # noqa: E402

__all__ += ["LinearMPC", "QPCode", "QPSolution", "solve_qp"]
