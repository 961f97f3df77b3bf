"""The result of filter-error maximum likelihood (:func:`casest.filter_error_estimate`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._casadi.array_json import decode_array
from ..estimation.diagnostics import ResidualCheck
from ..estimation.verdict import judged, residual_verdict
from ..estimation.reporting import (UNITS_CAUTION, closing_lines, correlation_lines, fit_statistic_lines,
                                   parameter_lines, std_text)
from ..estimation.result_files import JsonResult
from ..estimation.result_schema import decode_field, encode_field, file_format, format_version
from ..estimation.html_report import compact_html
from ..estimation.result_protocol import parameters_frame
from ..errors import OptionError
from ..options import FilterErrorFormulation
from ..status import Note, NoteCode, Outcome, StdReason, TrustCode, note_code
from ..filters.ekf import FilterResult
from .one_step import OneStepPredictions


__all__ = ["FilterErrorEstimate"]

_KIND = "casest.FilterErrorEstimate"


#: how FilterErrorEstimate.from_dict reads each field of a file of version 1 back (the others as they are)
_FIELD_DECODERS = {
    **{key: decode_array for key in ("theta", "std", "lower_bounds", "upper_bounds", "R", "R_std", "covariance")},
    **{key: tuple for key in ("parameter_names", "parameter_units", "output_names", "output_units")},
    **{key: float for key in ("cost", "log_likelihood", "seconds")},
    "std_reason_codes": lambda codes: [None if c is None else StdReason(c) for c in codes],
    "outcome": Outcome,
    "residual_checks": lambda checks: tuple(ResidualCheck.from_dict(c) for c in checks),
    **{key: (lambda v: None if v is None else decode_array(v))
       for key in ("innovation_covariance", "innovation_covariance_std")},
}


@dataclass
class FilterErrorEstimate(JsonResult):
    """Result of :func:`filter_error_estimate`, a member of casest's result family: codes
    beside the words, a JSON round trip, a report with units, one std per ``+/-`` and a
    trust line.

    Attributes
    ----------
    model_name : str
    parameter_names : tuple of str
    theta : ndarray, shape (n_parameters,)
    std : ndarray, shape (n_parameters,)
        From the inverse of the exact Hessian of V (NaN where unavailable: ``std_reasons``).
    std_reasons : list of (str or None)
    std_reason_codes : list of (StdReason or None)
    active_bounds : list of (str or None)
        ``"lower"``/``"upper"`` where a parameter ends on a bound.
    lower_bounds, upper_bounds : ndarray, shape (n_parameters,)
    parameter_units : tuple of str
    process_noise : dict
        State name -> intensity (estimated or fixed).
    process_noise_std : dict
        State name -> std of the intensity (estimated ones only).
    output_names, output_units : tuple of str
    R, R_std : ndarray, shape (n_outputs,)
        Measurement-noise variances (output unit squared) and their std (0 when R was given).
        The innovation formulation does not estimate them: R is the implied measurement noise
        ``diag(R_innovation - C P C')`` (NaN where negative) and R_std is NaN.
    R_estimated : bool
        Whether R is an estimated decision variable (False where given or implied).
    covariance : ndarray
        Of all decision variables in natural units (theta, estimated intensities, R).
    cost : float
        V at the optimum (Eq. 5.7 without constants).
    log_likelihood : float
        ln p(y) with the constants.
    success : bool
    status : str
        IPOPT's return status.
    outcome : Outcome
    n_iterations : int
    n_samples : int
    seconds : float
        Wall-clock time of the estimate (s).
    filter : FilterResult or None
        The EKF pass at the optimum (states, covariances, innovations) of the time-varying and
        steady-state forms; not saved to JSON (``predictions`` is).
    notes : list of Note
    residual_checks : tuple of ResidualCheck
        Whiteness of each channel's normalised innovations, in time order.
    formulation : str
        ``"time-varying"``, ``"steady-state"`` or ``"innovation"``.
    innovation_covariance : ndarray, shape (n_outputs, n_outputs), or None
        The innovation formulation's estimate of the innovation covariance (output units
        squared): its closed form ``sum e e' / N``, diagonal by default; None for the other
        formulations.
    innovation_covariance_std : ndarray, shape (n_outputs, n_outputs), or None
        Its large-sample std (0 where an entry is not estimated).
    n_rounds : int
        The innovation formulation's relaxation rounds (R updates); ``n_iterations`` counts the
        Gauss-Newton steps of all rounds. 0 for the other formulations.
    predictions : OneStepPredictions or None
        The filter at the estimate: one-step predictions, innovations and their std, the gain K
        and ``diag(K C)`` (:class:`~casest.filter_error.one_step.OneStepPredictions`); saved to
        JSON. None in files written without it.
    cpu_seconds : float
        CPU time of the estimate (s), this process's; NaN in files written without it.
    """

    FIELD_DECODERS = _FIELD_DECODERS  # how from_dict reads the saved fields back

    model_name: str
    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    std_reasons: list
    std_reason_codes: list
    active_bounds: list
    lower_bounds: np.ndarray
    upper_bounds: np.ndarray
    parameter_units: tuple
    process_noise: dict
    process_noise_std: dict
    output_names: tuple
    output_units: tuple
    R: np.ndarray
    R_std: np.ndarray
    R_estimated: bool
    covariance: np.ndarray
    cost: float
    log_likelihood: float
    success: bool
    status: str
    outcome: Outcome
    n_iterations: int
    n_samples: int
    seconds: float
    filter: FilterResult | None = field(default=None, repr=False)
    notes: list = field(default_factory=list)
    residual_checks: tuple = ()
    formulation: FilterErrorFormulation = "time-varying"
    innovation_covariance: np.ndarray | None = None
    innovation_covariance_std: np.ndarray | None = None
    n_rounds: int = 0
    predictions: OneStepPredictions | None = None
    cpu_seconds: float = float("nan")

    @property
    def values(self) -> dict:
        """Estimates by parameter name."""
        return dict(zip(self.parameter_names, self.theta.tolist()))

    @property
    def stds(self) -> dict:
        """Standard deviations by name (``None`` where unavailable)."""
        return {n: (float(s) if np.isfinite(s) else None) for n, s in zip(self.parameter_names, self.std)}

    @property
    def innovations(self) -> np.ndarray | None:
        """The innovations ``y_k - y(k|k-1)`` at the estimate, shape (N, n_outputs) (None without
        ``predictions``)."""
        return None if self.predictions is None else self.predictions.innovation

    @property
    def gain(self) -> np.ndarray | None:
        """The Kalman gain K at the estimate, shape (n_states, n_outputs) (``predictions.gain_at``
        says where it was formed)."""
        return None if self.predictions is None else self.predictions.gain

    @property
    def kc_diagonal(self) -> dict | None:
        """``diag(K C)`` by state name (below 1 for a filter that does not over-correct)."""
        if self.predictions is None:
            return None
        return dict(zip(self.predictions.state_names, self.predictions.kc_diagonal.tolist()))

    @property
    def process_noise_distribution(self) -> dict:
        """F per state, the process-noise distribution of the textbook (``q = F^2``, F >= 0), in
        state rate per root hertz."""
        return {name: float(np.sqrt(q)) if q >= 0 else float("nan") for name, q in self.process_noise.items()}

    @property
    def process_noise_distribution_std(self) -> dict:
        """The std of each estimated F, ``std(q) / (2 F)`` (the first-order propagation of ``q = F^2``)."""
        F = self.process_noise_distribution
        return {name: (float(s / (2 * F[name])) if F.get(name, 0.0) > 0 else float("nan"))
                for name, s in self.process_noise_std.items()}

    @property
    def decision_names(self) -> tuple:
        """The names of the rows of ``covariance``: the parameters, the estimated process noise
        (``F[state]`` in the innovation form, else ``q[state]``) and the estimated R (``R[output]``)."""
        noise = "F" if self.formulation == "innovation" else "q"
        return (tuple(self.parameter_names) + tuple(f"{noise}[{n}]" for n in self.process_noise_std)
                + (tuple(f"R[{n}]" for n in self.output_names) if self.R_estimated else ()))

    @property
    def correlation(self) -> np.ndarray:
        """The correlation matrix of the decision variables (rows: :attr:`decision_names`; NaN
        where a variable has no std), from ``covariance``."""
        cov = np.asarray(self.covariance, dtype=float)
        std = np.sqrt(np.diag(cov))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov / np.outer(std, std)
        corr[~np.isfinite(corr)] = np.nan
        return corr

    def plot_fit(self, title: str | None = None, max_lag: int = 50):
        """The filter's one-step predictions against the measurements, the normalised innovations
        and their autocorrelation, one row per output
        (:func:`casest.filter_error.figures.one_step_figure`).

        Parameters
        ----------
        title : str, optional
        max_lag : int
            Lags of the autocorrelation (samples).

        Returns
        -------
        matplotlib.figure.Figure

        Raises
        ------
        OptionError
            The estimate holds no predictions (a file written without them).
        """
        from .figures import one_step_figure

        if self.predictions is None:
            raise OptionError("this filter-error estimate holds no one-step predictions (a file written before they "
                              "were saved): estimate it again to draw them")
        return one_step_figure(self.predictions, self.output_units, title, max_lag)

    def record_figures(self) -> list:
        """The figures the HTML page draws from the estimate alone: :meth:`plot_fit` (none without
        predictions).

        Returns
        -------
        list of matplotlib.figure.Figure
        """
        return [] if self.predictions is None else [self.plot_fit()]

    def _repr_html_(self) -> str:
        """The notebook's view: the conclusion and the parameter table."""
        return compact_html(self)

    def to_dataframe(self):
        """The parameters as a pandas data frame
        (:func:`casest.estimation.result_protocol.parameters_frame`).

        Returns
        -------
        pandas.DataFrame
        """
        return parameters_frame(self)

    # -- JSON ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain-Python form, every field by :func:`~casest.estimation.result_schema.encode_field` (the filter
        pass is left out: it loads as None).

        Returns
        -------
        dict
        """
        return {"format": file_format(_KIND),
                **{key: encode_field(value) for key, value in self.__dict__.items() if key != "filter"}}

    @classmethod
    def from_dict(cls, data: dict) -> "FilterErrorEstimate":
        """The FilterErrorEstimate of :meth:`to_dict`'s form (or of the layout files of version 1 have).

        Parameters
        ----------
        data : dict

        Returns
        -------
        FilterErrorEstimate
        """
        if format_version(data.get("format"), _KIND, "casest filter-error estimate") == 1:
            kw = cls.decoded_fields(data)
            kw["notes"] = [Note(t, NoteCode(c)) for t, c in zip(data["notes"], data.get("note_codes", []))]
        else:
            kw = {key: decode_field(value) for key, value in data.items() if key != "format"}
        kw.setdefault("residual_checks", ())  # files written before the residual checks
        return cls(**kw)

    # -- report -------------------------------------------------------------------------
    def trust(self) -> tuple[bool, str]:
        """Whether to trust the estimate, and why (not), in one sentence (see :meth:`conclusion`).

        Returns
        -------
        bool
        str
        """
        code, reason = self.conclusion()
        return code is TrustCode.TRUSTED, reason

    def conclusion(self) -> tuple[TrustCode, str]:
        """Filter-error ML is a local solve from the given start: ``LOCAL`` (in neutral words) when it
        converged, every parameter has a std and the normalised innovations are white and
        independent of the inputs; ``MODEL_ERROR`` when they depend on an input or on time,
        ``COLOURED_NOISE`` when they are only correlated in time
        (:func:`casest.estimation.verdict.judged`); else ``CAUTION`` with the failed conditions.

        Returns
        -------
        TrustCode
        str
        """
        problems = []
        if not self.success:
            problems.append(f"the solve did not converge or has no std ({self.status})")
        missing = [n for n, s in zip(self.parameter_names, self.std) if not np.isfinite(s)]
        if missing:
            problems.append(f"no standard deviation for {missing} (see the notes)")
        if any(note_code(n) is NoteCode.UNITS for n in self.notes):
            problems.append(UNITS_CAUTION)
        if any(note_code(n) is NoteCode.NOISE_FLOOR for n in self.notes):
            problems.append("a measurement-noise variance went to its floor (see the notes): some std are far too small")
        tested = f"; the innovations pass {len(self.residual_checks)} test(s)" if self.residual_checks else ""
        passing = (TrustCode.LOCAL, f"converged from the given start, every parameter has a std{tested}; no global "
                                    "search was asked for")
        return judged(problems, residual_verdict(self.residual_checks), passing)

    def fit_statistics(self) -> list:
        """The fit's statistics as the report and the HTML page show them.

        Returns
        -------
        list of (str, str)
            Name and value in words, one pair per statistic.
        """
        steps = f"{self.n_iterations}" + (f" Gauss-Newton steps in {self.n_rounds} relaxation rounds"
                                          if self.n_rounds else "")
        cpu = f"{self.cpu_seconds:.2f} s CPU" if np.isfinite(self.cpu_seconds) else "CPU not recorded"
        return [("success", f"{self.success} ({self.status})"), ("iterations", steps),
                ("samples N", f"{self.n_samples}"), ("cost V", f"{self.cost:.10g}  (Eq. 5.7 without constants)"),
                ("log-likelihood", f"{self.log_likelihood:.10g}"), ("seconds", f"{self.seconds:.2f} s wall, {cpu}")]

    def report(self) -> str:
        """Text report in fixed sections; ``+/-`` is one standard deviation.

        Returns
        -------
        str
        """
        lines = [f"[[Model]] {self.model_name} (filter-error maximum likelihood, summary Eq. 5.7)", "[[Fit Statistics]]"]
        lines += fit_statistic_lines(self.fit_statistics())
        lines.append("[[Parameters]] (value +/- one standard deviation, unit, bounds)")
        lines += parameter_lines(self.parameter_names, self.theta, self.std, self.parameter_units, self.lower_bounds,
                                 self.upper_bounds, self.std_reasons)
        lines += self._process_noise_lines() + self._noise_lines() + self._gain_lines()
        lines.append("[[Correlations]] (|r| > 0.5, every estimated variable)")
        names = self.decision_names
        if len(names) == np.shape(self.covariance)[0]:
            lines += correlation_lines(names, self.correlation, 0.5)
        lines += closing_lines(self, "normalised innovations")
        return "\n".join(lines)

    def _process_noise_lines(self) -> list:
        """The report's process noise: F (the textbook's distribution) with its std beside q = F^2."""
        lines = ["[[Process noise]] (per state: F +/- one std, and the intensity q = F^2 +/- one std; or given)"]
        F, F_std = self.process_noise_distribution, self.process_noise_distribution_std
        for name, value in self.process_noise.items():
            std = self.process_noise_std.get(name)
            if std is None:
                lines.append(f"    {name}: F = {F[name]:.6g}, q = {value:.6g} (given)")
            else:
                lines.append(f"    {name}: F = {F[name]:.6g} +/- {std_text(F_std[name])}, "
                             f"q = {value:.6g} +/- {std_text(std)}")
        return lines

    def _gain_lines(self) -> list:
        """The report's Kalman gain K (rows: states) and diag(K C)."""
        if self.predictions is None:
            return []
        record = self.predictions
        lines = [f"[[Kalman gain]] (K at {record.gain_at}; columns {', '.join(record.output_names)}; diag(K C))"]
        for i, name in enumerate(record.state_names):
            row = "  ".join(f"{k:+.5g}" for k in record.gain[i])
            lines.append(f"    {name}: [{row}]  diag(K C) = {record.kc_diagonal[i]:.4g}")
        return lines

    def _noise_lines(self) -> list:
        """The report's innovation covariance (where estimated) and measurement-noise sections."""
        units = self.output_units or [""] * len(self.R)
        squared = [f" ({u})^2" if u else "" for u in units]
        lines = []
        if self.innovation_covariance is not None:
            lines.append("[[Innovation covariance]] (estimated in closed form; diagonal entries +/- one std)")
            for j, name in enumerate(self.output_names):
                lines.append(f"    {name}: {self.innovation_covariance[j, j]:.6g}{squared[j]} "
                             f"+/- {std_text(self.innovation_covariance_std[j, j], '.3g')}")
            lines.append("[[Noise]] (implied measurement-noise variance diag(R - C P C') per output, not estimated: "
                         "no std)")
            lines += [f"    {name}: R = {r:.6g}{sq}" for name, r, sq in zip(self.output_names, self.R, squared)]
            return lines
        lines.append("[[Noise]] (" + ("estimated" if self.R_estimated else "known") + " variance R per output)")
        for name, r, s, sq in zip(self.output_names, self.R, self.R_std, squared):
            lines.append(f"    {name}: R = {r:.6g}{sq}" + (f" +/- {std_text(s, '.3g')}" if self.R_estimated else ""))
        return lines
