"""Evaluation of CasADi Functions on NumPy arrays in place, through their buffers."""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["evaluate"]


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
    return [_dense(fun.sparsity_out(k), nz) for k, nz in enumerate(outputs)]


def _dense(sparsity: ca.Sparsity, nonzeros: np.ndarray) -> np.ndarray:
    """An output's nonzeros as a dense array of its shape (a column vector as 1-D)."""
    if not sparsity.is_dense():
        return np.asarray(ca.DM(sparsity, nonzeros).full())
    return nonzeros.reshape(sparsity.size2(), sparsity.size1()).T if sparsity.size2() > 1 else nonzeros
