"""A recursion over a record as one C function: a CasADi step ``(acc, d_k[, c]) -> (acc_next[, r_k])``
generated to C and called in a C loop over the samples, each sample's accumulator and record
written in place into the output arrays (no per-sample call from C++, no chunks).

The step's code is CasADi's own code generation, its pointer tests dropped (the loop passes every
array: :func:`~casest._casadi.generated_text.given_pointers`); the loop around it is a few lines
of C written here. The library is compiled once per source through the compile cache
(:func:`~casest._casadi.c_library.load_library`) and called through ctypes.
"""

from __future__ import annotations

import ctypes
from typing import NamedTuple

import casadi as ca
import numpy as np

from .c_library import load_library
from .generated_text import given_pointers
from .numerics import compiler_available

__all__ = ["RecordLoop", "RecordRows", "split_step"]

#: -O3 for the loop; neither -ffast-math nor fused multiply-adds: the results equal CasADi's evaluation to
#: rounding (contracted products differ by 1e-9 in the unscented filter's sigma-point sums)
_OPTIMISATION = ("-O3", "-march=native")
_FLAGS = ("-ffp-contract=off", "-shared", "-fPIC", "-fno-math-errno", "-Wl,-z,defs")

_LOOP = """
/* sample k's row of a filter's record, built from the record's own arrays (RecordRows): [y (a
   channel not finite: 0); mask; u(k); u(k); u(k + 1); t(k + 1) - t(k)], the last sample's step of
   length zero; S holds the rows [t, u] */
static void casest_signal_row(const casadi_real* Y, const casadi_real* S, long k, long n, casadi_real* d) {
  const casadi_real* y = Y + k * N_Y;
  const casadi_real* s = S + k * (N_U + 1);
  long i;
  for (i = 0; i < N_Y; ++i) { int seen = isfinite(y[i]); d[i] = seen ? y[i] : 0.0; d[N_Y + i] = seen; }
  for (i = 0; i < N_U; ++i) d[2 * N_Y + i] = s[1 + i];
  if (k + 1 < n) {
    for (i = 0; i < N_U; ++i) { d[2 * N_Y + N_U + i] = s[1 + i]; d[2 * N_Y + 2 * N_U + i] = s[N_U + 2 + i]; }
    d[2 * N_Y + 3 * N_U] = s[N_U + 1] - s[0];
  } else {
    for (i = 2 * N_Y + N_U; i < N_D; ++i) d[i] = 0.0;
  }
}

/* the loop: each sample's row read from D, or built from Y and S when Y is given */
static int casest_loop_rows(const casadi_real* D, const casadi_real* Y, const casadi_real* S, const casadi_real* c,
                            long n, casadi_real* accs, casadi_real** fields, long keep) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, k, j;
  const casadi_real** arg; casadi_real** res; casadi_int* iw; casadi_real *w, *next_acc, *row, *d_row;
  static const long widths[N_FIELDS + 1] = {FIELD_WIDTHS};
  int flag = 0;
  STEP_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**) calloc(sz_arg > 3 ? sz_arg : 3, sizeof(casadi_real*));
  res = (casadi_real**) calloc(sz_res > N_FIELDS + 1 ? sz_res : N_FIELDS + 1, sizeof(casadi_real*));
  iw = (casadi_int*) calloc(sz_iw > 1 ? sz_iw : 1, sizeof(casadi_int));
  w = (casadi_real*) calloc(sz_w > 1 ? sz_w : 1, sizeof(casadi_real));
  next_acc = (casadi_real*) calloc(N_ACC > 0 ? N_ACC : 1, sizeof(casadi_real));
  d_row = (casadi_real*) calloc(N_D > 0 ? N_D : 1, sizeof(casadi_real));
  if (!arg || !res || !iw || !w || !next_acc || !d_row) { flag = -1; goto done; }
  for (k = 0; k < n; ++k) {
    /* keep: every accumulator in its row; else two rows in turn (only the last is kept) */
    if (Y) casest_signal_row(Y, S, k, n, d_row);
    arg[0] = accs + (keep ? k : k & 1) * N_ACC; arg[1] = Y ? d_row : D + k * N_D; arg[2] = c;
    row = accs + (keep ? k + 1 : (k + 1) & 1) * N_ACC;
    res[0] = LAST_ENTRY_FIRST ? next_acc : row;
    for (j = 0; j < N_FIELDS; ++j) res[j + 1] = fields[j] + k * widths[j];
    if (STEP(arg, res, iw, w, 0)) { flag = (int) k + 1; goto done; }
    /* a step that gives the accumulator last entry first (see _source): put it back in order */
    if (LAST_ENTRY_FIRST) for (j = 0; j < N_ACC; ++j) row[j] = next_acc[N_ACC - 1 - j];
  }
done:
  free(arg); free(res); free(iw); free(w); free(next_acc); free(d_row);
  return flag;
}

/* the same loop with the accumulators and every field in one block, one after another */
static int casest_loop_block(const casadi_real* D, const casadi_real* Y, const casadi_real* S, const casadi_real* c,
                             long n, casadi_real* block, long keep) {
  casadi_real* fields[N_FIELDS + 1];
  static const long widths[N_FIELDS + 1] = {FIELD_WIDTHS};
  long j, offset = (keep ? n + 1 : 2) * N_ACC;
  for (j = 0; j < N_FIELDS; ++j) { fields[j] = block + offset; offset += n * widths[j]; }
  return casest_loop_rows(D, Y, S, c, n, block, fields, keep);
}

CASADI_SYMBOL_EXPORT int casest_record_loop(const casadi_real* D, const casadi_real* c, long n,
                                            casadi_real* accs, casadi_real** fields, long keep) {
  return casest_loop_rows(D, 0, 0, c, n, accs, fields, keep);
}

CASADI_SYMBOL_EXPORT int casest_record_loop_block(const casadi_real* D, const casadi_real* c, long n,
                                                  casadi_real* block, long keep) {
  return casest_loop_block(D, 0, 0, c, n, block, keep);
}

CASADI_SYMBOL_EXPORT int casest_record_loop_signals(const casadi_real* Y, const casadi_real* S, const casadi_real* c,
                                                    long n, casadi_real* accs, casadi_real** fields, long keep) {
  return casest_loop_rows(0, Y, S, c, n, accs, fields, keep);
}

CASADI_SYMBOL_EXPORT int casest_record_loop_signals_block(const casadi_real* Y, const casadi_real* S,
                                                          const casadi_real* c, long n, casadi_real* block, long keep) {
  return casest_loop_block(0, Y, S, c, n, block, keep);
}
"""


