"""Scenario builders shared by experiments and tuning targets: plain keyword arguments in, engine objects
(``jd.Rollout``, loops, samplers) out. Nothing here imports ``jaxdip.experiments``."""
