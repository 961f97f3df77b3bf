"""CasADi's generated C made fit for a flight computer's build: renamed after the export's
prefix, every parameter used (``-Wextra``), every truth value of a number an explicit comparison
(clang's ``-Wfloat-conversion``: CasADi writes ``(a0?a1:0)``, ``(!a0)``, ``(a0&&a1)``), the
kernel's tests of its array pointers dropped (the wrappers pass every one), and, in single
precision, every literal a float and every libm call its float form (no double arithmetic).
"""

from __future__ import annotations

import re

import casadi as ca

from .._casadi.generated_text import given_pointers
from .c_files import quiet_unused_parameters

#: the comment line before the code CasADi generated in an export's source (:mod:`casest.export.misra`)
KERNEL_MARK = "/* the step as CasADi's code generator wrote it */"

__all__ = ["KERNEL_MARK", "generated_c", "in_single_precision", "explicit_truth_values", "FLOAT_FUNCTIONS"]

# CasADi's SX code names its numbers a0, a1, ...; its MX code w0, w1, ... (with spaces around `!`)
_TRUTH_OPERAND = re.compile(r"\(([aw]\d+)\?")
_TRUTH_NOT = re.compile(r"\(! ?([aw]\d+) ?\)")
_TRUTH_LOGIC = re.compile(r"\(([aw]\d+)(&&|\|\|)([aw]\d+)\)")
# INFINITY and NAN are floats: in double code each use is a promotion (-Wdouble-promotion)
_FLOAT_CONSTANT = re.compile(r"(#define casadi_(?:inf|nan)) (INFINITY|NAN)$", re.M)


def explicit_truth_values(source: str) -> str:
    """CasADi's C with every number used as a truth value compared with zero: ``(a0?`` becomes
    ``((a0!=0)?``, ``(!a0)`` ``(a0==0)``, ``(a0&&a1)`` ``((a0!=0)&&(a1!=0))`` (MX code's
    ``w0`` alike): the same values, without the implicit float-to-bool conversion clang warns
    of; ``casadi_inf`` and ``casadi_nan`` cast to ``casadi_real`` (INFINITY and NAN are floats:
    each use in double code was a promotion).

    Parameters
    ----------
    source : str

    Returns
    -------
    str
    """
    source = _FLOAT_CONSTANT.sub(r"\1 ((casadi_real)\2)", source)
    source = _TRUTH_OPERAND.sub(r"((\1!=0)?", source)
    source = _TRUTH_NOT.sub(r"(\1==0)", source)
    return _TRUTH_LOGIC.sub(r"((\1!=0)\2(\3!=0))", source)


def generated_c(step: ca.Function, name: str, real: str = "double", includes: str = "") -> str:
    """CasADi's C for a step Function, renamed ``NAME_sample``, after ``#include "NAME.h"``.

    Parameters
    ----------
    step : casadi.Function
        An SX Function.
    name : str
        The C prefix.
    real : {"double", "float"}
        The C type of every number.
    includes : str
        ``#include`` lines the code after it needs, placed at the top (MISRA C rule 20.1).

    Returns
    -------
    str
        C99 text needing libm only (no heap: CasADi's work arrays are the caller's; every argument
        and result pointer must be given, :func:`given_pointers`), compiling
        without a warning under ``-Wall -Wextra -Wpedantic -Wshadow -Wconversion
        -Wdouble-promotion`` (gcc and clang).
    """
    renamed = ca.Function(f"{name}_sample", step.sx_in(), step.call(step.sx_in()), step.name_in(), step.name_out())
    generator = ca.CodeGenerator(f"{name}_sample", {"with_header": False, "with_mem": False, "main": False,
                                                   "casadi_real": real, "casadi_int": "long long"})
    generator.add(renamed)
    text = explicit_truth_values(given_pointers(quiet_unused_parameters(generator.dump())))
    return f'#include "{name}.h"\n' + includes + KERNEL_MARK + "\n" + (in_single_precision(text) if real == "float" else text)


#: libm's double functions CasADi writes, and their float forms
FLOAT_FUNCTIONS = {f: f + "f" for f in ("sqrt", "log", "exp", "sin", "cos", "tan", "fabs", "pow", "atan2", "tanh",
                                        "atan", "asin", "acos", "sinh", "cosh", "log10", "erf", "floor", "ceil",
                                        "fmin", "fmax", "fmod", "log1p", "expm1", "asinh", "acosh", "atanh")}
_FLOAT_LITERAL = re.compile(r"(?<![\w.])((?:\d+\.\d*|\.\d+)(?:[eE][+-]?\d+)?|\d+[eE][+-]?\d+)(?![\w.])")
_DOUBLE_CALL = re.compile(r"\b(" + "|".join(sorted(FLOAT_FUNCTIONS, key=len, reverse=True)) + r")\(")


def in_single_precision(source: str) -> str:
    """CasADi's C with every floating literal a float (``2.f``; magnitudes below 1e-37 or above
    3e38 brought inside float's range) and every libm call its float form (``sqrtf``), so that
    single precision computes in float throughout (a double literal or call promotes the
    expression to double: on a Cortex-M4F a software operation).

    Parameters
    ----------
    source : str

    Returns
    -------
    str
    """
    return _DOUBLE_CALL.sub(lambda m: FLOAT_FUNCTIONS[m.group(1)] + "(", _FLOAT_LITERAL.sub(_float_literal, source))


def _float_literal(match: re.Match) -> str:
    """A double literal as a float one; magnitudes float cannot hold are brought to its range (a
    guard such as ``1e-300`` against a zero divisor would otherwise round to zero and guard nothing)."""
    value = abs(float(match.group(1)))
    if 0.0 < value < 1e-37:
        return "1e-37f"
    if value > 3e38:
        return "3e38f"
    return match.group(1) + "f"
