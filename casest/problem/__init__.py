"""The estimation problem: model, data and experiments, the noise model, priors, fixed
parameters, and the measurement interface the stages call."""

from ..backend.output_error import dynamic_cost_expression, dynamic_data_views, output_error_sums
from .experiments import stack_dynamic_experiments, stack_experiments
from .measurement import (
    DynamicMeasurement,
    Measurement,
    StaticMeasurement,
    data_symbols,
    data_vector,
    measurement_of,
    ml_cost_expression,
    sum_data_symbols,
)
from .noise import CorrelatedNoise, DiagonalNoise, KnownNoise, NoiseModel, cholesky_vector, covariance_of
from .costs import concentrated_cost, ml_cost
from .problem import NOISE_KINDS, Problem, as_problem


__all__ = ["Problem", "as_problem", "ml_cost", "concentrated_cost", "NOISE_KINDS", "NoiseModel", "DiagonalNoise",
           "KnownNoise", "CorrelatedNoise", "Measurement", "StaticMeasurement", "DynamicMeasurement",
           "measurement_of", "ml_cost_expression", "data_vector", "data_symbols", "sum_data_symbols",
           "stack_experiments", "stack_dynamic_experiments", "cholesky_vector", "covariance_of",
           "output_error_sums", "dynamic_data_views", "dynamic_cost_expression"]
