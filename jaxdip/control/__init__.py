"""Controllers: Riccati/LQR, state feedback (power-series, projection control and networks join later)."""

from jaxdip.control.feedback import FeedbackParams, StateFeedback, feedback_params, state_feedback
from jaxdip.control.riccati import (RiccatiCode, RiccatiError, care, care_checked, dare, dare_checked, dlqr,
                                   error_if_failed, lqr, lyap, riccati_status)

__all__ = ["FeedbackParams", "StateFeedback", "feedback_params", "state_feedback", "care", "dare", "dlqr", "lqr",
           "lyap", "care_checked", "dare_checked", "riccati_status", "error_if_failed", "RiccatiCode",
           "RiccatiError"]