def split_step(step: ca.Function, widths=None) -> ca.Function:
    """``step`` with dense outputs and its record split into fields of ``widths`` entries (the loop
    writes each field of every sample into an array of its own).

    Parameters
    ----------
    step : casadi.Function
        ``(acc, d[, c]) -> (acc_next[, record])``.
    widths : sequence of int, optional
        The record's fields, in order; default the whole record as one field.

    Returns
    -------
    casadi.Function
        ``(acc, d[, c]) -> (acc_next, field_1, ..., field_m)``, all dense.
    """
    n_record = step.numel_out(1) if step.n_out() > 1 else 0
    widths = [n_record] if widths is None and n_record else list(widths or [])
    if sum(widths) != n_record:
        raise ValueError(f"{step.name()}: fields of {sum(widths)} entries for a record of {n_record}")
    inputs = step.sx_in() if step.is_a("SXFunction") else step.mx_in()
    outputs = step(*inputs)
    outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
    fields = ca.vertsplit(ca.densify(outputs[1]), np.cumsum([0] + widths).tolist()) if widths else []
    return ca.Function(step.name() + "_fields", inputs, [ca.densify(outputs[0])] + fields)


class RecordRows(NamedTuple):
    """A filter's record as it is stored, for a loop that builds each sample's row itself
    (``RecordLoop.build(..., signal_rows=(n_outputs, n_inputs))``): the row of sample k is
    ``[y (a channel not finite: 0); mask of the finite channels; u(k); u(k); u(k + 1); t(k + 1) - t(k)]``,
    the last sample's interval inputs and step zero (the columns of
    :func:`casest.filters.compiled_passes.record_columns` for a model whose intervals take the
    inputs at their ends), without an array of those rows.

    Attributes
    ----------
    outputs : ndarray, shape (N, n_outputs)
        NaN or another non-finite value: not measured.
    signals : ndarray, shape (N, 1 + n_inputs)
        Time (s) and the inputs, as :attr:`casest.Dataset.signals`.
    """

    outputs: np.ndarray
    signals: np.ndarray

    def columns(self) -> np.ndarray:
        """The rows as one array, shape (N, 2 n_outputs + 3 n_inputs + 1) (the loop's equal, for a
        path without it)."""
        Y, S = np.asarray(self.outputs, dtype=float), np.asarray(self.signals, dtype=float)
        N, ny, nu = Y.shape[0], Y.shape[1], S.shape[1] - 1
        seen = np.isfinite(Y)
        D = np.zeros((N, 2 * ny + 3 * nu + 1))
        D[:, :ny], D[:, ny:2 * ny], D[:, 2 * ny:2 * ny + nu] = np.where(seen, Y, 0.0), seen, S[:, 1:]
        if N > 1:
            a = 2 * ny + nu
            D[:-1, a:a + nu], D[:-1, a + nu:a + 2 * nu], D[:-1, -1] = S[:-1, 1:], S[1:, 1:], np.diff(S[:, 0])
        return D


