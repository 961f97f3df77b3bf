"""The family of residual tests of one fit: is the noise white, and are the residuals independent
of the signals, of the fitted value and of time?

Per output channel, on the residuals in time order (a dynamic model, or a static model's data
flagged ``time_ordered``) or in the record's own order (other static data: calibrations are
mostly recorded in time, and the test is valid under white noise whatever the order):

- **whiteness** (:attr:`CheckCode.WHITENESS`): Ljung-Box of the residuals as they are. Failing
  it alone says the noise is coloured.
- **independence** from each signal (:attr:`CheckCode.CROSS_CORRELATION`): the prewhitened
  cross-correlation at lags of both signs for a static model, past inputs for a dynamic one
  (:func:`casest.estimation.independence.independence_test`).
- **trend** (:attr:`CheckCode.TREND`, static models): Ljung-Box of the prewhitened residuals
  sorted by the fitted value and by each signal: a term missing in a signal (a calibration
  curve one order short, a cross-axis coupling left out) leaves a smooth trend along it. An
  order equal to one already tested (or its reverse), but for ties, is not tested again.
- **step** (:attr:`CheckCode.STEP`): a change of level during the record.
- **chi-square** (:attr:`CheckCode.CHI_SQUARE`, a known R only): the residuals' size.

Where a static record's own order equals a signal's or the fitted value's order (data sorted by
x), correlation in record order cannot be told from a smooth dependence on that signal: the
record-order test is then that signal's trend test, on the residuals as they are.

All tests of the fit are one family, Holm-adjusted (:func:`casest.estimation.diagnostics.family_adjusted`).
"""

from __future__ import annotations

import weakref
from dataclasses import replace

import numpy as np

from ..status import CheckCode
from .diagnostics import (EXACT_UP_TO, NULL_DRAWS, ResidualCheck, chi_square_check, family_adjusted, ljung_box,
                          ljung_box_p, whiteness_check)
from .verdict import DEPENDENCE
from .independence import (CROSS_LAGS, Prewhitener, independence_test, nuisance_basis, prewhitener, projected_out,
                           step_test)

__all__ = ["residual_checks", "series_checks", "cross_lags", "tested_signals"]

