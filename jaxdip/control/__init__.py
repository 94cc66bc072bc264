"""Controllers: Riccati/LQR, state feedback (power-series, projection control and networks join later)."""

from jaxdip.control.feedback import FeedbackParams, StateFeedback, feedback_params, state_feedback
from jaxdip.control.riccati import care, dare, dlqr, lqr, lyap

__all__ = ["FeedbackParams", "StateFeedback", "feedback_params", "state_feedback", "care", "dare", "dlqr", "lqr", "lyap"]
