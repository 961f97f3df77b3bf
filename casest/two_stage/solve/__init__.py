"""Stage 2: the IPOPT NLP of the full ML cost with ln|R| (paper Eq. 6), in full, reduced and
alternating mode, for static models and output error."""

from ...backend.ipopt import SolverSettings, active_bounds, noise_floor
from .result import MODES
from .solve import Stage2Result, solve_stage2, weighted_linear_parameters


__all__ = ["solve_stage2", "SolverSettings", "Stage2Result", "MODES", "weighted_linear_parameters",
           "active_bounds", "noise_floor"]
