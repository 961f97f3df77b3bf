"""Filter-error maximum likelihood: the time-varying (EKF), steady-state and practice (innovation)
formulations of one estimator, its recursive form, and their result."""

from .estimator import FORMULATIONS, filter_error_cost, filter_error_estimate
from .recursive import RecursiveFilterErrorML
from .result import FilterErrorEstimate


__all__ = ["FORMULATIONS", "filter_error_cost", "filter_error_estimate", "RecursiveFilterErrorML",
           "FilterErrorEstimate"]
