"""Symbolic measurement models: parameters, signals, outputs.

A :class:`Model` holds the measurement equation ``z_k = h(x_k, u_k, xi) + v_k`` of
paper Eq. (3), written by the user in CasADi. Symbols are matched to the declared
parameters and signals *by name*, so a model file simply creates ``casadi.SX.sym``
(or ``MX.sym``) symbols and lists them.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..errors import ModelError
from .declarations import Declarations
from .priors import Parameter, Signal
from .symbols import symbolic_expressions


__all__ = ["Model"]


class Model(Declarations):
    """A static measurement model ``z = h(signals, parameters) + v``.

    Parameters
    ----------
    parameters : sequence of Parameter
        The unknowns xi, in the order used for every vector of parameter values.
    signals : sequence of Signal or str
        Known per-sample states and inputs (x_k, u_k).
    outputs : mapping of str to CasADi expression
        One expression per measured channel, in terms of symbols whose names are the
        parameter and signal names. MX is accepted and expanded to SX. A vector (or matrix)
        expression, or a Function with one, is as many channels ``name_0, name_1, ...``
        (column-major), each with the entry's unit.
    name : str
        Label used in reports.
    output_units : mapping of str to str, optional
        Unit of each output channel (for reports and CSV headers, and so that a CSV column
        given in another unit is converted or refused).
    require_all_parameters : bool
        Refuse parameters that appear in no output (default). False for the output
        equation of a :class:`casest.DynamicModel`, whose other parameters act through the
        states (which may then have no parameters at all: a model for state estimation).

    Attributes
    ----------
    theta : casadi.SX, shape (n_parameters, 1)
    x : casadi.SX, shape (n_signals, 1)
    h : casadi.SX, shape (n_outputs, 1)
    function : casadi.Function
        ``h(signals[n_signals], theta[n_parameters]) -> z[n_outputs]``, one sample.

    Raises
    ------
    ModelError
        Duplicate names, ``lb > ub``, a nominal value outside its bounds, a symbol that
        is not declared, a parameter that appears in no output, a non-scalar output.
    """

    def __init__(
        self,
        parameters: Sequence[Parameter],
        signals: Sequence[Signal | str],
        outputs: Mapping[str, object],
        name: str = "model",
        output_units: Mapping[str, str] | None = None,
        require_all_parameters: bool = True,
    ):
        self.name = str(name)
        self.parameters: tuple[Parameter, ...] = tuple(parameters)
        self.signals: tuple[Signal, ...] = tuple(
            Signal(s) if isinstance(s, str) else s for s in signals
        )
        if not isinstance(outputs, Mapping) or not outputs:
            raise ModelError("outputs must be a non-empty mapping {channel name: expression}")
        channels = [str(k) for k in outputs]
        units = dict(output_units or {})
        unknown_units = [k for k in units if k not in channels]
        if unknown_units:
            raise ModelError(f"output_units names {unknown_units}, which are not outputs {channels}")
        declared = [p.name for p in self.parameters] + [sg.name for sg in self.signals]
        sx_outputs, symbols = symbolic_expressions(list(outputs.values()), declared)
        self.output_names, self.output_units, sx_outputs = _channels(channels, sx_outputs, units)
        self._require_all_parameters = bool(require_all_parameters)
        self._check_declarations()
        self.theta = ca.vertcat(*[symbols[p.name] for p in self.parameters])
        self.x = ca.vertcat(*[symbols[s.name] for s in self.signals]) if self.signals else ca.SX(0, 1)
        # common sub-expressions shared once: outputs written channel by channel often
        # repeat the same trigonometry (the Pitot model halves its operation count)
        self.h = ca.cse(ca.vertcat(*sx_outputs))

        unused = [p.name for p in self.parameters if not ca.depends_on(self.h, symbols[p.name])]
        if unused and require_all_parameters:
            raise ModelError(
                f"parameter(s) {unused} appear in no output, so the data cannot determine them; "
                "remove them from `parameters` or use them in the outputs"
            )
        self.function = ca.Function(
            "h", [self.x, self.theta], [self.h], ["signals", "theta"], ["z"]
        )
        self._jacobian_function = None

    # -- declarations -------------------------------------------------------------------
    def _check_declarations(self) -> None:
        seen: dict[str, str] = {}
        for kind, names in (
            ("parameter", [p.name for p in self.parameters]),
            ("signal", [s.name for s in self.signals]),
            ("output", list(self.output_names)),
        ):
            for n in names:
                if not isinstance(n, str) or not n:
                    raise ModelError(f"{kind} names must be non-empty strings, got {n!r}")
                key = n if kind != "output" else "out:" + n
                if key in seen:
                    raise ModelError(
                        f"duplicate name {n!r} (declared as {seen[key]} and as {kind}); "
                        "names must be unique"
                    )
                seen[key] = kind
        if not self.parameters and self._require_all_parameters:
            raise ModelError("a model needs at least one Parameter")
        for p in self.parameters:
            if not isinstance(p, Parameter):
                raise ModelError(f"parameters must be Parameter objects, got {p!r}")
            if math.isnan(p.lb) or math.isnan(p.ub) or p.lb > p.ub:
                raise ModelError(
                    f"parameter {p.name!r}: lower bound {p.lb} > upper bound {p.ub}; swap them"
                )
            if not (p.lb <= p.nominal <= p.ub):
                raise ModelError(
                    f"parameter {p.name!r}: nominal value {p.nominal} lies outside its bounds "
                    f"[{p.lb}, {p.ub}]"
                )
            if p.scale is not None and not (np.isfinite(p.scale) and p.scale > 0):
                raise ModelError(f"parameter {p.name!r}: scale must be finite and > 0")
            p.sampling_prior.check(p.name, p.lb, p.ub)

    # -- convenience --------------------------------------------------------------------
    @property
    def structure_key(self) -> str:
        """A hash of the model's expressions and declarations: objects with the same key share
        casest's built functions and solvers (a fresh ``model()`` reuses the first one's)."""
        if getattr(self, "_structure_key", None) is None:
            import hashlib

            text = "\0".join([self.function.serialize(), repr(self.parameters), repr(self.signals),
                               repr(self.output_names), repr(getattr(self, "output_units", None)), self.name])
            self._structure_key = hashlib.sha256(text.encode()).hexdigest()
        return self._structure_key

    def with_fixed(self, values: Mapping[str, float]) -> "Model":
        """The model with some parameters held at given values (substituted symbolically).

        Parameters
        ----------
        values : mapping of str to float
            Parameter name -> value (physical unit), each inside the parameter's bounds.

        Returns
        -------
        Model
            The other parameters, in the same order, and the same signals and outputs.

        Raises
        ------
        ModelError
            An unknown name, a non-finite value or one outside the bounds, every parameter
            fixed, or a parameter left in no output by the substitution.
        """
        values = dict(values)
        self.index(list(values))
        for name, value in values.items():
            p = self.parameters[self.parameter_names.index(name)]
            if not np.isfinite(value) or not p.lb <= value <= p.ub:
                raise ModelError(f"fixed value {name} = {value} must be finite and inside [{p.lb}, {p.ub}]")
        keep = [p for p in self.parameters if p.name not in values]
        if not keep:
            raise ModelError("every parameter is fixed: nothing is left to estimate")
        symbols = ca.vertcat(*[self.theta[self.parameter_names.index(n)] for n in values])
        h = ca.substitute(self.h, symbols, ca.DM([float(v) for v in values.values()]))
        outputs = {name: h[j] for j, name in enumerate(self.output_names)}
        return Model(keep, self.signals, outputs, name=self.name,
                     output_units=dict(zip(self.output_names, self.output_units)),
                     require_all_parameters=self._require_all_parameters)

    def with_bounds(self, bounds: Mapping[str, tuple]) -> "Model":
        """The model with other bounds on some parameters (nominal values clipped into them).

        Parameters
        ----------
        bounds : mapping of str to (float, float)
            Parameter name -> (lower, upper), physical units.

        Returns
        -------
        Model
            The same parameters, signals and outputs.

        Raises
        ------
        ModelError
            An unknown name or a lower bound above the upper one.
        """
        bounds = dict(bounds)
        self.index(list(bounds))
        params = []
        for p in self.parameters:
            if p.name not in bounds:
                params.append(p)
                continue
            lb, ub = (float(v) for v in bounds[p.name])
            if not lb <= ub:
                raise ModelError(f"bounds of {p.name}: the lower bound {lb} is above the upper one {ub}")
            params.append(replace(p, lb=lb, ub=ub, nominal=float(np.clip(p.nominal, lb, ub))))
        outputs = {name: self.h[j] for j, name in enumerate(self.output_names)}
        return Model(params, self.signals, outputs, name=self.name,
                     output_units=dict(zip(self.output_names, self.output_units)),
                     require_all_parameters=self._require_all_parameters)

    def with_output_weights(self, weights) -> "Model":
        """The model with each output multiplied by a weight (shape (n_outputs,)); same parameters.

        Multiplying outputs and data by ``1 / std`` turns a weighted least squares into an
        unweighted one (stage 1 with known noise).

        Parameters
        ----------
        weights : array_like, shape (n_outputs,)

        Returns
        -------
        Model
        """
        weights = np.asarray(weights, dtype=float).reshape(-1)
        h = self.h * ca.DM(weights)
        return Model(self.parameters, self.signals, {n: h[j] for j, n in enumerate(self.output_names)}, name=self.name)

    @property
    def jacobian_function(self) -> ca.Function:
        """``(signals, theta) -> (z[n_outputs], dz/dtheta[n_outputs x n_parameters])``, one sample.

        Differentiated once per model and reused by stage 1, the covariance, the filters.
        """
        if self._jacobian_function is None:
            self._jacobian_function = ca.Function(
                "h_jac", [self.x, self.theta], [self.h, ca.jacobian(self.h, self.theta)],
                ["signals", "theta"], ["z", "dz_dtheta"],
            )
        return self._jacobian_function

    def predict(self, theta, signals: np.ndarray) -> np.ndarray:
        """Evaluate h for many samples.

        Parameters
        ----------
        theta : mapping or array, shape (n_parameters,)
        signals : ndarray, shape (N, n_signals)

        Returns
        -------
        ndarray, shape (N, n_outputs)
        """
        from .._casadi.sample_blocks import evaluate_samples

        theta = self.vector(theta)
        signals = np.asarray(signals, dtype=float).reshape(-1, self.n_signals)
        (z,) = evaluate_samples(self.function, [signals], [theta])
        return z

    def __repr__(self) -> str:
        return (
            f"Model({self.name!r}, parameters={list(self.parameter_names)}, "
            f"signals={list(self.signal_names)}, outputs={list(self.output_names)})"
        )


def _channels(channels: list, expressions: list, units: dict) -> tuple:
    """Channel names, units and scalar expressions: a vector-valued output ``v`` becomes the
    channels ``v_0, v_1, ...`` (column-major), as vector symbols are named."""
    names, unit_list, flat = [], [], []
    for channel, expr in zip(channels, expressions):
        entries = ca.vertsplit(ca.vec(expr)) if expr.numel() != 1 else [expr]
        if not entries:
            raise ModelError(f"output {channel!r} is empty (shape {expr.shape}); give it an expression")
        names += [channel] if len(entries) == 1 and expr.numel() == 1 else [f"{channel}_{i}" for i in range(len(entries))]
        unit_list += [str(units.get(channel, ""))] * len(entries)
        flat += entries
    return tuple(names), tuple(unit_list), flat
