"""The estimate: a dataclass with the same fields on every path, JSON I/O and a report."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._casadi.array_json import decode_array, encode_array
from ..backend.tolerances import cost_tolerance
from ..errors import ResultFileError
from ..status import Note, NoteCode, Outcome, StdReason, TrustCode, note_code
from ..estimation.diagnostics import ResidualCheck
from ..estimation.diagnosis import Diagnosis
from ..estimation.intervals import ParameterInterval, ProfileInterval
from ..estimation.residual_analysis import ResidualAnalysis
from ..estimation.result_files import JsonResult, check_loaded_estimate, number_of_json, optional_decoder
from ..estimation.result_schema import decode_field, encode_field, file_format, format_version, register_record
from .result_views import EstimateViews, StdChoice
from ..estimation.history import ConvergenceHistory
from .merged_limit import MergedLimit
from .multistart import StartRecord
from ..estimation.reporting import UNITS_CAUTION, conclusion_words, estimate_fit_statistics, estimate_report, std_text
from ..estimation.verdict import ColouredStd, judged, residual_verdict
from .sweep import Landscape


__all__ = ["Estimate", "StdChoice", "JsonResult", "ResultFileError", "encode_array", "decode_array"]


_KIND = "casest.Estimate"
#: the one call that refits a diagnosed change (the reports name it)
REFIT_CALL = "casest.refit(estimate, model, data)"
#: |correlation| above which two parameters are determined only as a combination (their std with
#: the other free exceeds 1 / sqrt(1 - r^2) = 22 times their std with it known)
NEAR_DEPENDENCE = 0.999
#: outcomes at which a start reached a verified minimum
_SUCCESS = (Outcome.CONVERGED, Outcome.ACCEPTED_NEWTON, Outcome.EXACT_FIT)



#: how each field of a saved Estimate is read back (the others as they are)
_FIELD_DECODERS = {
    **{key: decode_array for key in ("theta", "std", "covariance", "correlation", "R", "lower_bounds", "upper_bounds")},
    **{key: tuple for key in ("parameter_names", "output_names", "linear", "nonlinear", "parameter_units",
                              "output_units", "fixed_parameters", "experiments")},
    "starts": lambda records: tuple(StartRecord.from_dict(record) for record in records),
    "residual_checks": lambda checks: tuple(ResidualCheck.from_dict(c) for c in checks),
    "R_full": optional_decoder(decode_array),
    "std_reason_codes": lambda codes: [None if c is None else StdReason(c) for c in codes],
    "cost": number_of_json,
    "start_cost": number_of_json,
    "timings": lambda timings: {k: number_of_json(v) for k, v in timings.items()},
    "landscape": optional_decoder(Landscape.from_dict),
    "residual_analysis": optional_decoder(ResidualAnalysis.from_dict),
    "convergence": optional_decoder(ConvergenceHistory.from_dict),
    "intervals": lambda records: tuple(ProfileInterval.from_dict(record) for record in records),
    "likelihood_sets": lambda records: tuple(ParameterInterval.from_dict(record) for record in records),
    "merged_limit": optional_decoder(MergedLimit.from_dict),
    "diagnosis": optional_decoder(Diagnosis.from_dict),
}
# the records an Estimate holds, written in the one schema by their own to_dict
for _record in (Landscape, ResidualAnalysis, ConvergenceHistory, MergedLimit, StartRecord, ProfileInterval,
                ParameterInterval, ResidualCheck, Diagnosis):
    register_record(_record)

#: fields a file written before they existed lacks, and their value then
_FIELDS_ADDED_LATER = {"parameter_units": (), "output_units": (), "fixed_parameters": (), "experiments": (),
                       "starts": (), "residual_checks": (), "std_reason_codes": [], "start_cost": None, "intervals": (), "likelihood_sets": (),
                       "dof_correction": False, "merged_limit": None, "diagnosis": None}


def _version_1_fields(data: dict) -> dict:
    """An Estimate's fields from a file of version 1 (its own layout: arrays untagged, notes as text
    beside a ``note_codes`` list)."""
    kw = {k: _FIELD_DECODERS.get(k, lambda v: v)(v) for k, v in data.items() if k not in ("format", "note_codes")}
    kw["outcome"] = Outcome(data.get("outcome", Outcome.CONVERGED if data.get("success") else Outcome.NOT_CONVERGED))
    texts = data.get("notes", [])
    codes = data.get("note_codes") or [NoteCode.OTHER] * len(texts)
    kw["notes"] = [Note(text, code) for text, code in zip(texts, codes)]
    return kw


@dataclass
class Estimate(EstimateViews, JsonResult):
    """The result of :func:`casest.estimate` (or of stage 2 alone).

    Attributes
    ----------
    model_name : str
    parameter_names : tuple of str
    output_names : tuple of str
    theta : ndarray, shape (n_parameters,)
        Estimated parameters, physical units, model order.
    std : ndarray, shape (n_parameters,)
        Standard deviations; NaN where unavailable (see ``std_reasons``).
    std_reasons : list of (str or None)
        Why a std is unavailable (active bound, not identifiable), else ``None``.
    covariance : ndarray, shape (n_parameters, n_parameters)
    correlation : ndarray, shape (n_parameters, n_parameters)
    covariance_method : {"hessian", "gauss-newton"}
        The information matrix inverted.
    dof_correction : bool
        Whether the covariance carries the degrees-of-freedom factor N m / (N m - p).
    R : ndarray, shape (n_outputs,)
        Estimated noise variances (diagonal of R), output unit squared.
    cost : float
        J of paper Eq. 6 at the estimate (constants dropped).
    n_samples : int
        N of the stage-2 data.
    lower_bounds, upper_bounds : ndarray, shape (n_parameters,)
    active_bounds : list of (str or None)
        ``"lower"``/``"upper"`` where a parameter ends on a bound.
    linear, nonlinear : tuple of str
        The partition xi1 / xi2.
    mode : str
        Stage-2 mode that produced the estimate.
    success : bool
    status : str
    message : str
    n_iterations : int
    landscape : Landscape or None
        The stage-1 sweep (``None`` when stage 1 did not run).
    timings : dict of str to float
        Seconds per step.
    notes : list of str
        Everything the user should know (fallbacks, floors, bounds).
    start_cost : float or None
        The lowest J among the starts stage 2 was given (``None`` for stage 2 alone); a
        successful estimate's ``cost`` is never above it.
    parameter_units : tuple of str
        Each parameter's unit as declared in the model ("" where none was given).
    output_units : tuple of str
        Each output's unit as declared in the model ("" where none was given).
    fixed_parameters : tuple of str
        Parameters held at a given value, not estimated (no std by design).
    noise_model : str
        "unknown diagonal R (estimated)" (paper Eq. 6), or the known R it was given.
    noise_estimated : bool
        R was estimated with theta (False: a known R was given and held).
    std_reason_codes : list of (StdReason or None)
        The code of each std reason.
    outcome : Outcome
        How stage 2 ended, as a code (``success`` is True only for converged, accepted
        and exact-fit outcomes).
    experiments : tuple of str
        The experiments' names when several data sets were estimated together.
    n_measured : int or None
        Measurements actually made (N x n_outputs less the missing ones).
    R_full : ndarray, shape (n_outputs, n_outputs), or None
        The estimated full noise covariance (``noise=CorrelatedNoise()``); ``R`` is its diagonal.
    starts : tuple of StartRecord
        Every stage-2 start: where it began and its cost there, the mode, outcome code, final
        cost and iterations, whether it was switched to the other mode or continued, and
        which one the estimate is (``kept``); empty for stage 2 alone.
    residual_checks : tuple of ResidualCheck
        The residual tests of the noise model at the estimate (chi-square against a known
        R, whiteness), with their statistics and p-values.
    residual_analysis : ResidualAnalysis or None
        A record in time (a dynamic model, or a static model's record, in time or in its own
        order): the residuals' autocorrelation with its band and the colored-residual std
        (:mod:`casest.estimation.residual_analysis`).
    convergence : ConvergenceHistory or None
        Stage 2's iterates (parameters, their std, the cost) when its solver records them
        (Gauss-Newton output error always, IPOPT with ``SolverSettings(record_iterates=True)``);
        :meth:`plot_convergence` draws them.
    intervals : tuple of ProfileInterval
        Profile-likelihood intervals of the parameters, when computed
        (:func:`casest.estimation.with_profile_intervals`); the report shows those that differ
        from ``theta +- z std`` by more than 10 % of ``z std``.
    likelihood_sets : tuple of ParameterInterval
        Likelihood-ratio sets of the swept parameters from the stage-1 sweep, when computed
        (:func:`casest.estimation.with_profile_intervals`); the report shows those in pieces or
        that differ from ``theta +- z std`` as the intervals do.
    merged_limit : MergedLimit or None
        When two exchangeable terms merge towards a limit that fits better than the estimate
        (the cost has no minimum in the box): that limit's fit
        (:mod:`casest.two_stage.merged_limit`).
    diagnosis : Diagnosis or None
        When the residuals depend on a signal, the fitted value or time: the cheapest change of
        the model that explains them, with a one-call refit (:mod:`casest.estimation.diagnosis`);
        None when they do not, or when no candidate explains them.
    """

    REFIT_CALL = REFIT_CALL  # a class attribute, not a field

    model_name: str
    parameter_names: tuple
    output_names: tuple
    theta: np.ndarray
    std: np.ndarray
    std_reasons: list
    covariance: np.ndarray
    correlation: np.ndarray
    covariance_method: str
    R: np.ndarray
    cost: float
    n_samples: int
    lower_bounds: np.ndarray
    upper_bounds: np.ndarray
    active_bounds: list
    linear: tuple
    nonlinear: tuple
    mode: str
    success: bool
    status: str
    message: str
    n_iterations: int
    landscape: Landscape | None = None
    timings: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    start_cost: float | None = None
    parameter_units: tuple = ()
    output_units: tuple = ()
    fixed_parameters: tuple = ()
    noise_model: str = "unknown diagonal R (estimated)"
    noise_estimated: bool = True
    std_reason_codes: list = field(default_factory=list)
    outcome: Outcome = Outcome.CONVERGED
    experiments: tuple = ()
    n_measured: int | None = None
    R_full: np.ndarray | None = None
    starts: tuple = ()
    residual_checks: tuple = ()
    residual_analysis: ResidualAnalysis | None = None
    convergence: ConvergenceHistory | None = None
    intervals: tuple = ()
    likelihood_sets: tuple = ()
    dof_correction: bool = False
    merged_limit: MergedLimit | None = None
    diagnosis: Diagnosis | None = None

    # -- by name ------------------------------------------------------------------------
    @property
    def values(self) -> dict:
        """Estimates by parameter name."""
        return {n: float(v) for n, v in zip(self.parameter_names, self.theta)}

    @property
    def stds(self) -> dict:
        """Standard deviations by name (``None`` where unavailable)."""
        return {n: (float(s) if np.isfinite(s) else None) for n, s in zip(self.parameter_names, self.std)}

    @property
    def noise(self) -> dict:
        """Noise variances R_j by output name."""
        return {n: float(r) for n, r in zip(self.output_names, self.R)}

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    # -- JSON ---------------------------------------------------------------------------
    @property
    def note_codes(self) -> list:
        """The :class:`~casest.status.NoteCode` of each note."""
        return [note_code(n) for n in self.notes]

    def to_dict(self) -> dict:
        """Plain-Python form, every field by :func:`~casest.estimation.result_schema.encode_field`
        (lossless; the one schema of every result file).

        Returns
        -------
        dict
        """
        return {"format": file_format(_KIND), **{key: encode_field(value) for key, value in self.__dict__.items()}}

    @classmethod
    def from_dict(cls, data: dict) -> "Estimate":
        """The Estimate of :meth:`to_dict`'s form (or of the layout files of version 1 have).

        Parameters
        ----------
        data : dict

        Returns
        -------
        Estimate

        Raises
        ------
        ResultFileError
            Not the form of an Estimate, of a newer version, or fields that contradict each other.
        """
        version = format_version(data.get("format"), _KIND, "casest estimate")
        if version == 1:
            kw = _version_1_fields(data)
        else:
            kw = {key: decode_field(value) for key, value in data.items() if key != "format"}
        for key, empty in _FIELDS_ADDED_LATER.items():  # files written before these fields existed
            kw.setdefault(key, empty)
        estimate = cls(**kw)
        check_loaded_estimate(estimate)
        return estimate

    # -- report -------------------------------------------------------------------------
    def trust(self) -> tuple[bool, str]:
        """Whether to trust the estimate, and why (not), in one sentence (see :meth:`conclusion`).

        Returns
        -------
        trusted : bool
            True only when :meth:`conclusion` is :attr:`TrustCode.TRUSTED`.
        reason : str
        """
        code, reason = self.conclusion()
        return code is TrustCode.TRUSTED, reason

    def conclusion(self) -> tuple[TrustCode, str]:
        """What casest says of the estimate, from codes and records (never from note text).

        ``TRUSTED`` when all hold: stage 2 converged; there is global evidence (a unique or
        linear stage-1 verdict, or two or more starts that reached the same minimum); every
        estimated parameter has a std; no distinct minimum of equal cost has other values;
        every unit the data file gives is one the model declares; and every residual test
        passed (:mod:`casest.estimation.diagnostics`). ``LOCAL`` when all but the global
        evidence hold and stage 2 ran from one given start (no global search was asked
        for). ``CAUTION`` otherwise, naming each failed condition and what to do.

        Returns
        -------
        code : TrustCode
        reason : str
        """
        problems = self._failed_conditions()
        evidence = self._global_evidence()
        if evidence is not None and not evidence:
            verdict = self.landscape.verdict if self.landscape is not None else "none"
            if self._landscape_unresolved():
                problems.append(f"stage 1 says {verdict!r} and does not resolve its landscape ({len(self.landscape.unresolved)} "
                                "further minima fail the linearisation check, paper Eq. 17): a deeper minimum may lie "
                                "between its candidates, which starts that agree cannot rule out; sweep more candidates "
                                "(SweepSettings.n_candidates) or narrow the box")
            else:
                problems.append(f"stage 1 says {verdict!r} and no two stage-2 starts reached the same minimum; sweep "
                                "more candidates (SweepSettings.n_candidates) or give more starts (max_starts)")
        tested = (f"; the residuals pass {len(self.residual_checks)} test(s) of the noise model"
                  if self.residual_checks else "")
        if evidence is None:
            passing = (TrustCode.LOCAL, ("converged from the given start, every parameter has a std"
                                         f"{tested}; no global search was asked for (estimate without start= runs "
                                         "stage 1 and several starts)"))
        else:
            passing = (TrustCode.TRUSTED, f"converged ({', '.join(evidence)}); every parameter has a std{tested}")
        analysis = self.residual_analysis
        usable = analysis is not None and tuple(analysis.parameter_names) == tuple(self.parameter_names)
        return judged(problems, residual_verdict(self.residual_checks), passing,
                      ColouredStd.of(analysis.ratio) if usable else ColouredStd(), self.diagnosis)

    def _failed_conditions(self) -> list:
        problems = [] if self.success else [f"stage 2 did not converge ({self.status})"]
        return problems + self._determination_problems() + self._search_problems()

    def _determination_problems(self) -> list:
        """What the data leave undetermined: parameters without a std, a symmetric minimum,
        pairs determined only as a combination."""
        problems = []
        codes = self.std_reason_codes or [None] * len(self.parameter_names)
        missing = [n for n, s, c in zip(self.parameter_names, self.std, codes)
                   if not np.isfinite(s) and c is not StdReason.FIXED and n not in self.fixed_parameters]
        if missing:
            problems.append(f"no standard deviation for {missing} (see the notes)")
        if NoteCode.MERGING in self.note_codes:
            problems.append("two terms merge with amplitudes that cancel (see the notes): the cost has no minimum in the "
                            "box, only a limit the model does not attain; fit a model with one term fewer or with the "
                            "derivative term")
        if NoteCode.SYMMETRY in self.note_codes:
            problems.append("another minimum of the same cost has other parameter values (see the notes): the data "
                            "cannot tell them apart; fix or constrain the parameters involved, or collect data that do")
        pairs = self.near_dependent_pairs()
        if pairs:
            named = ", ".join(f"{a} and {b} (r = {r:+.4f})" for a, b, r in pairs[:4])
            problems.append(f"the data determine a combination, not the parameters one by one: {named}; fix one of "
                            "each pair, reparametrise (the product or the sum), or collect data that separate them")
        return problems

    def _search_problems(self) -> list:
        """What the search or the data's declaration leave open: a lower unfinished start, undeclared units."""
        problems = []
        if NoteCode.LOWER_UNFINISHED in self.note_codes:
            problems.append("a start that did not converge ended lower than the estimate (see the notes): the "
                            "minimum kept is not the lowest point of the box")
        if NoteCode.UNITS in self.note_codes:
            problems.append(UNITS_CAUTION)
        return problems

    def near_dependent_pairs(self, limit: float = NEAR_DEPENDENCE) -> list:
        """Pairs of estimated parameters whose correlation exceeds ``limit`` in magnitude.

        Parameters
        ----------
        limit : float
            Default :data:`NEAR_DEPENDENCE` (0.999): the std of each is then more than 20 times
            its std with the other known, and the pair is determined only as a combination.

        Returns
        -------
        list of (str, str, float)
            The names and the correlation, strongest first.
        """
        C = np.asarray(self.correlation, dtype=float)
        names = self.parameter_names
        pairs = [(names[i], names[j], float(C[i, j])) for i in range(len(names)) for j in range(i)
                 if np.isfinite(C[i, j]) and abs(C[i, j]) > limit]
        return sorted(pairs, key=lambda p: -abs(p[2]))

    def _starts_at_the_estimate(self) -> int:
        """How many started solves converged to the estimate's cost (within the cost tolerance)."""
        return sum(1 for r in self.starts if r.started and r.outcome in _SUCCESS
                   and abs(r.cost - self.cost) <= cost_tolerance(self.cost))

    def _landscape_unresolved(self) -> bool:
        """Stage 1 found further minima its design does not resolve (:attr:`Landscape.unresolved`):
        starts drawn from such a landscape may all miss a deeper minimum between its candidates."""
        unresolved = None if self.landscape is None else getattr(self.landscape, "unresolved", None)
        return unresolved is not None and len(unresolved) > 0

    def _global_evidence(self) -> list | None:
        """Why the minimum is global (empty: no evidence), or None for a solve from one given start."""
        evidence = []
        if self.landscape is not None and self.landscape.verdict in ("unique", "linear"):
            evidence.append(f"stage-1 verdict {self.landscape.verdict}")
        agreeing = self._starts_at_the_estimate()
        if agreeing > 1 and not self._landscape_unresolved():
            evidence.append(f"{agreeing} of {sum(r.started for r in self.starts)} starts reached it")
        if evidence:
            return evidence
        if self.landscape is None and sum(r.started for r in self.starts) <= 1:
            return None
        return []

    def report(self, correlation_threshold: float = 0.5) -> str:
        """Text report in fixed sections (lmfit style); ``+/-`` is one standard deviation
        (:func:`casest.estimation.reporting.estimate_report`).

        Parameters
        ----------
        correlation_threshold : float
            Correlations of larger magnitude are listed.

        Returns
        -------
        str
        """
        return estimate_report(self, correlation_threshold)

    def fit_statistics(self) -> list:
        """The fit statistics of the report and the HTML page
        (:func:`casest.estimation.reporting.estimate_fit_statistics`).

        Returns
        -------
        list of (str, str)
            Name and value in words.
        """
        return estimate_fit_statistics(self)

    def _repr_html_(self) -> str:
        """HTML table for notebooks: parameters with one-std error bars, noise, conclusion."""
        from html import escape

        units = dict(zip(self.parameter_names, self.parameter_units or ("",) * len(self.parameter_names)))
        rows = "".join(
            f"<tr><td>{escape(n)}</td><td>{v:.8g}</td><td>{std_text(s)}</td>"
            f"<td>{escape(units.get(n, ''))}</td><td>[{lo:.6g}, {hi:.6g}]</td>"
            f"<td>{escape(r or '')}</td></tr>"
            for n, v, s, lo, hi, r in zip(self.parameter_names, self.theta, self.std, self.lower_bounds,
                                          self.upper_bounds, self.std_reasons)
        )
        noise = "".join(f"<tr><td>{escape(n)}</td><td>{r:.6g}</td><td>{math.sqrt(r):.6g}</td></tr>"
                        for n, r in zip(self.output_names, self.R))
        code, reason = self.conclusion()
        return (
            f"<div><b>{escape(self.model_name)}</b>: success {self.success} ({escape(self.status)}), "
            f"ML cost J = {self.cost:.10g}, N = {self.n_samples}, mode {escape(self.mode)}"
            "<table><tr><th>parameter</th><th>value</th><th>std (1 sigma)</th><th>unit</th><th>bounds</th>"
            f"<th>note</th></tr>{rows}</table>"
            f"<table><tr><th>output</th><th>noise variance R</th><th>noise std</th></tr>{noise}</table>"
            f"<p><b>{conclusion_words(code)}</b>: {escape(reason)}</p></div>"
        )


