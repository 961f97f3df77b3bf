"""Model-structure determination by stepwise regression (Klein and Morelli, *Aircraft System
Identification*, Sec. 5.4): terms enter by the largest partial F above ``f_in``, leave by the
smallest below ``f_out``, and a term enters only when it raises R^2 by at least ``min_r2_gain``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..errors import OptionError
from ..status import Note, NoteCode
from ..estimation.result_protocol import PlainResult
from ..estimation.result_schema import register_record
from .regression import Regression, dependent_variable, fit_least_squares, regressor_matrix, with_residual_checks

__all__ = ["StepwiseStep", "Stepwise", "stepwise"]

#: the largest number of steps (each adds or removes one term) before the search stops
MAX_STEPS = 200


@register_record
@dataclass(frozen=True)
class StepwiseStep:
    """One step of the search: the term added (``"+name"``) or removed (``"-name"``), its partial
    F, and the model's R^2 and PSE after it."""

    action: str
    partial_f: float
    r_squared: float
    pse: float


@register_record
@dataclass(frozen=True)
class Stepwise(PlainResult):
    """The selected model structure, a member of the result protocol through its final fit
    (:class:`~casest.estimation.result_protocol.EstimateLike`).

    Attributes
    ----------
    selected : tuple of str
        The terms chosen (the forced ones first, then in the order they entered).
    fit : Regression
        The least squares on the selected terms.
    steps : tuple of StepwiseStep
        The search, step by step.
    stopped : str
        Why the search ended.
    """

    KIND = "casest.Stepwise"

    selected: tuple
    fit: Regression
    steps: tuple
    stopped: str

    # the protocol: the final fit's parameters, std and trust line
    parameter_names = property(lambda self: self.fit.parameter_names, doc="The selected terms.")
    theta = property(lambda self: self.fit.theta, doc="The final fit's estimates.")
    std = property(lambda self: self.fit.std, doc="Their std.")
    covariance = property(lambda self: self.fit.covariance, doc="Their covariance.")
    success = property(lambda self: self.fit.success, doc="Whether the final fit is finite.")
    status = property(lambda self: self.fit.status, doc="The final fit's status.")

    @property
    def notes(self) -> tuple:
        """The final fit's notes and why the search stopped."""
        return self.fit.notes + (Note(f"stepwise search: {self.stopped}", NoteCode.OTHER),)

    def conclusion(self) -> tuple:
        """The final fit's trust line (:meth:`Regression.conclusion`).

        Returns
        -------
        TrustCode
        str
        """
        return self.fit.conclusion()

    def fit_statistics(self) -> list:
        """The final fit's statistics (:meth:`Regression.fit_statistics`) after the selection's steps
        and why it stopped.

        Returns
        -------
        list of (str, str)
            Name and value in words.
        """
        return [("steps", f"{len(self.steps)}"), ("stopped", self.stopped),
                ("selected", ", ".join(self.selected))] + self.fit.fit_statistics()

    def report(self) -> str:
        """The steps, then the final fit's table.

        Returns
        -------
        str
        """
        lines = [f"{'step':>4} {'term':>16} {'partial F':>11} {'R^2 %':>8} {'PSE':>11}"]
        lines += [f"{k + 1:>4} {s.action:>16} {s.partial_f:>11.4g} {100 * s.r_squared:>8.2f} {s.pse:>11.4g}"
                  for k, s in enumerate(self.steps)]
        return "\n".join(lines + [f"stopped: {self.stopped}", self.fit.report()])


def _sse(y, X) -> float:
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ theta
    return float(e @ e)


def _partial_f(y, X_small, X_big) -> float:
    """The partial F of the column X_big has beyond X_small: (SSE_small - SSE_big) / s^2_big."""
    N, p = X_big.shape
    sse_big = _sse(y, X_big)
    s2 = sse_big / (N - p)
    return (_sse(y, X_small) - sse_big) / s2 if s2 > 0 else np.inf


