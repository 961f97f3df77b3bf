"""Time delays of a dynamic model's inputs as estimated parameters (fractional, by interpolation).

An input ``u`` delayed by the parameter ``tau`` enters the model as ``u(t - tau)``, built
from the sampled record by cubic convolution (Keys' kernel with a = -1/2, the Catmull-Rom
spline through the four nearest samples)::

    u(t_k - tau) = sum_j w(tau / dt - j) u_{k-j},   j = 0 ... M
    w(s) = 1.5|s|^3 - 2.5|s|^2 + 1 (|s| <= 1),  -0.5|s|^3 + 2.5|s|^2 - 4|s| + 2 (1 < |s| < 2),  0 else

with ``dt`` the model's declared ``sample_time`` and ``M = ceil(tau_max / dt) + 2`` from the
upper bound of ``tau``. The interpolation error falls with dt^3 and the cost is continuously
differentiable in ``tau`` (linear interpolation would attenuate the delayed input between
samples and bias ``tau`` by several std on long records). The lagged samples ``u@1 ... u@M`` are extra input columns that
:meth:`DynamicModel.dataset` (and the CSV and MATLAB readers) derive from ``u`` itself, so
the data need only ``u``. Because ``tau`` enters the right-hand side, it is a parameter of
the dynamics: the sweep, the sensitivities and both stage-2 solvers treat it like any other.

Limits (documented): the record must be sampled uniformly at ``sample_time``; between
samples the delayed input follows the model's input hold of the interpolated samples (exact
for a delay of whole samples); the second derivative in ``tau`` jumps at whole samples; the
first samples see the record's first value held (the input before the record is unknown);
lags do not stop at the boundaries between manoeuvres.
"""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from ..errors import ModelError
from .priors import Parameter, Signal

__all__ = ["InputDelays"]


class InputDelays:
    """The delayed inputs of a model: ``{input name: delay parameter name}`` at a sample time (s)."""

    def __init__(self, delays: Mapping[str, str] | None, sample_time: float | None, parameters, inputs):
        self.delays = dict(delays or {})
        self.sample_time = None if sample_time is None else float(sample_time)
        self.lags: dict[str, int] = {}
        if not self.delays:
            return
        if self.sample_time is None or not np.isfinite(self.sample_time) or self.sample_time <= 0:
            raise ModelError("input delays need the record's sampling interval: give sample_time=dt (s) to the "
                             "DynamicModel")
        by_name = {p.name: p for p in parameters if isinstance(p, Parameter)}
        input_names = [s.name if isinstance(s, Signal) else str(s) for s in inputs]
        for u, tau in self.delays.items():
            if u not in input_names:
                raise ModelError(f"delays names {u!r}, which is not an input of the model ({input_names})")
            if tau not in by_name:
                raise ModelError(f"the delay of {u!r} is the parameter {tau!r}, which is not declared")
            lo, hi = by_name[tau].lb, by_name[tau].ub
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
                raise ModelError(f"the delay parameter {tau!r} needs finite bounds 0 <= lower < upper (s), got "
                                 f"[{lo:g}, {hi:g}]: the upper bound sets how many lagged samples are kept")
            self.lags[u] = int(np.ceil(hi / self.sample_time)) + 2

    def lag_names(self, u: str) -> list[str]:
        """The names of the lagged samples of input ``u``: ``u@1 ... u@M``."""
        return [f"{u}@{j}" for j in range(1, self.lags.get(u, 0) + 1)]

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
                samples = [symbols[u]] + [ca.SX.sym(name) for name in self.lag_names(u)]
                position = tau_sym / self.sample_time
                delayed = sum(_keys_weight(position - j) * s for j, s in enumerate(samples))
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
            for j, name in enumerate(self.lag_names(u), start=1):
                if name not in out:
                    out[name] = np.concatenate([np.full(min(j, base.size), base[0] if base.size else 0.0),
                                                base[:max(base.size - j, 0)]])
        return out

    def derived_columns(self) -> set:
        """The column names a data set may leave out (derived from the inputs)."""
        return {name for u in self.delays for name in self.lag_names(u)}


def _keys_weight(s):
    """Keys' cubic convolution kernel (a = -1/2) at offset s (samples), as a CasADi expression."""
    a = ca.fabs(s)
    inner = 1.5 * a**3 - 2.5 * a**2 + 1
    outer = -0.5 * a**3 + 2.5 * a**2 - 4 * a + 2
    return ca.if_else(a <= 1, inner, ca.if_else(a < 2, outer, 0))
