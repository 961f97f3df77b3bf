"""Text passes over the C that CasADi's code generator writes, shared by the compiled loops over a
record (:mod:`casest._casadi.record_loop`) and the C exports (:mod:`casest.export.c_kernel`)."""

from __future__ import annotations

import re

__all__ = ["given_pointers"]

# CasADi's SX kernel reads an argument as `arg[0]? arg[0][3] : 0` and writes `if (res[1]!=0) res[1][2]=a5;`
_TESTED_READ = re.compile(r"\barg\[(\d+)\]\? (arg\[\1\]\[\d+\]) : 0\b")
_TESTED_WRITE = re.compile(r"\bif \(res\[(\d+)\]!=0\) (res\[\1\]\[\d+\]=)")
# each CasADi Function of the file: the entry point and the Functions it calls
_GENERATED_FUNCTION = re.compile(r"^static int casadi_f\d+\(", re.M)


def given_pointers(source: str) -> str:
    """CasADi's SX kernel with its tests of the argument and result pointers dropped:
    ``arg[0]? arg[0][3] : 0`` becomes ``arg[0][3]`` and ``if (res[1]!=0) res[1][2]=a5;``
    ``res[1][2]=a5;``. For a kernel whose caller passes every array (each export's wrapper and
    the record loop do): the tests split the straight-line code into blocks, and across them gcc
    neither pairs ``sin`` and ``cos`` of one value into one ``sincos`` nor keeps values in
    registers. A source holding more than one generated Function is returned unchanged: a
    Function called from another may be given a null pointer for an argument it does not need.

    Parameters
    ----------
    source : str

    Returns
    -------
    str
    """
    if len(_GENERATED_FUNCTION.findall(source)) > 1:
        return source
    return _TESTED_WRITE.sub(r"\2", _TESTED_READ.sub(r"\2", source))
