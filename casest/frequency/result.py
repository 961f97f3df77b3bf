"""The frequency-domain estimate: a member of casest's result protocol, with its residual tests,
its colored-residual std and what explains residuals coherent with an input."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimation.diagnosis import Diagnosis
from ..estimation.diagnostics import ALPHA
from ..estimation.reporting import fit_statistic_lines, std_text
from ..estimation.result_protocol import PlainResult, conclusion_of
from ..estimation.result_schema import register_record
from ..estimation.verdict import ColouredStd, summary_lines

__all__ = ["FrequencyEstimate"]


@register_record
@dataclass(frozen=True)
class FrequencyEstimate(PlainResult):
    """A frequency-domain estimate, a member of casest's result protocol
    (:class:`~casest.estimation.result_protocol.EstimateLike`).

    Attributes
    ----------
    method : str
        ``"output-error"`` or ``"equation-error"``.
    parameter_names : tuple of str
        The model's parameters, then the delay (``delay`` or ``delay_NAME``, seconds) when one
        was estimated.
    theta : ndarray, shape (n_parameters,)
        Every parameter (the held ones at their nominal values).
    std : ndarray, shape (n_parameters,)
        The std to use: the colored-residual std when ``colored``, else the white-noise std;
        NaN for the held ones.
    held : tuple of str
        Parameters that do not act at the chosen frequencies (biases), held at their nominals.
    frequencies : ndarray, shape (F,)
        Angular frequencies (rad/s).
    spectra : ndarray, shape (channels,)
        The residual spectra S_j at the estimate.
    success : bool
    notes : tuple of Note
        Each a ``str`` with its :class:`~casest.status.NoteCode` in ``.code``.
    covariance : ndarray, shape (n_parameters, n_parameters), or None
        The covariance ``std`` comes from (NaN rows and columns for the held ones).
    std_white : ndarray, shape (n_parameters,), or None
        The white-noise std (the inverse information with a flat residual spectrum).
    colored : bool
        Whether the residual tests found coloured noise, so that ``std`` are the colored-residual
        std (:func:`casest.frequency.spectral_checks.colored_covariance`).
    residual_checks : tuple of ResidualCheck
        The family of flatness and coherence tests (:mod:`casest.frequency.spectral_checks`).
    diagnosis : Diagnosis or None
        A delay of the inputs that explains residuals coherent with them
        (:mod:`casest.frequency.delay_diagnosis`), in samples of the record.
    sample_interval : float
        The record's sample interval (s), which turns a diagnosed delay into seconds.
    delayed : tuple of str
        The inputs delayed together by the estimated delay parameter (empty: none).
    """

    KIND = "casest.FrequencyEstimate"

    method: str
    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    held: tuple
    frequencies: np.ndarray
    spectra: np.ndarray
    success: bool
    notes: tuple
    covariance: np.ndarray | None = None
    std_white: np.ndarray | None = None
    colored: bool = False
    residual_checks: tuple = ()
    diagnosis: Diagnosis | None = None
    sample_interval: float = float("nan")
    delayed: tuple = ()

    @property
    def status(self) -> str:
        """``"Solve_Succeeded"``, or ``"Not_Converged"`` (the notes say why)."""
        return "Solve_Succeeded" if self.success else "Not_Converged"

    def conclusion(self) -> tuple:
        """``CAUTION`` naming what failed (no convergence, a parameter without std, frequencies
        too close), else what the residual tests say: ``MODEL_ERROR`` (residuals coherent with an
        input or the fitted transform), ``COLOURED_NOISE`` (a residual spectrum that is not flat,
        independent of the inputs: the std are the colored-residual std), else ``LOCAL``.

        Returns
        -------
        TrustCode
        str
        """
        acting = _ActingView(self)
        ratio = None
        if self.colored and self.std_white is not None:
            ratio = np.asarray(self.std, dtype=float) / np.asarray(self.std_white, dtype=float)
        coloured = ColouredStd.of(ratio) if self.colored else ColouredStd()
        return conclusion_of(acting, f"the frequency-domain {self.method} converged over {self.frequencies.size} "
                                     "frequencies", coloured, self.diagnosis)

    def fit_statistics(self) -> list:
        """The fit statistics of the report and the HTML page.

        Returns
        -------
        list of (str, str)
            Name and value in words.
        """
        w = self.frequencies
        return [("success", f"{self.success} ({self.status})"),
                ("frequencies", f"{w.size} from {w.min():.4g} to {w.max():.4g} rad/s"),
                ("residual spectra", ", ".join(f"{s:.4g}" for s in self.spectra)),
                ("std", "colored-residual" if self.colored else "white-noise")]

    def report(self) -> str:
        """Text report in fixed sections; ``+/-`` is one standard deviation.

        Returns
        -------
        str
        """
        kind = "colored-residual" if self.colored else "white-noise"
        lines = [f"[[Model]] frequency-domain {self.method} (Klein and Morelli Ch. 7)", "[[Fit Statistics]]"]
        lines += fit_statistic_lines(self.fit_statistics())
        lines.append(f"[[Parameters]] (value +/- one standard deviation, {kind} std)")
        for name, value, std in zip(self.parameter_names, self.theta, self.std):
            held = " (held: does not act in the band)" if name in self.held else ""
            lines.append(f"    {name} = {value:.8g} +/- {std_text(std)}{held}")
        lines.append("[[Residual spectra]] (per channel)")
        lines += [f"    S[{j}] = {s:.6g}" for j, s in enumerate(self.spectra)]
        if self.residual_checks:
            lines.append(f"[[Residual checks]] (one family, held at {ALPHA:g} by Holm's adjustment)")
            lines += [f"    {line}" for line in summary_lines(self.residual_checks)]
        if self.diagnosis is not None:
            lines += ["[[Diagnosis]]", f"    {self.diagnosis.describe()}"]
        if self.notes:
            lines.append("[[Notes]]")
            lines += [f"    - {n}" for n in self.notes]
        code, reason = self.conclusion()
        lines.append(f"[[Conclusion]] {code.value.upper()}: {reason}")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        """``{name: (value, std)}``.

        Returns
        -------
        dict
        """
        return {n: (float(v), float(s)) for n, v, s in zip(self.parameter_names, self.theta, self.std)}


class _ActingView:
    """A frequency estimate seen through its acting parameters (the held ones have no std by design)."""

    def __init__(self, estimate: FrequencyEstimate):
        keep = [i for i, n in enumerate(estimate.parameter_names) if n not in estimate.held]
        self.parameter_names = tuple(estimate.parameter_names[i] for i in keep)
        self.std = np.asarray(estimate.std)[keep]
        self.success, self.status, self.notes = estimate.success, estimate.status, estimate.notes
        self.residual_checks = estimate.residual_checks
