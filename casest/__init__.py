"""casest: two-stage batch estimation of nonlinear static parameters (CasADi + IPOPT).

Pipeline: :class:`Model` (and data, noise model, priors, fixed parameters: :class:`Problem`)
-> :func:`separate` -> :func:`sweep` (stage 1) -> :func:`solve_stage2` ->
:func:`parameter_uncertainty` -> :class:`Estimate`; :func:`estimate` runs all of it.

Subpackages, lowest layer first: :mod:`casest.data`, :mod:`casest.models`,
:mod:`casest.backend`, :mod:`casest.problem`, :mod:`casest.estimation` (what every estimator
shares) beside :mod:`casest.filters` (the state filters), the estimator families
:mod:`casest.two_stage`, :mod:`casest.equation_error`, :mod:`casest.frequency`,
:mod:`casest.design`, :mod:`casest.filter_error` and :mod:`casest.recursive`, then
:mod:`casest.interop`, :mod:`casest.export` (every C export) and :mod:`casest.apps` (with
:mod:`casest.errors` and :mod:`casest.status` at the base). ``docs/explanation/layout.md`` is the map.
"""

from .data import DataError, Dataset, read_mat_paths
from .errors import CasestError, IdentifiabilityError
from .errors import OutputPathError, ResultFileError
from .models import (
    DynamicModel,
    Gaussian,
    LogUniform,
    Model,
    ModelError,
    ModelFileError,
    ModelFileHooks,
    OptionError,
    Parameter,
    Signal,
    State,
    Uniform,
    artificially_stabilised,
    bundled_data_dir,
    bundled_model_names,
    flight_path_columns,
    flight_path_model,
    load_model_file,
    lookup_table,
    model_file_hooks,
    stabilised_dataset,
    table_coverage,
)


__version__ = "0.1.0"

# the estimators, the problem, state estimation and experiment design, imported on first use
# (``casest models`` and ``--help`` need none of them)
_LAZY = {
    "Estimate": "two_stage",
    "Landscape": "two_stage",
    "Partition": "two_stage",
    "SeparationError": "two_stage",
    "SolverSettings": "two_stage",
    "Stage2Result": "two_stage",
    "SweepSettings": "two_stage",
    "correlation": "estimation",
    "covariance_from_hessian": "estimation",
    "estimate": "two_stage",
    "refit": "two_stage",
    "parameter_uncertainty": "estimation",
    "separate": "two_stage",
    "solve_stage2": "two_stage",
    "std_from_covariance": "estimation",
    "sweep": "two_stage",
    "theil_inequality": "estimation",
    "validate": "estimation",
    "Validation": "estimation",
    "Regression": "equation_error",
    "regress": "equation_error",
    "total_least_squares": "equation_error",
    "Stepwise": "equation_error",
    "stepwise": "equation_error",
    "FrequencyEstimate": "frequency",
    "EstimateLike": "estimation",
    "RecursiveFourierTransform": "frequency",
    "fourier_transform": "frequency",
    "frequency_domain_estimate": "frequency",
    "CorrelatedNoise": "problem",
    "DiagonalNoise": "problem",
    "KnownNoise": "problem",
    "NoiseModel": "problem",
    "Problem": "problem",
    "concentrated_cost": "problem",
    "ml_cost": "problem",
    "stack_experiments": "problem",
    "KalmanFilter": "filters", "ExtendedKalmanFilter": "filters", "UnscentedKalmanFilter": "filters",
    "rts_smoother": "filters", "FilterResult": "filters", "SmootherResult": "filters",
    "information_function": "design", "information_matrix": "design",
    "design_experiment": "design", "design_inputs": "design", "ExperimentDesign": "design", "InputDesign": "design",
    "filter_error_estimate": "filter_error", "FilterErrorEstimate": "filter_error",
    "export_c": "export",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'casest' has no attribute {name!r}")

__all__ = [
    "CasestError",
    "DataError",
    "Dataset",
    "DynamicModel",
    "State",
    "Estimate",
    "ResultFileError",
    "OutputPathError",
    "Gaussian",
    "IdentifiabilityError",
    "KnownNoise",
    "CorrelatedNoise",
    "DiagonalNoise",
    "NoiseModel",
    "Landscape",
    "LogUniform",
    "Model",
    "lookup_table",
    "table_coverage",
    "artificially_stabilised",
    "stabilised_dataset",
    "ModelError",
    "OptionError",
    "Parameter",
    "Partition",
    "Problem",
    "SeparationError",
    "Signal",
    "SolverSettings",
    "Stage2Result",
    "SweepSettings",
    "Uniform",
    "correlation",
    "covariance_from_hessian",
    "estimate",
    "refit",
    "load_model_file",
    "ModelFileError",
    "ModelFileHooks",
    "model_file_hooks",
    "bundled_data_dir",
    "bundled_model_names",
    "ml_cost",
    "concentrated_cost",
    "parameter_uncertainty",
    "separate",
    "solve_stage2",
    "std_from_covariance",
    "sweep",
    "stack_experiments",
    "validate",
    "Validation",
    "flight_path_model",
    "flight_path_columns",
    "read_mat_paths",
    "theil_inequality",
    "regress",
    "total_least_squares",
    "Regression",
    "stepwise",
    "Stepwise",
    "frequency_domain_estimate",
    "FrequencyEstimate",
    "EstimateLike",
    "fourier_transform",
    "RecursiveFourierTransform",
    *_LAZY,
]
__all__ = list(dict.fromkeys(__all__))  # the eager names, then the lazy ones not named above: each once
