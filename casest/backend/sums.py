"""Sums over samples of per-sample functions and their exact derivatives.

The ML cost of Eq. 6 is a sum over samples, and so are its gradient and Hessian. Each is
built here once per model as a small SX function of one sample (exact symbolic
derivatives) and mapped over the N samples with CasADi's map-reduce: the sum is
accumulated inside the map, so no N-long intermediate is stored. With ``jit`` each
block's loop is compiled to C; with ``threads > 1`` the samples are split into equal
blocks evaluated on separate threads.

Two forms take the data. :func:`map_sum` takes them as N-long symbolic inputs, for graphs
that CasADi differentiates; building on them costs time and memory linear in N (CasADi
stores the sparsity pattern of every N-long input: about 1 s per function at N = 10^6).
:func:`bound_sum` keeps them outside the graph, in a :class:`Record` read in place, and
takes only its handle: stage 2's NLP and the covariance are built on it, in the same time
whatever N is; their derivatives are sums of their own, never CasADi's AD of the callback.
"""

from __future__ import annotations

import functools
import itertools
import threading

import casadi as ca
import numpy as np

from .._casadi.numerics import (  # noqa: F401  (re-exported: the sums' public helpers)
    MIN_SAMPLES_PER_THREAD,
    available_cores,
    compile_function,
    compile_library,
    compiler_available,
    default_threads,
)
from .._casadi.evaluation import evaluate  # noqa: F401  (re-exported with the helpers above)
from .._casadi.library_index import indexed_library
from .._casadi.memory import StructureCache
from .._casadi.sample_blocks import evaluate_samples
from ..errors import OptionError
from ..models import Model
from .noise_terms import DIAGONAL, NoiseTerm


__all__ = ["map_sum", "bound_sum", "Record", "data_outside_graph", "BOUND_MIN_SAMPLES", "MLSums", "ml_sums", "per_sample_cost", "residual_jacobian", "prediction_and_jacobian", "compiler_available", "default_threads", "evaluate"]

#: Samples per compiled block of a sum over at least 16 such blocks: the compiled code does
#: not depend on N, so one library serves long records of any length.
SUM_BLOCK = 4096

#: From this many samples the stage-2 NLP and the covariance keep the data outside the graph
#: (:func:`bound_sum`): the build no longer grows with N, and an evaluation reads the data in
#: place (Pitot Hessian sums: 1.2-1.7x faster than the in-graph path from 7833 samples on
#: two threads; equal within noise at 3000-6000). Below it the data are an N-long parameter
#: of the graph, whose build is cheap there, and each evaluation stays in C (the callback's
#: Python round trip, ~70 us, dominated the thousands of evaluations of short NIST records:
#: 1.3x slower at 500-2000 samples, 2-5x on whole multi-start pipelines).
BOUND_MIN_SAMPLES = SUM_BLOCK


