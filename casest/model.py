"""Symbolic measurement models: parameters, signals, outputs.

A :class:`Model` holds the measurement equation ``z_k = h(x_k, u_k, xi) + v_k`` of
paper Eq. (3), written by the user in CasADi. Symbols are matched to the declared
parameters and signals *by name*, so a model file simply creates ``casadi.SX.sym``
(or ``MX.sym``) symbols and lists them.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from .errors import ModelError, OptionError

__all__ = [
    "Uniform",
    "LogUniform",
    "Gaussian",
    "Parameter",
    "Signal",
    "Model",
    "ModelError",
]


# ----------------------------------------------------------------------------- priors
def _ndtr(x):
    from scipy import special  # scipy is imported on first use: `import casest` stays fast

    return special.ndtr(x)


def _ndtri(q):
    from scipy import special

    return special.ndtri(q)


@dataclass(frozen=True)
class Uniform:
    """Uniform sampling prior on the parameter's box ``[lb, ub]`` (both must be finite)."""

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Quantile function on ``[lb, ub]``; ``u`` in [0, 1], any shape."""
        return lb + (ub - lb) * np.asarray(u, dtype=float)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1]."""
        return (np.asarray(x, dtype=float) - lb) / (ub - lb)

    def check(self, name: str, lb: float, ub: float) -> None:
        if not (np.isfinite(lb) and np.isfinite(ub)):
            raise ModelError(
                f"parameter {name!r}: a Uniform prior needs finite bounds, got [{lb}, {ub}]; "
                "give lb and ub, or use Gaussian(mean, std)"
            )

    def spread(self, lb: float, ub: float) -> float:
        return (ub - lb) / math.sqrt(12.0)

    def finite_support(self, lb: float, ub: float) -> bool:
        return True


@dataclass(frozen=True)
class LogUniform:
    """Log-uniform prior on ``[lb, ub]`` with ``0 < lb < ub`` (or ``lb < ub < 0``, mirrored)."""

    def check(self, name: str, lb: float, ub: float) -> None:
        if not (np.isfinite(lb) and np.isfinite(ub)) or lb * ub <= 0 or lb == ub:
            raise ModelError(
                f"parameter {name!r}: a LogUniform prior needs finite bounds of one sign, "
                f"not containing 0, got [{lb}, {ub}]"
            )

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        sign = 1.0 if lb > 0 else -1.0
        log_lb, log_ub = np.log(abs(lb)), np.log(abs(ub))
        return sign * np.exp(log_lb + (log_ub - log_lb) * u)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1]."""
        log_lb, log_ub = np.log(abs(lb)), np.log(abs(ub))
        return (np.log(np.abs(np.asarray(x, dtype=float))) - log_lb) / (log_ub - log_lb)

    def spread(self, lb: float, ub: float) -> float:
        """Typical magnitude: the geometric mean of the bounds' magnitudes."""
        return math.sqrt(abs(lb * ub))

    def finite_support(self, lb: float, ub: float) -> bool:
        return True


