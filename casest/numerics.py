"""Low-level numerics shared by every stage: evaluation of CasADi Functions on NumPy arrays,
C compilation, threads, and the lossless JSON form of arrays.

This module imports nothing else from casest, so that every other module may use it.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import tempfile
import warnings

import casadi as ca
import numpy as np

__all__ = [
    "MIN_SAMPLES_PER_THREAD",
    "available_cores",
    "build_folder",
    "compile_function",
    "compiler_available",
    "decode_array",
    "default_threads",
    "encode_array",
    "evaluate",
]

_JIT_FOLDER: list = []


@contextlib.contextmanager
def build_folder(jit: bool):
    """Run a solver build in a private temporary folder when JIT writes C files there.

    CasADi writes the generated C source and the shared library into the working
    folder and removes them itself when the solver is destroyed, so the folder (one per
    process) stays until then.
    """
    if not jit:
        yield
        return
    if not _JIT_FOLDER:
        _JIT_FOLDER.append(tempfile.mkdtemp(prefix="casest_jit_"))
    previous = os.getcwd()
    os.chdir(_JIT_FOLDER[0])
    try:
        yield
    finally:
        os.chdir(previous)



#: Smallest block of samples worth a thread of its own.
MIN_SAMPLES_PER_THREAD = 2000


def compiler_available() -> bool:
    """True when a C compiler for CasADi's ``shell`` JIT is on the PATH."""
    return bool(shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc"))


def available_cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_threads(n_samples: int) -> int:
    """Threads for sums over ``n_samples``: one per core, one block >= 2000 samples each."""
    return int(max(1, min(available_cores(), n_samples // MIN_SAMPLES_PER_THREAD)))


def compile_function(fun: ca.Function, flags=("-O2",)) -> ca.Function:
    """``fun`` compiled to C by CasADi's shell JIT (in a private temporary folder)."""
    with build_folder(True):
        inputs = [ca.MX.sym(fun.name_in(k), fun.sparsity_in(k)) for k in range(fun.n_in())]
        outputs = fun(*inputs)
        outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
        try:
            return ca.Function(
                fun.name() + "_c", inputs, outputs, fun.name_in(), fun.name_out(),
                {"jit": True, "compiler": "shell", "jit_options": {"flags": list(flags), "verbose": False}},
            )
        except RuntimeError as err:
            warnings.warn(
                f"compiling {fun.name()} to C failed ({str(err).splitlines()[-1][:200]}); using CasADi's "
                "virtual machine instead (slower, same results). Set jit=False to skip the attempt",
                RuntimeWarning,
                stacklevel=2,
            )
            return fun


def evaluate(fun: ca.Function, *args) -> list:
    """Evaluate ``fun`` on NumPy arrays through its buffer interface.

    Converting a large NumPy array to a CasADi matrix costs about 65 ns per element
    (1.2 s for 10^6 samples of 18 columns); the buffer interface reads the arrays in
    place. Each argument is taken column-major (``ndarray.T`` of a sample-by-column
    array is the usual (n_columns x N) input), dense, in the input's full shape.

    Returns
    -------
    list of ndarray
        Every output, dense, with the output's shape (column vectors as 1-D arrays).
    """
    inputs = []
    for k, arg in enumerate(args):
        arr = np.asarray(arg, dtype=float)
        if arr.size != fun.numel_in(k):
            raise ValueError(f"{fun.name()}: input {fun.name_in(k)} needs {fun.numel_in(k)} values, got {arr.size}")
        inputs.append(np.ascontiguousarray(arr.reshape(-1, order="F")))
    outputs = [np.zeros(fun.nnz_out(k)) for k in range(fun.n_out())]
    buffer, run = fun.buffer()
    for k, arr in enumerate(inputs):
        if fun.nnz_in(k) != fun.numel_in(k):
            raise ValueError(f"{fun.name()}: sparse input {fun.name_in(k)} is not supported here")
        buffer.set_arg(k, memoryview(arr))
    for k, arr in enumerate(outputs):
        buffer.set_res(k, memoryview(arr))
    run()
    if buffer.ret() != 0:
        raise RuntimeError(f"evaluating {fun.name()} failed (return code {buffer.ret()})")
    dense = []
    for k, nz in enumerate(outputs):
        sp = fun.sparsity_out(k)
        if sp.is_dense():
            out = nz.reshape(sp.size2(), sp.size1()).T if sp.size2() > 1 else nz
        else:
            out = np.asarray(ca.DM(sp, nz).full())
        dense.append(out)
    return dense



def encode_array(a: np.ndarray) -> dict:
    """Lossless JSON form of an array: shape plus values, non-finite values as strings."""
    a = np.asarray(a)
    flat = []
    for v in a.reshape(-1).tolist():
        if isinstance(v, float) and not math.isfinite(v):
            flat.append("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
        else:
            flat.append(v)
    return {"shape": list(a.shape), "values": flat}


def decode_array(d: dict, dtype=float) -> np.ndarray:
    """Inverse of :func:`encode_array`."""
    values = [float(v) if isinstance(v, str) else v for v in d["values"]]
    return np.array(values, dtype=dtype).reshape(d["shape"])
