"""The estimator as plain CasADi objects, for larger CasADi optimisation workflows."""

from .embed import MLProblem, estimator_function, ml_cost_function, ml_problem, remembering
from .opti import OptiEstimation, add_to_opti
from .two_stage import two_stage_function
from .two_stage_graph import stage1_function, two_stage_graph_function


__all__ = ["MLProblem", "ml_problem", "OptiEstimation", "add_to_opti", "estimator_function", "two_stage_function",
           "two_stage_graph_function", "stage1_function", "ml_cost_function", "remembering"]
