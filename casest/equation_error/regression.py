"""Equation error: ordinary and weighted least squares on measured or reconstructed regressors,
with the statistics flight-test practice reads (Klein and Morelli, *Aircraft System
Identification*, Ch. 5), and the covariance corrected for coloured residuals.

The regressors are CasADi expressions of signal symbols, named like the columns of the data,
so that a term is written once (``alpha * de``, ``q * c / (2 * V)``) and evaluated over the
record. :func:`regress` fits given terms; :mod:`casest.equation_error.stepwise` selects them.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..checks import finite_array
from ..data.dataset import Dataset
from ..errors import DataError, OptionError
from ..status import Note, NoteCode, ResidualCode
from ..estimation.diagnosis import Diagnosis, diagnose_arrays
from ..estimation.diagnostics import ALPHA
from ..estimation.residual_family import series_checks
from ..estimation.reporting import std_text
from ..estimation.result_protocol import PlainResult, conclusion_of
from ..estimation.result_schema import register_record
from ..estimation.verdict import ColouredStd, residual_verdict, summary_lines

__all__ = ["Regression", "regress", "regressor_matrix", "fit_least_squares", "colored_lags", "record_columns",
           "dependent_variable", "symbolic_terms"]


@register_record
@dataclass(frozen=True)
class Regression(PlainResult):
    """A least-squares fit of ``y = X theta + e`` and its statistics.

    Attributes
    ----------
    names : tuple of str
        The terms, in the order of ``theta``.
    theta : ndarray, shape (p,)
    std : ndarray, shape (p,)
        Standard deviations: from the coloured-residual covariance when ``colored``, else
        ``std_white``.
    std_white : ndarray, shape (p,)
        ``sqrt(diag(s^2 (X'WX)^-1))``, right only for white residuals.
    covariance : ndarray, shape (p, p)
        The covariance behind ``std``.
    fitted, residuals : ndarray, shape (N,)
    s2 : float
        Fit error variance ``e'We / (N - p)``.
    r_squared : float
        Coefficient of determination (fraction of the variation about the mean explained).
    f_statistic : float
        ``(SST - SSE) / (p - 1) / s2``, the regression's F against the mean alone (nan for p = 1).
    t_values : ndarray, shape (p,)
        ``theta / std``.
    press : float
        Prediction error sum of squares: ``sum (e_i / (1 - h_ii))^2`` (leave-one-out residuals).
    pse : float
        Predicted squared error, ``e'e / N + sigma_max^2 p / N`` with ``sigma_max^2`` the
        variance of ``y`` about its mean (Klein and Morelli's model-structure criterion).
    colored : bool
        Whether ``std`` accounts for the residuals' autocorrelation.
    method : str
        ``"least squares"`` (:func:`regress`) or ``"total least squares"``
        (:func:`casest.total_least_squares`).
    residual_checks : tuple of ResidualCheck
        The residual tests in record order (:func:`casest.estimation.residual_family.series_checks`:
        whiteness, independence from the record's other columns, no trend along them or the
        fitted value, no change in time; one Holm family).
    diagnosis : Diagnosis or None
        When the residuals depend on something: the term, bias, scale or step of the record's
        columns that explains them (:func:`casest.estimation.diagnosis.diagnose_arrays`).
    """

    KIND = "casest.Regression"

    names: tuple
    theta: np.ndarray
    std: np.ndarray
    std_white: np.ndarray
    covariance: np.ndarray
    fitted: np.ndarray
    residuals: np.ndarray
    s2: float
    r_squared: float
    f_statistic: float
    t_values: np.ndarray
    press: float
    pse: float
    colored: bool
    method: str = "least squares"
    residual_checks: tuple = ()
    diagnosis: Diagnosis | None = None

    @property
    def n_samples(self) -> int:
        """The samples fitted."""
        return int(self.residuals.size)

    @property
    def parameter_names(self) -> tuple:
        """The terms (the result protocol's name for :attr:`names`)."""
        return tuple(self.names)

    @property
    def success(self) -> bool:
        """A closed-form solve: True where every estimate is finite."""
        return bool(np.all(np.isfinite(self.theta)))

    @property
    def status(self) -> str:
        """``"Solved"`` (closed form), or ``"Not_Finite"``."""
        return "Solved" if self.success else "Not_Finite"

    @property
    def notes(self) -> tuple:
        """Coded notes: which std are reported."""
        kind = ("coloured-residual std (the residuals' autocorrelation counted)" if self.colored else
                "white-residual std (the residuals taken as white)")
        return (Note(f"{self.method}: {kind}", NoteCode.NOISE_MODEL),)

    def conclusion(self) -> tuple:
        """``LOCAL`` (the least squares is closed-form; nothing global was searched) when every
        term has a std, else ``CAUTION``.

        Returns
        -------
        TrustCode
        str
        """
        ratio = self.std / self.std_white if self.colored else None
        return conclusion_of(self, f"the closed-form {self.method} over {self.n_samples} samples",
                             ColouredStd.of(ratio) if self.colored else ColouredStd(), self.diagnosis)

    def fit_statistics(self) -> list:
        """The fit's statistics as flight-test practice reads them (Klein and Morelli Ch. 5), for
        the report and the HTML page: N, p, R^2, the regression's F, the fit error's std s and
        variance s^2, PSE and PRESS.

        Returns
        -------
        list of (str, str)
            Name and value in words.
        """
        kind = "coloured-residual" if self.colored else "white-residual"
        return [("samples N", f"{self.n_samples}"), ("terms p", f"{len(self.names)}"),
                ("R^2", f"{100 * self.r_squared:.2f} %"), ("F", f"{self.f_statistic:.4g}  (the regression against "
                                                                  "the mean alone)"),
                ("fit error std s", f"{np.sqrt(self.s2):.4g}"), ("s^2", f"{self.s2:.4g}"),
                ("PSE", f"{self.pse:.4g}  (predicted squared error)"), ("PRESS", f"{self.press:.4g}"),
                ("std", kind)]

    def report(self) -> str:
        """The table (:meth:`table`) with the notes and the conclusion.

        Returns
        -------
        str
        """
        code, reason = self.conclusion()
        lines = [f"[[Model]] equation error ({self.method})", self.table()]
        if self.residual_checks:
            lines.append(f"[[Residual checks]] (one family, held at {ALPHA:g} by Holm's adjustment)")
            lines += [f"    {line}" for line in summary_lines(self.residual_checks)]
        lines += ["[[Notes]]"] + [f"    - {n}" for n in self.notes]
        return "\n".join(lines + [f"[[Conclusion]] {code.value.upper()}: {reason}"])

    def table(self) -> str:
        """The estimates, std and t-values, one line each, and the fit's statistics.

        Returns
        -------
        str
        """
        kind = "coloured-residual" if self.colored else "white-residual"
        if self.method != "least squares":
            kind = f"{self.method}, {kind}"
        lines = [f"{'term':>14} {'estimate':>13} {'std':>11} {'t':>8}", "-" * 49]
        lines += [f"{n:>14} {v:>13.6g} {std_text(s, '>11.3g')} {std_text(t if np.isfinite(s) else np.nan, '>8.2f')}"
                  for n, v, s, t in zip(self.names, self.theta, self.std, self.t_values)]
        lines.append(f"N = {self.n_samples}, R^2 = {100 * self.r_squared:.2f} %, F = {self.f_statistic:.4g}, "
                     f"s^2 = {self.s2:.4g}, PSE = {self.pse:.4g}, PRESS = {self.press:.4g}; std: {kind}")
        return "\n".join(lines)


def record_columns(data) -> dict:
    """The data's columns by name: a mapping of arrays, or a Dataset's signals and outputs."""
    if isinstance(data, Dataset):
        names = list(data.signal_names) + list(data.output_names)
        return {name: data.column(name) for name in names}
    if not isinstance(data, Mapping):
        raise DataError(f"data must map signal names to arrays or be a casest.Dataset, got {type(data).__name__}")
    return {str(k): v for k, v in data.items()}


def regressor_matrix(terms: Mapping, data) -> tuple[tuple, np.ndarray]:
    """Evaluate each term over the record.

    Parameters
    ----------
    terms : mapping of str to CasADi expression or number
        Regressor name -> expression of signal symbols named like the data's columns (a
        number is a constant regressor: ``{"bias": 1}``). Symbols are matched by name: two
        symbols of one name, made separately, are the same column.
    data : mapping of str to array_like, or Dataset

    Returns
    -------
    names : tuple of str
    X : ndarray, shape (N, p)

    Raises
    ------
    DataError
        A symbol the data do not hold (named, with the closest columns), columns of unequal
        lengths, values that are not finite.
    OptionError
        No terms, or a term that is not an expression.
    """
    names, exprs, symbols = symbolic_terms(terms)
    columns = record_columns(data)
    lengths = {np.asarray(v).reshape(-1).size for v in columns.values()}
    if len(lengths) != 1:
        raise DataError(f"the data's columns have different lengths {sorted(lengths)}; give one record")
    N = lengths.pop()
    missing = [s for s in symbols if s not in columns]
    if missing:
        hints = {m: difflib.get_close_matches(m, list(columns), n=1) for m in missing}
        raise DataError(f"the terms use {missing}, which the data do not hold (columns: {sorted(columns)})"
                        + "".join(f"; did you mean {h[0]!r} for {m!r}?" for m, h in hints.items() if h))
    args = [s for s in symbols.values()]
    f = ca.Function("regressors", args, [ca.vertcat(*exprs)]) if args else None
    # each column checked as the record holds it: a NaN named by its row, a text column by its name
    inputs = [finite_array(columns[s.name()], f"column {s.name()!r}", shape=(N,)).reshape(1, -1) for s in args]
    if f is None:
        X = np.tile(np.array([float(ca.evalf(e)) for e in exprs]), (N, 1))
    else:
        X = np.asarray(f.map(N)(*inputs), dtype=float).reshape(len(exprs), N).T
    if not np.all(np.isfinite(X)):
        rows = np.flatnonzero(~np.isfinite(X).all(axis=1))[:5].tolist()
        raise DataError(f"a term is not finite at rows {rows} (a division by zero or a log of a negative value); "
                        "drop those samples or rewrite the term")
    return names, X


def symbolic_terms(terms: Mapping) -> tuple[tuple, list, dict]:
    """The regressors as scalar CasADi expressions of one kind, over one symbol per signal name.

    Parameters
    ----------
    terms : mapping of str to CasADi expression or number
        As :func:`regressor_matrix` takes them.

    Returns
    -------
    names : tuple of str
    expressions : list of casadi.SX or casadi.MX
        A number as a constant; all MX where any term is MX.
    symbols : dict of str to casadi.SX or casadi.MX
        The signal symbols by name, in order of first use (a symbol made afresh with a name
        already seen is replaced by the first one: two symbols of one name are one column).

    Raises
    ------
    OptionError
        No terms, or a term that is not a scalar expression or a number.
    """
    if not isinstance(terms, Mapping) or not terms:
        raise OptionError("terms must be a non-empty mapping {name: CasADi expression of signal symbols or number}")
    names, exprs, symbols = [], [], {}
    for name, term in terms.items():
        if isinstance(term, (int, float, np.integer, np.floating)) and not isinstance(term, bool):
            term = ca.SX(float(term))
        if not isinstance(term, (ca.SX, ca.MX)) or term.numel() != 1:
            raise OptionError(f"term {name!r} must be a scalar CasADi expression or a number, got {type(term).__name__}")
        for s in ca.symvar(term):
            symbols.setdefault(s.name(), s)
        same = [(s, symbols[s.name()]) for s in ca.symvar(term)
                if type(s) is type(symbols[s.name()]) and not ca.is_equal(s, symbols[s.name()])]
        if same:
            term = ca.substitute([term], [a for a, _ in same], [b for _, b in same])[0]
        names.append(str(name))
        exprs.append(term)
    return tuple(names), _one_kind(exprs, names), symbols


def _one_kind(exprs: list, names: list) -> list:
    """The terms as one kind of CasADi expression: numbers become MX where the others are MX."""
    if not any(isinstance(e, ca.MX) for e in exprs):
        return exprs
    out = []
    for name, e in zip(names, exprs):
        if isinstance(e, ca.SX):
            if not e.is_constant():
                raise OptionError(f"term {name!r} is an SX expression and others are MX: build every term from one "
                                  "kind of symbol (casadi.SX.sym or casadi.MX.sym)")
            e = ca.MX(float(ca.evalf(e)))
        out.append(e)
    return out


def colored_lags(e: np.ndarray) -> int:
    """The lags the coloured-residual covariance sums: Andrews' (1991) automatic bandwidth for the
    Bartlett kernel, from an AR(1) fit of the residuals, ``1.1447 (alpha N)^(1/3)`` with
    ``alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2)``.

    Parameters
    ----------
    e : ndarray, shape (N,)

    Returns
    -------
    int
        Between 0 and N - 1.
    """
    N = e.size
    r0 = float(e @ e)
    rho = float(np.clip(e[:-1] @ e[1:] / r0, -0.97, 0.97)) if r0 > 0 and N > 1 else 0.0
    alpha = 4.0 * rho**2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    return int(min(N - 1, np.ceil(1.1447 * (alpha * N) ** (1.0 / 3.0))))


def _colored_gram(Xw: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``X' T X`` with T the Toeplitz matrix of the residuals' autocorrelation, Bartlett-weighted up
    to :func:`colored_lags` (a positive semi-definite estimate; the unweighted sum over every lag is
    biased towards zero, since the residuals are orthogonal to X), by FFT."""
    N = e.size
    n_fft = 1 << int(np.ceil(np.log2(2 * N)))
    spectrum = np.fft.rfft(e, n_fft)
    lags = colored_lags(e)
    r = np.fft.irfft(spectrum * np.conj(spectrum), n_fft)[:N] / N  # r(k), k = 0 .. N-1
    r = r * np.clip(1.0 - np.arange(N) / (lags + 1.0), 0.0, None)  # Bartlett weights
    circulant = np.concatenate([r, np.zeros(n_fft - 2 * N + 1), r[:0:-1]])
    TX = np.fft.irfft(np.fft.rfft(circulant)[:, None] * np.fft.rfft(Xw, n_fft, axis=0), n_fft, axis=0)[:N]
    G = Xw.T @ TX
    return 0.5 * (G + G.T)


def fit_least_squares(y: np.ndarray, X: np.ndarray, names, weights=None, colored: bool = True) -> Regression:
    """Least squares of ``y`` on the columns of ``X`` and the statistics of :class:`Regression`.

    Parameters
    ----------
    y : ndarray, shape (N,)
    X : ndarray, shape (N, p)
    names : sequence of str, length p
    weights : ndarray, shape (N,), optional
        Positive weights (inverse variances): weighted least squares.
    colored : bool
        Correct the covariance for the residuals' autocorrelation (samples in time order).

    Returns
    -------
    Regression

    Raises
    ------
    DataError
        Fewer samples than terms, or regressors that are linearly dependent (named).
    """
    N, p = X.shape
    if N <= p:
        raise DataError(f"{N} samples cannot determine {p} terms; give a longer record or fewer terms")
    w = np.ones(N) if weights is None else finite_array(weights, "weights", shape=(N,))
    if np.any(w <= 0):
        raise DataError("weights must be positive (inverse variances of the samples)")
    sw = np.sqrt(w)
    Xw, yw = X * sw[:, None], y * sw
    Q, Rq = np.linalg.qr(Xw)
    diag = np.abs(np.diag(Rq))
    if diag.min() <= 1e-10 * max(diag.max(), 1e-300):
        dependent = [names[j] for j in np.flatnonzero(diag <= 1e-10 * diag.max())]
        raise DataError(f"the regressors {dependent} are linear combinations of the others on this record; drop them "
                        "or collect data that excite them separately")
    theta = np.linalg.solve(Rq, Q.T @ yw)
    e = y - X @ theta
    ew = e * sw
    sse = float(ew @ ew)
    s2 = sse / (N - p)
    Rinv = np.linalg.inv(Rq)
    XtX_inv = Rinv @ Rinv.T
    cov_white = s2 * XtX_inv
    cov = XtX_inv @ _colored_gram(Xw, ew) @ XtX_inv if colored else cov_white
    std, std_white = np.sqrt(np.clip(np.diag(cov), 0.0, None)), np.sqrt(np.diag(cov_white))
    ybar = float(np.sum(w * y) / np.sum(w))
    sst = float(np.sum(w * (y - ybar) ** 2))
    leverage = np.sum(Q * Q, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        press = float(np.sum((ew / (1.0 - leverage)) ** 2))
        t_values = theta / std
    sigma_max2 = sst / N
    return Regression(tuple(names), theta, std, std_white, cov, X @ theta, e, s2,
                      1.0 - sse / sst if sst > 0 else np.nan,
                      (sst - sse) / (p - 1) / s2 if p > 1 and s2 > 0 else np.nan,
                      t_values, press, sse / N + sigma_max2 * p / N, bool(colored))


def regress(y, terms: Mapping, data, weights=None, colored: bool = True) -> Regression:
    """Equation error: the least squares of ``y`` on the given terms over a record.

    Parameters
    ----------
    y : array_like, shape (N,), or str
        The dependent variable (a force or moment coefficient, an acceleration), or the name of
        a column of ``data``.
    terms : mapping of str to CasADi expression or number
        Regressor name -> scalar expression of signal symbols named like the columns of
        ``data`` (``{"bias": 1, "alpha": alpha, "q_hat": q * c / (2 * V)}``).
    data : mapping of str to array_like, or Dataset
        The record's columns (measured or reconstructed), in time order.
    weights : array_like, shape (N,), optional
        Positive weights (inverse variances of the samples): weighted least squares.
    colored : bool
        Report the std of coloured residuals (default): the covariance
        ``(X'X)^-1 X' R_ee X (X'X)^-1`` with the residuals' autocorrelation in ``R_ee``
        (Morelli and Klein 1997), Bartlett-weighted up to an automatic lag
        (:func:`colored_lags`), which the white-residual ``s^2 (X'X)^-1`` underestimates when
        the residuals are correlated in time (``Regression.std_white`` keeps that one).

    Returns
    -------
    Regression

    Raises
    ------
    DataError
        ``y`` of the wrong length or not finite, symbols the data lack, dependent regressors,
        fewer samples than terms.
    """
    names, X = regressor_matrix(terms, data)
    fit = fit_least_squares(dependent_variable(y, data, X.shape[0]), X, names, weights, colored)
    return with_residual_checks(fit, X, y, data)


def with_residual_checks(fit: Regression, X: np.ndarray, y, data) -> Regression:
    """The fit with its residual tests against the record's columns (``y``'s own column apart).

    Parameters
    ----------
    fit : Regression
    X : ndarray, shape (N, p)
        The regressors fitted (the fit's own error directions, which the tests leave aside).
    y : array_like or str
        The dependent variable as given (a column's name is left out of the signals).
    data : mapping of str to array_like, or Dataset

    Returns
    -------
    Regression
    """
    from dataclasses import replace

    columns = record_columns(data)
    own = y if isinstance(y, str) else None
    names = [n for n, v in columns.items() if n != own and np.shape(v) == (X.shape[0],)
             and np.all(np.isfinite(np.asarray(v, dtype=float)))]
    signals = np.column_stack([np.asarray(columns[n], dtype=float) for n in names]) if names else np.zeros((X.shape[0], 0))
    channel, residuals, fitted = [own or "y"], fit.residuals[:, None], fit.fitted[:, None]
    checks = series_checks(residuals, channel, signals, names, in_time=True, dynamic=False, fitted=fitted,
                           jacobian=X[:, None, :])
    found = None
    if residual_verdict(checks).code is ResidualCode.DEPENDENT:
        found = diagnose_arrays(residuals, channel, signals, names, fitted, in_time=True, jacobian=X, checks=checks)
    return replace(fit, residual_checks=checks, diagnosis=found)


def dependent_variable(y, data, n_samples: int) -> np.ndarray:
    """``y`` as a finite array of the record's length, or the column of ``data`` it names.

    Parameters
    ----------
    y : array_like, shape (N,), or str
    data : mapping of str to array_like, or Dataset
    n_samples : int

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    DataError
        A name the data do not hold, the wrong length, values that are not finite.
    """
    name = "y"
    if isinstance(y, str):
        columns = record_columns(data)
        if y not in columns:
            raise DataError(f"y names {y!r}, which the data do not hold (columns: {sorted(columns)})")
        y, name = columns[y], f"y (column {y!r})"
    return finite_array(y, name, shape=(n_samples,))
