"""Matching the user's CasADi symbols to the declared names, and expanding MX and Function
calls into SX (refusing what cannot be differentiated)."""

from __future__ import annotations

from typing import Sequence

import casadi as ca
import numpy as np

from ..checks import with_suggestion
from ..errors import ModelError


__all__ = ["symbolic_expressions"]


def _symbol_names(expr: ca.SX) -> list[str]:
    return [s.name() for s in ca.symvar(expr)]


def symbolic_expressions(outputs: Sequence, declared: Sequence[str]) -> tuple[list[ca.SX], dict[str, ca.SX]]:
    """User expressions (SX, MX, numbers, named Functions) as SX expressions in fresh symbols named ``declared``.

    Symbols are matched by name. Lookup tables (``casadi.interpolant``, linear or B-spline)
    stay calls inside the expressions (CasADi differentiates and compiles them); any other
    Function that cannot be inlined (a ``casadi.integrator``: a simulation over time) raises
    :class:`ModelError` pointing to :class:`casest.DynamicModel`.

    Returns
    -------
    expressions : list of casadi.SX
    symbols : dict of str to casadi.SX
    """
    expressions, symbols = _to_sx(outputs, declared)
    for expr in expressions:
        _refuse_calls(expr, symbols)
    return expressions, symbols


#: the CasADi Function classes an expression may call: lookup tables, evaluated sample by sample
#: with derivatives (a B-spline's are smooth; a linear table's jump at its grid points)
LOOKUP_TABLES = ("LinearInterpolant", "BSplineInterpolant")


def _refuse_calls(expr: ca.SX, symbols: dict) -> None:
    """Raise if an SX expression calls a Function other than a lookup table (``casadi.interpolant``)."""
    args = list(symbols.values())
    f = ca.Function("check", args, [expr]) if args else ca.Function("check", [], [expr])
    if not any(f.instruction_id(k) == ca.OP_CALL for k in range(f.n_instructions())):
        return
    for called in f.find_functions():
        if not _only_lookup_tables(called):
            raise ModelError(
                f"an output calls the CasADi Function {called.name()!r} ({called.class_name()}), which cannot be "
                "written out sample by sample: an integrator is a simulation over time; declare the states and their "
                "ODE with casest.DynamicModel instead. Lookup tables (casadi.interpolant, 'linear' or 'bspline') are "
                "accepted in outputs and right-hand sides"
            )


def _only_lookup_tables(fn: ca.Function) -> bool:
    """A lookup table, or a graph (CasADi's wrapper of a call, say) that calls nothing else."""
    if fn.class_name() in LOOKUP_TABLES:
        return True
    return fn.class_name() in ("MXFunction", "SXFunction") and all(_only_lookup_tables(g) for g in fn.find_functions())


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
    if f.n_out() != 1:
        raise ModelError(
            f"casadi.Function {f.name()!r} given as an output must have one output (a scalar or a vector of "
            f"channels); it has {f.n_out()} outputs of sizes {[f.numel_out(k) for k in range(f.n_out())]}: "
            "give each as its own output"
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
    return _as_sx_function(f)(*args)


def _as_sx_function(f: ca.Function) -> ca.Function:
    """``f`` as an SX function (casest's derivatives need SX), or a ModelError saying why it cannot be."""
    if f.is_a("SXFunction"):
        return f
    try:
        return f.expand()
    except RuntimeError as err:
        raise ModelError(
            f"casadi.Function {f.name()!r} cannot be expanded to SX ({str(err).splitlines()[-1]}); models need "
            "expressions of CasADi operations (a dynamic model with an integrator is not a static model)"
        ) from None


def _raise_unknown(unknown: Sequence[str], declared: Sequence[str]) -> None:
    raise ModelError(
        "the outputs use symbol(s) that are declared neither as Parameter nor as Signal: "
        + ", ".join(with_suggestion(name, declared) for name in unknown)
        + "; add them to `parameters` or `signals`"
    )
