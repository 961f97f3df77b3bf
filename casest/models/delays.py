"""Time delays of a dynamic model's inputs and outputs as estimated parameters (fractional, by interpolation).

An input ``u`` delayed by the parameter ``tau`` enters the model as ``u(t - tau)``, built
from the sampled record by cubic convolution (Keys' kernel with a = -1/2, the Catmull-Rom
spline through the four nearest samples)::

    u(t_k - tau) = sum_j w(tau / dt - j) u_{k-j},   j = -1 ... M
    w(s) = 1.5|s|^3 - 2.5|s|^2 + 1 (|s| <= 1),  -0.5|s|^3 + 2.5|s|^2 - 4|s| + 2 (1 < |s| < 2),  0 else

with ``dt`` the model's declared ``sample_time`` and ``M = ceil(tau_max / dt) + 2`` from the
upper bound of ``tau``. The interpolation error falls with dt^3 and the cost is continuously
differentiable in ``tau`` (linear interpolation would attenuate the delayed input between
samples and bias ``tau`` by several std on long records). The next sample ``u@lead`` (j = -1,
which a delay under one sample needs) and the lagged samples ``u@1 ... u@M`` are extra input columns that
:meth:`DynamicModel.dataset` (and the CSV and MATLAB readers) derive from ``u`` itself, so
the data need only ``u``. Because ``tau`` enters the right-hand side, it is a parameter of
the dynamics: the sweep, the sensitivities and both stage-2 solvers treat it like any other.

Sampling: the kernel works in sample index, so the record must be sampled at ``sample_time``
up to jitter: time stamps within 5 % of a sample of the uniform grid k * dt (within each
manoeuvre; :data:`casest.models.dynamic_records.JITTER_TOLERANCE`) are accepted, and the
time of a delayed sample then errs by at most that deviation (AP2 record: 0.13 ms, 0.67 % of
a sample); give the record's mean interval as ``sample_time``.

Limits (documented): between
samples the delayed input follows the model's input hold of the interpolated samples (exact
for a delay of whole samples); the second derivative in ``tau`` jumps at whole samples; the
first samples see the record's first value held (the input before the record is unknown),
the last sample's lead is its own value. With several manoeuvres (segments) each one's lags
are derived from its own record, so they stop at the boundaries.

An output ``y`` delayed by ``tau`` is the model's output at ``t - tau``: the same kernel
applied to the *simulated, noise-free* output sequence (:class:`OutputDelays`), so the
measurement noise is untouched and the likelihood stays that of white noise (interpolating
the measured record instead would shrink and correlate its noise between samples and pull
the delay towards half samples). Because the delayed output mixes neighbouring samples,
output delays are a property of output error by single shooting (both solvers, stage 1,
the covariance, the Fisher information); the filters and multiple shooting refuse them.
Before the record the output is held at its first simulated value; after it, at its last
(a delay under one sample interpolates towards the next sample). With several manoeuvres
stacked in one record (:func:`casest.problem.experiments.stack_dynamic_experiments`) each segment is
convolved alone, its own ends held, so no delayed output reaches across a boundary.
"""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from ..checks import positive_number
from ..errors import ModelError
from .priors import Parameter, Signal

__all__ = ["InputDelays", "OutputDelays"]


def _delay_parameter(u: str, tau: str, input_names: list, by_name: dict) -> Parameter:
    """The declared parameter ``tau`` that delays input ``u``."""
    if u not in input_names:
        raise ModelError(f"delays names {u!r}, which is not an input or an output of the model (inputs: "
                         f"{input_names})")
    if tau not in by_name:
        raise ModelError(f"the delay of {u!r} is the parameter {tau!r}, which is not declared")
    return by_name[tau]


