"""Recursive estimators: the parameters updated sample by sample on one symbolic model. Recursive least
squares of the linear parameters and the parameter EKF (:mod:`~casest.recursive.least_squares`), recursive
ML with static and output-error predictors (:mod:`~casest.recursive.ml`), recursive filter-error ML
(:mod:`~casest.recursive.filter_error`), and joint state and parameter estimation
(:mod:`~casest.recursive.joint`). Their start from stage 1 on a record's first samples is
:func:`casest.two_stage.seed_from_stage1`; their C exports are in :mod:`casest.export`."""

from .filter_error import RecursiveFilterErrorML
from .joint import augmented_model, joint_filter
from .least_squares import FilterHistory, ParameterEKF, RecursiveLeastSquares
from .ml import RecursiveML


__all__ = ["RecursiveLeastSquares", "ParameterEKF", "FilterHistory", "RecursiveML", "RecursiveFilterErrorML",
           "augmented_model", "joint_filter"]
