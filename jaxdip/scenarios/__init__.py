"""Scenarios: the closed loops that an experiment and a tuning target share, built from plain keyword
arguments (no experiment config), so that neither imports the other."""