class InputDelays:
    """The delayed inputs of a model: ``{input name: delay parameter name}`` at a sample time (s)."""

    def __init__(self, delays: Mapping[str, str] | None, sample_time: float | None, parameters, inputs):
        self.delays = dict(delays or {})
        self.sample_time = None if sample_time is None else float(sample_time)
        self.lags: dict[str, int] = {}
        if not self.delays:
            return
        _check_sample_time(self.sample_time, "input")
        by_name = {p.name: p for p in parameters if isinstance(p, Parameter)}
        input_names = [s.name if isinstance(s, Signal) else str(s) for s in inputs]
        self.delays = {u: _delay_name(u, tau, "input") for u, tau in self.delays.items()}
        self.lags = {u: _lag_count(_delay_parameter(u, tau, input_names, by_name), self.sample_time)
                     for u, tau in self.delays.items()}

    def lag_names(self, u: str) -> list[str]:
        """The names of the next and the lagged samples of input ``u``: ``u@lead, u@1 ... u@M``."""
        if u not in self.lags:
            return []
        return [f"{u}@lead"] + [f"{u}@{j}" for j in range(1, self.lags[u] + 1)]

    def extra_inputs(self, inputs) -> list:
        """The lag signals to append to the model's inputs (each with its input's unit)."""
        out = []
        for s in inputs:
            signal = s if isinstance(s, Signal) else Signal(str(s))
            out += [Signal(name, signal.unit) for name in self.lag_names(signal.name)]
        return out

    def apply(self, expressions: Mapping[str, object]) -> dict:
        """``expressions`` with every delayed input replaced by its interpolated delayed value."""
        if not self.delays:
            return dict(expressions)
        out = {}
        for key, expr in expressions.items():
            if not isinstance(expr, ca.SX):
                out[key] = expr
                continue
            symbols = {s.name(): s for s in ca.symvar(expr)}
            for u, tau in self.delays.items():
                if u not in symbols or f"{u}@1" in symbols:  # absent, or already delayed
                    continue
                tau_sym = symbols.get(tau, ca.SX.sym(tau))
                lead, *lagged = [ca.SX.sym(name) for name in self.lag_names(u)]
                position = tau_sym / self.sample_time
                samples = zip(range(-1, len(lagged) + 1), [lead, symbols[u]] + lagged)
                delayed = sum(_keys_weight(position - j) * s for j, s in samples)
                expr = ca.substitute(expr, symbols[u], delayed)
            out[key] = expr
        return out

    def complete_columns(self, columns: Mapping) -> Mapping:
        """``columns`` with the lagged samples of every delayed input derived from the input (first value held)."""
        if not self.delays:
            return columns
        out = dict(columns)
        for u in self.delays:
            if u not in out:
                continue
            base = np.asarray(out[u], dtype=float).reshape(-1)
            lead, *lagged = self.lag_names(u)
            if lead not in out:
                out[lead] = np.concatenate([base[1:], base[-1:]])
            for j, name in enumerate(lagged, start=1):
                if name not in out:
                    out[name] = np.concatenate([np.full(min(j, base.size), base[0] if base.size else 0.0),
                                                base[:max(base.size - j, 0)]])
        return out

    def derived_columns(self) -> set:
        """The column names a data set may leave out (derived from the inputs)."""
        return {name for u in self.delays for name in self.lag_names(u)}


