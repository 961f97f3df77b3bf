"""The two-stage estimator: the separator, stage 1 (the sweep), stage 2 (the solve), the
multi-start policy, the uncertainty, the pipeline and its result."""

from ..errors import IdentifiabilityError, SeparationError
from .multistart import MultiStartResult, StartRecord, run_starts
from .pipeline import estimate, finish_estimate, package_estimate
from .result import Estimate
from .separate import Partition, interaction_graph, separate
from .solve import MODES, SolverSettings, Stage2Result, solve_stage2, weighted_linear_parameters
from .sweep import VERDICTS, Landscape, SweepSettings, draw_candidates, sweep
from .uncertainty import (
    COVARIANCE_METHODS,
    Uncertainty,
    correlation,
    covariance_from_hessian,
    parameter_uncertainty,
    std_from_covariance,
)
from .result_protocol import EstimateLike, parameters_frame
from .frequency import FrequencyEstimate, RecursiveFourierTransform, fourier_transform, frequency_domain_estimate
from .regression import Regression, regress
from .total_least_squares import total_least_squares
from .stepwise import Stepwise, StepwiseStep, stepwise
from .validation import Validation, theil_inequality, validate
from .profile import ProfileInterval, profile_intervals, with_profile_intervals
from .sweep.confidence import LikelihoodRatioSet, ParameterInterval, confidence_sets, likelihood_ratio_set


__all__ = ["estimate", "finish_estimate", "package_estimate", "Estimate", "Partition", "separate",
           "interaction_graph", "SeparationError", "IdentifiabilityError", "sweep", "SweepSettings", "Landscape",
           "draw_candidates", "VERDICTS", "solve_stage2", "SolverSettings", "Stage2Result", "MODES",
           "weighted_linear_parameters", "StartRecord", "MultiStartResult", "run_starts", "COVARIANCE_METHODS",
           "Uncertainty", "covariance_from_hessian", "std_from_covariance", "correlation", "parameter_uncertainty",
           "Validation", "theil_inequality", "validate", "Regression", "regress", "total_least_squares", "Stepwise", "StepwiseStep",
           "stepwise", "EstimateLike", "parameters_frame", "FrequencyEstimate", "RecursiveFourierTransform", "fourier_transform",
           "frequency_domain_estimate", "profile_intervals", "with_profile_intervals", "ProfileInterval", "confidence_sets",
           "likelihood_ratio_set", "LikelihoodRatioSet", "ParameterInterval"]
