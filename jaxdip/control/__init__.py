"""Controllers: Riccati/LQR, state feedback, power-series and relaxed projection control, constrained linear MPC
(engine controllers) and the dense QP solver under it, and the python-control-style design toolbox (LQR/LQE
designs, pole placement, Lyapunov equations and Gramians, frequency responses and margins)."""

from jaxdip.control.feedback import ConstantInput, SaturatedFeedback, StateFeedback
from jaxdip.control.designs import dlqe, dlqr, lqe, lqi, lqr
from jaxdip.control.frequency import bode, evalfr, freqresp, margins
from jaxdip.control.lyapunov import LyapunovError, ctrb, dlyap, gram, lyap, obsv
from jaxdip.control.placement import acker, place
from jaxdip.control.responses import initial_response, step_response
from jaxdip.control.riccati import (RiccatiCode, RiccatiError, care, care_checked, dare, dare_checked,
                                   error_if_failed, riccati_status)
from jaxdip.control.statespace import StateSpace, c2d, from_control, ss, to_control

from jaxdip._public import public_dir

__all__ = ["ConstantInput", "SaturatedFeedback", "StateFeedback", "care", "dare", "dlqr", "lqr", "lqi", "lqe",
           "dlqe", "lyap", "dlyap", "ctrb", "obsv", "gram", "LyapunovError", "place", "acker", "StateSpace", "ss", "c2d",
           "from_control", "to_control", "evalfr", "freqresp", "bode", "margins", "step_response", "initial_response", "care_checked", "dare_checked",
           "riccati_status", "error_if_failed", "RiccatiCode", "RiccatiError"]
__dir__ = public_dir(globals())
from jaxdip.control.power_series import PowerSeries  # noqa: E402
from jaxdip.control.projection import RelaxedProjection  # noqa: E402

__all__ += ["PowerSeries", "RelaxedProjection"]
from jaxdip.control.mpc import LinearMPC  # noqa: E402
from jaxdip.control.qp import QPCode, QPSolution, solve_qp  # noqa: E402

__all__ += ["LinearMPC", "QPCode", "QPSolution", "solve_qp"]
