"""The two-stage estimator: stage 1 (the sweep), stage 2 (the solve), the multi-start policy, the
pipeline (`estimate`) and its result, profile intervals and likelihood sets, and the start a
recursive estimator takes from stage 1. The separator it splits the parameters by is
:mod:`casest.problem.separate` (exported here too)."""

from ..errors import IdentifiabilityError, SeparationError
from .multistart import MultiStartResult, StartRecord, run_starts
from .pipeline import estimate, finish_estimate, package_estimate
from .result import Estimate
from ..problem.separate import Partition, interaction_graph, separate
from .solve import MODES, SolverSettings, Stage2Result, solve_stage2, weighted_linear_parameters
from .sweep import VERDICTS, Landscape, SweepSettings, draw_candidates, sweep
from .profile import ProfileInterval, profile_intervals, with_profile_intervals
from .refit import refit
from .seed import seed_from_stage1
from .sweep.confidence import LikelihoodRatioSet, ParameterInterval, confidence_sets, likelihood_ratio_set


__all__ = ["estimate", "finish_estimate", "package_estimate", "Estimate", "Partition", "separate",
           "interaction_graph", "SeparationError", "IdentifiabilityError", "sweep", "SweepSettings", "Landscape",
           "draw_candidates", "VERDICTS", "solve_stage2", "SolverSettings", "Stage2Result", "MODES",
           "weighted_linear_parameters", "StartRecord", "MultiStartResult", "run_starts", "profile_intervals",
           "with_profile_intervals", "ProfileInterval", "confidence_sets", "likelihood_ratio_set",
           "LikelihoodRatioSet", "ParameterInterval", "refit", "seed_from_stage1"]
