"""casest: two-stage batch estimation of nonlinear static parameters (CasADi + IPOPT).

Pipeline: :class:`Model` (and data, noise model, priors, fixed parameters: :class:`Problem`)
-> :func:`separate` -> :func:`sweep` (stage 1) -> :func:`solve_stage2` ->
:func:`parameter_uncertainty` -> :class:`Estimate`; :func:`estimate` runs all of it.
"""

from .errors import CasestError
from .data import DataError, Dataset
from .model import Gaussian, LogUniform, Model, ModelError, OptionError, Parameter, Signal, Uniform
from .modelfile import (
    ModelFileError,
    ModelFileHooks,
    bundled_data_dir,
    bundled_model_names,
    load_model_file,
    model_file_hooks,
)
from .dynamic import DynamicModel, State
from .experiments import stack_experiments
from .noise import CorrelatedNoise, DiagonalNoise, KnownNoise, NoiseModel
from .pipeline import estimate
from .result import Estimate, ResultFileError
from .separate import Partition, SeparationError, separate
from .stage1 import IdentifiabilityError, Landscape, SweepSettings, sweep
from .problem import Problem, concentrated_cost, ml_cost
from .stage2 import SolverSettings, Stage2Result, solve_stage2
from .uncertainty import correlation, covariance_from_hessian, parameter_uncertainty, std_from_covariance

__version__ = "0.1.0"

# state estimation and experiment design, imported on first use
_LAZY = {
    "KalmanFilter": "filters", "ExtendedKalmanFilter": "filters", "rts_smoother": "filters",
    "FilterResult": "filters", "SmootherResult": "filters",
    "information_function": "information", "information_matrix": "information",
    "design_experiment": "design", "design_inputs": "design", "ExperimentDesign": "design", "InputDesign": "design",
    "filter_error_estimate": "filter_error", "FilterErrorEstimate": "filter_error",
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
    "Gaussian",
    "IdentifiabilityError",
    "KnownNoise",
    "CorrelatedNoise",
    "DiagonalNoise",
    "NoiseModel",
    "Landscape",
    "LogUniform",
    "Model",
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
    *_LAZY,
]