@dataclass(frozen=True)
class Gaussian:
    """Gaussian prior N(mean, std**2), truncated to the parameter's box (paper Sec. III).

    Parameters
    ----------
    mean : float
        Mean, in the parameter's unit.
    std : float
        Standard deviation (> 0), in the parameter's unit.
    """

    mean: float = 0.0
    std: float = 1.0

    def check(self, name: str, lb: float, ub: float) -> None:
        if not (np.isfinite(self.mean) and np.isfinite(self.std) and self.std > 0):
            raise ModelError(f"parameter {name!r}: Gaussian prior needs a finite mean and std > 0")
        cdf_lo, cdf_hi = self._cdf_box(lb, ub)
        if cdf_hi - cdf_lo < 1e-12:
            raise ModelError(
                f"parameter {name!r}: Gaussian({self.mean}, {self.std}) has no probability "
                f"mass inside the bounds [{lb}, {ub}]; move the mean or widen the bounds"
            )

    def _cdf_box(self, lb: float, ub: float) -> tuple[float, float]:
        lo = _ndtr((lb - self.mean) / self.std) if np.isfinite(lb) else 0.0
        hi = _ndtr((ub - self.mean) / self.std) if np.isfinite(ub) else 1.0
        return float(lo), float(hi)

    def cdf(self, x: np.ndarray, lb: float, ub: float) -> np.ndarray:
        """Inverse of :meth:`ppf`: position in [0, 1] of the truncated distribution."""
        lo, hi = self._cdf_box(lb, ub)
        return (_ndtr((np.asarray(x, dtype=float) - self.mean) / self.std) - lo) / (hi - lo)

    def ppf(self, u: np.ndarray, lb: float, ub: float) -> np.ndarray:
        lo, hi = self._cdf_box(lb, ub)
        q = lo + (hi - lo) * np.asarray(u, dtype=float)
        values = self.mean + self.std * _ndtri(np.clip(q, 1e-300, 1 - 1e-16))
        return np.clip(values, lb, ub)

    def spread(self, lb: float, ub: float) -> float:
        return self.std

    def finite_support(self, lb: float, ub: float) -> bool:
        return bool(np.isfinite(lb) and np.isfinite(ub))


# ----------------------------------------------------------------------------- declarations
@dataclass(frozen=True)
class Parameter:
    """An unknown static parameter (an element of xi).

    Parameters
    ----------
    name : str
        Name of the CasADi symbol that stands for it in the model's outputs.
    lb, ub : float
        Box constraint, physical unit (``-inf``/``inf`` for none).
    nominal : float, optional
        Prior best guess; used as a start where stage 1 gives none. Default: the mean of
        a Gaussian prior, the geometric mean of a log-uniform box, the midpoint of a
        finite box, else 0 (moved into a half-open box).
    prior : Uniform, LogUniform or Gaussian, optional
        Distribution from which stage 1 draws candidates (truncated to ``[lb, ub]``).
        Default: ``Uniform()`` when both bounds are finite, otherwise
        ``Gaussian(nominal, max(1, |nominal|))``.
    unit : str
        Unit label for reports and CSV headers.
    scale : float, optional
        Typical magnitude; the NLP works with ``theta / scale``. Default from the prior.
    fixed : bool
        Hold the parameter at ``nominal`` instead of estimating it (it drops out of every
        stage; see ``casest.estimate(fixed=...)`` to fix values without editing the model).
    """

    name: str
    lb: float = -math.inf
    ub: float = math.inf
    nominal: float | None = None
    prior: Uniform | LogUniform | Gaussian | None = None
    unit: str = ""
    scale: float | None = None
    fixed: bool = False

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ModelError(f"a parameter name must be a non-empty string, got {self.name!r}")
        if self.nominal is None:
            object.__setattr__(self, "nominal", self._default_nominal())
        for field_name, default in (("lb", "-inf"), ("ub", "inf"), ("nominal", None)):
            value = getattr(self, field_name)
            label = {"lb": "lower bound", "ub": "upper bound", "nominal": "nominal value"}[field_name]
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ModelError(
                    f"parameter {self.name!r}: {label} {value!r} is a {type(value).__name__}, not a number"
                    + (f"; write {field_name}=float({value!r})" if isinstance(value, str) else "")
                )
            if math.isnan(value):
                raise ModelError(
                    f"parameter {self.name!r}: {label} is NaN"
                    + (f"; use {default} for no bound" if default else "; give a finite value inside the bounds")
                )
        if math.isinf(self.nominal):
            raise ModelError(f"parameter {self.name!r}: nominal value {self.nominal} must be finite")

    def _default_nominal(self):
        """The nominal value of a declaration without one (see ``nominal``); bad bounds pass through."""
        lb, ub = self.lb, self.ub
        if not all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in (lb, ub)) \
                or math.isnan(lb) or math.isnan(ub):
            return 0.0  # the bound checks below name the problem
        if isinstance(self.prior, Gaussian):
            return float(min(max(self.prior.mean, lb), ub))
        if isinstance(self.prior, LogUniform) and np.isfinite(lb) and np.isfinite(ub) and lb * ub > 0:
            return float(math.copysign(math.sqrt(lb * ub), lb))
        if np.isfinite(lb) and np.isfinite(ub):
            return 0.5 * (lb + ub)
        return float(min(max(0.0, lb), ub))

    @property
    def sampling_prior(self) -> Uniform | LogUniform | Gaussian:
        """The prior used for sampling, with the documented default filled in."""
        if self.prior is not None:
            return self.prior
        if np.isfinite(self.lb) and np.isfinite(self.ub):
            return Uniform()
        return Gaussian(self.nominal, max(1.0, abs(self.nominal)))

    @property
    def typical_scale(self) -> float:
        """Magnitude used to scale the NLP unknown (user ``scale``, else prior spread)."""
        if self.scale is not None:
            return float(self.scale)
        spread = self.sampling_prior.spread(self.lb, self.ub)
        return float(max(spread, abs(self.nominal), 1e-8)) if np.isfinite(spread) else 1.0


