"""Filter-error maximum likelihood: the time-varying (EKF), steady-state and practice (innovation)
formulations of one estimator, and their result. Its recursive form is one of the recursive
estimators (:class:`casest.recursive.RecursiveFilterErrorML`)."""

from .estimator import FORMULATIONS, filter_error_cost, filter_error_estimate
from .result import FilterErrorEstimate


__all__ = ["FORMULATIONS", "filter_error_cost", "filter_error_estimate", "FilterErrorEstimate"]
