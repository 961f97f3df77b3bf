"""Sums over samples for many candidates at once: the SIMD C of :mod:`.lane_code`, compiled once
per source into the compile cache and called through ctypes (which releases the GIL, so
threads over candidates run in parallel)."""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading

import casadi as ca
import numpy as np

from .._casadi.ccache import file_digest
from .._casadi.ccache import valid as valid_entry
from .._casadi.numerics import (LOADED_LIBRARIES, c_compiler, cache_dir, cache_usable, compiler_available, compiler_id,
                                record_compile)
from .lane_code import LANES, lane_source

__all__ = ["LaneSum", "LaneValues"]

_FLAGS = ("-O3", "-march=native", "-shared", "-fPIC", "-fno-math-errno", "-Wl,-z,defs")
_LOCK = threading.Lock()


def _build(source: str, folder: str, stem: str) -> str | None:
    """Compile ``source`` into ``folder/stem.so`` (written under a temporary name, then renamed);
    with libmvec's vector functions first, lane by lane through libm if that does not link."""
    cc = c_compiler()
    with tempfile.TemporaryDirectory(prefix="casest_lanes_") as work:
        c_path, so_tmp = os.path.join(work, stem + ".c"), os.path.join(work, stem + ".so")
        with open(c_path, "w", encoding="utf-8") as fh:
            fh.write(source)
        for extra in (["-lmvec", "-lm"], ["-DCASEST_LANEWISE", "-lm"]):
            # libraries after the source: -Wl,-z,defs refuses a library with unresolved names
            command = [cc, *_FLAGS, c_path, "-o", so_tmp, *extra]
            try:
                done = subprocess.run(command, capture_output=True, text=True, timeout=600)
            except (OSError, subprocess.SubprocessError):
                return None
            if done.returncode == 0:
                break
        else:
            return None
        os.makedirs(folder, exist_ok=True)
        target = os.path.join(folder, stem + ".so")
        handle, staged = tempfile.mkstemp(prefix=stem, suffix=".so.part", dir=folder)
        os.close(handle)
        shutil.copyfile(so_tmp, staged)
        handle, digest = tempfile.mkstemp(prefix=stem, suffix=".sha256.part", dir=folder)
        with os.fdopen(handle, "w", encoding="ascii") as fh:  # the entry's digest: loaded only when it matches
            fh.write(file_digest(staged))
        os.replace(staged, target)
        os.replace(digest, os.path.join(folder, stem + ".sha256"))
        return target


def _library(source: str) -> ctypes.CDLL | None:
    """The loaded library of ``source``: from this process, the compile cache, or compiled now."""
    cc = c_compiler()
    key = hashlib.sha256("\0".join([source, " ".join(_FLAGS), compiler_id(cc)]).encode()).hexdigest()
    with _LOCK:
        if key in LOADED_LIBRARIES:
            return LOADED_LIBRARIES[key]
        folder = cache_dir() if cache_usable() else tempfile.mkdtemp(prefix="casest_lanes_")
        stem = "lanes_" + key[:32]
        path = os.path.join(folder, stem + ".so")
        library, damaged = None, False
        if os.path.exists(path):
            # a truncated or altered library can crash the process when loaded (a bus error, not an
            # exception): only an entry whose digest matches is loaded, any other is compiled again
            damaged = not valid_entry(path)
            if not damaged:
                try:
                    library = ctypes.CDLL(path)
                    record_compile("hit")
                except OSError:
                    damaged = True
        if library is None:
            built = _build(source, folder, stem)
            if built is None:
                return None
            library = ctypes.CDLL(built)
            record_compile("rebuilt" if damaged else "compiled")
        LOADED_LIBRARIES[key] = library
        return library


class LaneSum:
    """``sum_k f(data_k, candidate)`` for many candidates, four per SIMD vector.

    Built by :meth:`build`; calling it evaluates the sums for M candidates on the data
    given at construction. The data are read in place; ctypes releases the GIL, so
    several threads may call one LaneSum on different candidates.
    """

    summed = True

    def __init__(self, function, n_out: int, n_values: int, data: np.ndarray):
        self._function = function
        self.n_out, self.n_values = n_out, n_values
        self._data = np.ascontiguousarray(data, dtype=float)
        self.n_samples = self._data.shape[0]

    @classmethod
    def build(cls, per_sample: ca.Function, data: list[np.ndarray], name: str = "lane_sum") -> "LaneSum | None":
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

        Returns
        -------
        LaneSum or None
            None without a C compiler, when ``per_sample`` has an operation with no vector
            form (see :func:`~casest.backend.lane_code.lane_source`) or compiling fails: the
            caller keeps its scalar path.
        """
        if not compiler_available():
            return None
        source = lane_source(per_sample, len(data), name, summed=cls.summed)
        if source is None:
            return None
        library = _library(source)
        if library is None:
            return None
        function = getattr(library, name)
        function.restype = None
        function.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p]
        n_values = sum(per_sample.nnz_in(k) for k in range(len(data), per_sample.n_in()))
        columns = [np.asarray(d, dtype=float).reshape(d.shape[0], -1) for d in data]
        return cls(function, per_sample.nnz_out(0), n_values, np.hstack(columns))

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
        """The C function on groups of four candidates: out (n_groups, *shape, 4)."""
        M = values.shape[0]
        groups = -(-M // LANES)
        padded = np.empty((groups * LANES, self.n_values))
        padded[:M] = values
        padded[M:] = values[-1] if M else 0.0  # the last group's spare lanes repeat a candidate
        lanes = np.ascontiguousarray(padded.reshape(groups, LANES, self.n_values).transpose(0, 2, 1))
        out = np.empty((groups, *shape, LANES))
        self._function(self._data.ctypes.data, self.n_samples, lanes.ctypes.data, groups, out.ctypes.data)
        return out


class LaneValues(LaneSum):
    """``f(data_k, candidate)`` at every sample for many candidates, four per SIMD vector
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