@dataclass(frozen=True)
class Signal:
    """A known per-sample quantity (a state x_k or an input u_k).

    Parameters
    ----------
    name : str
        Name of the CasADi symbol and of the data column.
    unit : str
        Unit label.
    """

    name: str
    unit: str = ""


def _symbol_names(expr: ca.SX) -> list[str]:
    return [s.name() for s in ca.symvar(expr)]


def symbolic_expressions(outputs: Sequence, declared: Sequence[str]) -> tuple[list[ca.SX], dict[str, ca.SX]]:
    """User expressions (SX, MX, numbers, named Functions) as SX expressions in fresh symbols named ``declared``.

    Symbols are matched by name. A simulation over time (a ``casadi.integrator``, a
    ``mapaccum``) inside an expression raises :class:`ModelError` pointing to
    :class:`casest.DynamicModel`.

    Returns
    -------
    expressions : list of casadi.SX
    symbols : dict of str to casadi.SX
    """
    expressions, symbols = _to_sx(outputs, declared)
    for expr in expressions:
        _refuse_calls(expr, symbols)
    return expressions, symbols


def _refuse_calls(expr: ca.SX, symbols: dict) -> None:
    """Raise if an SX expression still calls a Function (one that could not be inlined)."""
    args = list(symbols.values())
    f = ca.Function("check", args, [expr]) if args else ca.Function("check", [], [expr])
    for k in range(f.n_instructions()):
        if f.instruction_id(k) == ca.OP_CALL:
            raise ModelError(
                "an output calls a CasADi Function that cannot be written out sample by sample (an integrator or a "
                "mapaccum: a simulation over time). A static Model evaluates h(x, theta) at each sample on its own; "
                "declare the states and their ODE with casest.DynamicModel instead"
            )


def _to_sx(outputs: Sequence, declared: Sequence[str]) -> tuple[list[ca.SX], dict[str, ca.SX]]:
    """Turn user outputs (SX, MX, numbers) into SX expressions in fresh named symbols."""
    symbols: dict[str, ca.SX] = {name: ca.SX.sym(name) for name in declared}
    sx_outputs: list[ca.SX] = []
    for expr in outputs:
        if isinstance(expr, (int, float, np.floating, np.integer)):
            sx_outputs.append(ca.SX(float(expr)))
            continue
        if isinstance(expr, ca.DM):
            sx_outputs.append(ca.SX(expr))
            continue
        if isinstance(expr, ca.Function):
            sx_outputs.append(_call_function_output(expr, symbols, declared))
            continue
        if not isinstance(expr, (ca.SX, ca.MX)):
            raise ModelError(
                f"an output is a {type(expr).__name__}; write it as a CasADi SX or MX expression "
                "(or a casadi.Function whose inputs are named after declared symbols)"
            )
        prims = ca.symvar(expr)
        f = ca.Function("user_output", prims, [expr])
        if isinstance(expr, ca.MX):
            f = f.expand()
        if prims:
            sx_outputs.append(f(*[_declared_symbol(p.name(), p.sparsity(), symbols, declared) for p in prims]))
        else:
            sx_outputs.append(ca.SX(f.call([])[0]))
    return sx_outputs, symbols


