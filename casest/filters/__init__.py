"""State filters on a dynamic model: the linear Kalman filter, the EKF/IEKF and the unscented filter, the RTS
smoother, process-noise smoothing and the continuous-to-discrete conversion, the filter protocol, and their
passes over a record as compiled C loops. The estimators built on them (filter error, the recursive
estimators) and their C exports live in rooms above."""

from .ekf import ExtendedKalmanFilter, measurement_update, process_noise_matrix, rts_smoother
from .filter_records import FilterResult, SmootherResult
from .kalman import KalmanFilter
from .model_filter import ModelFilter, StateFilter
from .smoothing import continuous_to_discrete, process_noise_smoothing, single_stage_smoother
from .unscented import UnscentedKalmanFilter, merwe_weights


__all__ = ["KalmanFilter", "ExtendedKalmanFilter", "UnscentedKalmanFilter", "FilterResult", "SmootherResult",
           "rts_smoother", "process_noise_matrix", "measurement_update", "merwe_weights", "StateFilter",
           "ModelFilter", "continuous_to_discrete", "process_noise_smoothing", "single_stage_smoother"]
