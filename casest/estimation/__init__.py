"""What every estimator shares: the result protocol and its reports (text, HTML, files, figures),
the covariance from the Hessian, the residual checks and
their verdict, the diagnosis of what a model lacks, validation on a record not used, the
Gauss-Newton step and the convergence history."""

from .result_protocol import EstimateLike, parameters_frame
from .uncertainty import (
    COVARIANCE_METHODS,
    Uncertainty,
    correlation,
    covariance_from_hessian,
    parameter_uncertainty,
    std_from_covariance,
)
from .validation import Validation, theil_inequality, validate
from .verdict import ResidualVerdict, residual_verdict
from .residual_family import series_checks
from .diagnosis import Diagnosis
from .refit import Refit, shifted_dataset, shifted_signal_model


__all__ = ["EstimateLike", "parameters_frame", "COVARIANCE_METHODS", "Uncertainty", "covariance_from_hessian",
           "std_from_covariance", "correlation", "parameter_uncertainty", "Validation", "theil_inequality", "validate",
           "ResidualVerdict", "residual_verdict", "series_checks", "Diagnosis", "Refit", "shifted_signal_model",
           "shifted_dataset"]
