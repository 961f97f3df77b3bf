"""The text report of an estimate, in fixed sections (lmfit's ``fit_report`` style):
``[[Model]]``, ``[[Fit Statistics]]``, ``[[Parameters]]`` as ``value +/- std unit (rel %)
[lb, ub]``, ``[[Noise]]``, ``[[Correlations]]``, ``[[Stage 1]]``, ``[[Notes]]`` and the
``[[Conclusion]]`` trust line."""

from __future__ import annotations


import math
import re

import numpy as np

from ..status import TrustCode
from .diagnostics import ALPHA
from .verdict import TRUST_WORDS, summary_lines


#: the caution of a result whose data carry units its model does not declare
UNITS_CAUTION = ("the data give units the model does not declare (see the notes): declare them and casest converts "
                 "the data")


__all__ = ["estimate_report", "estimate_fit_statistics", "fit_statistic_lines", "parameter_lines", "correlation_lines", "conclusion_words", "std_text", "NO_STD"]

#: how every report shows a standard deviation there is none of (NaN: held, fixed, not identifiable)
NO_STD = "n/a"


def estimate_report(est, correlation_threshold: float = 0.5) -> str:
    """The report of a :class:`casest.Estimate` (see the module docstring)."""
    lines = [f"[[Model]] {est.model_name}", "[[Fit Statistics]]"] + fit_statistic_lines(est.fit_statistics())
    choice = est.std_choice()
    kind = "colored-residual" if choice.kind == "colored" else "one"
    lines.append(f"[[Parameters]] (value +/- {kind} standard deviation, unit, bounds)")
    lines += parameter_lines(est.parameter_names, est.theta, choice.std, est.parameter_units, est.lower_bounds,
                             est.upper_bounds, est.std_reasons)
    lines += interval_lines(est)
    lines.append("[[Noise]] (" + ("estimated noise variance R and noise std per output" if est.noise_estimated
                                  else "known noise variance R and noise std per output, as given") + ")")
    lines += _noise_lines(est)
    lines.append(f"[[Correlations]] (|r| > {correlation_threshold})")
    lines += correlation_lines(est.parameter_names, est.correlation, correlation_threshold)
    lines.append("[[Stage 1]]")
    lines += ["    not run"] if est.landscape is None else ["    " + line for line in est.landscape.summary().splitlines()]
    bound = None if est.landscape is None else est.landscape.error_bound
    # the bracket compares costs of the same data and noise model: stage-1 data apart, or a known or full R, do not
    if bound is not None and bound.comparable:
        lines.append(f"    stage-2 optimum J* = {est.cost:.8g} against the bracket [{bound.lower:.8g}, "
                     f"{bound.stage1_cost:.8g}]: {bound.verdict(est.cost)}")
    elif bound is not None:
        lines.append("    stage-2 optimum not compared with the bracket: stage 1 ran on other data or another noise model")
    lines += closing_lines(est, "")
    return "\n".join(lines)


def closing_lines(result, checked: str) -> list[str]:
    """The report's closing sections, shared by the result family: residual checks, notes
    and the conclusion line.

    Parameters
    ----------
    result : Estimate or FilterErrorEstimate
        Anything with ``residual_checks``, ``notes`` and ``conclusion()``.
    checked : str
        What the residual checks test, put in the heading ("" for the residuals).

    Returns
    -------
    list of str
        Report lines.
    """
    lines = []
    if result.residual_checks:
        what = f"{checked}; " if checked else ""
        lines.append(f"[[Residual checks]] ({what}one family, held at {ALPHA:g} by Holm's adjustment)")
        lines += [f"    {line}" for line in summary_lines(result.residual_checks)]
        lines.append("    every test:")
        lines += [f"      {check.describe()}" for check in result.residual_checks]
    diagnosis = getattr(result, "diagnosis", None)
    if diagnosis is not None:
        lines += ["[[Diagnosis]]", f"    {diagnosis.describe()}"]
        if getattr(result, "REFIT_CALL", ""):
            lines.append(f"    {result.REFIT_CALL} estimates the model with this change")
    analysis = getattr(result, "residual_analysis", None)
    if analysis is not None:
        lines.append("[[Residual analysis]] (a record in time)")
        lines += [f"    {line}" for line in analysis.describe()]
        if hasattr(result, "std_choice"):
            choice = result.std_choice()
            lines.append(f"    std to report: {'colored-residual' if choice.kind == 'colored' else 'ML'} "
                         f"(Estimate.std_choice(): {choice.reason})")
    if result.notes:
        lines.append("[[Notes]]")
        lines += [f"    - {note}" for note in result.notes]
    code, reason = result.conclusion()
    lines.append(f"[[Conclusion]] {conclusion_words(code)}: {reason}")
    return lines


def conclusion_words(code: TrustCode) -> str:
    """The conclusion line's first words (:data:`casest.estimation.verdict.TRUST_WORDS`)."""
    return TRUST_WORDS[code]


def estimate_fit_statistics(est) -> list:
    """The fit statistics of a :class:`casest.Estimate`, as its report and page show them.

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    list of (str, str)
        Name and value in words.
    """
    n_meas = est.n_measured if est.n_measured is not None else est.n_samples * len(est.output_names)
    return [
        ("success", f"{est.success} ({est.status})"),
        ("message", f"{est.message}"),
        ("stage-2 mode", f"{est.mode}"),
        ("iterations", f"{est.n_iterations}"),
        ("samples N", f"{est.n_samples}"),
        ("measurements", f"{n_meas}"),
        ("parameters", f"{len(est.parameter_names)}"),
        ("ML cost J", f"{est.cost:.10g}  (negative log-likelihood without constants, paper Eq. 6)"),
        ("covariance", f"{est.covariance_method}"
         + (", degrees-of-freedom corrected (N m / (N m - p))" if est.dof_correction else "")),
        ("partition", f"linear xi1 [{', '.join(est.linear)}], nonlinear xi2 [{', '.join(est.nonlinear)}]"),
    ]


