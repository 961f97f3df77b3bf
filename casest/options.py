"""The values each of casest's string options takes, as ``Literal`` types for the signatures,
and the one check that validates a value against them.

Each option kind is declared once here; the modules that take the option annotate it with the
type and call :func:`check_option`, whose message names the option, the allowed values and
the value given.
"""

from __future__ import annotations

from typing import Literal, get_args

from .errors import OptionError

__all__ = ["Mode", "EstimateMode", "CovarianceMethod", "Integrator", "InputHold", "OutputErrorSolver", "LeastSquaresSolver",
           "Robust", "Criterion", "Shooting", "FilterErrorFormulation", "FilterErrorSolver", "FilterErrorCovariance", "OperatingPoint",
           "InnovationCovariance", "SweepDesign", "SweepMethod", "MissingOutputs", "TableMethod", "OptiStart",
           "GraphSolver", "SweepCriterion", "ErrorBoundChoice", "ValidityChecks", "FrequencyMethod", "Inversion", "ExportedEstimator", "CodePrecision",
           "check_option", "choices"]

#: stage 2's mode (``"auto"`` chooses per problem)
Mode = Literal["full", "reduced", "alternating"]
#: :func:`casest.estimate`'s mode: stage 2's modes, or chosen per problem (``auto``) or by the paper's Step 5
EstimateMode = Literal["auto", "paper", "full", "reduced", "alternating"]
#: the information matrix whose inverse is the parameters' covariance at stage 2's optimum: the exact
#: Hessian of the ML cost, or the Gauss-Newton (Fisher) information (the degrees-of-freedom correction
#: is a separate option, ``dof_correction``)
CovarianceMethod = Literal["hessian", "gauss-newton"]
#: the discretisation of a dynamic model
Integrator = Literal["rk4", "cvodes"]
#: how a dynamic model holds its inputs between samples
InputHold = Literal["linear", "cubic", "zoh"]
#: stage 2's solver of output error
OutputErrorSolver = Literal["auto", "gauss-newton", "ipopt"]
#: stage 2's solver of small static least-squares problems
LeastSquaresSolver = Literal["auto", "levenberg-marquardt", "ipopt"]
#: experiment design over uncertain parameters: the average or the worst case of the criterion
Robust = Literal["average", "worst"]
#: experiment design's optimality criterion
Criterion = Literal["D", "A", "E", "c"]
#: output error's simulation: one shot over each record, or shooting intervals
Shooting = Literal["single", "multiple"]
#: filter-error ML's likelihood
FilterErrorFormulation = Literal["time-varying", "steady-state", "innovation"]
#: filter-error ML's optimiser
FilterErrorSolver = Literal["ipopt", "scoring"]
#: filter-error ML's covariance: observed (Hessian) or expected (Fisher) information, or the innovation
#: form's sandwich (the estimator's own covariance where the channels' innovations are correlated)
FilterErrorCovariance = Literal["hessian", "fisher", "sandwich"]
#: where the one-gain filter-error forms linearise
OperatingPoint = Literal["first", "mean"]
#: the innovation formulation's innovation covariance: its diagonal (practice) or the full matrix
InnovationCovariance = Literal["diagonal", "full"]
#: where stage 1 samples xi2 (``"auto"``: a grid up to two swept parameters, Sobol beyond)
SweepDesign = Literal["auto", "grid", "sobol", "random"]
#: stage 1's linear least squares: normal equations on Gram sums, or QR of the stacked columns
SweepMethod = Literal["gram", "qr"]
#: a record's missing outputs: refused, or allowed (NaN: not measured at that sample)
MissingOutputs = Literal["error", "allow"]
#: a lookup table's interpolation
TableMethod = Literal["linear", "bspline"]
#: where an estimation put into a CasADi Opti starts: the nominal values or stage 1's best candidate
OptiStart = Literal["nominal", "stage1"]
#: the NLP solver of the two-stage graph Function (``sqpmethod`` can be generated as C)
GraphSolver = Literal["ipopt", "sqpmethod"]
#: how stage 1 ranks candidates: Tr[R], or the concentrated likelihood sum ln R_jj
SweepCriterion = Literal["trace", "likelihood"]
#: whether stage 1 computes the paper's cost-error bound: by its cost (``"auto"``), always, never
ErrorBoundChoice = Literal["auto", True, False]
#: where stage 1 applies the paper's validity conditions (Eq. 17-18): the best candidate, or every one (Step 2)
ValidityChecks = Literal["best", "every"]
#: the frequency-domain estimator's error: output error, or equation error on measured states
FrequencyMethod = Literal["output-error", "equation-error"]
#: recursive least squares' information inverse: q x q (parameters) or n x n (measurements)
Inversion = Literal["parameters", "measurements"]
#: the online estimators casest writes as C (``casest export-c --estimator``; ``rls``, ``rml`` for a static model)
ExportedEstimator = Literal["ekf", "iekf", "ukf", "rls", "rml"]
#: the C type of the numbers of generated code
CodePrecision = Literal["double", "single"]


def choices(kind) -> tuple:
    """The values of an option kind.

    Parameters
    ----------
    kind : typing.Literal
        One of this module's types.

    Returns
    -------
    tuple of str
    """
    return get_args(kind)


def check_option(name: str, value, kind) -> None:
    """Raise an :class:`~casest.errors.OptionError` unless ``value`` is one of the kind's values.

    Parameters
    ----------
    name : str
        The option as the user wrote it (``"formulation"``, ``"SolverSettings.least_squares_solver"``).
    value : object
        The value given.
    kind : typing.Literal
        One of this module's types.

    Raises
    ------
    OptionError
        Naming the option, its values and the value given.
    """
    allowed = get_args(kind)
    if value not in allowed:
        raise OptionError(f"{name} must be one of {allowed}, got {value!r}")
