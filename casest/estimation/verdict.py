"""What the residual tests of a fit say, and the words of every trust outcome, in one place.

The family of residual tests (:mod:`casest.estimation.residual_family`) is read as one of:

- **white** (:attr:`ResidualCode.WHITE`): every test passed;
- **coloured noise** (:attr:`ResidualCode.COLOURED`): correlated in time, but independent of every
  signal, of the fitted value and of time. The model fits; the noise is coloured (turbulence, a
  sensor's own dynamics). The estimate stands, and the white-noise std are too small: the
  colored-residual std (Morelli and Klein) are the ones to report;
- **model error** (:attr:`ResidualCode.DEPENDENT`): the residuals depend on a signal, on the
  fitted value or on time. The model lacks something, named by the failed test and, where a
  candidate explains it, by the diagnosis (:mod:`casest.estimation.diagnosis`);
- **noise level** (:attr:`ResidualCode.NOISE_LEVEL`): the residuals do not match a given noise.

:func:`judged` turns the verdict and an estimator's other conditions into the conclusion line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..status import CheckCode, ResidualCode, TrustCode
from .diagnostics import ALPHA

__all__ = ["ResidualVerdict", "residual_verdict", "judged", "summary_lines", "TRUST_WORDS", "DEPENDENCE",
           "ColouredStd"]

#: the conclusion line's first words for each outcome
TRUST_WORDS = {TrustCode.TRUSTED: "trust it", TrustCode.LOCAL: "local solve", TrustCode.CAUTION: "CAUTION",
               TrustCode.COLOURED_NOISE: "coloured noise", TrustCode.MODEL_ERROR: "MODEL ERROR"}

#: the tests whose failure says the residuals depend on something the model should explain
DEPENDENCE = (CheckCode.CROSS_CORRELATION, CheckCode.TREND, CheckCode.STEP, CheckCode.COHERENCE)

_ADVICE = {
    ResidualCode.DEPENDENT: ("the model lacks something the data show; add what the diagnosis names (or the term, "
                             "delay or change the failed test points to) and estimate again; until then the estimate "
                             "and its std describe the wrong model"),
    ResidualCode.NOISE_LEVEL: ("check the noise std given (or estimate it: leave noise= out) and the model"),
}


@dataclass(frozen=True)
class ColouredStd:
    """How much the colored-residual std exceed the white-noise std.

    Attributes
    ----------
    median, largest : float
        Of the ratio colored std / white-noise std over the parameters.
    available : bool
        Whether the estimator computed colored-residual std (False: the std shown are too small
        by an unknown factor).
    """

    median: float = float("nan")
    largest: float = float("nan")
    available: bool = False

    @classmethod
    def of(cls, ratio) -> "ColouredStd":
        """From the ratios per parameter (NaN where there is none)."""
        ratio = np.asarray(ratio if ratio is not None else [], dtype=float)
        ratio = ratio[np.isfinite(ratio)]
        if ratio.size == 0:
            return cls()
        return cls(float(np.median(ratio)), float(np.max(ratio)), True)


@dataclass(frozen=True)
class ResidualVerdict:
    """The reading of one fit's family of residual tests.

    Attributes
    ----------
    code : ResidualCode
    checks : tuple of ResidualCheck
        Every test of the family.
    """

    code: ResidualCode
    checks: tuple

    @property
    def failed(self) -> tuple:
        """The failed tests, most significant first."""
        return tuple(sorted((c for c in self.checks if not c.passed), key=lambda c: c.family_p))

    @property
    def dependence(self) -> tuple:
        """The failed tests of dependence (signal, fitted value, time), most significant first."""
        return tuple(c for c in self.failed if c.code in DEPENDENCE)

    def finding(self) -> str:
        """What the residuals show, in one clause.

        Returns
        -------
        str
            The most significant dependence (with its test), the noise-level mismatch, or the
            coloured channels; empty when the residuals are white or untested.
        """
        if self.code is ResidualCode.DEPENDENT:
            worst = self.dependence[0]
            others = len(self.dependence) - 1
            return (f"the residuals depend on {_named(worst)} ({worst.channel}: {worst.what()}, p = "
                    f"{worst.family_p:.3g} in the family of {len(self.checks)} tests"
                    + (f"; {others} more dependence test(s) failed" if others else "") + ")")
        if self.code is ResidualCode.NOISE_LEVEL:
            worst = next(c for c in self.failed if c.code is CheckCode.CHI_SQUARE)
            return f"the residuals do not match the given noise ({worst.describe()})"
        if self.code is ResidualCode.COLOURED:
            channels = ", ".join(sorted({c.channel for c in self.failed}))
            return (f"the residuals of {channels} are correlated in time but independent of every signal, of the "
                    "fitted value and of time")
        return ""


def _named(check) -> str:
    """What a dependence test points to: a signal (with the lag), the fitted value, or time."""
    if check.code is CheckCode.CROSS_CORRELATION:
        return f"signal {check.signal} (largest cross-correlation at lag {check.lag:+.0f} samples)"
    if check.code is CheckCode.STEP:
        return f"time (a change of level at sample {check.lag:.0f})"
    if check.code is CheckCode.COHERENCE:
        return f"input {check.signal} across the band" if check.signal else "the fitted transform across the band"
    return f"signal {check.signal}" if check.signal else "the fitted value"


def residual_verdict(checks) -> ResidualVerdict:
    """Read a fit's family of residual tests (module docstring).

    Parameters
    ----------
    checks : sequence of ResidualCheck

    Returns
    -------
    ResidualVerdict
    """
    checks = tuple(checks)
    failed = [c for c in checks if not c.passed]
    if not checks:
        code = ResidualCode.UNTESTED
    elif any(c.code in DEPENDENCE for c in failed):
        code = ResidualCode.DEPENDENT
    elif any(c.code is CheckCode.CHI_SQUARE for c in failed):
        code = ResidualCode.NOISE_LEVEL
    elif failed:
        code = ResidualCode.COLOURED
    else:
        code = ResidualCode.WHITE
    return ResidualVerdict(code, checks)


def judged(problems: list, verdict: ResidualVerdict, passing: tuple, coloured: ColouredStd = ColouredStd(),
           diagnosis=None) -> tuple:
    """The conclusion of a result from its failed conditions and its residual verdict.

    Parameters
    ----------
    problems : list of str
        The estimator's failed conditions other than the residual tests (no convergence, a
        parameter without std, ...), each in words a user can act on.
    verdict : ResidualVerdict
    passing : (TrustCode, str)
        The outcome and reason when nothing failed (``TRUSTED`` or ``LOCAL``).
    coloured : ColouredStd
        The colored-residual std's ratio to the white-noise std, where the estimator has them.
    diagnosis : Diagnosis, optional
        The structural change that explains dependent residuals (:mod:`casest.estimation.diagnosis`).

    Returns
    -------
    TrustCode
    str
    """
    finding = verdict.finding()
    if problems:
        extra = [finding] if finding else []
        return TrustCode.CAUTION, "do not rely on it: " + "; ".join(list(problems) + extra)
    if verdict.code is ResidualCode.DEPENDENT:
        named = f"; {diagnosis.describe()}" if diagnosis is not None else "; no candidate change explains it"
        return TrustCode.MODEL_ERROR, f"{finding}{named}: {_ADVICE[ResidualCode.DEPENDENT]}"
    if verdict.code is ResidualCode.NOISE_LEVEL:
        return TrustCode.CAUTION, f"do not rely on it: {finding}: {_ADVICE[ResidualCode.NOISE_LEVEL]}"
    if verdict.code is ResidualCode.COLOURED:
        code, reason = passing
        if coloured.available:
            std = (f"the std reported are the colored-residual std, x{coloured.median:.3g} the white-noise std "
                   f"(median; up to x{coloured.largest:.3g})")
        else:
            std = ("this estimator has no colored-residual std: the std shown assume white noise and are too "
                   "small")
        solved = "" if code is TrustCode.TRUSTED else " (a local solve from the given start)"
        return TrustCode.COLOURED_NOISE, (f"{finding}: the model fits and the estimate stands{solved}; {std}")
    return passing


def summary_lines(checks) -> list:
    """The residual tests summarised one line per output: how many failed, the worst, the family's level.

    Parameters
    ----------
    checks : sequence of ResidualCheck

    Returns
    -------
    list of str
    """
    checks = tuple(checks)
    lines = []
    for channel in dict.fromkeys(c.channel for c in checks):
        own = [c for c in checks if c.channel == channel]
        failed = [c for c in own if not c.passed]
        worst = min(own, key=lambda c: c.family_p)
        lines.append(f"{channel}: {len(failed)} of {len(own)} failed; worst {worst.what()}, p = {worst.p_value:.3g} "
                     f"({worst.family_p:.3g} in the family)")
    if checks:
        lines.append(f"family of {len(checks)} tests held at {ALPHA:g} (Holm): a right model with white noise fails "
                     f"any of them at most at that rate")
    return lines