def fit_statistic_lines(statistics) -> list:
    """A report's ``[[Fit Statistics]]`` lines: ``    name               = value``.

    Parameters
    ----------
    statistics : sequence of (str, str)
        A result's ``fit_statistics()``.

    Returns
    -------
    list of str
    """
    return [f"    {name:<18} = {value}" for name, value in statistics]


def std_text(std, spec: str = ".4g") -> str:
    """A standard deviation as every report shows it: formatted by ``spec``, or :data:`NO_STD` where there is
    none (NaN or infinite).

    Parameters
    ----------
    std : float or None
    spec : str
        A format specification (``".4g"``, ``">11.3g"``); its width applies to :data:`NO_STD` too.

    Returns
    -------
    str
    """
    if std is not None and np.isfinite(std):
        return format(float(std), spec)
    width = re.match(r"[<>^]?(\d*)", spec).group(1)
    return format(NO_STD, f">{width}") if width else NO_STD


def parameter_lines(names, theta, std, units, lower, upper, reasons) -> list:
    """``name = value +/- std unit (rel %) [lb, ub]``, or ``+/- n/a`` with the reason."""
    units = units or ("",) * len(names)
    width = max([len(n) for n in names] + [1])
    lines = []
    for name, v, s, unit, lo, hi, why in zip(names, theta, std, units, lower, upper, reasons):
        bounds = f"[{lo:.6g}, {hi:.6g}]"
        unit = f" {unit}" if unit else ""
        if np.isfinite(s):
            rel = f"({abs(s / v) * 100:.2f}%)" if v != 0 else "(n/a %)"
            lines.append(f"    {name:<{width}} = {v:.8g} +/- {s:.4g}{unit} {rel} {bounds}")
        else:
            lines.append(f"    {name:<{width}} = {v:.8g} +/- {std_text(s)}{unit} {bounds}  # {why}")
    return lines


def interval_lines(est) -> list:
    """``[[Profile intervals]]``: the parameters whose profile-likelihood interval differs from
    ``theta +- z std`` by more than :data:`~casest.estimation.intervals.WALD_DIFFERENCE` of ``z std``
    (asymmetric, at a bound, or where no std exists), the others named in one line.

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    list of str
    """
    from .intervals import WALD_DIFFERENCE

    if not est.intervals:
        return []
    std = dict(zip(est.parameter_names, est.std))
    level = est.intervals[0].level
    lines = [f"[[Profile intervals]] ({100 * level:g} %, likelihood ratio; shown where an end differs from "
             f"value +/- z std by more than {100 * WALD_DIFFERENCE:g} % of z std)"]
    close = []
    for item in est.intervals:
        if not item.differs_from_wald(std.get(item.name, np.nan)):
            close.append(item.name)
            continue
        ends = [f"{v:.8g}" + (" (bound)" if b else "") for v, b in zip((item.lower, item.upper), item.at_bound)]
        lines.append(f"    {item.name}: [{ends[0]}, {ends[1]}], {item.upper - item.estimate:.4g} above and "
                     f"{item.estimate - item.lower:.4g} below the value")
    if close:
        lines.append(f"    as value +/- z std: {', '.join(close)}")
    return lines + _set_lines(est, std)


def _set_lines(est, std: dict) -> list:
    """The sweep's likelihood-ratio sets in pieces, or whose ends differ from value +/- z std."""
    from scipy.stats import norm

    from .intervals import WALD_DIFFERENCE

    shown = []
    theta = dict(zip(est.parameter_names, est.theta))
    for item in est.likelihood_sets:
        if not item.intervals:
            continue
        half = norm.ppf(0.5 + item.level / 2) * std.get(item.name, np.nan)
        lo, hi = item.intervals[0][0], item.intervals[-1][1]
        value = theta.get(item.name, np.nan)
        differs = not (np.isfinite(half) and half > 0) or max(abs(value - half - lo), abs(value + half - hi)) > \
            WALD_DIFFERENCE * half
        if item.connected and not differs:
            continue
        pieces = " U ".join(f"[{a:.8g}, {b:.8g}]" for a, b in item.intervals)
        shown.append(f"    {item.name}: {pieces} (likelihood-ratio set from the sweep"
                     + (f", {len(item.intervals)} pieces)" if not item.connected else ")"))
    return shown


def _noise_lines(est) -> list:
    lines = []
    out_units = est.output_units or ("",) * len(est.output_names)
    for name, r, unit in zip(est.output_names, est.R, out_units):
        squared = f" ({unit})^2" if unit else ""
        lines.append(f"    {name}: R = {r:.6g}{squared}, noise std = {math.sqrt(r):.6g}{' ' + unit if unit else ''}")
    if est.R_full is not None:
        sd = np.sqrt(np.diag(est.R_full))
        corr = est.R_full / np.outer(sd, sd)
        names = est.output_names
        lines += [f"    noise correlation({names[i]}, {names[j]}) = {corr[i, j]:+.4f}"
                  for i in range(len(names)) for j in range(i + 1, len(names))]
    return lines


def correlation_lines(names, correlation: np.ndarray, threshold: float) -> list:
    """The parameter pairs correlated above ``threshold``, strongest first (``none`` if none)."""
    pairs = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            r = correlation[i, j]
            if np.isfinite(r) and abs(r) > threshold:
                pairs.append((abs(r), f"    C({names[i]}, {names[j]}) = {r:+.4f}"))
    return [text for _, text in sorted(pairs, reverse=True)] or ["    none"]
