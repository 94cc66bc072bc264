"""Estimators of the common init/step interface (``jaxdip.sim.component``)."""

from jaxdip.estimators import cpx, kalman, linearized, proximal, scpx
from jaxdip.engine.roles import FanOut, Passthrough
from jaxdip.estimators.cpx import CPX, CPXParams, LinearizedCPX, cpx_linearized, cpx_qr
from jaxdip.estimators.kalman import EKFParams, KFParams, ekf
from jaxdip.estimators.kalman import kalman as kalman_filter
from jaxdip.estimators.kf import ExtendedKalmanFilter, KalmanFilter
from jaxdip.estimators.ldf import LDF
from jaxdip.estimators.wrappers import Delayed, InitialError
from jaxdip.estimators.linearized import AffineStep, local_model
from jaxdip.estimators.passthrough import passthrough
from jaxdip.estimators.run import filter_sequence
from jaxdip.estimators.proximal import LSMHEParams, ls_mhe, ls_mhe_filter, prox_ls, prox_ls_svd
from jaxdip.estimators.scpx import scpx_linearized, scpx_lti
from jaxdip.estimators import bias_observers, continuous, homd, luenberger  # reaction-wheel pendulum
from jaxdip.estimators import lgssm  # batch filter, smoother and likelihood over whole sequences
from jaxdip.estimators.weighted_mhe import WeightedMHE
from jaxdip.estimators.ekf_online import NonlinearEKF
from jaxdip.estimators import ukf  # unscented Kalman filter: batch form and engine estimator
from jaxdip.estimators.ukf import NonlinearUKF

__all__ = [
    "passthrough", "cpx", "kalman", "linearized", "proximal", "scpx", "CPXParams", "cpx_linearized", "cpx_qr",
    "EKFParams", "KFParams", "ekf", "kalman_filter", "AffineStep", "local_model", "LSMHEParams", "ls_mhe",
    "ls_mhe_filter", "prox_ls", "prox_ls_svd", "scpx_linearized", "scpx_lti", "filter_sequence",
]
__all__ += ["CPX", "LinearizedCPX", "KalmanFilter", "ExtendedKalmanFilter", "Passthrough", "FanOut", "LDF", "Delayed",
            "InitialError"]  # engine estimators (equinox Modules)
__all__ += ["bias_observers", "continuous", "homd", "luenberger"]
__all__ += ["lgssm", "WeightedMHE", "NonlinearEKF", "ukf", "NonlinearUKF"]