def _declared_symbol(name: str, sparsity: ca.Sparsity, symbols: dict, declared: Sequence[str]) -> ca.SX:
    """The SX standing for a user symbol: a declared scalar, or a vector of declared elements.

    A vector symbol ``m`` of n elements (MX or SX) stands for the declared names ``m_0 ..
    m_{n-1}`` (the names CasADi gives the elements of ``SX.sym('m', n)``).
    """
    if sparsity.numel() == 1:
        if name not in symbols:
            _raise_unknown([name], declared)
        return symbols[name]
    elements = [f"{name}_{k}" for k in range(sparsity.numel())]
    missing = [e for e in elements if e not in symbols]
    if missing:
        raise ModelError(
            f"the vector symbol {name!r} ({sparsity.size1()} x {sparsity.size2()}) is used, so its elements "
            f"{elements} must be declared as Parameters or Signals; missing: {missing}"
        )
    return ca.reshape(ca.vertcat(*[symbols[e] for e in elements]), sparsity.size1(), sparsity.size2())


def _call_function_output(f: ca.Function, symbols: dict, declared: Sequence[str]) -> ca.SX:
    """A casadi.Function given as an output, called on the declared symbols its inputs are named after."""
    if f.n_out() != 1 or f.numel_out(0) != 1:
        raise ModelError(
            f"casadi.Function {f.name()!r} given as an output must have one scalar output; it has "
            f"{f.n_out()} output(s) of sizes {[f.numel_out(k) for k in range(f.n_out())]}"
        )
    names = [f.name_in(k) for k in range(f.n_in())]
    unknown = [n for n in names if n not in symbols and f"{n}_0" not in symbols]
    if unknown:
        raise ModelError(
            f"casadi.Function {f.name()!r} given as an output has inputs {names}, and {unknown} are not declared "
            "parameters or signals; name its inputs after them, e.g. ca.Function('h', [a, eta], [expr], "
            "['a', 'eta'], ['z']), or pass the expression itself"
        )
    args = [_declared_symbol(n, f.sparsity_in(k), symbols, declared) for k, n in enumerate(names)]
    try:
        call = f if f.is_a("SXFunction") else f.expand()  # casest's derivatives need SX
    except RuntimeError as err:
        raise ModelError(
            f"casadi.Function {f.name()!r} cannot be expanded to SX ({str(err).splitlines()[-1]}); models need "
            "expressions of CasADi operations (a dynamic model with an integrator is not a static model)"
        ) from None
    return call(*args)


def _raise_unknown(unknown: Sequence[str], declared: Sequence[str]) -> None:
    hints = []
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=1)
        hints.append(f"{name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    raise ModelError(
        "the outputs use symbol(s) that are declared neither as Parameter nor as Signal: "
        + ", ".join(hints)
        + "; add them to `parameters` or `signals`"
    )


