"""State estimation around the batch estimator: Kalman filter and smoother, EKF/IEKF, the unscented filter,
filter-error maximum likelihood, recursive least squares and ML, the parameter EKF, joint state and
parameter estimation, process-noise smoothing and the continuous-to-discrete conversion."""

from ..filter_error.estimator import filter_error_cost, filter_error_estimate
from ..filter_error.result import FilterErrorEstimate
from ..filters.ekf import (
    ExtendedKalmanFilter,
    FilterResult,
    KalmanFilter,
    SmootherResult,
    measurement_update,
    process_noise_matrix,
    rts_smoother,
)
from .c_export import EXPORTED_ESTIMATORS, export_c
from .c_export_rls import export_rls_c
from .c_export_rml import export_rml_c
from ..recursive.joint import augmented_model, joint_filter
from ..filters.model_filter import ModelFilter, StateFilter
from ..recursive.least_squares import FilterHistory, ParameterEKF, RecursiveLeastSquares
from ..two_stage.seed import seed_from_stage1
from ..recursive.filter_error import RecursiveFilterErrorML
from ..recursive.ml import RecursiveML
from ..filters.smoothing import continuous_to_discrete, process_noise_smoothing, single_stage_smoother
from ..filters.unscented import UnscentedKalmanFilter, merwe_weights


__all__ = ["KalmanFilter", "ExtendedKalmanFilter", "FilterResult", "SmootherResult", "rts_smoother",
           "process_noise_matrix", "measurement_update", "filter_error_estimate", "filter_error_cost",
           "FilterErrorEstimate", "FilterHistory", "ParameterEKF", "RecursiveLeastSquares", "seed_from_stage1",
           "RecursiveML", "augmented_model", "joint_filter", "continuous_to_discrete", "process_noise_smoothing",
           "single_stage_smoother", "UnscentedKalmanFilter", "merwe_weights", "RecursiveFilterErrorML",
           "StateFilter", "ModelFilter", "export_c", "EXPORTED_ESTIMATORS",
           "export_rls_c", "export_rml_c"]