def _source(step: ca.Function, last_entry_first: bool, signal_rows: tuple = (0, 0)) -> str:
    """The step's generated C followed by the loop, with the step's name and sizes substituted
    (``signal_rows``: the outputs and inputs of a :class:`RecordRows` row, or zeros).

    With ``last_entry_first`` the generated step gives the next accumulator last entry first (the
    loop puts it back in order): CasADi orders the code by a depth-first walk from the outputs, and a
    walk that starts from the accumulator's last entries (a filter's covariance, which needs the
    tangent and the state) lays the state's chain of calls out between the tangent's arithmetic,
    which the processor overlaps; the operations, and so the results, are the same.
    """
    if last_entry_first:
        inputs = step.sx_in() if step.is_a("SXFunction") else step.mx_in()
        outputs = step(*inputs)
        outputs = list(outputs) if isinstance(outputs, (list, tuple)) else [outputs]
        reverse = list(range(step.nnz_out(0) - 1, -1, -1))
        step = ca.Function(step.name(), inputs, [outputs[0][reverse]] + outputs[1:])
    gen = ca.CodeGenerator(step.name() + ".c", {"prefix": "casest_loop_"})
    gen.add(step)
    widths = [step.nnz_out(k) for k in range(1, step.n_out())]
    sizes = {"LAST_ENTRY_FIRST": str(int(last_entry_first)), "STEP": step.name(), "N_D": str(step.nnz_in(1)),
             "N_Y": str(signal_rows[0]), "N_U": str(signal_rows[1]), "N_ACC": str(step.nnz_out(0)),
             "N_FIELDS": str(len(widths)), "FIELD_WIDTHS": ", ".join(map(str, widths + [0]))}
    loop = _LOOP
    for name, value in sizes.items():
        loop = loop.replace(name, value)
    return "#include <math.h>\n#include <stdlib.h>\n" + given_pointers(gen.dump()) + loop


