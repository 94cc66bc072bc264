"""Scenarios shared by an experiment and a tuning target: builders with plain keyword arguments."""