class Model:
    """A static measurement model ``z = h(signals, parameters) + v``.

    Parameters
    ----------
    parameters : sequence of Parameter
        The unknowns xi, in the order used for every vector of parameter values.
    signals : sequence of Signal or str
        Known per-sample states and inputs (x_k, u_k).
    outputs : mapping of str to CasADi expression
        One scalar expression per measured channel, in terms of symbols whose names are
        the parameter and signal names. MX is accepted and expanded to SX.
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
        self.output_names: tuple[str, ...] = tuple(str(k) for k in outputs)
        units = dict(output_units or {})
        unknown_units = [k for k in units if k not in self.output_names]
        if unknown_units:
            raise ModelError(f"output_units names {unknown_units}, which are not outputs {list(self.output_names)}")
        self.output_units: tuple[str, ...] = tuple(str(units.get(k, "")) for k in self.output_names)
        self._require_all_parameters = bool(require_all_parameters)
        self._check_declarations()

        declared = self.parameter_names + self.signal_names
        exprs = []
        for channel, expr in outputs.items():
            if isinstance(expr, (ca.SX, ca.MX, ca.DM)) and expr.numel() != 1:
                raise ModelError(
                    f"output {channel!r} has shape {expr.shape}; each output must be scalar. "
                    "Give vector outputs as separate channels, e.g. {'z_0': e[0], 'z_1': e[1]}"
                )
            exprs.append(expr)
        sx_outputs, symbols = symbolic_expressions(exprs, declared)
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
        self._predict_maps: dict = {}  # N -> h mapped over N samples (a few kept)

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
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def signal_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.signals)

    @property
    def n_parameters(self) -> int:
        return len(self.parameters)

    @property
    def n_signals(self) -> int:
        return len(self.signals)

    @property
    def n_outputs(self) -> int:
        return len(self.output_names)

    @property
    def lower_bounds(self) -> np.ndarray:
        """Lower bounds, shape (n_parameters,)."""
        return np.array([p.lb for p in self.parameters], dtype=float)

    @property
    def upper_bounds(self) -> np.ndarray:
        """Upper bounds, shape (n_parameters,)."""
        return np.array([p.ub for p in self.parameters], dtype=float)

    @property
    def nominal(self) -> np.ndarray:
        """Nominal values, shape (n_parameters,)."""
        return np.array([p.nominal for p in self.parameters], dtype=float)

    @property
    def scales(self) -> np.ndarray:
        """Typical magnitudes used to scale the NLP, shape (n_parameters,)."""
        return np.array([p.typical_scale for p in self.parameters], dtype=float)

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

    def index(self, names: Sequence[str] | str) -> list[int]:
        """Positions of parameter names; raises with a suggestion for unknown names."""
        if isinstance(names, str):
            names = [names]
        out = []
        for n in names:
            if n not in self.parameter_names:
                close = difflib.get_close_matches(str(n), self.parameter_names, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ModelError(
                    f"unknown parameter {n!r}{hint}; the model's parameters are "
                    f"{list(self.parameter_names)}"
                )
            out.append(self.parameter_names.index(n))
        return out

    def vector(self, values: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        """Parameter values as a vector of shape (n_parameters,) in model order.

        A mapping must name every parameter; unknown names raise :class:`ModelError`.
        """
        if isinstance(values, Mapping):
            self.index(list(values))
            missing = [n for n in self.parameter_names if n not in values]
            if missing:
                raise ModelError(f"values for parameter(s) {missing} are missing")
            return np.array([float(values[n]) for n in self.parameter_names])
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.size != self.n_parameters:
            raise ModelError(
                f"expected {self.n_parameters} parameter values "
                f"{list(self.parameter_names)}, got {arr.size}"
            )
        return arr

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

    def gaussian_prior_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """Means and precisions (1/std^2) of the parameters' Gaussian priors, shape (n_parameters,) each.

        Parameters without a Gaussian prior get precision 0. Used when the priors enter the
        cost as penalties ``(theta - mean)^2 / (2 std^2)`` (MAP estimation).
        """
        means = np.array([p.prior.mean if isinstance(p.prior, Gaussian) else 0.0 for p in self.parameters])
        precisions = np.array([1.0 / p.prior.std**2 if isinstance(p.prior, Gaussian) else 0.0 for p in self.parameters])
        return means, precisions

    def with_output_weights(self, weights) -> "Model":
        """The model with each output multiplied by a weight (shape (n_outputs,)); same parameters.

        Multiplying outputs and data by ``1 / std`` turns a weighted least squares into an
        unweighted one (stage 1 with known noise).
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
        from .numerics import evaluate

        theta = self.vector(theta)
        signals = np.asarray(signals, dtype=float).reshape(-1, self.n_signals)
        n = signals.shape[0]
        if n not in self._predict_maps:
            if len(self._predict_maps) >= 4:
                self._predict_maps.pop(next(iter(self._predict_maps)))
            self._predict_maps[n] = self.function.map(f"h_{n}", "serial", n, [1], [])
        (z,) = evaluate(self._predict_maps[n], signals.T, theta)
        return z.reshape(self.n_outputs, n).T

    def __repr__(self) -> str:
        return (
            f"Model({self.name!r}, parameters={list(self.parameter_names)}, "
            f"signals={list(self.signal_names)}, outputs={list(self.output_names)})"
        )
