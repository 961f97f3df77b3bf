"""Codes beside the words: stage-2 outcomes, reasons for a missing std, and note kinds.

Every outcome, std reason and note that casest reports carries one of these codes, so that
programs (and casest itself) branch on the code, never on the wording of a message.
"""

from __future__ import annotations

from enum import Enum


__all__ = ["Outcome", "StdReason", "NoteCode", "Note", "CheckCode", "ResidualCode", "DiagnosisCode", "TrustCode"]


class Outcome(str, Enum):
    """How stage 2 ended (``Estimate.outcome``)."""

    CONVERGED = "converged"  # IPOPT Solve_Succeeded, not above its start
    ACCEPTED_NEWTON = "accepted_newton"  # IPOPT stopped short; the exact Newton step is below newton_acceptance
    EXACT_FIT = "exact_fit"  # the data are fitted to the noise floor; a Gauss-Newton step confirms the point
    CLIMBED = "climbed"  # a converged solve ended above its start's cost: not a success
    NOT_CONVERGED = "not_converged"  # IPOPT failed and no check could accept the point
    NO_IMPROVEMENT = "no_improvement"  # no solve improved on the starts: the best start is returned, not a success


class StdReason(str, Enum):
    """Why a parameter has no standard deviation (``Estimate.std_reason_codes``)."""

    ACTIVE_BOUND = "active_bound"
    NOT_IDENTIFIABLE = "not_identifiable"
    NOT_A_MINIMUM = "not_a_minimum"
    SINGULAR = "singular"
    NO_NOISE_ESTIMATE = "no_noise_estimate"
    FIXED = "fixed"


class NoteCode(str, Enum):
    """The kind of a note (``Estimate.note_codes``)."""

    STARTS = "starts"  # which stage-2 starts ran and which one was kept
    MODE_SWITCH = "mode_switch"  # a start re-solved in the other mode (failure or climb)
    CONTINUED = "continued"  # a promising start given the full iteration budget
    SYMMETRY = "symmetry"  # distinct minima of equal cost
    MERGING = "merging"  # two exchangeable terms merge with cancelling amplitudes: the cost's limit is not attained
    LABELS = "labels"  # a symmetry of the model (term exchange, sign / phase): the estimate labelled canonically
    NOT_VERIFIED = "not_verified"  # nothing converged at or below the starts
    FOCUSED = "focused"  # residuals failed: stage 1 again in the ranges the data inform (casest.two_stage.focused)
    LOWER_UNFINISHED = "lower_unfinished"  # a start that did not converge ended below the kept estimate
    ACCEPTED = "accepted"  # a short-of-tolerance IPOPT stop accepted by a check
    CLIMBED = "climbed"
    NOISE_FLOOR = "noise_floor"  # R at the floor: an exact fit
    STD_FROM_RSS = "std_from_rss"  # exact fit: std from RSS / dof
    BOUNDS = "bounds"  # a parameter on a bound, or a reduced solve leaving the box
    NOT_IDENTIFIABLE = "not_identifiable"
    NOISE_MODEL = "noise_model"  # known noise, MAP priors
    FIXED = "fixed"
    STAGE1 = "stage1"
    SIMULATION = "simulation"  # the simulation from a start diverges
    NOT_FINITE = "not_finite"  # the model is NaN or infinite at a start
    UNITS = "units"  # a data column's unit that the model does not declare: the values used as they are
    ALIGNMENT = "alignment"  # data columns resampled onto one time base by a log reader
    TABLE_RANGE = "table_range"  # a lookup table's argument beyond its grid (extrapolated), or a grid not known
    FREQUENCIES = "frequencies"  # the chosen frequencies limit what the estimate or its std mean
    OTHER = "other"


class CheckCode(str, Enum):
    """A residual test (``Estimate.residual_checks``, :mod:`casest.estimation.diagnostics`)."""

    CHI_SQUARE = "chi_square"  # the residuals against a known R
    WHITENESS = "whiteness"  # Ljung-Box of the residuals in time (or record) order: are they coloured?
    TREND = "trend"  # Ljung-Box of the prewhitened residuals along a signal or the fitted value: a smooth dependence
    CROSS_CORRELATION = "cross_correlation"  # prewhitened cross-correlation with a signal at several lags
    STEP = "step"  # cumulative sum in time: a change of level during the record
    FLATNESS = "flatness"  # frequency domain: one mean of the residual periodogram across the band (white noise)
    COHERENCE = "coherence"  # frequency domain: residuals regressed on an input's (or the fit's) transform


class ResidualCode(str, Enum):
    """What the family of residual tests of one fit says (:func:`casest.estimation.verdict.residual_verdict`)."""

    WHITE = "white"  # every test passed: white and independent of the signals
    COLOURED = "coloured"  # correlated in time, independent of every signal, of the fitted value and of time
    DEPENDENT = "dependent"  # the residuals depend on a signal, on the fitted value or on time: a model error
    NOISE_LEVEL = "noise_level"  # the residuals do not match a given noise variance (chi-square)
    UNTESTED = "untested"  # no test ran (too few samples)


class DiagnosisCode(str, Enum):
    """The structural change that explains residuals that depend on something (:mod:`casest.estimation.diagnosis`)."""

    BIAS = "bias"  # a constant offset of an output
    SCALE = "scale"  # a scale error of an output (residuals proportional to the fitted value)
    LAG = "lag"  # a time shift between a signal and the outputs
    STEP = "step"  # a change of level during the record
    TERM = "term"  # a term of the signals missing from an output (a signal, its square, a product)


class TrustCode(str, Enum):
    """What casest says of an estimate (``Estimate.conclusion()``)."""

    TRUSTED = "trusted"  # every condition holds: trust it
    LOCAL = "local"  # a local solve from a given start that converged cleanly: no global search was asked for
    CAUTION = "caution"  # a condition failed: the line says which and what to do
    COLOURED_NOISE = "coloured_noise"  # the noise is correlated in time, the model fits: the estimate stands, colored-residual std
    MODEL_ERROR = "model_error"  # the residuals depend on a signal, the fitted value or time: the model lacks something


class Note(str):
    """A note's text (it is a ``str``) with its :class:`NoteCode` in ``.code``."""

    code: NoteCode

    def __new__(cls, text: str, code: NoteCode = NoteCode.OTHER):
        note = super().__new__(cls, text)
        note.code = NoteCode(code)
        return note

    def __reduce__(self):  # pickles with its code (Monte-Carlo workers)
        return (Note, (str(self), self.code))


def note_code(note) -> NoteCode:
    """The code of a note (``OTHER`` for a plain string)."""
    return getattr(note, "code", NoteCode.OTHER)
