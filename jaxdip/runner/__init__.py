"""The experiment runner: the ``Experiment`` contract and ``run_experiment`` (runner.experiment), the registry that
finds the experiments of the top-level ``experiments`` package (runner.discovery), and the helpers their reports
share: what may be written (runner.results), summaries over seeds (runner.summaries), figures (runner.figures)
and weight matrices from a config (runner.weights)."""

from jaxdip.runner.experiment import Experiment, Outcome, RunContext, run_experiment
from jaxdip.runner.discovery import get, registry

__all__ = ["Experiment", "Outcome", "RunContext", "run_experiment", "registry", "get"]