class OutputDelays:
    """The delayed outputs of a model: ``{output name: delay parameter name or known delay (s)}``.

    Each delayed output is ``y(t_k - tau) = sum_j w(tau / dt - j) y_{k-j}``, ``j = -1 ... M``,
    over the simulated output sequence (the kernel of :class:`InputDelays`; ``j = -1`` is the
    next sample, needed when ``tau < dt``). A known delay is a number; an estimated one the
    name of a declared parameter with finite bounds ``0 <= lower < upper``.
    """

    def __init__(self, delays: Mapping[str, object] | None, sample_time: float | None, parameters,
                 output_names, segment_lengths=()):
        self.delays = dict(delays or {})
        self.sample_time = None if sample_time is None else float(sample_time)
        self.output_names = tuple(output_names)
        self.segment_lengths = tuple(int(n) for n in segment_lengths)
        self.lags: dict[str, int] = {}
        if not self.delays:
            return
        _check_sample_time(self.sample_time, "output")
        by_name = {p.name: p for p in parameters if isinstance(p, Parameter)}
        self.delays = {y: _delay_name(y, tau, "output") for y, tau in self.delays.items()}
        for y, tau in self.delays.items():
            if y not in self.output_names:
                raise ModelError(f"delays names {y!r}, which is not an output of the model ({list(self.output_names)})")
            if isinstance(tau, str):
                if tau not in by_name:
                    raise ModelError(f"the delay of output {y!r} is the parameter {tau!r}, which is not declared")
                self.lags[y] = _lag_count(by_name[tau], self.sample_time)
            else:
                value = float(tau)
                if not (np.isfinite(value) and value >= 0):
                    raise ModelError(f"the known delay of output {y!r} must be a finite number >= 0 (s), got {tau!r}")
                self.lags[y] = _checked_lags(int(np.ceil(value / self.sample_time)) + 2,
                                             f"the known delay of output {y!r}", f"{value:g} s", self.sample_time)
        self._weights = {M: _weight_function(M) for M in set(self.lags.values())}

    def __bool__(self) -> bool:
        return bool(self.delays)

    def __repr__(self) -> str:
        segments = f", segment_lengths={self.segment_lengths!r}" if self.segment_lengths else ""
        return f"OutputDelays({self.delays!r}, sample_time={self.sample_time!r}{segments})"

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The estimated delay parameters, in first-use order."""
        return tuple(dict.fromkeys(t for t in self.delays.values() if isinstance(t, str)))

    def apply(self, Y, theta, parameter_names, blocks: int = 1):
        """The delayed output sequences.

        Parameters
        ----------
        Y : casadi.MX, shape (blocks * n_outputs, N)
            Sequences of the outputs, or of any per-output quantity stacked ``blocks`` times
            (row ``i * n_outputs + c`` belongs to output ``c``).
        theta : casadi.MX, shape (n_parameters, 1)
        parameter_names : sequence of str
            The names of theta's entries.

        Returns
        -------
        casadi.MX
            The same shape, every row of a delayed output convolved with its kernel weights.
        """
        return self._delayed(Y, None, theta, list(parameter_names), blocks)[0]

    def apply_with_jacobian(self, Y, dY, theta, parameter_names):
        """The delayed outputs and their parameter derivatives.

        Parameters
        ----------
        Y : casadi.MX, shape (n_outputs, N)
        dY : casadi.MX, shape (n_parameters * n_outputs, N)
            ``dy_c / dtheta_i`` in row ``i * n_outputs + c``.

        Returns
        -------
        tuple of casadi.MX
            The delayed ``Y`` and its derivatives, including ``dy_c / dtau`` from the kernel's slope.
        """
        names = list(parameter_names)
        return self._delayed(Y, dY, theta, names, len(names))

    def _delayed(self, Y, dY, theta, names: list, blocks: int):
        ny = len(self.output_names)
        rows = ca.vertsplit(Y) if Y.size1() else []
        d_rows = ca.vertsplit(dY) if dY is not None and dY.size1() else []
        for y, tau in self.delays.items():
            c, M = self.output_names.index(y), self.lags[y]
            position = (theta[names.index(tau)] if isinstance(tau, str) else float(tau)) / self.sample_time
            w, dw = self._weights[M](position)
            pieces = self.segment_lengths
            if dY is None:
                for i in range(blocks):
                    rows[i * ny + c] = _convolve(rows[i * ny + c], w, M, pieces)
                continue
            for i in range(blocks):
                d_rows[i * ny + c] = _convolve(d_rows[i * ny + c], w, M, pieces)
            if isinstance(tau, str):  # the kernel's slope: d y(t - tau) / d tau
                k = names.index(tau) * ny + c
                d_rows[k] = d_rows[k] + _convolve(rows[c], dw, M, pieces) / self.sample_time
            rows[c] = _convolve(rows[c], w, M, pieces)
        delayed = ca.vertcat(*rows) if rows else Y
        return delayed, (None if dY is None else (ca.vertcat(*d_rows) if d_rows else dY))


def _check_sample_time(sample_time: float | None, kind: str) -> None:
    if sample_time is None:
        raise ModelError(f"{kind} delays need the record's sampling interval: give sample_time=dt (s) to the "
                         "DynamicModel")
    positive_number(sample_time, "sample_time", error=ModelError, meaning="the record's sampling interval")


def _delay_name(target: str, tau, kind: str) -> str:
    """The delay parameter's name; a CasADi symbol given for it is named in the fix."""
    if isinstance(tau, (ca.SX, ca.MX)):
        name = tau.name() if tau.is_symbolic() else str(tau)
        raise ModelError(f"the delay of {kind} {target!r} is a CasADi expression ({name}); delays map a name to the "
                         f"parameter's name: write delays={{{target!r}: {name!r}}}")
    return tau