def block_size(n_samples: int, threads: int) -> int:
    """Samples per block of a sum: ``SUM_BLOCK`` for long records (from 16 blocks, so that one
    compiled block serves every N; the padding wastes < 1/16), else one block per thread."""
    threads = int(max(1, min(threads, n_samples)))
    return SUM_BLOCK if n_samples >= 16 * SUM_BLOCK else -(-n_samples // threads)


def data_outside_graph(n_samples: int) -> bool:
    """Whether sums over ``n_samples`` take their data as a :class:`Record` (see :data:`BOUND_MIN_SAMPLES`).

    Parameters
    ----------
    n_samples : int
        N.

    Returns
    -------
    bool
    """
    return n_samples >= BOUND_MIN_SAMPLES


def _as_list(out) -> list:
    """A Function call's outputs as a list (one output comes back bare)."""
    return list(out) if isinstance(out, (list, tuple)) else [out]


def map_sum(per_sample: ca.Function, n_samples: int, threads: int = 1, name: str | None = None,
            jit: bool = False, jit_flags=("-O2",), n_data: int = 2, block: int | None = None) -> ca.Function:
    """Map ``per_sample`` over samples and sum its outputs.

    Parameters
    ----------
    per_sample : casadi.Function
        Inputs ``(x, z, *rest)``: one sample's column vectors first (``n_data`` of them),
        then inputs shared by all samples.
    n_samples : int
        N.
    threads : int
        Evaluate the blocks of samples (``SUM_BLOCK`` each from N = 16 ``SUM_BLOCK``, else
        N / threads) on this many threads (1: serial).
    jit : bool
        Compile each block's loop (the map-reduce over its samples, with the per-sample
        function inlined) to C; about 0.1-0.3 s per function.
    n_data : int
        Number of leading per-sample inputs.
    block : int, optional
        Samples per block (default: as for ``threads``). Small blocks suit a large
        uncompiled ``per_sample``: CasADi's map of an SX Function builds in time and memory
        growing with its length (0.27 s and 90 MB at 1500 samples of a 20 000-instruction body).

    Returns
    -------
    casadi.Function
        ``(X[n_x x N], Z[n_z x N], *rest) -> sums``, each output of ``per_sample`` summed
        over the N samples (same shape and sparsity).
    """
    name = name or per_sample.name() + "_sum"
    shared = list(range(n_data, per_sample.n_in()))
    all_out = list(range(per_sample.n_out()))
    data = [ca.MX.sym(per_sample.name_in(k) + "_all", per_sample.size1_in(k), n_samples) for k in range(n_data)]
    rest = [ca.MX.sym(per_sample.name_in(k), per_sample.sparsity_in(k)) for k in shared]

    def summed(count: int, label: str) -> ca.Function:
        loop = per_sample.map(f"{name}_{label}", "serial", count, shared, all_out)
        return compile_function(loop, jit_flags) if jit else loop

    threads = int(max(1, min(threads, n_samples)))
    size = block_size(n_samples, threads) if block is None else int(max(1, min(block, n_samples)))
    if size == n_samples:
        return ca.Function(name, data + rest, _as_list(summed(n_samples, "all")(*(data + rest))))
    return ca.Function(name, data + rest, _sums_over_blocks(per_sample, summed(size, "block"), data, rest, threads,
                                                            f"{name}_blocks"))


def _sums_over_blocks(per_sample: ca.Function, block: ca.Function, data: list, rest: list, threads: int,
                      name: str) -> list:
    """The sums of ``block`` (a loop over a block of samples) mapped over equal blocks of the data.

    The data are padded with copies of the last sample, whose extra terms are subtracted
    afterwards (one sample, evaluated once).
    """
    n_samples, size, n_data = data[0].size2(), block.size2_in(0), len(data)
    n_blocks = -(-n_samples // size)
    pad = n_blocks * size - n_samples
    # horzsplit keeps only offsets; indexing d[:, a:b] would store N-long index vectors
    last = [ca.horzsplit(d, [0, n_samples - 1, n_samples])[1] for d in data]
    padded = [ca.horzcat(d, ca.repmat(e, 1, pad)) for d, e in zip(data, last)] if pad else data
    parallel = ("thread", {"max_num_threads": threads}) if threads > 1 else ("serial", {})
    outer = block.map(name, parallel[0], n_blocks, list(range(n_data, block.n_in())), list(range(block.n_out())),
                      parallel[1])
    sums = _as_list(outer(*(padded + rest)))
    if pad:
        extra = _as_list(per_sample(*(last + rest)))
        sums = [a - pad * b for a, b in zip(sums, extra)]
    return sums


# ----------------------------------------------------------------------------- data outside the graph
_RECORDS: dict = {}
_HANDLES = itertools.count(1)  # next() is atomic under the GIL: unique handles across threads
#: every bound-sum callback made in this process: CasADi keeps only a raw pointer to a
#: Python callback, so it must outlive every Function that calls it (they are few and small)
_CALLBACKS: list = []


class Record:
    """A record's per-sample data, held outside CasADi graphs for :func:`bound_sum`.

    A bound sum takes the record's handle (a number) where :func:`map_sum` takes the N-long
    data, so the graphs, the NLP built on them and their memory do not grow with N. The
    blocks are handed to the compiled code in place (no copy), sample-major arrays having
    the memory layout of CasADi's column-major (rows x samples) blocks.

    Parameters
    ----------
    *arrays : ndarray, each shape (N, n_rows_i)
        The per-sample data, one row per sample, in the order the per-sample function takes
        them (e.g. the signals and the outputs).


    Examples
    --------
    >>> with Record(data.signals, data.outputs) as record:      # doctest: +SKIP
    ...     value = summed(record.handle, w)
    """

    def __init__(self, *arrays: np.ndarray):
        self.arrays = [np.ascontiguousarray(a, dtype=float) for a in arrays]
        sizes = {a.shape[0] for a in self.arrays}
        if len(sizes) != 1 or any(a.ndim != 2 for a in self.arrays):
            raise OptionError("a record needs 2-D arrays with one row per sample and the same number of rows, got "
                             f"shapes {[a.shape for a in self.arrays]}")
        self.n_samples = sizes.pop()
        self.handle = float(next(_HANDLES))
        self._layouts: dict = {}

    def __enter__(self) -> "Record":
        _RECORDS[self.handle] = self
        return self

    def __exit__(self, *exc) -> None:
        _RECORDS.pop(self.handle, None)

    def layout(self, size: int, per_call: int) -> tuple[list, list, list, int]:
        """The record cut for a sum over blocks of ``size`` samples, ``per_call`` blocks per call.

        Returns the calls (each a list of arrays, one per input, ``per_call * size`` samples),
        the single blocks left over, the last sample's arrays and the number of padding
        samples (copies of the last sample that fill the last block).

        Parameters
        ----------
        size : int
            Samples per block.
        per_call : int
            Blocks per call.

        Returns
        -------
        calls : list
        single : list
        last : list
        padding : int
        """
        key = (size, per_call)
        if key not in self._layouts:
            N = self.n_samples
            n_blocks = -(-N // size)
            pad = n_blocks * size - N
            last = [a[N - 1:N] for a in self.arrays]

            def samples(start: int, stop: int) -> list:
                if stop <= N:
                    return [a[start:stop] for a in self.arrays]  # views: rows of a C-ordered array
                return [np.vstack([a[start:N], np.repeat(e, stop - N, axis=0)]) for a, e in zip(self.arrays, last)]

            width = size * per_call
            n_calls = n_blocks // per_call
            calls = [samples(k * width, (k + 1) * width) for k in range(n_calls)]
            singles = [samples(b * size, (b + 1) * size) for b in range(n_calls * per_call, n_blocks)]
            self._layouts[key] = (calls, singles, last, pad)
        return self._layouts[key]


def bound_record(handle) -> Record:
    """The record bound under ``handle`` (see :class:`Record`)."""
    try:
        return _RECORDS[float(handle)]
    except KeyError:
        raise OptionError(f"no record is bound under handle {float(handle):g}: evaluate this function inside "
                         "`with Record(...) as record:` and pass record.handle") from None


class _BoundSum(ca.Callback):
    """``(record handle, *shared) -> sums`` over the record's samples (see :func:`bound_sum`)."""

    def __init__(self, name: str, per_sample: ca.Function, n_samples: int, threads: int, jit: bool, jit_flags,
                 n_data: int):
        ca.Callback.__init__(self)
        self.per_sample, self.n_data = per_sample, n_data
        shared = list(range(n_data, per_sample.n_in()))
        all_out = list(range(per_sample.n_out()))
        threads = int(max(1, min(threads, n_samples)))
        self.size = block_size(n_samples, threads)  # the same blocks as map_sum

        def block():
            return per_sample.map(f"{name}_block", "serial", self.size, shared, all_out)

        # only evaluated (the callback gives no derivatives): a library loaded without CasADi's JIT,
        # found by the per-sample function and block size without building the block's map
        self.block = (indexed_library(f"bound_sum {name} {self.size} {n_data}\n{per_sample.serialize()}", block,
                                      jit_flags) if jit else block())
        self.threads = threads
        if threads > 1:
            self.threaded = self.block.map(f"{name}_threads", "thread", threads, list(range(n_data, self.block.n_in())),
                                           all_out, {"max_num_threads": threads})
        else:
            self.threaded = self.block
        self._buffers: dict = {}
        # the last evaluation: IPOPT asks the cost, gradient and Hessian at the same point, and
        # each of them starts from the same sums (reduced mode's normal equations)
        self._last = None
        self.construct(name, {})
        _CALLBACKS.append(self)

    def get_n_in(self):
        return 1 + self.per_sample.n_in() - self.n_data

    def get_n_out(self):
        return self.per_sample.n_out()

    def get_name_in(self, i):
        return "record" if i == 0 else self.per_sample.name_in(self.n_data + i - 1)

    def get_name_out(self, i):
        return self.per_sample.name_out(i)

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(1, 1) if i == 0 else self.per_sample.sparsity_in(self.n_data + i - 1)

    def get_sparsity_out(self, i):
        return self.per_sample.sparsity_out(i)

    def _buffer(self, function: ca.Function):
        """The function's evaluation buffer and its output arrays, one per thread (made once)."""
        key = (function.name(), threading.get_ident())
        if key not in self._buffers:
            buffer, run = function.buffer()
            outs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
            for i, out in enumerate(outs):
                buffer.set_res(i, memoryview(out))
            self._buffers[key] = (buffer, run, outs)
        return self._buffers[key]

    def eval(self, args):
        shared = [np.array(a.nonzeros(), dtype=float) for a in args[1:]]
        # a handle is never reused, and nothing writes a record's arrays while it is bound
        key = (float(args[0]),) + tuple(v.tobytes() for v in shared)
        last = self._last
        if last is not None and last[0] == key:
            return [ca.DM(self.per_sample.sparsity_out(i), total) for i, total in enumerate(last[1])]
        totals = self._sums(bound_record(args[0]), shared)
        self._last = (key, totals)
        return [ca.DM(self.per_sample.sparsity_out(i), total) for i, total in enumerate(totals)]

    def _add_calls(self, function: ca.Function, pieces: list, shared: list, totals: list) -> None:
        """Add ``function``'s outputs on each piece of the record (its data columns) to ``totals``."""
        buffer, run, outs = self._buffer(function)
        for k, value in enumerate(shared):
            buffer.set_arg(self.n_data + k, memoryview(value))
        for arrays in pieces:
            for k, arr in enumerate(arrays):
                buffer.set_arg(k, memoryview(arr))
            run()
            for total, out in zip(totals, outs):
                total += out

    def _sums(self, record, shared: list) -> list:
        """The per-sample outputs summed over the record, as arrays."""
        calls, singles, last, pad = record.layout(self.size, self.threads)
        totals = [np.zeros(self.per_sample.nnz_out(i)) for i in range(self.per_sample.n_out())]
        for function, pieces in ((self.threaded, calls), (self.block, singles)):
            if pieces:
                self._add_calls(function, pieces, shared, totals)
        if pad:
            buffer, run, outs = self._buffer(self.per_sample)
            for k, arr in enumerate(list(last) + shared):
                buffer.set_arg(k, memoryview(arr))
            run()
            for total, out in zip(totals, outs):
                total -= pad * out
        return totals


def bound_sum(per_sample: ca.Function, n_samples: int, threads: int = 1, name: str | None = None,
              jit: bool = False, jit_flags=("-O2",), n_data: int = 2) -> ca.Function:
    """:func:`map_sum` with the data outside the graph: ``(record handle, *shared) -> sums``.

    The same compiled blocks and padding as :func:`map_sum`, evaluated by a callback on the
    columns of the :class:`Record` bound under the handle. No N-long symbol enters the graph,
    so building functions and NLPs on it takes the same time whatever N is (CasADi spends
    about 1 s per N-long input at N = 10^6). Not differentiable by CasADi: give derivatives
    as sums of their own (as :class:`MLSums` does).

    Parameters
    ----------
    per_sample, n_samples, threads, name, jit, jit_flags, n_data
        As in :func:`map_sum`; ``n_samples`` sets the block size (the record's N must give
        the same blocks to reuse the compiled code, any N is evaluated correctly).

    Returns
    -------
    casadi.Function
        ``(record, *shared) -> sums``, ``record`` a scalar handle (:attr:`Record.handle`).
    """
    name = name or per_sample.name() + "_sum"
    callback = _BoundSum(name + "_bound", per_sample, n_samples, threads, jit, jit_flags, n_data)
    args = [ca.MX.sym("record")] + [ca.MX.sym(per_sample.name_in(k), per_sample.sparsity_in(k))
                                    for k in range(n_data, per_sample.n_in())]
    out = callback(*args)
    out = list(out) if isinstance(out, (list, tuple)) else [out]
    return ca.Function(name, args, out, [callback.get_name_in(i) for i in range(len(args))],
                       [per_sample.name_out(i) for i in range(len(out))])


class MLSums:
    """The ML cost J/N of Eq. 6, its gradient and its Hessian as sums over samples.

    Decision vector ``w = [s; rho]`` with ``theta = scale * s`` (physical parameters
    scaled to order one) and ``rho = ln R``. Every function takes ``(w, X, Z)`` with the
    signals ``X`` (n_signals x N) and outputs ``Z`` (n_outputs x N), or with ``bound``
    ``(w, record)``, the handle of a :class:`Record` of (X, Z).

    Attributes
    ----------
    cost : casadi.Function
        ``(w, X, Z) -> J/N``.
    gradient : casadi.Function
        ``(w, X, Z) -> (J/N, dJ/dw / N)``.
    hessian : casadi.Function
        ``(w, X, Z) -> triu(d2J/dw2) / N`` (upper triangle, sparse).
    per_sample_cost : casadi.Function
        ``(x, z, w) -> f``: one sample's term of J (SX), the function the sums map.
    """

    def __init__(self, model: Model, n_samples: int, scale: np.ndarray, threads: int = 1, jit: bool = False,
                 jit_flags=("-O2",), masked: bool = False, noise: NoiseTerm = DIAGONAL, bound: bool = False):
        self.n_samples = N = n_samples
        self.bound = bound
        ny = model.n_outputs
        f_i, g_i, h_i = _per_sample_functions(model, tuple(np.asarray(scale, dtype=float)), masked, noise)
        w = ca.MX.sym("w", model.n_parameters + noise.block_size(ny))
        if bound:  # the data outside the graph: one scalar handle
            data = [ca.MX.sym("record")]
            summed = bound_sum
        else:
            data = [ca.MX.sym("X", model.n_signals, N), ca.MX.sym("Z", 2 * ny if masked else ny, N)]
            summed = map_sum
        names = ["w"] + [d.name() for d in data]
        cost = summed(f_i, N, threads, "ml_cost_sum", jit, jit_flags)(*data, w)
        self.per_sample_cost = f_i
        self.cost = ca.Function("ml_cost", [w] + data, [cost / N], names, ["f"])
        # the derivatives' sums are built when first asked: a cost alone (Problem.cost) does not need them
        self._build = (summed, g_i, h_i, w, data, names, threads, jit, jit_flags)

    @functools.cached_property
    def gradient(self) -> ca.Function:
        """``(w, X, Z) -> (J/N, dJ/dw / N)`` (built on first use)."""
        summed, g_i, _, w, data, names, threads, jit, jit_flags = self._build
        value, grad = summed(g_i, self.n_samples, threads, "ml_grad_sum", jit, jit_flags)(*data, w)
        return ca.Function("ml_gradient", [w] + data, [value / self.n_samples, grad / self.n_samples], names,
                           ["f", "g"])

    @functools.cached_property
    def hessian(self) -> ca.Function:
        """``(w, X, Z) -> triu(d2J/dw2) / N`` (built on first use)."""
        summed, _, h_i, w, data, names, threads, jit, jit_flags = self._build
        hess = summed(h_i, self.n_samples, threads, "ml_hess_sum", jit, jit_flags)(*data, w)
        return ca.Function("ml_hessian", [w] + data, [hess / self.n_samples], names, ["H"])


def symmetric(triu: ca.MX) -> ca.MX:
    """The full symmetric matrix from its upper triangle."""
    return triu + triu.T - ca.diag(ca.diag(triu))


_PER_SAMPLE = StructureCache()


def _per_sample_functions(model: Model, scale: tuple, masked: bool = False, noise: NoiseTerm = DIAGONAL):
    """One sample's ML cost, (cost, gradient) and triu(Hessian) in w = [s; noise block]; cached per model.

    The noise block and its share of the cost are the ``noise`` term's (:mod:`casest.backend.noise_terms`).
    ``masked``: the sample's data are ``[z; m]`` with m = 1 for a measured output, 0 for a
    missing one; a missing output adds neither its residual nor its ln R_j (so each channel's
    ln R_j counts its own N_j).
    """
    key = (scale, masked, noise)
    cache = _PER_SAMPLE.setdefault(model, {})
    if key not in cache:
        if masked and not noise.takes_mask:
            raise ValueError(f"the {type(noise).__name__} noise term needs complete data (no observation mask)")
        ny, n = model.n_outputs, model.n_parameters
        s = ca.SX.sym("s", n)
        block = ca.SX.sym("noise", noise.block_size(ny))
        w = ca.vertcat(s, block)
        z = ca.SX.sym("z", 2 * ny if masked else ny)
        h = ca.substitute(model.h, model.theta, s * ca.DM(np.asarray(scale)))
        f = noise.sample_cost(z[:ny] - h, block, z[ny:] if masked else None)
        names, prefix = ["x", "z", "w"], noise.name
        f_i = ca.Function(f"{prefix}_cost_i", [model.x, z, w], [f], names, ["f"])
        g_i = ca.Function(f"{prefix}_grad_i", [model.x, z, w], [f, ca.gradient(f, w)], names, ["f", "g"])
        h_i = ca.Function(f"{prefix}_hess_i", [model.x, z, w], [ca.triu(ca.hessian(f, w)[0])], names, ["H"])
        cache[key] = (f_i, g_i, h_i)
    return cache[key]


def per_sample_cost(model: Model, masked: bool = False, noise: NoiseTerm = DIAGONAL) -> ca.Function:
    """One sample's term of J, ``(x, z, w) -> f`` with ``w = [theta; noise block]`` (physical theta).

    The noise block is the ``noise`` term's: ``ln R`` (:data:`DIAGONAL`) or the log-Cholesky
    vector of a full R (:data:`CHOLESKY`). The function every sum of this module maps.

    Parameters
    ----------
    model : Model
    masked : bool
        z is ``[z; m]``, m the observation mask.
    noise : NoiseTerm

    Returns
    -------
    casadi.Function
    """
    return _per_sample_functions(model, tuple(np.ones(model.n_parameters)), masked, noise)[0]


_SUMS = StructureCache()


def ml_sums(model: Model, n_samples: int, scale=None, threads: int | None = None, jit: bool = False,
            jit_flags=("-O2",), masked: bool = False, noise: NoiseTerm = DIAGONAL, bound: bool = False) -> MLSums:
    """Cached :class:`MLSums` for (model, N, scale, threads, jit).

    Parameters
    ----------
    scale : array_like, shape (n_parameters,), optional
        Parameter scales (default ``model.scales``; pass ones for physical theta).
    threads : int, optional
        Default :func:`default_threads`.
    masked : bool
        The data carry an observation mask (missing outputs), see :func:`_per_sample_functions`.
    noise : NoiseTerm
        R's parametrisation (:mod:`casest.backend.noise_terms`; default diagonal).
    bound : bool
        The data outside the graph: the functions take ``(w, record)``, a :class:`Record`'s
        handle, instead of ``(w, X, Z)`` (:func:`bound_sum`).

    Returns
    -------
    MLSums
        Shared by every caller with the same arguments.
    """
    scale = tuple(np.asarray(model.scales if scale is None else scale, dtype=float))
    threads = default_threads(n_samples) if threads is None else int(threads)
    key = (n_samples, scale, threads, bool(jit), tuple(jit_flags), bool(masked), noise, bool(bound))
    cache = _SUMS.setdefault(model, {})
    if key not in cache:
        cache[key] = MLSums(model, n_samples, np.array(scale), threads, jit, jit_flags, masked, noise, bound)
    return cache[key]


def prediction_and_jacobian(model: Model, signals: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """h and d h / d theta at every sample, sample-major (the rows of one sample together).

    Parameters
    ----------
    signals : ndarray, shape (N, n_signals)
    theta : ndarray, shape (n_parameters,)

    Returns
    -------
    h : ndarray, shape (N * n_outputs,)
    J : ndarray, shape (N * n_outputs, n_parameters)
    """
    h, J = evaluate_samples(model.jacobian_function, [signals], [theta])
    ny, n = model.n_outputs, model.n_parameters
    # each sample's Jacobian (ny x n) is stored column-major
    return h.reshape(-1), J.reshape(-1, n, ny).transpose(0, 2, 1).reshape(-1, n)


def residual_jacobian(model: Model, data, theta: np.ndarray) -> np.ndarray:
    """d h / d theta for all samples.

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : ndarray, shape (n_parameters,)
        Physical units.

    Returns
    -------
    ndarray, shape (N n_outputs, n_parameters)
        Rows sample-major.
    """
    return prediction_and_jacobian(model, data.signals, theta)[1]
