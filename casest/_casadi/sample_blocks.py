"""A per-sample CasADi function evaluated over a record in blocks of a fixed number of samples.

Building a ``map`` over a whole record costs time in proportion to its length (5-11 ms at
N = 7833 for the Pitot model's h and its Jacobian, 150 ms at N = 1e5), and a map is built for
every record length a process meets. Here one map of ``BLOCK`` samples per function is
built once and run block after block on the record's rows in place (sample-major arrays
have the memory layout of CasADi's column-major ``rows x samples`` blocks); a record
shorter than a block gets a map of its own length.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import casadi as ca
import numpy as np

from .memory import register_memory_cache

__all__ = ["BLOCK", "evaluate_samples"]

#: samples per call of the mapped function
BLOCK = 1024

_MAPS: OrderedDict = OrderedDict()  # (id(fun), size, n_shared) -> (fun, map): the function held, so its id stays its own
_LOCK = threading.Lock()  # the sweep's threads share the maps
register_memory_cache(_MAPS.clear)


def _dense_outputs(fun: ca.Function) -> ca.Function:
    """``fun`` with every output dense (a sparse Jacobian's structural zeros written as zeros)."""
    if all(fun.sparsity_out(k).is_dense() for k in range(fun.n_out())):
        return fun
    inputs = fun.sx_in() if fun.is_a("SXFunction") else fun.mx_in()
    outputs = fun(*inputs)
    outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
    return ca.Function(fun.name() + "_dense", inputs, [ca.densify(o) for o in outputs], fun.name_in(), fun.name_out())


def _block_map(fun: ca.Function, size: int, n_shared: int) -> ca.Function:
    key = (id(fun), size, n_shared)
    with _LOCK:
        if key in _MAPS:
            _MAPS.move_to_end(key)
            return _MAPS[key][1]
        dense = _dense_outputs(fun)
        shared = list(range(fun.n_in() - n_shared, fun.n_in()))
        mapped = dense.map(f"{fun.name()}_blocks", "serial", size, shared, [])
        _MAPS[key] = (fun, mapped)
        while len(_MAPS) > 64:
            _MAPS.popitem(last=False)
        return mapped


def evaluate_samples(fun: ca.Function, samples, shared=()) -> list:
    """``fun`` at every sample of a record, the per-sample inputs read in place.

    Parameters
    ----------
    fun : casadi.Function
        ``(per-sample inputs..., shared inputs...) -> outputs``: each per-sample input a column of
        the sample's values, each shared input the same for all samples.
    samples : sequence of ndarray, each shape (N, n_rows_i)
        The per-sample inputs, one row per sample.
    shared : sequence of array_like
        The shared inputs (for example theta), each with ``fun``'s input's number of values.

    Returns
    -------
    list of ndarray, each shape (N, numel_out_k)
        Every output at every sample, one row per sample: the output's entries in column-major
        order, dense.
    """
    samples = [np.ascontiguousarray(a, dtype=float).reshape(a.shape[0], -1) for a in samples]
    shared = [np.ascontiguousarray(np.asarray(v, dtype=float).reshape(-1, order="F")) for v in shared]
    n_data, N = len(samples), samples[0].shape[0]
    for k, arr in enumerate(samples + shared):
        if not fun.sparsity_in(k).is_dense():
            raise ValueError(f"{fun.name()}: sparse input {fun.name_in(k)} is not supported here")
        expected = fun.numel_in(k) * (N if k < n_data else 1)
        if arr.size != expected:
            raise ValueError(f"{fun.name()}: input {fun.name_in(k)} needs {expected} values, got {arr.size}")
    outputs = [np.empty((N, fun.numel_out(k))) for k in range(fun.n_out())]
    if N == 0:
        return outputs
    size = min(N, BLOCK)
    buffer, run = _block_map(fun, size, len(shared)).buffer()
    for k, value in enumerate(shared):
        buffer.set_arg(n_data + k, memoryview(value))
    for start in range(0, N, size):
        stop = min(start + size, N)
        if stop - start == size:
            ins = [a[start:stop] for a in samples]
            outs = [o[start:stop] for o in outputs]
        else:  # the last, shorter block: padded with its last sample, the padding's outputs dropped
            ins = [np.concatenate([a[start:stop], np.repeat(a[stop - 1:stop], size - (stop - start), axis=0)])
                   for a in samples]
            outs = [np.empty((size, o.shape[1])) for o in outputs]
        for k, arr in enumerate(ins):
            buffer.set_arg(k, memoryview(arr))
        for k, arr in enumerate(outs):
            buffer.set_res(k, memoryview(arr))
        run()
        if buffer.ret() != 0:
            raise RuntimeError(f"evaluating {fun.name()} failed (return code {buffer.ret()})")
        if stop - start != size:
            for o, part in zip(outputs, outs):
                o[start:stop] = part[:stop - start]
    return outputs