def _lag_count(parameter: Parameter, sample_time: float) -> int:
    """The lagged samples a delay parameter needs, from its upper bound: ceil(ub / dt) + 2."""
    lo, hi = parameter.lb, parameter.ub
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ModelError(f"the delay parameter {parameter.name!r} needs finite bounds 0 <= lower < upper (s), got "
                         f"[{lo:g}, {hi:g}]: the upper bound sets how many lagged samples are kept")
    return _checked_lags(int(np.ceil(hi / sample_time)) + 2, f"the delay parameter {parameter.name!r}",
                         f"upper bound {hi:g} s", sample_time)


#: the most lagged samples a delay may need: each is a column of the record and a term of the kernel
MAX_LAGS = 500


def _checked_lags(lags: int, what: str, where: str, sample_time: float) -> int:
    if lags > MAX_LAGS:
        raise ModelError(f"{what} ({where}) needs {lags} lagged samples at sample_time {sample_time:g} s, more than "
                         f"the {MAX_LAGS} casest builds (each is a column of the record and a term of the delay's "
                         f"kernel); bound the delay by what it can physically be, at most "
                         f"{(MAX_LAGS - 2) * sample_time:g} s here")
    return lags


def _weight_function(lags: int) -> ca.Function:
    """``s -> (w, dw/ds)``: the kernel weights of the samples k+1, k, k-1 ... k-lags at a delay of s samples."""
    s = ca.SX.sym("s")
    w = ca.vertcat(*[_keys_weight(s - j) for j in range(-1, lags + 1)])
    return ca.Function("delay_weights", [s], [w, ca.jacobian(w, s)], ["s"], ["w", "dw"])


def _convolve(row, weights, lags: int, pieces=()):
    """``sum_j weights[j + 1] * row shifted by j samples``, j = -1 ... lags, the ends held (row: 1 x N);
    with ``pieces`` (the segments' lengths, summing to N) each segment is convolved alone, its own
    ends held, so that no delayed value reaches across a boundary between manoeuvres."""
    if len(pieces) > 1 and sum(pieces) == row.size2():
        parts = ca.horzsplit(row, list(np.cumsum((0,) + tuple(pieces))))
        return ca.horzcat(*[_convolve(part, weights, lags) for part in parts])
    return sum(weights[j + 1] * _shifted(row, j) for j in range(-1, lags + 1))


def _shifted(row, j: int):
    """``row`` delayed by j samples (j = -1: advanced by one), the first (last) value held at the ends."""
    N = row.size2()
    if j == 0 or N == 1:
        return row
    if j < 0:
        _, tail = ca.horzsplit(row, [0, 1, N])
        _, last = ca.horzsplit(row, [0, N - 1, N])
        return ca.horzcat(tail, last)
    first, _ = ca.horzsplit(row, [0, 1, N])
    if j >= N:
        return ca.repmat(first, 1, N)
    body, _ = ca.horzsplit(row, [0, N - j, N])
    return ca.horzcat(ca.repmat(first, 1, j), body)


def _keys_weight(s):
    """Keys' cubic convolution kernel (a = -1/2) at offset s (samples), as a CasADi expression."""
    a = ca.fabs(s)
    inner = 1.5 * a**3 - 2.5 * a**2 + 1
    outer = -0.5 * a**3 + 2.5 * a**2 - 4 * a + 2
    return ca.if_else(a <= 1, inner, ca.if_else(a < 2, outer, 0))
