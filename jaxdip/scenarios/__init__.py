"""Closed-loop scenarios shared by an experiment and a tuning target: plain builders of ``jaxdip.Rollout``s."""