def stepwise(y, candidates: Mapping, data, always: Sequence[str] = (), f_in: float = 4.0, f_out: float = 4.0,
             min_r2_gain: float = 0.005, colored: bool = True) -> Stepwise:
    """Choose the terms of an equation-error model by forward and backward stepwise regression.

    Parameters
    ----------
    y : array_like, shape (N,), or str
        The dependent variable, or the name of a column of ``data``.
    candidates : mapping of str to CasADi expression or number
        Candidate regressors, as ``terms`` of :func:`casest.regress` (a bias ``{"bias": 1}``
        is usually among them and in ``always``).
    data : mapping of str to array_like, or Dataset
    always : sequence of str
        Candidates kept in every model (the bias).
    f_in, f_out : float
        Partial F a term needs to enter, and below which it leaves (Klein and Morelli use 4 for
        both; 4 is about the 95 % point of F(1, N - p) for the record lengths of flight tests).
    min_r2_gain : float
        The least increase of R^2 (a fraction: 0.005 is half a percentage point) for a term to
        enter; a smaller gain stops the search.
    colored : bool
        Whether the final fit's std account for coloured residuals (:func:`casest.regress`).

    Returns
    -------
    Stepwise

    Raises
    ------
    OptionError
        ``always`` names a term that is not a candidate, ``f_out > f_in`` (a term could cycle
        in and out), thresholds that are not positive.
    DataError
        As :func:`casest.regress`.
    """
    names, X = regressor_matrix(candidates, data)
    _check_search_options(names, always, f_in, f_out, min_r2_gain)
    original, y = y, dependent_variable(y, data, X.shape[0])
    index = {n: j for j, n in enumerate(names)}
    chosen = [index[a] for a in always]
    search = _Search(y, X, names, always)
    stopped = search.run(chosen, f_in, f_out, min_r2_gain)
    selected = [names[j] for j in chosen]
    fit = with_residual_checks(fit_least_squares(y, X[:, chosen], selected, colored=colored), X[:, chosen],
                               original, data)
    return Stepwise(tuple(selected), fit, tuple(search.steps), stopped)


def _check_search_options(names, always, f_in: float, f_out: float, min_r2_gain: float) -> None:
    """``always`` among the candidates; thresholds with which no term can cycle in and out."""
    unknown = [a for a in always if a not in names]
    if unknown:
        raise OptionError(f"always names {unknown}, which are not candidates {list(names)}")
    if not (f_in > 0 and f_out > 0 and f_out <= f_in and min_r2_gain >= 0):
        raise OptionError(f"need 0 < f_out <= f_in and min_r2_gain >= 0 (a term must not cycle in and out); got "
                          f"f_in={f_in}, f_out={f_out}, min_r2_gain={min_r2_gain}")


class _Search:
    """The stepwise search over the columns of X: each model's R^2 and PSE, and the steps taken."""

    def __init__(self, y: np.ndarray, X: np.ndarray, names, always):
        self.y, self.X, self.names, self.always = y, X, names, set(always)
        self.sst = float(np.sum((y - y.mean()) ** 2))
        self.steps: list = []

    def r2(self, cols) -> float:
        return 1.0 - _sse(self.y, self.X[:, cols]) / self.sst if cols and self.sst > 0 else 0.0

    def pse(self, cols) -> float:
        y = self.y
        return (_sse(y, self.X[:, cols]) if cols else float(y @ y)) / y.size + self.sst / y.size * len(cols) / y.size

    def run(self, chosen: list, f_in: float, f_out: float, min_r2_gain: float) -> str:
        """Forward steps (each followed by backward elimination) until a rule stops them; why, in words."""
        y, X, names = self.y, self.X, self.names
        for _ in range(MAX_STEPS):
            free = [j for j in range(len(names)) if j not in chosen]
            if not free or len(chosen) + 1 >= y.size:
                break
            base = X[:, chosen] if chosen else np.zeros((y.size, 0))
            best_f, best = max((_partial_f(y, base, X[:, chosen + [j]]), j) for j in free)
            gain = self.r2(chosen + [best]) - self.r2(chosen)
            if best_f < f_in:
                return f"no candidate has a partial F above f_in = {f_in:g} (the best, {names[best]}, {best_f:.3g})"
            if gain < min_r2_gain:
                return (f"the best candidate, {names[best]} (partial F {best_f:.3g}), raises R^2 by "
                        f"{100 * gain:.2f} percentage points, less than {100 * min_r2_gain:g}")
            chosen.append(best)
            self.steps.append(StepwiseStep("+" + names[best], best_f, self.r2(chosen), self.pse(chosen)))
            self.drop_weak(chosen, f_out)
        return "no candidate left"

    def drop_weak(self, chosen: list, f_out: float) -> None:
        """Backward elimination: remove the weakest term while its partial F is below ``f_out``."""
        while True:
            removable = [j for j in chosen if self.names[j] not in self.always]
            if not removable:
                return
            scores = [(_partial_f(self.y, self.X[:, [c for c in chosen if c != j]], self.X[:, chosen]), j)
                      for j in removable]
            worst_f, worst = min(scores)
            if worst_f >= f_out:
                return
            chosen.remove(worst)
            self.steps.append(StepwiseStep("-" + self.names[worst], worst_f, self.r2(chosen), self.pse(chosen)))
