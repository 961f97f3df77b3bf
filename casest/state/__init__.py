"""State estimation around the batch estimator: Kalman filter and smoother, EKF/IEKF,
filter-error maximum likelihood, recursive least squares and the parameter EKF."""

from .filter_error import filter_error_cost, filter_error_estimate
from .filter_error_result import FilterErrorEstimate
from .filters import (
    ExtendedKalmanFilter,
    FilterResult,
    KalmanFilter,
    SmootherResult,
    measurement_update,
    process_noise_matrix,
    rts_smoother,
)
from .recursive import FilterHistory, ParameterEKF, RecursiveLeastSquares, seed_from_stage1


__all__ = ["KalmanFilter", "ExtendedKalmanFilter", "FilterResult", "SmootherResult", "rts_smoother",
           "process_noise_matrix", "measurement_update", "filter_error_estimate", "filter_error_cost",
           "FilterErrorEstimate", "FilterHistory", "ParameterEKF", "RecursiveLeastSquares", "seed_from_stage1"]
