"""What the stages compute with: sums over samples with exact derivatives (data in or outside
the graph), the noise covariance's share of the cost (one term per parametrisation of R),
output-error sensitivities, the log-Cholesky algebra, the Gaussian penalty and the one IPOPT
path."""

from .ipopt import (
    ACCEPTABLE_STATUSES,
    IpoptRun,
    SolverSettings,
    active_bounds,
    newton_step_accepts,
    noise_floor,
    run_ipopt,
)
from .linalg import cholesky_factor, cholesky_vector, covariance_of, n_cholesky, variances_of
from .noise_terms import CHOLESKY, DIAGONAL, CholeskyTerm, DiagonalTerm, NoiseTerm, term_of_covariance
from .output_error import OutputErrorSums, dynamic_cost_expression, dynamic_data_views, output_error_sums
from .penalty import GaussianPenalty
from .sums import (
    BOUND_MIN_SAMPLES,
    MLSums,
    Record,
    bound_sum,
    data_outside_graph,
    map_sum,
    ml_sums,
    per_sample_cost,
    prediction_and_jacobian,
    residual_jacobian,
)


__all__ = ["SolverSettings", "ACCEPTABLE_STATUSES", "IpoptRun", "run_ipopt", "active_bounds", "noise_floor",
           "newton_step_accepts", "cholesky_factor", "cholesky_vector", "covariance_of", "n_cholesky", "variances_of",
           "OutputErrorSums", "output_error_sums", "dynamic_data_views", "dynamic_cost_expression", "GaussianPenalty",
           "map_sum", "bound_sum", "Record", "data_outside_graph", "BOUND_MIN_SAMPLES", "MLSums", "ml_sums",
           "per_sample_cost", "residual_jacobian", "prediction_and_jacobian", "NoiseTerm", "DiagonalTerm",
           "CholeskyTerm", "DIAGONAL", "CHOLESKY", "term_of_covariance"]