class RecordLoop:
    """A step repeated over the rows of a record in one compiled C loop.

    Built by :meth:`build` from a step ``(acc, d_k[, c]) -> (acc_next[, record_k])`` with dense
    column inputs; calling it returns the accumulator before and after every sample and each
    field of every sample's record, as CasADi's ``mapaccum`` of the step would, every array
    contiguous (the loop writes into them in place).
    """

    def __init__(self, library, step: ca.Function, signal_rows: tuple | None = None):
        # the C entries by (rows read from D or built from RecordRows, fields by pointers or in one block)
        self._entries = {}
        for rows, leading in (("d", 1), ("signals", 2)):
            for form, outputs in (("pointers", 2), ("block", 1)):
                function = getattr(library, "casest_record_loop" + ("_signals" if rows == "signals" else "")
                                   + ("_block" if form == "block" else ""))
                function.restype = ctypes.c_int
                function.argtypes = ([ctypes.c_void_p] * (leading + 1) + [ctypes.c_long]
                                     + [ctypes.c_void_p] * outputs + [ctypes.c_long])
                self._entries[rows, form] = function
        self.signal_rows = signal_rows
        self.n_acc, self.n_d = step.nnz_out(0), step.nnz_in(1)
        self.n_c = step.nnz_in(2) if step.n_in() > 2 else 0
        self.widths = [step.nnz_out(k) for k in range(1, step.n_out())]
        starts = np.cumsum([0] + self.widths).tolist()
        self._field_starts = list(zip(starts[:-1], self.widths))  # (first column, width) in a record row
        self._record_width = starts[-1]

    @classmethod
    def build(cls, step: ca.Function, widths=None, optimisation=_OPTIMISATION,
              cached_only: bool = False, last_entry_first: bool = False,
              signal_rows: tuple | None = None) -> "RecordLoop | None":
        """The compiled loop of ``step``, or None (no C compiler, no C code for the step, a
        failed compile, inputs that are not dense columns): the caller keeps its own path.

        Parameters
        ----------
        step : casadi.Function
            ``(acc, d[, c]) -> (acc_next[, record])``; ``acc`` and ``acc_next`` of one size.
        widths : sequence of int, optional
            The record's fields (:func:`split_step`); default one field.
        optimisation : tuple of str
            The compiler's optimisation flags (default ``-O3 -march=native``; a large step, such
            as a sensitivity pass's, compiles far faster at ``-O1``).
        cached_only : bool
            Only a loop already compiled (in this process or the compile cache); never compile.
        last_entry_first : bool
            Generate the step's next accumulator last entry first (the same results): a filter's
            step, whose covariance needs the state's chain of evaluations, then runs faster; a large
            sensitivity step keeps CasADi's order (reordered, its compile took longer).
        signal_rows : (n_outputs, n_inputs), optional
            The loop can also build each sample's row itself from a :class:`RecordRows` (a
            filter's record: no array of rows, no pass over the record in Python); ``d`` then has
            ``2 n_outputs + 3 n_inputs + 1`` entries.

        Returns
        -------
        RecordLoop or None

        Raises
        ------
        ValueError
            ``signal_rows`` that do not give the step's row size.
        """
        if signal_rows is not None and step.numel_in(1) != 2 * signal_rows[0] + 3 * signal_rows[1] + 1:
            raise ValueError(f"{step.name()}: rows of {step.numel_in(1)} entries, not those of {signal_rows[0]} "
                             f"outputs and {signal_rows[1]} inputs (2 n_outputs + 3 n_inputs + 1)")
        if not compiler_available() or step.n_in() not in (2, 3) or step.n_out() not in (1, 2):
            return None
        if any(not step.sparsity_in(k).is_dense() for k in range(step.n_in())) or step.numel_in(0) != step.numel_out(0):
            return None
        step = split_step(step, widths)
        try:
            source = _source(step, last_entry_first, tuple(signal_rows or (0, 0)))
        except RuntimeError:  # a step CasADi cannot generate C for
            return None
        library = load_library(source, tuple(optimisation) + _FLAGS, prefix="loop_", cached_only=cached_only)
        if library is None:
            return None
        return cls(library, step, signal_rows)

    def __call__(self, acc0: np.ndarray, D: np.ndarray | RecordRows, c: np.ndarray | None = None,
                 keep_accumulators: bool = True, out: tuple | None = None) -> tuple:
        """Run the step over the rows of ``D`` from ``acc0``.

        Parameters
        ----------
        acc0 : ndarray, shape (n_acc,)
        D : ndarray, shape (N, n_d), or RecordRows
            One row per sample, or the record the loop builds them from (a loop built with
            ``signal_rows``).
        c : ndarray, shape (n_c,), optional
            The constants every step reads.
        keep_accumulators : bool
            Keep the accumulator after every sample (default); False: only the last (a pass
            whose records hold what it needs writes two rows instead of N + 1).
        out : (accs, fields), optional
            Arrays of an earlier call with the same N (as it returned them: C-contiguous float64
            of the shapes below) to write into instead of new ones: a pass repeated over records
            of one length touches no fresh memory.

        Returns
        -------
        accs : ndarray, shape (N + 1, n_acc), or (1, n_acc) without ``keep_accumulators``
            ``acc0``, then the accumulator after each sample (or only after the last).
        fields : list of ndarray, shapes (N, width)
            The record's fields at every sample.
        """
        if type(D) is RecordRows:
            kind, record = "signals", self._record_arrays(D)
        else:
            kind, record = "d", (_contiguous(D).reshape(-1, self.n_d),)
        N = record[0].shape[0]
        c = _contiguous(np.zeros(0) if c is None else c).reshape(self.n_c)
        rows = N + 1 if keep_accumulators else 2
        addresses = tuple(_address(a) for a in record) + (_address(c) if self.n_c else None, N)
        if out is None:
            block, accs, fields = self._fresh_arrays(rows, N)
            block[:self.n_acc] = np.asarray(acc0, dtype=float).reshape(self.n_acc)
            flag = self._entries[kind, "block"](*addresses, _address(block), int(keep_accumulators))
        else:
            accs, fields = self._checked_out(out, [(rows, self.n_acc)] + [(N, w) for w in self.widths])
            accs[0] = np.asarray(acc0, dtype=float).reshape(self.n_acc)
            pointers = (ctypes.c_void_p * max(len(fields), 1))(*[f.ctypes.data for f in fields])
            flag = self._entries[kind, "pointers"](*addresses, accs.ctypes.data, pointers, int(keep_accumulators))
        if flag < 0:
            raise MemoryError("the record loop could not allocate the step's work arrays")
        if flag > 0:
            raise RuntimeError(f"the step failed at sample {flag - 1}")
        return (accs if keep_accumulators else accs[N % 2][None, :]), fields

    def _record_arrays(self, record: RecordRows) -> tuple:
        """The outputs and signals of ``record`` as C-contiguous float64 arrays, their shapes checked
        against the loop's ``signal_rows`` (ValueError: a loop built without them, other sizes)."""
        if self.signal_rows is None:
            raise ValueError("this record loop reads rows of D: build it with signal_rows to give it a RecordRows")
        ny, nu = self.signal_rows
        Y, S = _contiguous(record.outputs), _contiguous(record.signals)
        if Y.ndim != 2 or S.ndim != 2 or Y.shape[1] != ny or S.shape != (Y.shape[0], nu + 1):
            raise ValueError(f"RecordRows: outputs of shape (N, {ny}) and signals of shape (N, {nu + 1}) for this "
                             f"loop, got {Y.shape} and {S.shape}")
        return Y, S

    def _fresh_arrays(self, rows: int, N: int) -> tuple:
        """One new block holding the accumulators' rows and then every field's N rows, in the order
        the C loop's block entry lays them out, and the views of it (a short record's call costs
        tens of microseconds: one allocation, not one per array)."""
        n0 = rows * self.n_acc
        block = np.empty(n0 + N * self._record_width)
        fields = [block[n0 + N * a:n0 + N * (a + w)].reshape(N, w) for a, w in self._field_starts]
        return block, block[:n0].reshape(rows, self.n_acc), fields

    def _checked_out(self, out: tuple, shapes: list) -> tuple:
        """``out``'s accumulators and fields, raising ValueError unless they are what the loop writes."""
        accs, fields = out[0], list(out[1])
        if len(fields) != len(self.widths) or any(
                a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous or not a.flags.writeable
                for a, shape in zip([accs] + fields, shapes)):
            raise ValueError(f"out: the record loop writes arrays of shapes {shapes} (C-contiguous float64), got "
                             f"{[getattr(a, 'shape', None) for a in [accs] + fields]}")
        return accs, fields


def _address(a: np.ndarray) -> int:
    """The address of a C-contiguous array's first element (through the buffer protocol for a
    writable array: a third of the time of ``a.ctypes.data``, which a short record's call feels)."""
    if a.flags.writeable and a.size:
        return ctypes.addressof(ctypes.c_char.from_buffer(a))
    return a.ctypes.data


def _contiguous(a) -> np.ndarray:
    """``a`` as a C-contiguous float64 array, copied only when it is not one already."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=float)
