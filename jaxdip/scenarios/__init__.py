"""Closed loops shared by experiments, tuning targets and the bench, built from plain arguments.

A scenario function returns a ``jd.Rollout`` (or a few of them); it never reads an experiment's config class,
so a tuning target or a benchmark can build the same loop an experiment runs without importing the experiment.
"""
