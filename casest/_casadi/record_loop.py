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

import casadi as ca
import numpy as np

from .c_library import load_library
from .generated_text import given_pointers
from .numerics import compiler_available

__all__ = ["RecordLoop", "split_step"]

#: -O3 for the loop; neither -ffast-math nor fused multiply-adds: the results equal CasADi's evaluation to
#: rounding (contracted products differ by 1e-9 in the unscented filter's sigma-point sums)
_OPTIMISATION = ("-O3", "-march=native")
_FLAGS = ("-ffp-contract=off", "-shared", "-fPIC", "-fno-math-errno", "-Wl,-z,defs")

_LOOP = """
CASADI_SYMBOL_EXPORT int casest_record_loop(const casadi_real* D, const casadi_real* c, long n,
                                            casadi_real* accs, casadi_real** fields, long keep) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, k, j;
  const casadi_real** arg; casadi_real** res; casadi_int* iw; casadi_real *w, *next_acc, *row;
  static const long widths[N_FIELDS + 1] = {FIELD_WIDTHS};
  int flag = 0;
  STEP_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**) calloc(sz_arg > 3 ? sz_arg : 3, sizeof(casadi_real*));
  res = (casadi_real**) calloc(sz_res > N_FIELDS + 1 ? sz_res : N_FIELDS + 1, sizeof(casadi_real*));
  iw = (casadi_int*) calloc(sz_iw > 1 ? sz_iw : 1, sizeof(casadi_int));
  w = (casadi_real*) calloc(sz_w > 1 ? sz_w : 1, sizeof(casadi_real));
  next_acc = (casadi_real*) calloc(N_ACC > 0 ? N_ACC : 1, sizeof(casadi_real));
  if (!arg || !res || !iw || !w || !next_acc) { flag = -1; goto done; }
  for (k = 0; k < n; ++k) {
    /* keep: every accumulator in its row; else two rows in turn (only the last is kept) */
    arg[0] = accs + (keep ? k : k & 1) * N_ACC; arg[1] = D + k * N_D; arg[2] = c;
    row = accs + (keep ? k + 1 : (k + 1) & 1) * N_ACC;
    res[0] = LAST_ENTRY_FIRST ? next_acc : row;
    for (j = 0; j < N_FIELDS; ++j) res[j + 1] = fields[j] + k * widths[j];
    if (STEP(arg, res, iw, w, 0)) { flag = (int) k + 1; goto done; }
    /* a step that gives the accumulator last entry first (see _source): put it back in order */
    if (LAST_ENTRY_FIRST) for (j = 0; j < N_ACC; ++j) row[j] = next_acc[N_ACC - 1 - j];
  }
done:
  free(arg); free(res); free(iw); free(w); free(next_acc);
  return flag;
}

/* the same loop with the accumulators and every field in one block, one after another */
CASADI_SYMBOL_EXPORT int casest_record_loop_block(const casadi_real* D, const casadi_real* c, long n,
                                                  casadi_real* block, long keep) {
  casadi_real* fields[N_FIELDS + 1];
  static const long widths[N_FIELDS + 1] = {FIELD_WIDTHS};
  long j, offset = (keep ? n + 1 : 2) * N_ACC;
  for (j = 0; j < N_FIELDS; ++j) { fields[j] = block + offset; offset += n * widths[j]; }
  return casest_record_loop(D, c, n, block, fields, keep);
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


def _source(step: ca.Function, last_entry_first: bool) -> str:
    """The step's generated C followed by the loop, with the step's name and sizes substituted.

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
             "N_ACC": str(step.nnz_out(0)), "N_FIELDS": str(len(widths)), "FIELD_WIDTHS": ", ".join(map(str, widths + [0]))}
    loop = _LOOP
    for name, value in sizes.items():
        loop = loop.replace(name, value)
    return "#include <stdlib.h>\n" + given_pointers(gen.dump()) + loop


class RecordLoop:
    """A step repeated over the rows of a record in one compiled C loop.

    Built by :meth:`build` from a step ``(acc, d_k[, c]) -> (acc_next[, record_k])`` with dense
    column inputs; calling it returns the accumulator before and after every sample and each
    field of every sample's record, as CasADi's ``mapaccum`` of the step would, every array
    contiguous (the loop writes into them in place).
    """

    def __init__(self, function, block_function, step: ca.Function):
        self._function, self._block_function = function, block_function
        self.n_acc, self.n_d = step.nnz_out(0), step.nnz_in(1)
        self.n_c = step.nnz_in(2) if step.n_in() > 2 else 0
        self.widths = [step.nnz_out(k) for k in range(1, step.n_out())]
        starts = np.cumsum([0] + self.widths).tolist()
        self._field_starts = list(zip(starts[:-1], self.widths))  # (first column, width) in a record row
        self._record_width = starts[-1]

    @classmethod
    def build(cls, step: ca.Function, widths=None, optimisation=_OPTIMISATION,
              cached_only: bool = False, last_entry_first: bool = False) -> "RecordLoop | None":
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

        Returns
        -------
        RecordLoop or None
        """
        if not compiler_available() or step.n_in() not in (2, 3) or step.n_out() not in (1, 2):
            return None
        if any(not step.sparsity_in(k).is_dense() for k in range(step.n_in())) or step.numel_in(0) != step.numel_out(0):
            return None
        step = split_step(step, widths)
        try:
            source = _source(step, last_entry_first)
        except RuntimeError:  # a step CasADi cannot generate C for
            return None
        library = load_library(source, tuple(optimisation) + _FLAGS, prefix="loop_", cached_only=cached_only)
        if library is None:
            return None
        function, block_function = library.casest_record_loop, library.casest_record_loop_block
        function.restype = block_function.restype = ctypes.c_int
        function.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                             ctypes.c_long]
        block_function.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_long]
        return cls(function, block_function, step)

    def __call__(self, acc0: np.ndarray, D: np.ndarray, c: np.ndarray | None = None,
                 keep_accumulators: bool = True, out: tuple | None = None) -> tuple:
        """Run the step over the rows of ``D`` from ``acc0``.

        Parameters
        ----------
        acc0 : ndarray, shape (n_acc,)
        D : ndarray, shape (N, n_d)
            One row per sample.
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
        D = _contiguous(D).reshape(-1, self.n_d)
        c = _contiguous(np.zeros(0) if c is None else c).reshape(self.n_c)
        N = D.shape[0]
        rows = N + 1 if keep_accumulators else 2
        addresses = (_address(D), _address(c) if self.n_c else None, N)
        if out is None:
            block, accs, fields = self._fresh_arrays(rows, N)
            block[:self.n_acc] = np.asarray(acc0, dtype=float).reshape(self.n_acc)
            flag = self._block_function(*addresses, _address(block), int(keep_accumulators))
        else:
            accs, fields = self._checked_out(out, [(rows, self.n_acc)] + [(N, w) for w in self.widths])
            accs[0] = np.asarray(acc0, dtype=float).reshape(self.n_acc)
            pointers = (ctypes.c_void_p * max(len(fields), 1))(*[f.ctypes.data for f in fields])
            flag = self._function(*addresses, accs.ctypes.data, pointers, int(keep_accumulators))
        if flag < 0:
            raise MemoryError("the record loop could not allocate the step's work arrays")
        if flag > 0:
            raise RuntimeError(f"the step failed at sample {flag - 1}")
        return (accs if keep_accumulators else accs[N % 2][None, :]), fields

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
