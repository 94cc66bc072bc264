"""Estimators: engine roles (``jaxdip.engine.roles.Estimator``), their wrappers, and runs over recorded data."""

from jaxdip.engine.roles import FanOut, Passthrough
from jaxdip.estimators import em, kalman, linearized, proximal, recorded, sampling  # noqa: F401
from jaxdip.estimators import bias_observers, continuous, homd, luenberger  # reaction-wheel pendulum  # noqa: F401
from jaxdip.estimators.cpx import CPX, LinearizedCPX
from jaxdip.estimators.dmso import DMSO
from jaxdip.estimators.em import fit_em
from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.ldf import LDF
from jaxdip.estimators.linearized import AffineStep, local_model
from jaxdip.estimators.proximal import LeastSquaresMHE, ls_mhe_filter, prox_ls, prox_ls_svd
from jaxdip.estimators.recorded import kalman_filter, log_likelihood, rts_smoother, run_estimator
from jaxdip.estimators.sampling import sample_posterior
from jaxdip.estimators.ukf import UnscentedKalmanFilter
from jaxdip.estimators.weighted_mhe import WeightedMHE
from jaxdip.estimators.varying_mhe import TimeVaryingMHE
from jaxdip.estimators.wrappers import Ahead, Delayed, DelayedMeasurement, FromTruth, InitialError, Prior

from jaxdip._public import public_dir

__all__ = [
    "kalman", "linearized", "proximal", "recorded", "bias_observers", "continuous", "homd", "luenberger",
    "CPX", "LinearizedCPX", "DMSO", "KalmanFilter", "ExtendedKalmanFilter", "UnscentedKalmanFilter", "LDF",
    "LeastSquaresMHE", "WeightedMHE", "TimeVaryingMHE", "Passthrough", "FanOut",
    "Ahead", "Delayed", "DelayedMeasurement", "FromTruth", "InitialError", "Prior",
    "AffineStep", "local_model", "ls_mhe_filter", "prox_ls", "prox_ls_svd",
    "kalman_filter", "log_likelihood", "rts_smoother", "run_estimator",
    "em", "sampling", "fit_em", "sample_posterior",
]
__dir__ = public_dir(globals())