#: each live problem's last tests and the point they were made at (a problem's data do not change)
_LAST_CHECKS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def cross_lags(n_samples: int, dynamic: bool) -> np.ndarray:
    """The lags of the cross-correlation test: ``1 ... M`` (past inputs of a dynamic model) or
    ``-M ... M`` (a static model), ``M = min(CROSS_LAGS, N // 40)``, at least 1.

    A dynamic model's residual at t is tested against inputs up to t - 1 only: under feedback
    (an input computed from the same sample's measurement) the residual of a right model
    correlates with the input of its own sample, never with earlier ones (Ljung, Sec. 16.6)."""
    M = max(1, min(CROSS_LAGS, n_samples // 40))
    return np.arange(1, M + 1) if dynamic else np.arange(-M, M + 1)


def residual_checks(problem, theta: np.ndarray, min_samples: int = 20) -> tuple:
    """The family of residual tests of an estimate (module docstring).

    Parameters
    ----------
    problem : Problem
        The problem estimated: its noise model decides the chi-square test, its measurement
        whether the record is in time and the signals are inputs (a dynamic model).
    theta : ndarray, shape (n_parameters,)
        The estimate.
    min_samples : int
        Channels with fewer measurements are not tested.

    Returns
    -------
    tuple of ResidualCheck
        Holm-adjusted within the family.
    """
    theta = np.asarray(theta, dtype=float)
    known = _LAST_CHECKS.get(problem)
    if known is not None and known[0] == int(min_samples) and np.allclose(known[1], theta, rtol=1e-9, atol=0):
        return known[2]  # the pipeline asks at the same point twice (or at a start's equal solution)
    model = problem.model
    predicted = problem.predict(theta)
    dynamic = bool(problem.measurement.simulated)
    N, ny = predicted.shape
    names, signals = tested_signals(model, problem.data)
    checks = series_checks(problem.data.outputs - predicted, model.output_names, signals, names, in_time=dynamic or bool(getattr(problem.data, "time_ordered", False)),
                         dynamic=dynamic, fitted=predicted, known_R=problem.known_R,
                         n_fitted=model.n_parameters / model.n_outputs, min_samples=min_samples,
                         jacobian=problem.jacobian(theta).reshape(N, ny, -1))
    _LAST_CHECKS[problem] = (int(min_samples), theta.copy(), checks)
    return checks


def tested_signals(model, data) -> tuple[list, np.ndarray]:
    """The signals the residuals must not depend on: a static model's signals, a dynamic model's
    inputs (its time apart).

    Parameters
    ----------
    model : Model or DynamicModel
    data : Dataset

    Returns
    -------
    names : list of str
    values : ndarray, shape (N, n_names)
    """
    names = [s.name for s in model.inputs] if hasattr(model, "inputs") else list(model.signal_names)
    values = np.column_stack([data.column(n) for n in names]) if names else np.zeros((data.n_samples, 0))
    return names, values


def series_checks(residuals: np.ndarray, channels, signals: np.ndarray, signal_names, *, in_time: bool,
                  dynamic: bool, fitted: np.ndarray | None = None, known_R=None, n_fitted: float = 0.0,
                  min_samples: int = 20, jacobian: np.ndarray | None = None, stop_below: float = 0.0) -> tuple:
    """The family of residual tests of residuals given as arrays (module docstring).

    Parameters
    ----------
    residuals : ndarray, shape (N, n_channels)
        Measured less fitted (NaN: not measured), in the record's order.
    channels : sequence of str
    signals : ndarray, shape (N, n_signals)
        The signals the residuals must not depend on (a dynamic model's inputs).
    signal_names : sequence of str
    in_time : bool
        The record is in time order (labels the tests "time", else "record").
    dynamic : bool
        The residuals come from a dynamic model: cross-correlation with past inputs only, no
        trend tests along the signals.
    fitted : ndarray, shape (N, n_channels), optional
        The fitted values (a static model's trend test along them).
    known_R : array_like, shape (n_channels,), optional
        Given noise variances (the chi-square test).
    n_fitted : float
        Parameters per channel (the chi-square test's degrees of freedom).
    min_samples : int
        Channels with fewer measurements are not tested.
    jacobian : ndarray, shape (N, n_channels, n_parameters), optional
        The fitted model's Jacobian: the residuals carry its estimation error along these
        directions, which the tests of dependence leave aside (with coloured noise that error
        is larger than the white-noise std say and depends on the signals).

    Returns
    -------
    tuple of ResidualCheck
        Holm-adjusted within the family.
    """
    residuals = np.asarray(residuals, dtype=float).reshape(len(residuals), -1)
    signals = np.asarray(signals, dtype=float).reshape(residuals.shape[0], -1)
    usable = [(name, signals[:, i]) for i, name in enumerate(signal_names)
              if np.all(np.isfinite(signals[:, i])) and np.ptp(signals[:, i]) > 0]
    checks, shared = [], [] if dynamic else _signal_orders(residuals.shape[0], usable)
    for j, channel in enumerate(channels):
        r = residuals[:, j]
        if np.isfinite(r).sum() < min_samples:
            continue
        if known_R is not None:
            checks.append(chi_square_check(r, float(np.asarray(known_R).reshape(-1)[j]), n_fitted, channel))
        key = None if fitted is None or dynamic else np.asarray(fitted, dtype=float)[:, j]
        directions = None if jacobian is None else np.asarray(jacobian, dtype=float)[:, j, :]
        checks += _channel_checks(r, channel, key, usable, shared, "time" if in_time else "record", dynamic,
                                  directions)
        if any(c.code in DEPENDENCE and c.p_value < stop_below for c in checks):
            break
    return family_adjusted(checks)


def _channel_checks(r: np.ndarray, channel: str, fitted, usable: list, signal_orders: list, series: str,
                    dynamic: bool, directions: np.ndarray | None) -> list:
    """Whiteness, trend, independence and step tests of one channel's residuals (``signal_orders``:
    :func:`_signal_orders`; ``directions``: the channel's Jacobian, the fit's own error directions)."""
    along = [] if dynamic else _trend_orders(fitted, signal_orders, record_is_time=series == "time")
    whiteness = whiteness_check(r, channel, series)
    alias = next((item for item in along if item[3]), None)
    filled = np.where(np.isfinite(r), r, np.nanmean(r))
    if alias is not None:  # the record is sorted by a signal: its order's test is that signal's trend test
        _, label, signal, _ = alias
        whiteness = whiteness and replace(whiteness, code=CheckCode.TREND, order=label, signal=signal)
        whitener = Prewhitener(np.zeros(0), float(np.var(filled)))
    else:
        whitener = prewhitener(filled)
    checks = [whiteness] if whiteness else []
    e = whitener.apply(filled - filled.mean())
    nuisance = None
    if directions is not None:
        measured = np.isfinite(r)[:, None]
        nuisance = np.column_stack([whitener.apply(col) for col in (directions * measured).T]) \
            if directions.shape[1] else None
    e_free = projected_out(e, nuisance)  # the fit's own error directions left aside
    for order, label, signal, is_alias in along:
        if is_alias:
            continue
        check = trend_check(e_free, order, channel, label, signal)
        checks += [check] if check else []
    lags = cross_lags(r.size, dynamic)
    basis = nuisance_basis(nuisance, e.size, lags)
    for name, x in usable:
        test = independence_test(e, whitener.apply(x), lags, basis=basis)
        if test is not None:
            peak = int(np.argmax(np.abs(test.correlation)))
            checks.append(ResidualCheck(CheckCode.CROSS_CORRELATION, channel, test.statistic, test.dof, test.p_value,
                                        series, signal=name, lag=float(test.peak_lag),
                                        size=float(test.correlation[peak])))
    step = step_test(filled, whitener)
    if step is not None:
        checks.append(ResidualCheck(CheckCode.STEP, channel, step.statistic, 1.0, step.p_value, series,
                                    lag=float(step.location), size=step.size))
    return checks


#: circular shifts of the residuals against a signal's order whose mean trend statistic scales the test
TREND_SHIFTS = 19


def trend_check(e: np.ndarray, order: np.ndarray, channel: str, label: str, signal: str) -> ResidualCheck | None:
    """The trend test along one order: Ljung-Box of the prewhitened residuals sorted by a signal
    (or the fitted value), its statistic divided by how much the colour the prewhitening left
    raises it: the mean statistic over :data:`TREND_SHIFTS` circular shifts of the residuals in
    time (each keeps their colour and breaks their alignment with the signal) over its white-noise
    mean ``h``, at least 1. A slowly varying signal sorts neighbours in time together, so that
    residual colour alone would otherwise pass for a trend.

    Parameters
    ----------
    e : ndarray, shape (N,)
        Prewhitened residuals in time order, the fit's own directions left aside.
    order : ndarray of int
        The samples sorted by the signal.
    channel, label, signal : str
        The output, the order's label (``"signal x"``) and the signal's name.

    Returns
    -------
    ResidualCheck or None
        None when the record is too short to test.
    """
    Q, h, _ = ljung_box(e[order])
    if not h:
        return None
    n = e.size
    shifts = np.linspace(0, n, TREND_SHIFTS + 2)[1:-1].astype(int)
    index = (order[None, :] - shifts[:, None]) % n  # row s: e shifted by s in time, then sorted
    inflation = max(float(np.mean(_ljung_box_rows(e[index], h))) / h, 1.0)
    p = ljung_box_p(Q / inflation, n, h)
    from_draws = n <= EXACT_UP_TO and p >= 1.0 / (NULL_DRAWS + 1)
    return ResidualCheck(CheckCode.TREND, channel, Q / inflation, h, p, label, NULL_DRAWS if from_draws else 0,
                         signal=signal)


def _ljung_box_rows(rows: np.ndarray, h: int) -> np.ndarray:
    """The Ljung-Box statistic of each row (h lags), its lag products summed directly (h is at
    most 20: five times faster than an FFT's whole autocorrelation from 1000 samples up)."""
    x = rows - rows.mean(axis=1, keepdims=True)
    n = x.shape[1]
    energy = np.maximum(np.einsum("ij,ij->i", x, x), 1e-300)
    lagged = np.stack([np.einsum("ij,ij->i", x[:, k:], x[:, :-k]) for k in range(1, h + 1)], axis=1)
    rho = lagged / energy[:, None]
    return n * (n + 2) * (rho**2 @ (1.0 / (n - np.arange(1, h + 1))))


def _signal_orders(n: int, usable: list) -> list:
    """``(order, places, label, signal, is_record_order)`` of each signal whose order differs from
    every signal's before it (the part of the trend orders the channels share)."""
    record_places = _places(np.arange(n))
    out, seen = [], []
    for name, x in usable:
        order = np.argsort(x, kind="stable")
        if any(_same_order(order, s) for s in seen):
            continue
        seen.append(_places(order))
        out.append((order, seen[-1], f"signal {name}", name, _same_order(order, record_places)))
    return out


def _trend_orders(fitted, signal_orders: list, record_is_time: bool) -> list:
    """``(order, label, signal, is_record_order)`` of the fitted value and each signal, each order
    distinct from those before it; one equal to the record's own order is marked (and kept
    only when the record is not in time, where it stands for the record-order test)."""
    keys, fitted_places = [], None
    if fitted is not None and np.all(np.isfinite(fitted)) and np.ptp(fitted) > 0:
        order = np.argsort(fitted, kind="stable")
        fitted_places = _places(order)
        keys.append((order, "fitted value", "", _same_order(order, _places(np.arange(order.size)))))
    keys += [(order, label, name, is_record) for order, _, label, name, is_record in signal_orders
             if fitted_places is None or not _same_order(order, fitted_places)]
    out, aliased = [], False
    for order, label, signal, is_record in keys:
        if is_record and (record_is_time or aliased):
            continue
        aliased = aliased or is_record
        out.append((order, label, signal, is_record))
    return out


def _places(order: np.ndarray) -> np.ndarray:
    """Each sample's place in ``order`` (the inverse permutation)."""
    where = np.empty_like(order)
    where[order] = np.arange(order.size)
    return where


def _same_order(order: np.ndarray, where: np.ndarray) -> bool:
    """Whether two orders give the same test (``where``: the other order's :func:`_places`): equal,
    or reversed (the same autocorrelations), but for at most 1 % of the samples moved by more than
    one place (near-ties, such as the values of a sine at mirrored times, swapped by rounding)."""
    probe = np.linspace(0, order.size - 1, min(order.size, 256)).astype(int)  # a cheap look first
    moved = np.abs(where[order[probe]] - probe)
    if np.mean(moved > 1) > 0.1 and np.mean(np.abs(where[order[probe]] - (order.size - 1 - probe)) > 1) > 0.1:
        return False  # far more than 1 % moved (a chance below 1e-12 of saying so wrongly)
    places, k = where[order], np.arange(order.size)
    return bool(np.mean(np.abs(places - k) > 1) <= 0.01 or np.mean(np.abs(places - (order.size - 1 - k)) > 1) <= 0.01)
