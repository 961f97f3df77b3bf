"""Equation error: ordinary and weighted least squares on regressors (`regress`), stepwise
selection of the regressors (`stepwise`) and total least squares for errors in the regressors."""

from .regression import Regression, regress
from .stepwise import Stepwise, StepwiseStep, stepwise
from .total_least_squares import total_least_squares


__all__ = ["Regression", "regress", "Stepwise", "StepwiseStep", "stepwise", "total_least_squares"]
