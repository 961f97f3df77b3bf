"""Sums over samples for many candidates at once: the SIMD C of :mod:`.lane_code`, compiled once
per source into the compile cache and called through ctypes (which releases the GIL, so
threads over candidates run in parallel)."""

from __future__ import annotations

import ctypes
import weakref

import casadi as ca
import numpy as np

from .._casadi.c_library import load_library
from .._casadi.numerics import compiler_available
from .lane_code import lane_source

__all__ = ["LaneSum", "LaneValues"]

_FLAGS = ("-O3", "-march=native", "-shared", "-fPIC", "-fno-math-errno", "-Wl,-z,defs")
#: libmvec's vector functions first, lane by lane through libm if that does not link
_LINKS = (("-lmvec", "-lm"), ("-DCASEST_LANEWISE", "-lm"))
#: per per-sample Function, its loaded kernels by (inputs read per sample, name, summed): a sweep
#: built again on the same model (each estimate) finds its C function without generating and
#: hashing the C text again (milliseconds for a small problem)
_KERNELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class LaneSum:
    """``sum_k f(data_k, candidate)`` for many candidates, one per SIMD lane.

    Built by :meth:`build`; calling it evaluates the sums for M candidates on the data
    given at construction, :attr:`lanes` candidates per vector (8 on a CPU with AVX-512,
    else 4: the compiled library decides). The data are read in place; ctypes releases the GIL, so
    several threads may call one LaneSum on different candidates.
    """

    summed = True

    def __init__(self, function, n_out: int, n_values: int, data: np.ndarray, *, lanes: int):
        # ``lanes`` must be the width the library was compiled for (its ``<name>_lanes()``)
        self._function = function
        self.lanes = lanes
        self.n_out, self.n_values = n_out, n_values
        self._data = np.ascontiguousarray(data, dtype=float)
        self.n_samples = self._data.shape[0]

    @classmethod
    def build(cls, per_sample: ca.Function, data: list[np.ndarray], name: str = "lane_sum",
              cached_only: bool = False) -> "LaneSum | None":
        """The compiled sums of ``per_sample`` over the rows of ``data``, or None.

        Parameters
        ----------
        per_sample : casadi.Function
            SX function of one sample: its first ``len(data)`` inputs take one row of each
            data array, the others a candidate's values; one dense output column.
        data : list of ndarray
            Per-sample arrays, each (N, size of the matching input).
        name : str
            Name of the C function.
        cached_only : bool
            Only a library already compiled (in this process or the compile cache); never compile.

        Returns
        -------
        LaneSum or None
            None without a C compiler, when ``per_sample`` has an operation with no vector
            form (see :func:`~casest.backend.lane_code.lane_source`), compiling fails, or
            ``cached_only`` and it is not compiled yet: the caller keeps its scalar path.
        """
        if not compiler_available():
            return None
        kernel = _kernel(per_sample, len(data), name, cls.summed, cached_only)
        if kernel is None:
            return None
        function, lanes = kernel
        n_values = sum(per_sample.nnz_in(k) for k in range(len(data), per_sample.n_in()))
        columns = [np.asarray(d, dtype=float).reshape(d.shape[0], -1) for d in data]
        return cls(function, per_sample.nnz_out(0), n_values, np.hstack(columns), lanes=lanes)

    @property
    def nbytes(self) -> int:
        """Bytes of the per-sample data this instance holds."""
        return int(self._data.nbytes)

    def on(self, data: list[np.ndarray]) -> "LaneSum":
        """The same compiled sums over other samples (a block of the record, say).

        Parameters
        ----------
        data : list of ndarray
            Per-sample arrays as :meth:`build` takes them, each (N_block, size of its input).

        Returns
        -------
        LaneSum
        """
        columns = [np.asarray(d, dtype=float).reshape(d.shape[0], -1) for d in data]
        return type(self)(self._function, self.n_out, self.n_values, np.hstack(columns), lanes=self.lanes)

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Sums for M candidates.

        Parameters
        ----------
        values : ndarray, shape (M, n_values)
            Each candidate's values (the non-data inputs of ``per_sample``, concatenated).

        Returns
        -------
        ndarray, shape (M, n_out)
        """
        out = self._run(values, (self.n_out,))
        return out.transpose(0, 2, 1).reshape(-1, self.n_out)[: values.shape[0]]

    def _run(self, values: np.ndarray, shape: tuple) -> np.ndarray:
        """The C function on groups of ``lanes`` candidates: out (n_groups, *shape, lanes)."""
        M, width = values.shape[0], self.lanes
        groups = -(-M // width)
        padded = np.empty((groups * width, self.n_values))
        padded[:M] = values
        padded[M:] = values[-1] if M else 0.0  # the last group's spare lanes repeat a candidate
        lanes = np.ascontiguousarray(padded.reshape(groups, width, self.n_values).transpose(0, 2, 1))
        out = np.empty((groups, *shape, width))
        self._function(self._data.ctypes.data, self.n_samples, lanes.ctypes.data, groups, out.ctypes.data)
        return out


class LaneValues(LaneSum):
    """``f(data_k, candidate)`` at every sample for many candidates, one per SIMD lane
    (built by :meth:`LaneSum.build`; the same compiled C without the sum)."""

    summed = False

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Every sample's values for M candidates.

        Parameters
        ----------
        values : ndarray, shape (M, n_values)
            Each candidate's values (the non-data inputs of ``per_sample``, concatenated).

        Returns
        -------
        ndarray, shape (M, N, n_out)
        """
        out = self._run(values, (self.n_samples, self.n_out))
        return out.transpose(0, 3, 1, 2).reshape(-1, self.n_samples, self.n_out)[: values.shape[0]]


def _kernel(per_sample: ca.Function, n_data: int, name: str, summed: bool, cached_only: bool) -> tuple | None:
    """The loaded C function of ``per_sample`` and its lane width, or None (no vector form, a failed
    compile, or ``cached_only`` and not compiled yet); kept per Function: a found kernel, else
    its C text (a later call may find it compiled, or compile it)."""
    kept = _KERNELS.setdefault(per_sample, {})
    key = (n_data, name, summed)
    if isinstance(kept.get(key), tuple):
        return kept[key]
    source = kept[key] if key in kept else lane_source(per_sample, n_data, name, summed=summed)
    kept[key] = source
    if source is None:
        return None
    library = load_library(source, _FLAGS, _LINKS, prefix="lanes_", cached_only=cached_only)
    if library is None:
        return None
    function = getattr(library, name)
    function.restype = None
    function.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p]
    width = getattr(library, name + "_lanes")
    width.restype, width.argtypes = ctypes.c_int, []
    kept[key] = (function, int(width()))
    return kept[key]
